"""``spherecal solve DATASET``: calls :mod:`spherecal.app.solve` and prints the result and
its verdict."""

from __future__ import annotations

from pathlib import Path

from spherecal.app.solve import default_out, run_solve
from spherecal.cli.finish import finish, say_result
from spherecal.cli.output import result_json
from spherecal.cli.session import Session
from spherecal.core.errors import ConfigError
from spherecal.io import dataset as dataio
from spherecal.io.runlog import progress_log
from spherecal.report.terminal import truth_check, truth_errors


def run(args, session: Session) -> int:
    out = Path(args.out) if args.out else default_out(args.dataset)
    session.run_folder(out)
    kind = dataio.recording_kind(args.dataset)
    if kind in ("stream", "rosbag"):
        return _run_recording(args, session, out, kind)
    bag_only = [f"--{name.replace('_', '-')}" for name in ("profile_topic", "pose_topic", "mounting", "sphere_radius_mm",
                                                           "base_frame", "flange_frame") if getattr(args, name)]
    if bag_only:
        raise ConfigError(f"{', '.join(bag_only)}: only for a ROS 2 bag; {args.dataset} is a dataset file")
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
    return _finish(args, session, out, outcome)


def _finish(args, session: Session, out: Path, outcome) -> int:
    """The result and its verdict printed (the details too with -v), the truth beside it for
    simulated data, the exit code."""
    say_result(session, outcome.solution, outcome.verdict, verbose=bool(args.verbose))
    session.summary.update(result_json(outcome.solution.result, outcome.verdict, outcome.exports_written))
    check = truth_check(outcome.solution, outcome.dataset)
    if check:
        session.say(check)
    session.summary["simulated_truth"] = truth_errors(outcome.solution, outcome.dataset)
    return finish(session, out, outcome.verdict, outcome.exports_written, report=not args.no_report)


def _run_recording(args, session: Session, out: Path, kind: str) -> int:
    """A recording (dataset format version 3, the stream form, or a ROS 2 bag converted
    once into it, ``<out>/recording.jsonl``): the clock relation too."""
    # (imported for a recording only: a dataset's solve does not load the stream readers,
    # the bag reader and the time model, tests/cli/test_startup_imports.py)
    from spherecal.app.solve_recording import convert_bag, run_solve_recording
    from spherecal.io import streams as streamio

    if kind == "rosbag":
        recording = convert_bag(Path(args.dataset), out, profile_topic=args.profile_topic, pose_topic=args.pose_topic,
                                mounting=args.mounting, sphere_radius_mm=args.sphere_radius_mm,
                                line_axis=args.line_axis, base_frame=args.base_frame, flange_frame=args.flange_frame,
                                robot_type=args.robot, robot_config=Path(args.robot_config) if args.robot_config
                                else None, overwrite=args.overwrite, log=progress_log("run"))
        source = out / "recording.jsonl"  # the bag as solved (a folder has no one hash)
    else:
        recording = streamio.read_recording(args.dataset)
        source = Path(args.dataset)
    session.note_file("recording", source)
    outcome = run_solve_recording(
        recording, source, out, nominal=args.nominal, robot_type=args.robot,
        robot_config=Path(args.robot_config) if args.robot_config else None, fit_radius=args.fit_radius,
        robot_error_model=args.robot_error_model, offset_ms=getattr(args, "clock_offset_ms", None),
        overwrite=args.overwrite, report=not args.no_report, force=args.force, operator=args.operator,
        log=progress_log("run"))
    return _finish(args, session, out, outcome)
