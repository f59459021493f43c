"""``spherecal scan CONFIG``: calls :mod:`spherecal.app.scan` and says what it wrote."""

from __future__ import annotations

from pathlib import Path

from spherecal.app.scan import UNNAMED_REMEDY, run_scan
from spherecal.cli.output import EXIT_OK, EXIT_VALIDATION
from spherecal.cli.session import Session, ask
from spherecal.config import load_config
from spherecal.io.runlog import progress_log


def run(args, session: Session) -> int:
    loaded = load_config(args.config)
    session.run_folder(Path(args.out) if args.out else loaded.output_dir)
    path, summary = run_scan(loaded, out_dir=Path(args.out) if args.out else None, log=progress_log("run"),
                             progress_stream=session.progress_stream(), yes=args.yes, ask=ask)
    session.say(f"wrote {summary.points} points from {summary.profiles} profiles to {path}")
    if summary.calibration_doubt:
        session.err(f"{summary.calibration_doubt}: the points were mapped with it (exit 5); "
                    f"{summary.calibration_remedy or UNNAMED_REMEDY}")
        return EXIT_VALIDATION
    return EXIT_OK


def after_failure(session: Session) -> str:
    """What to do after a scan stopped half-way."""
    return "; the PLY holds the profiles taken so far; set [scan] ply to a new name and scan again"
