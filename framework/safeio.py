"""Writing output files safely: never through a symbolic link, never into a device or
a pipe, and a failed write (a full disk) names the file.

A planted link (``report.html -> ~/.bashrc``) would otherwise redirect the write to
wherever it points; :func:`open_for_write` opens with ``O_NOFOLLOW`` and refuses an
existing path that is not a regular file, with an :class:`~spherecal.errors.InputError`
naming the path. Every writer of the report, its figures, the exports and PLY files
goes through here (the dataset and result writers write a new temporary file and
rename it into place, which replaces a link instead of following it).
"""

from __future__ import annotations

import errno
import os
import stat
from pathlib import Path
from typing import BinaryIO

from .errors import FileWriteError, InputError

_NOFOLLOW = getattr(os, "O_NOFOLLOW", 0)


def check_writable_target(path: str | os.PathLike) -> None:
    """Raise InputError when ``path`` exists as a symbolic link or as anything but a
    regular file (a folder, a device, a pipe)."""
    try:
        st = os.lstat(path)
    except FileNotFoundError:
        return
    if stat.S_ISLNK(st.st_mode):
        raise InputError(f"{os.fspath(path)} is a symbolic link: spherecal does not write through links (a planted "
                         "link would redirect the write); remove the link or choose another output folder")
    if not stat.S_ISREG(st.st_mode):
        raise InputError(f"{os.fspath(path)} exists and is not a regular file: remove it or choose another "
                         "output folder")


def open_for_write(path: str | os.PathLike, *, exclusive: bool = False) -> BinaryIO:
    """``open(path, "wb")`` that never follows a symbolic link (``exclusive``: the file
    must not exist yet)."""
    check_writable_target(path)
    flags = os.O_WRONLY | os.O_CREAT | _NOFOLLOW | (os.O_EXCL if exclusive else os.O_TRUNC)
    try:
        fd = os.open(path, flags, 0o666)
    except OSError as exc:
        if exc.errno == errno.ELOOP:
            check_writable_target(path)  # a link planted since the check
        if exc.errno == errno.EEXIST:
            raise FileExistsError(f"{os.fspath(path)} exists (nothing is overwritten)") from None
        raise FileWriteError(f"{os.fspath(path)}: cannot write ({exc.strerror or exc})") from None
    return os.fdopen(fd, "wb")


def write_bytes(path: str | os.PathLike, data: bytes) -> None:
    """Write ``data`` to ``path`` (replacing a regular file, never through a link); a
    failed write (e.g. a full disk) raises FileWriteError naming the file."""
    with open_for_write(path) as f:
        try:
            f.write(data)
            f.flush()
        except OSError as exc:
            raise FileWriteError(f"{os.fspath(path)}: cannot write ({exc.strerror or exc})") from None


def write_text(path: str | os.PathLike, text: str) -> None:
    write_bytes(path, text.encode("utf-8"))


def is_inside(path: Path, folder: Path) -> bool:
    """True when ``path`` (resolved) lies within ``folder`` (resolved)."""
    try:
        Path(os.path.realpath(path)).relative_to(os.path.realpath(folder))
    except ValueError:
        return False
    return True
