"""One command's console state, passed to the command: where human text goes, the run's
record, the output folder and the ``--json`` summary being built."""

from __future__ import annotations

import sys
from dataclasses import dataclass, field
from pathlib import Path

from spherecal.io.files import check_output_folder_writable
from spherecal.io.runlog import RunRecord, describe_file, file_text_for_record


@dataclass
class Session:
    """One command's console state: where human text goes (standard output, or standard
    error with --json), the run's record (for run.log), the output folder, the --json
    summary being built, and the run's plugin host when the command line needed it
    before the command (compare and validate offer the robot types' own options)."""

    json: bool = False
    quiet: bool = False
    record: RunRecord | None = None
    host: object | None = None
    out_dir: Path | None = None
    summary: dict = field(default_factory=dict)
    before: dict = field(default_factory=dict)
    out_existed: bool = False
    #: The command that continues this run after an interruption (calibrate sets it).
    resume_command: str = ""

    def say(self, text: str) -> None:
        """Human output: standard output (standard error with --json), and the run's record."""
        print(text, file=sys.stderr if self.json else sys.stdout)
        if self.record is not None:
            self.record.note(text)

    def note(self, text: str) -> None:
        """Text for the run's record only (run.log), not printed: what ``-v`` would have shown."""
        if self.record is not None:
            self.record.note(text)

    def err(self, msg: str) -> None:
        """An error line on standard error, in the record and (the first) in the summary."""
        print(f"spherecal: error: {msg}", file=sys.stderr)
        if self.record is not None:
            self.record.note(f"error: {msg}", "spherecal.cli")
        self.summary.setdefault("error", msg)

    def progress_stream(self):
        """Where progress bars go: standard error (None), or nowhere with -q."""
        return _Discard() if self.quiet else None

    def note_file(self, what: str, path: str | Path, with_text: bool = False) -> None:
        """The run's record names an input file (its hash), with its text when asked."""
        if self.record is not None:
            text = f"{what}: {describe_file(path)}"
            self.record.note(text + "\n" + file_text_for_record(path) if with_text else text)

    def run_folder(self, out: Path) -> None:
        """The command's output folder: run.log goes there, and the files written in it are
        listed in the --json summary."""
        check_output_folder_writable(out, "give another folder with --out")  # before any work
        self.out_dir = out
        self.out_existed = out.is_dir()
        self.before = _snapshot(out)

    def files_written(self) -> dict[str, str]:
        """The files of the output folder this command wrote or changed."""
        out = self.out_dir
        if out is None:
            return {}
        now = _snapshot(out)
        return {name: str(out / name) for name, t in sorted(now.items()) if self.before.get(name) != t}


def ask(prompt: str) -> str:
    """A typed answer from the operator (looked up at call time, so tests can stand in)."""
    return input(prompt)


class _Discard:
    def write(self, text: str) -> int:
        return len(text)

    def flush(self) -> None:
        pass

    def isatty(self) -> bool:
        return False


def _snapshot(out: Path) -> dict:
    try:
        if not out.is_dir():
            return {}
        stats = {p.name: p.stat() for p in out.iterdir() if p.is_file()}
        return {name: (st.st_mtime_ns, st.st_size, st.st_ino) for name, st in stats.items()}
    except OSError:
        return {}
