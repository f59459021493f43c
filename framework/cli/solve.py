"""``spherecal solve DATASET``: calls :mod:`spherecal.app.solve` and prints the result and
its verdict."""

from __future__ import annotations

from pathlib import Path

from spherecal.app.solve import default_out, run_solve
from spherecal.cli.finish import finish
from spherecal.cli.output import result_json
from spherecal.cli.session import Session
from spherecal.io import dataset as dataio
from spherecal.io.runlog import progress_log
from spherecal.report.terminal import summary, truth_check


def run(args, session: Session) -> int:
    out = Path(args.out) if args.out else default_out(args.dataset)
    session.run_folder(out)
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
