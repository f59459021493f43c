"""spherecal's messages, through the standard library's :mod:`logging`.

Every message goes to a logger named under ``spherecal``: ``spherecal.run`` for what
the commands do (the plan, the devices, the acquisition, the solution, the files
written), ``spherecal.cli`` for what the command line prints (its result summaries).
Importing spherecal installs no handler and sets no level: an application embedding it
routes the messages as it likes (``logging.getLogger("spherecal").addHandler(...)``).
Without any handler, Python shows warnings and errors only (its last-resort handler).

The command line (:mod:`spherecal.cli`) installs, for the length of one command, a
console handler on standard error (``-v`` adds debug messages, ``-q`` keeps warnings
and errors only) and a :class:`RunRecord`, which collects every message of the run and
appends it to ``run.log`` in the run's output folder (docs/cli.md, "Logging").
"""

from __future__ import annotations

import logging
import os
from datetime import datetime, timezone
from pathlib import Path
from typing import Callable

ROOT = "spherecal"
RUN_LOG_NAME = "run.log"


def logger(name: str = "run") -> logging.Logger:
    """The logger ``spherecal.<name>`` (``name`` may itself hold dots)."""
    return logging.getLogger(f"{ROOT}.{name}" if name else ROOT)


class Notice(str):
    """A message the operator must see even with ``-q`` (e.g. what is about to move before
    a typed confirmation): a plain ``str`` to any ``log`` callable, logged at WARNING by
    :func:`progress_log`."""


def progress_log(name: str = "run") -> Callable[[str], None]:
    """A ``log(message)`` callable, as the runner's functions take, that logs to
    ``spherecal.<name>``: at WARNING for a :class:`Notice` or a message starting with
    ``warning``, else INFO."""
    lg = logger(name)

    def log(message: str) -> None:
        important = isinstance(message, Notice) or str(message).lower().startswith("warning")
        level = logging.WARNING if important else logging.INFO
        lg.log(level, "%s", message)

    return log


class RunRecord(logging.Handler):
    """Collects the messages of one run (every level) in memory, with their UTC time,
    so that they can be appended to the run's ``run.log`` once its output folder is
    known and exists (:meth:`append_to`). ``note`` adds a line that went to the console
    by other means (a result summary on standard output)."""

    def __init__(self) -> None:
        super().__init__(logging.DEBUG)
        self.lines: list[str] = []

    @staticmethod
    def _stamp(created: float) -> str:
        return datetime.fromtimestamp(created, timezone.utc).strftime("%Y-%m-%dT%H:%M:%S.%fZ")[:-4] + "Z"

    def emit(self, record: logging.LogRecord) -> None:
        try:
            text = record.getMessage()
        except Exception:  # noqa: BLE001 - a bad message must not stop the run
            text = str(record.msg)
        self._add(record.created, record.levelname, record.name, text)

    def note(self, text: str, source: str = "spherecal.cli") -> None:
        """Record ``text`` (printed to the console by the caller) as an INFO line."""
        import time

        self._add(time.time(), "INFO", source, text)

    def _add(self, created: float, level: str, name: str, text: str) -> None:
        stamp = self._stamp(created)
        for i, line in enumerate(str(text).splitlines() or [""]):
            self.lines.append(f"{stamp} {level:<7} {name}: {line}" if i == 0 else f"{'':{len(stamp)}}   {line}")

    def append_to(self, folder: Path) -> Path | None:
        """Append the collected lines to ``folder/run.log`` (created when missing; never
        through a symbolic link). Returns the file, or None when ``folder`` does not
        exist (a run that stopped before making it)."""
        if not folder.is_dir():
            return None
        from spherecal.io.files import append_text

        path = folder / RUN_LOG_NAME
        append_text(path, "\n".join(self.lines) + "\n")
        return path


def describe_file(path: Path | str | None) -> str:
    """``path (sha256 <hex>)`` for the record of a run; ``path (not a regular file)`` for a
    device or a pipe (never read: /dev/zero has no end), ``path (unreadable: why)``."""
    if path is None:
        return "none"
    import hashlib
    import stat

    try:
        if not stat.S_ISREG(os.stat(path).st_mode):
            return f"{os.fspath(path)} (not a regular file)"
        h = hashlib.sha256()
        with open(path, "rb") as f:
            for block in iter(lambda: f.read(1 << 20), b""):
                h.update(block)
        return f"{os.fspath(path)} (sha256 {h.hexdigest()})"
    except OSError as exc:
        return f"{os.fspath(path)} (unreadable: {exc.strerror or exc})"


def file_text_for_record(path: Path | str, max_bytes: int = 1 << 20) -> str:
    """The text of a regular file (a configuration) for the record of a run, at most
    ``max_bytes``; empty for a device, a pipe or an unreadable file (never read twice)."""
    import stat

    try:
        if not stat.S_ISREG(os.stat(path).st_mode):
            return ""
        with open(path, "rb") as f:
            data = f.read(max_bytes + 1)
    except OSError:
        return ""
    text = data[:max_bytes].decode("utf-8", errors="replace")
    return text + ("\n[... cut at %d bytes]" % max_bytes if len(data) > max_bytes else "")
