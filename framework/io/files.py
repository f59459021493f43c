"""Writing output files safely: never through a symbolic link, never into a device or
a pipe, and a failed write (a full disk) names the file.

A planted link (``report.html -> ~/.bashrc``) would otherwise redirect the write to
wherever it points; :func:`open_for_write` opens with ``O_NOFOLLOW`` and refuses an
existing path that is not a regular file, with an :class:`~spherecal.core.errors.InputError`
naming the path. Every writer of the report, its figures, the exports and PLY files
goes through here (the dataset and result writers write a new temporary file and
rename it into place, which replaces a link instead of following it).
"""

from __future__ import annotations

import errno
import hashlib
import os
import stat
from pathlib import Path
from typing import BinaryIO

from spherecal.core.errors import FileWriteError, InputError

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


def append_text(path: str | os.PathLike, text: str) -> None:
    """Append ``text`` (UTF-8) to ``path``, creating it when missing; never through a
    symbolic link (:func:`check_writable_target`); a failed write names the file."""
    check_writable_target(path)
    try:
        fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_APPEND | _NOFOLLOW, 0o666)
    except OSError as exc:
        if exc.errno == errno.ELOOP:
            check_writable_target(path)
        raise FileWriteError(f"{os.fspath(path)}: cannot write ({exc.strerror or exc})") from None
    with os.fdopen(fd, "ab") as f:
        try:
            f.write(text.encode("utf-8"))
            f.flush()
        except OSError as exc:
            raise FileWriteError(f"{os.fspath(path)}: cannot write ({exc.strerror or exc})") from None


def check_output_folder_writable(folder: str | os.PathLike, hint: str = "") -> None:
    """Raise :class:`~spherecal.core.errors.FileWriteError` naming ``folder`` when the files of
    a run could not be written into it: the check a command makes before it reads,
    solves or moves anything, so that it does not fail with the work done. An existing
    folder is probed by creating and removing a file in it (what permissions alone do not
    show: a read-only or immutable file system, a folder root cannot write either); for
    a folder not made yet, the nearest existing folder above it must be a writable folder
    (nothing is written there). ``hint`` ends the message (what to do instead)."""
    target = Path(folder)
    end = f": {hint}" if hint else ""
    if target.exists():
        if not target.is_dir():
            raise FileWriteError(f"{os.fspath(target)}: not a folder, cannot hold the run's files{end}")
        probe = target / f".spherecal-write-check-{os.getpid()}"
        try:
            fd = os.open(probe, os.O_WRONLY | os.O_CREAT | os.O_EXCL | _NOFOLLOW, 0o600)
        except OSError as exc:
            raise FileWriteError(f"{os.fspath(target)}: cannot write into this folder "
                                 f"({exc.strerror or exc}){end}") from None
        os.close(fd)
        os.unlink(probe)
        return
    above = target.parent
    while not above.exists() and above != above.parent:
        above = above.parent
    if not above.is_dir() or not os.access(above, os.W_OK | os.X_OK):
        raise FileWriteError(f"{os.fspath(target)}: cannot be made ({os.fspath(above)} is not a writable "
                             f"folder){end}")


def is_inside(path: Path, folder: Path) -> bool:
    """True when ``path`` (resolved) lies within ``folder`` (resolved)."""
    try:
        Path(os.path.realpath(path)).relative_to(os.path.realpath(folder))
    except ValueError:
        return False
    return True


#: Largest input file read whole (a dataset of 100 000 profiles of 3200 points is ~10 GB
#: in text; this bound is for what is read into memory at once).
MAX_INPUT_BYTES = 8 << 30


def check_input(path: str | os.PathLike, error: type[Exception], what: str) -> os.stat_result:
    """Raise ``error`` naming ``path`` unless it is an existing regular file."""
    name = os.fspath(path)
    try:
        st = os.stat(path)
    except FileNotFoundError:
        raise error(f"{name}: " + (f"cannot read {what} (no such file)" if what.startswith("the ") else
                                   "no such file")) from None
    except OSError as exc:
        raise error(f"{name}: cannot read {what} ({exc.strerror or exc})") from None
    if stat.S_ISDIR(st.st_mode):
        raise error(f"{name}: is a directory, expected {what}") from None
    if not stat.S_ISREG(st.st_mode):
        raise error(f"{name}: is not a regular file (a device, a pipe or a socket); expected {what}")
    return st


def read_input(path: str | os.PathLike, error: type[Exception], what: str, max_bytes: int = MAX_INPUT_BYTES) -> bytes:
    """The bytes of an input file, refusing what is not a regular file (a device such as
    /dev/zero, a pipe, a folder) before opening it, so that nothing endless is read.
    ``error`` is the exception class raised (its message names the file); ``what``
    says what the file should be ("a dataset file")."""
    name = os.fspath(path)
    st = check_input(path, error, what)
    if st.st_size > max_bytes:
        raise error(f"{name}: {st.st_size} bytes is larger than {what} can be (at most {max_bytes} bytes)")
    try:
        with open(path, "rb") as f:
            # the size it has now (reading max_bytes + 1 at once would reserve that much
            # memory first), then whatever it grew by since, up to the limit
            parts = [f.read(min(st.st_size, max_bytes) + 1)]
            size = len(parts[0])
            while size <= max_bytes and (more := f.read(min(1 << 24, max_bytes + 1 - size))):
                parts.append(more)
                size += len(more)
            data = parts[0] if len(parts) == 1 else b"".join(parts)
    except OSError as exc:
        raise error(f"{name}: cannot read ({exc.strerror or exc})") from None
    if len(data) > max_bytes:
        raise error(f"{name}: larger than {what} can be (at most {max_bytes} bytes)")
    return data


def text_encoding_problem(data: bytes) -> str | None:
    """Why ``data`` is not UTF-8 text with LF line ends, in words, or None: a UTF-16 or
    UTF-32 file, binary data (NUL bytes), CR-only line ends."""
    head = data[:4096]
    if b"\x00" in head:  # a zero-filled tail is what a crash leaves (judged elsewhere): not counted here
        head = data.rstrip(b"\x00")[:4096]
    if head.startswith((b"\xff\xfe", b"\xfe\xff")):
        return "it is UTF-16 (or UTF-32) text; save it as UTF-8 (e.g. iconv -f UTF-16 -t UTF-8)"
    if b"\x00" in head:
        even, odd = head[0::2].count(0), head[1::2].count(0)
        if len(head) > 8 and max(even, odd) > 0.4 * len(head) / 2 and min(even, odd) < 0.1 * len(head) / 2:
            return "it looks like UTF-16 text without a byte order mark; save it as UTF-8"
        return "it holds NUL bytes: binary data, not text"
    if b"\r" in data and b"\n" not in data:
        return "its lines end in CR only (old Mac style); convert the line ends to LF (or CR LF)"
    return None


def sha256_of(path: str | Path) -> str:
    """SHA-256 of a file's bytes, hex (read a megabyte at a time)."""
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()
