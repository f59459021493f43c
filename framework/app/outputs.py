"""A run's output folder: the files a calibration writes there, the checks before
writing, and the calibration's result read back from it."""

from __future__ import annotations

import json
from pathlib import Path
from typing import TYPE_CHECKING

from spherecal.core.errors import ConfigError, InputError
from spherecal.core.models import CalibrationResult
from spherecal.io import dataset as dataio
from spherecal.io.exporters import CALIBRATED_URDF_NAME, JOURNAL_NAME, RESULT_NAME, ExportPlan
from spherecal.io.files import check_writable_target

if TYPE_CHECKING:
    from spherecal.config import LoadedConfig  # (not loaded by solve: tests/cli/test_startup_imports.py)

__all__ = ["CALIBRATED_URDF_NAME", "JOURNAL_NAME", "OUTPUT_PATTERNS", "RESULT_NAME", "calibrated_setup", "calibrated_urdf_in",
           "STREAM_JOURNAL_NAME", "check_output_folder", "check_output_targets", "existing_outputs", "journal_holds_shots",
           "journal_of", "result_for",
           "written_files"]

#: What a calibration writes into its folder besides its exporters' files (an
#: :class:`~spherecal.io.exporters.ExportPlan` gives theirs).
OUTPUT_PATTERNS = (RESULT_NAME, "report.html", "report_*.png", CALIBRATED_URDF_NAME)


def existing_outputs(out: Path, patterns: tuple[str, ...] = ()) -> list[Path]:
    """The files in ``out`` that writing a calibration there would replace (links too):
    :data:`OUTPUT_PATTERNS` and the exporters' ``patterns``."""
    if not out.is_dir():
        return []
    found = {p for pattern in (*OUTPUT_PATTERNS, *patterns) for p in out.glob(pattern)}
    return sorted(found)


def calibrated_urdf_in(out: Path) -> Path | None:
    """The calibration's ``robot_calibrated.urdf`` in its folder ``out`` (a kinematic
    calibration written there), or None."""
    path = out / CALIBRATED_URDF_NAME
    return path if path.is_file() else None


def check_output_folder(out: Path, what: str, how: str, exports: ExportPlan | None = None) -> None:
    """Refuse (InputError naming the file) to write a calibration into ``out`` when that
    would replace a file already there: ``what`` is the command, ``how`` how to proceed,
    ``exports`` the run's :class:`~spherecal.io.exporters.ExportPlan` (its files count too)."""
    if out.exists() and not out.is_dir():
        raise InputError(f"{out} is not a folder: give an output folder")
    check_output_targets(out, exports)  # a planted link is named as a link, before anything else
    found = existing_outputs(out, exports.file_patterns() if exports is not None else ())
    journal = out / JOURNAL_NAME
    if found:
        kind = "a calibration run" if journal.exists() else "a result"
        raise InputError(f"{found[0]} exists: {out} already holds {kind}, and {what} would replace it "
                         f"(nothing is overwritten silently); {how}")


def check_output_targets(out: Path, exports: ExportPlan | None = None) -> None:
    """Refuse (InputError naming it) before anything is written into ``out`` when a file
    a calibration would write there exists as a symbolic link or as anything but a
    regular file: the run then writes nothing at all, instead of stopping half-way at the
    first link (:func:`spherecal.io.files.check_writable_target`)."""
    for path in existing_outputs(out, exports.file_patterns() if exports is not None else ()):
        check_writable_target(path)


def written_files(out: Path) -> dict[str, Path]:
    """The files in ``out`` by name (none when it does not exist)."""
    return {p.name: p for p in sorted(out.iterdir()) if p.is_file()} if out.exists() else {}


#: The journal of an on-the-fly calibration (a stream recording, docs/on-the-fly.md).
STREAM_JOURNAL_NAME = "journal.stream.jsonl"


def journal_of(folder: Path) -> Path:
    """The calibration journal in ``folder``: the on-the-fly one when it is there, else
    the stop-and-go one (whether or not it exists)."""
    stream = folder / STREAM_JOURNAL_NAME
    return stream if stream.is_file() else folder / JOURNAL_NAME


def journal_holds_shots(folder: Path | None) -> bool:
    """Does the calibration journal in ``folder`` hold at least one shot (an observation,
    or an on-the-fly journal's profile)? (Read a line at a time, at most until the first.)"""
    if folder is None or not journal_of(folder).is_file():
        return False
    try:
        with open(journal_of(folder), "rb") as fh:
            return any(b"observation" in line[:32] or line.startswith(b'{"profile"') for line in fh)
    except OSError:
        return False


def interrupted_runs(config_path: Path, near: list[Path]) -> list[Path]:
    """Folders (one level below each of ``near``, and ``near`` themselves) that hold an
    interrupted calibration of the configuration at ``config_path``: a journal with shots,
    no result, and a header naming that configuration. For a ``--resume`` that found a
    finished run where an interrupted one was meant."""
    want = str(Path(config_path).resolve())
    found: list[Path] = []
    seen: set[Path] = set()
    for base in near:
        try:
            folders = [base, *(p for p in sorted(base.iterdir()) if p.is_dir())] if base.is_dir() else []
        except OSError:
            continue
        for folder in folders:
            folder = folder.resolve()
            if folder in seen or (folder / RESULT_NAME).exists() or not journal_holds_shots(folder):
                continue
            seen.add(folder)
            try:
                with open(journal_of(folder), "rb") as fh:
                    header = json.loads(fh.readline())
            except (OSError, ValueError):
                continue
            if isinstance(header, dict) and (header.get("provenance") or {}).get("config") == want:
                found.append(folder)
    return found


def result_for(loaded: LoadedConfig, section, out: Path) -> tuple[Path, CalibrationResult]:
    """The calibration result ``section`` (validate's or scan's) names, else the one in
    ``out``; InputError when it is of another mounting than the configuration's."""
    cfg = loaded.config
    path = loaded.resolve(section.result) if section.result else out / RESULT_NAME
    result = dataio.read_result(path)
    if result.mounting != cfg.mounting:
        raise InputError(f"{path}: the result is {result.mounting} but the configuration says {cfg.mounting}")
    return path, result


def calibrated_setup(loaded: LoadedConfig, section, missing: str, moving: str, out_dir: Path | None,
                     read_result: bool = True):
    """What validate and scan both need first: their section, the acquisition settings,
    the output folder and the calibration result in it (``(out, None, None)`` without
    ``read_result``)."""
    cfg = loaded.config
    if section is None:
        raise ConfigError(f"{loaded.path}: {missing}")
    if cfg.acquisition is None:
        raise ConfigError(f"{loaded.path}: {moving} moves the robot: it needs [acquisition] (speeds, workspace)")
    out = Path(out_dir) if out_dir is not None else loaded.output_dir
    return (out, *result_for(loaded, section, out)) if read_result else (out, None, None)
