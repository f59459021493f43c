"""``spherecal validate CONFIG``: calls :mod:`spherecal.app.validate` and prints the
acceptance figures and the verdict."""

from __future__ import annotations

from pathlib import Path

from spherecal.app.compare import given_transform
from spherecal.app.validate import run_validate
from spherecal.cli.output import EXIT_OK, EXIT_VALIDATION, transform_json, verdict_json
from spherecal.cli.session import Session, ask
from spherecal.config import load_config
from spherecal.io.runlog import progress_log
from spherecal.motion.validation import format_outcome, position_rows
from spherecal.report.terminal import format_verdict


def run(args, session: Session) -> int:
    loaded = load_config(args.config)
    session.run_folder(Path(args.out) if args.out else loaded.output_dir)
    session.note_file("configuration", loaded.path, with_text=True)
    given = given_transform(session.host, transform=args.transform, frames=args.controller_frame or [],
                            frame_words=args.frame_words, robot_type=loaded.config.robot["type"])
    outcome = run_validate(loaded, out_dir=Path(args.out) if args.out else None, log=progress_log("run"),
                           progress_stream=session.progress_stream(), report=not args.no_report, yes=args.yes,
                           ask=ask, transform=given, host=session.host)
    session.say(format_outcome(outcome, loaded.config.mounting))
    session.say("validation " + ("passed" if outcome.passed else "FAILED: a figure exceeds its MPE"))
    session.say(format_verdict(outcome.verdict))
    session.say(f"figures: {outcome.figures_path} (validation.json: the latest validation)")
    if outcome.report_path is not None:
        session.say(f"report: {outcome.report_path}, a new version with this validation (report.html and result.json "
                    "stay as the calibration wrote them)")
    session.summary.update(
        verdict=verdict_json(outcome.verdict),
        transform=transform_json(outcome.transform_name, outcome.transform) | {"source": outcome.transform_source},
        validation={"passed": outcome.passed, "transform_given": given is not None,
                    "figures": outcome.table(), "positions": position_rows(outcome),
                    "cause": outcome.cause.as_dict() if outcome.cause is not None else None,
                    "figures_file": str(outcome.figures_path),
                    "report": None if outcome.report_path is None else str(outcome.report_path)},
    )
    return EXIT_OK if outcome.passed else EXIT_VALIDATION


def after_failure(session: Session) -> str:
    """What to do after a validation stopped half-way."""
    return "; the shots taken are in the validation journal; run the validation again"
