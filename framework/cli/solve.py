"""``spherecal solve DATASET``: calls :mod:`spherecal.app.solve` and prints the result and
its verdict."""

from __future__ import annotations

from pathlib import Path

from spherecal.app.solve import default_out, run_solve, run_solve_recording
from spherecal.cli.finish import finish
from spherecal.cli.output import result_json
from spherecal.cli.session import Session
from spherecal.io import dataset as dataio
from spherecal.io import streams as streamio
from spherecal.io.runlog import progress_log
from spherecal.report.terminal import summary, truth_check


def run(args, session: Session) -> int:
    out = Path(args.out) if args.out else default_out(args.dataset)
    session.run_folder(out)
    if streamio.recording_kind(args.dataset) == "stream":
        return _run_recording(args, session, out)
    dataset = dataio.read_dataset(args.dataset)  # checks the file first (a device, a pipe, a size limit)
    session.note_file("dataset", args.dataset)
    outcome = run_solve(
        dataset, Path(args.dataset), out, nominal=args.nominal, robot_type=args.robot,
        robot_config=Path(args.robot_config) if args.robot_config else None, pose_from=args.pose_from,
        fit_radius=args.fit_radius, station_rotation_tolerance_deg=args.station_rotation_tolerance_deg,
        identify_kinematics=args.identify_kinematics, robot_error_model=args.robot_error_model,
        overwrite=args.overwrite, report=not args.no_report, force=args.force, operator=args.operator,
        log=progress_log("run"),
    )
    session.say(summary(outcome.solution, outcome.verdict))
    session.summary.update(result_json(outcome.solution.result, outcome.verdict, outcome.exports_written))
    check = truth_check(outcome.solution, outcome.dataset)
    if check:
        session.say(check)
    return finish(session, out, outcome.verdict, outcome.exports_written, report=not args.no_report)


def _run_recording(args, session: Session, out: Path) -> int:
    """A recording (dataset format version 3, the stream form): the clock relation too."""
    recording = streamio.read_recording(args.dataset)
    session.note_file("recording", args.dataset)
    outcome = run_solve_recording(
        recording, Path(args.dataset), out, nominal=args.nominal, robot_type=args.robot,
        robot_config=Path(args.robot_config) if args.robot_config else None, fit_radius=args.fit_radius,
        robot_error_model=args.robot_error_model, offset_ms=getattr(args, "clock_offset_ms", None),
        overwrite=args.overwrite, report=not args.no_report, force=args.force, operator=args.operator,
        log=progress_log("run"))
    session.say(summary(outcome.solution, outcome.verdict))
    session.summary.update(result_json(outcome.solution.result, outcome.verdict, outcome.exports_written))
    check = truth_check(outcome.solution, outcome.dataset)
    if check:
        session.say(check)
    return finish(session, out, outcome.verdict, outcome.exports_written, report=not args.no_report)
