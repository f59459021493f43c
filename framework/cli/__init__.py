"""The ``spherecal`` command line. It parses arguments, loads the configuration and
calls :mod:`spherecal.app.runner`; nothing else.

Exit codes (scripts may rely on them; docs/cli.md):
  0  success
  1  internal error (a bug: please report it with the traceback)
  2  usage or configuration error (bad arguments, bad TOML, unknown keys, bad plugin settings)
  3  data error (bad or degenerate data, a plan outside the limits, an unreadable dataset)
  4  device error (robot or sensor: timeout, disconnect, protocol); what was taken is kept
  5  validation failed (an acceptance figure exceeds its MPE)
  6  plugin error (a plugin failed to load or misbehaved)
  7  the result is RED (do not use it): the verdict says why; result.json and the exports
     are written only with --force (the report always)
  8  compare --fail-on-drift: drift found (a difference beyond a threshold and significant)
  130 interrupted (Ctrl-C); what was taken is kept (calibrate: continue with --resume)
  141 standard output closed early by its reader (`spherecal plugins | head`): the rest is
      dropped, no error is printed (128 + SIGPIPE, as a shell reports such a program)
"""

from __future__ import annotations

import argparse
import contextlib
import gc
import logging
import os
import sys
import time
import traceback
from dataclasses import dataclass, field
from pathlib import Path

from spherecal import __version__
from spherecal.io.runlog import progress_log
from spherecal.core.errors import FileWriteError, ConfigError, DatasetFileError, DegenerateDataError, DeviceError, InputError, PluginError

EXIT_OK = 0
EXIT_INTERNAL = 1
EXIT_USAGE = 2
EXIT_DATA = 3
EXIT_DEVICE = 4
EXIT_VALIDATION = 5
EXIT_PLUGIN = 6
EXIT_RED = 7
EXIT_DRIFT = 8
EXIT_INTERRUPTED = 130
EXIT_PIPE = 141

#: What each exit code means, for the --json summary.
EXIT_MEANING = {
    EXIT_OK: "success", EXIT_INTERNAL: "internal error", EXIT_USAGE: "usage or configuration error",
    EXIT_DATA: "data error", EXIT_DEVICE: "device error", EXIT_VALIDATION: "validation failed",
    EXIT_PLUGIN: "plugin error", EXIT_RED: "the result is RED", EXIT_DRIFT: "drift found",
    EXIT_INTERRUPTED: "interrupted", EXIT_PIPE: "standard output closed by its reader",
}

#: Version of the --json summary's layout (docs/cli.md, "Machine-readable output").
JSON_SCHEMA = "spherecal-cli-summary/1"

_log = logging.getLogger("spherecal.cli")
#: True while the ``spherecal`` program (:func:`console`) holds Python's cyclic garbage
#: collector off for a command's imports (:func:`_imports_done` ends it).
_GC_HELD = False
#: The runner's ``log``: its progress lines go to logger ``spherecal.run`` (console and run.log).
_RUN_LOG = progress_log("run")


@dataclass
class _Session:
    """One command's console state: where human text goes (standard output, or standard
    error with --json), the run's record (for run.log), the output folder, and the
    --json summary being built."""

    json: bool = False
    quiet: bool = False
    record: object | None = None
    out_dir: Path | None = None
    summary: dict = field(default_factory=dict)
    before: dict = field(default_factory=dict)
    out_existed: bool = False


_session = _Session()


def _say(text: str) -> None:
    """Human output: standard output (standard error with --json), and the run's record."""
    print(text, file=sys.stderr if _session.json else sys.stdout)
    if _session.record is not None:
        _session.record.note(text)


def _progress_stream():
    """Where progress bars go: standard error, or nowhere with -q."""
    return _Discard() if _session.quiet else None


class _Discard:
    def write(self, text: str) -> int:
        return len(text)

    def flush(self) -> None:
        pass

    def isatty(self) -> bool:
        return False


def _run_folder(out: Path) -> None:
    """The command's output folder: run.log goes there, and the files written in it are
    listed in the --json summary."""
    from spherecal.io.files import check_output_folder_writable

    check_output_folder_writable(out, "give another folder with --out")  # before any work
    _session.out_dir = out
    _session.out_existed = out.is_dir()
    _session.before = _snapshot(out)


def _snapshot(out: Path) -> dict:
    try:
        if not out.is_dir():
            return {}
        stats = {p.name: p.stat() for p in out.iterdir() if p.is_file()}
        return {name: (st.st_mtime_ns, st.st_size, st.st_ino) for name, st in stats.items()}
    except OSError:
        return {}


def _files_written() -> dict[str, str]:
    out = _session.out_dir
    if out is None:
        return {}
    now = _snapshot(out)
    return {name: str(out / name) for name, t in sorted(now.items()) if _session.before.get(name) != t}


def _transform_json(name: str, pose) -> dict:
    a, b = name.split("_from_") if name and "_from_" in name else (None, None)
    return {"name": name, "maps": f"points in the {b} frame to the {a} frame" if a else None,
            "translation_mm": list(pose.translation_mm), "quaternion_wxyz": list(pose.quaternion_wxyz),
            "quaternion_order": "w, x, y, z (scalar first, as ABB and result.json)"}


def _verdict_json(v) -> dict | None:
    if v is None:
        return None
    return {"level": v.level, "headline": v.headline,
            "reasons": [{"level": lvl, "text": text} for lvl, text in v.reasons]}


def _result_json(result, verdict, written: bool) -> None:
    """The --json summary of calibrate and solve."""
    a = result.transform_name.split("_from_")[0]
    unc = {"about": f"the {a} frame's x, y, z axes", "std_rotation_deg": list(result.std_rotation_deg),
           "std_translation_mm": list(result.std_translation_mm), "coverage_factor_k": 2,
           "expanded_rotation_deg": [2 * v for v in result.std_rotation_deg],
           "expanded_translation_mm": [2 * v for v in result.std_translation_mm],
           "std_rotation_deg_robot_frame": None, "std_translation_mm_robot_frame": None,
           "point_error_k2_mm": None}
    re_ = result.robot_error
    if re_ is not None:
        unc.update(std_rotation_deg_robot_frame=list(re_.std_rotation_deg_robot_frame),
                   std_translation_mm_robot_frame=list(re_.std_translation_mm_robot_frame),
                   point_error_k2_mm=re_.point_error_k2_mm)
    _session.summary.update(
        verdict=_verdict_json(verdict), transform=_transform_json(result.transform_name, result.transform),
        uncertainty=unc, result_written=written,
        sphere={"radius_mm": result.sphere_radius_mm, "radius_fitted": result.radius_fitted,
                "centre_mm": list(result.sphere_centre_mm), "centre_frame": result.sphere_centre_frame},
        residuals={"rms_mm": result.residuals.rms_mm, "points_used": result.residuals.n_points_used,
                   "points_rejected": result.residuals.n_points_rejected},
    )


def _ask(prompt: str) -> str:
    """A typed answer from the operator (looked up at call time, so tests can stand in)."""
    return input(prompt)


def _err(msg: str) -> None:
    print(f"spherecal: error: {msg}", file=sys.stderr)
    if _session.record is not None:
        _session.record.note(f"error: {msg}", "spherecal.cli")
    _session.summary.setdefault("error", msg)


def cmd_calibrate(args) -> int:
    from spherecal.config import load_config
    from spherecal.app.runner import run_calibrate, summary, truth_check

    _imports_done()
    loaded = load_config(args.config)
    out = Path(args.out) if args.out else loaded.output_dir
    _run_folder(out)
    _log.debug("configuration %s", loaded.path)
    if _session.record is not None:
        from spherecal.io.runlog import describe_file, file_text_for_record

        _session.record.note(f"configuration: {describe_file(loaded.path)}\n" + file_text_for_record(loaded.path))
    outcome = run_calibrate(
        loaded, dry_run=args.dry_run, resume=args.resume, manual=args.manual,
        out_dir=Path(args.out) if args.out else None, log=_RUN_LOG, progress_stream=_progress_stream(),
        report=not args.no_report, force=args.force, yes=args.yes, ask=_ask, operator=args.operator,
    )
    if outcome.finished:
        _say(f"{out} holds a finished run ({out / 'result.json'}): nothing to resume; its result, exports and "
             "report were left as they are")
        return EXIT_OK
    if outcome.solution is None:
        return EXIT_OK
    _say(summary(outcome.solution, outcome.verdict))
    _result_json(outcome.solution.result, outcome.verdict, outcome.exports_written)
    if loaded.config.validation is not None and outcome.verdict.level != "red":
        from shlex import quote  # (a command to copy: paths quoted where they need it)

        folder = f" -o {quote(str(args.out))}" if args.out else ""  # (the run validate is to check)
        _say(f"acceptance test: spherecal validate {quote(str(args.config))}{folder} (its figures then join "
             "this verdict, in the terminal and the report)")
    from spherecal.io import dataset as dataio

    journal = outcome.files.get("journal")
    if journal is not None:
        check = truth_check(outcome.solution, dataio.read_dataset(journal))
        if check:
            _say(check)
    return _finish(out, outcome.verdict, outcome.exports_written,
                   "--resume --force" if outcome.files.get("journal") else "--force",
                   report=not getattr(args, "no_report", False))


def _finish(out: Path, graded, written: bool, force: str = "--force", report: bool = True) -> int:
    """The last line of calibrate and solve, and the exit code: a RED result exits 7.
    ``report``: whether report.html was written (solve --no-report writes none)."""
    if graded.level != "red":
        _say(f"results in {out}")
        return EXIT_OK
    if written:
        _say(f"results in {out} (written with --force although the result is RED: do not use it in production)")
    else:
        where = f"report in {out}" if report else "no report either: --no-report"
        _say(f"the result is RED: result.json and the exports were NOT written ({where}); fix the cause "
              f"and run again, or give {force} to write them anyway")
    _err("the result is RED (exit 7): see the verdict" + ("" if _session.json else " above"))
    return EXIT_RED


def cmd_solve(args) -> int:
    from spherecal.io import dataset as dataio
    from spherecal.estimation import CalibrationOptions
    from spherecal.core.models import Pose
    from spherecal.app.runner import (make_host, provenance_type, solve_and_write, solve_kinematics, solve_robot_type, summary,
                         truth_check)

    _imports_done()
    out = Path(args.out) if args.out else Path(args.dataset).with_suffix("").with_suffix(".calibration")
    _run_folder(out)
    dataset = dataio.read_dataset(args.dataset)  # checks the file first (a device, a pipe, a size limit)
    if _session.record is not None:
        from spherecal.io.runlog import describe_file

        _session.record.note(f"dataset: {describe_file(args.dataset)}")
    if not dataset.observations:
        raise InputError(f"{args.dataset}: the dataset holds no observations (only its header): nothing to solve")
    nominal = None
    if args.nominal is not None:
        from spherecal.report.compare import parse_xyz_quat

        nominal = parse_xyz_quat(args.nominal, "--nominal")
    robot_config = Path(args.robot_config) if args.robot_config else None
    host = make_host()
    fk, dataset, arm = solve_kinematics(dataset, args.robot, robot_config, args.pose_from, host=host)
    robot_type = solve_robot_type(dataset, args.robot, robot_config)
    sensor_type = provenance_type(dataset, "sensor")
    exports = host.export_plan(None, dataset.mounting, robot_type)
    options = CalibrationOptions(
        fit_radius=args.fit_radius, nominal_transform=nominal,
        station_rotation_tolerance_deg=args.station_rotation_tolerance_deg,
        identify_kinematics=args.identify_kinematics,
        robot_error_model=args.robot_error_model,
    )
    if args.identify_kinematics and arm is None:
        raise ConfigError("--identify-kinematics needs the robot's kinematics: give --robot TYPE (a type whose "
                          "plugin describes its arm; `spherecal plugins` lists them) and joints_deg in every "
                          "observation")
    _log.debug("options: %s", options.model_dump_json(exclude={"nominal_transform"}))
    if not args.overwrite:
        from spherecal.app.runner import check_output_folder

        check_output_folder(out, "solve", "give a new folder with --out, or --overwrite to replace its result, "
                            "exports and report", exports)
    from spherecal.app.runner import traceability

    solution, graded, written = solve_and_write(dataset, options, out, fk, log=_RUN_LOG,
                                                report=not args.no_report, force=args.force, kinematics=arm,
                                                exports=exports,
                                                provenance=traceability(dataset, Path(args.dataset),
                                                                        operator=args.operator))
    host.calibration_finished(result=solution.result, dataset=dataset, out_dir=out, exports_written=written,
                              robot_type=robot_type, sensor_type=sensor_type)
    _say(summary(solution, graded))
    _result_json(solution.result, graded, written)
    check = truth_check(solution, dataset)
    if check:
        _say(check)
    return _finish(out, graded, written, report=not args.no_report)


def _number(text: str, lo: float | None = None, hi: float | None = None, lo_open: bool = False) -> float:
    import math

    try:
        v = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number, got {text!r}") from None
    if not math.isfinite(v):
        raise argparse.ArgumentTypeError(f"expected a finite number, got {text}")
    if lo is not None and (v < lo or (lo_open and v == lo)):
        raise argparse.ArgumentTypeError(f"must be {'greater than' if lo_open else 'at least'} {lo:g}, got {text}")
    if hi is not None and v > hi:
        raise argparse.ArgumentTypeError(f"must be at most {hi:g}, got {text}")
    return v


def _positive_float(text: str) -> float:
    return _number(text, 0.0, 180.0, lo_open=True)


def _non_negative_float(text: str) -> float:
    return _number(text, 0.0, 1e3)


def _fraction(text: str) -> float:
    return _number(text, 0.0, 1.0)


def _int_in(lo: int, hi: int):
    def parse(text: str) -> int:
        try:
            v = int(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected a whole number, got {text!r:.40}") from None
        if not lo <= v <= hi:
            raise argparse.ArgumentTypeError(f"must be from {lo} to {hi}, got {text:.40}")
        return v
    return parse


def _significance(text: str) -> float:
    v = _number(text, 0.0, 1.0, lo_open=True)
    if v >= 1.0:
        raise argparse.ArgumentTypeError(f"must be below 1, got {text}")
    return v


class _FrameAction(argparse.Action):
    """``--controller-frame LINE`` and a robot type's own name for it: keeps each (option
    as typed, text), so that a message names the option the user gave."""

    def __call__(self, parser, namespace, values, option_string=None):
        given = list(getattr(namespace, self.dest, None) or [])
        given.append((option_string, values))
        setattr(namespace, self.dest, given)


def _installed_frame_options() -> dict[str, list[str]]:
    """The installed robot types' names for ``--controller-frame``
    (:attr:`spherecal.devices.contract.RobotType.frame_option`): ``{option: [robot type, ...]}``.
    Empty when the plugin host cannot be built: the command that needs it reports why."""
    try:
        from spherecal.app.runner import make_host

        host = make_host()
    except Exception:  # noqa: BLE001 - reported by the command itself, with its exit code
        return {}
    found: dict[str, list[str]] = {}
    for t in host.registry.robots.values():
        if t.frame_option:
            found.setdefault(t.frame_option, []).append(t.name)
    return found


def _frame_words(frame_options: dict[str, list[str]]) -> str:
    """``--<option> / --controller-frame``: the options that take a controller frame."""
    return " / ".join([f"--{o}" for o in sorted(frame_options)] + ["--controller-frame"])


def _transform_options(p: argparse.ArgumentParser, role: str, frame_options: dict[str, list[str]],
                       with_std: bool = True) -> None:
    """--transform and --controller-frame with the robot types' names for it (compare and
    validate), --std-mm and --std-deg (compare)."""
    p.add_argument("--transform", metavar="X", help=f"a transform {role}: x,y,z,qw,qx,qy,qz (translation in mm, "
                   "unit quaternion w first, as in result.json), or a file: a result.json or run folder, or a text "
                   "file holding those seven numbers or a controller frame line")
    p.add_argument("--controller-frame", dest="controller_frame", action=_FrameAction, metavar="LINE",
                   help=f"a transform {role} as the robot controller stores it (a tool or work-object data line), "
                   "read by the robot plugin that knows its syntax (docs/cli.md)")
    for option, robot_types in sorted(frame_options.items()):
        p.add_argument(f"--{option}", dest="controller_frame", action=_FrameAction, metavar="LINE",
                       help=f"--controller-frame, as robot type {', '.join(robot_types)} calls it")
    p.set_defaults(controller_frame=None, frame_words=_frame_words(frame_options))
    if not with_std:
        return
    p.add_argument("--std-mm", type=_non_negative_float, metavar="MM", help="1-sigma per axis of the translation of "
                   "--transform/--controller-frame given as numbers, mm (default 0: known exactly)")
    p.add_argument("--std-deg", type=_non_negative_float, metavar="DEG", help="1-sigma per axis of its rotation, deg "
                   "(default 0)")


def _simulated_sensor_fov(name: str | None):
    """The field of view ``spherecal simulate`` measures with: that of the sensor type
    registered as ``name`` (``--sensor``), or, without one, of the only installed sensor
    type that declares one. :class:`ConfigError` naming ``--sensor`` (with the known
    types) for an unknown name, a type that declares none, or a choice to make."""
    from spherecal.app.runner import make_host

    sensors = make_host().registry.sensors
    with_fov = sorted(n for n, t in sensors.items() if t.field_of_view is not None)
    if name is None:
        if len(with_fov) == 1:
            return sensors[with_fov[0]].field_of_view
        raise ConfigError("--sensor: give the sensor type to simulate (installed sensor types with a field of view: "
                          f"{', '.join(with_fov) or 'none'})")
    if name not in sensors:
        raise ConfigError(f"--sensor {name}: unknown sensor type; installed sensor types: "
                          f"{', '.join(sorted(sensors)) or 'none'} (list them with `spherecal plugins`)")
    fov = sensors[name].field_of_view
    if fov is None:
        raise ConfigError(f"--sensor {name}: sensor type {name!r} declares no field of view to simulate; simulate it "
                          "from a configuration that gives one in [simulation.fov] (--config)")
    return fov


#: The defaults of simulate's options for the standard cell (with --config these options
#: are refused, so the parser leaves them None and cmd_simulate fills them in).
_SIMULATE_DEFAULTS = {"mounting": "eye_in_hand", "seed": 0, "profiles": 10, "point_noise_mm": 0.01,
                      "pose_noise_mm": 0.02, "stray_fraction": 0.0}


def _flag(name: str) -> str:
    """The command-line flag of an argparse destination (``point_noise_mm`` -> ``--point-noise-mm``)."""
    return "--" + name.replace("_", "-")


def cmd_simulate(args) -> int:
    from spherecal.io import dataset as dataio
    from spherecal.sim import NoiseModel, SweepPlan, simulate_dataset, standard_cell

    _imports_done()
    if args.config:
        from spherecal.config import load_config
        from spherecal.app.runner import configured_for_sensor, make_cell, make_host, robot_arm

        from spherecal.motion.kinematic_plan import plan_kinematic_stations, uses_planner

        # the configuration gives the cell and the plan: an option that would change them is refused, never ignored
        clash = [_flag(name) for name in ("sensor", *_SIMULATE_DEFAULTS) if name != "seed"
                 and getattr(args, name) is not None]
        if clash:
            raise ConfigError(f"{', '.join(clash)}: the configuration gives the sensor, the mounting, the plan and "
                              "the noise ([sensor], mounting, [acquisition], [simulation]); give these options "
                              "without --config, or change the configuration")
        host = make_host()
        loaded, fov = configured_for_sensor(load_config(args.config), host)  # the standoffs the sensor sets, as a run
        cfg = loaded.config
        arm = robot_arm(loaded, host)
        cell = make_cell(cfg, arm, field_of_view=fov)
        if cell is None:  # no [simulation]: the standard cell, measuring with the configured sensor's field of view
            if fov is None:
                raise ConfigError(f"{loaded.path}: sensor.type {cfg.sensor['type']!r} declares no field of view to "
                                  "simulate; give it whole in [simulation.fov]")
            cell = standard_cell(cfg.mounting, seed=args.seed or 0, fov=fov)
        elif args.seed is not None:
            raise ConfigError(f"--seed {args.seed}: {loaded.path} has a [simulation] section, whose seed is used; "
                              "change simulation.seed there")
        if arm is not None and cell.arm is None:
            cell.attach_arm(arm)  # as the simulated controller does: the joints of every shot are recorded
        if uses_planner(cfg.acquisition, cfg.calibration):  # the kinematic planner's stations, as calibrate does
            plan = plan_kinematic_stations(cfg.acquisition, cfg.calibration, cfg.mounting, cfg.nominal_transform,
                                           cfg.sphere, arm, robot_type=cfg.robot.get("type")).sweep
        else:
            plan = cfg.acquisition.sweep if cfg.acquisition else SweepPlan()
    else:
        for name, default in _SIMULATE_DEFAULTS.items():
            if getattr(args, name) is None:
                setattr(args, name, default)
        noise = NoiseModel(
            point_noise_mm=args.point_noise_mm,
            pose_translation_noise_mm=args.pose_noise_mm,
            stray_profile_fraction=args.stray_fraction,
        )
        cell = standard_cell(args.mounting, seed=args.seed, noise=noise, fov=_simulated_sensor_fov(args.sensor))
        plan = SweepPlan(profiles_per_station=args.profiles)
    if not args.force and os.path.lexists(args.out):
        raise InputError(f"{args.out} already exists; give --force to replace it, or another file name")
    ds = simulate_dataset(cell, plan)
    dataio.write_dataset(args.out, ds, overwrite=args.force)
    _say(f"wrote {len(ds.observations)} observations ({cell.mounting}) to {args.out}")
    return EXIT_OK


def cmd_validate(args) -> int:
    from spherecal.config import load_config
    from spherecal.app.runner import run_validate

    _imports_done()
    loaded = load_config(args.config)
    _run_folder(Path(args.out) if args.out else loaded.output_dir)
    if _session.record is not None:
        from spherecal.io.runlog import describe_file, file_text_for_record

        _session.record.note(f"configuration: {describe_file(loaded.path)}\n" + file_text_for_record(loaded.path))
    given = _given_transform(args, robot_type=loaded.config.robot["type"])
    outcome = run_validate(loaded, out_dir=Path(args.out) if args.out else None, log=_RUN_LOG,
                           progress_stream=_progress_stream(), report=not args.no_report, yes=args.yes, ask=_ask,
                           transform=given)
    from spherecal.app.runner import format_verdict
    from spherecal.motion.validation import format_outcome, position_rows

    _say(format_outcome(outcome))
    _say("validation " + ("passed" if outcome.passed else "FAILED: a figure exceeds its MPE"))
    _say(format_verdict(outcome.verdict))
    _session.summary.update(
        verdict=_verdict_json(outcome.verdict),
        transform=_transform_json(outcome.transform_name, outcome.transform) | {"source": outcome.transform_source},
        validation={"passed": outcome.passed, "transform_given": given is not None,
                    "figures": outcome.table(), "positions": position_rows(outcome)},
    )
    return EXIT_OK if outcome.passed else EXIT_VALIDATION


def _given_transform(args, robot_type: str | None = None):
    """The transform of --transform or --controller-frame (None when neither is given), with the
    covariance of --std-mm/--std-deg."""
    from spherecal.report import compare as cmp

    frames = args.controller_frame or []
    if len(frames) + (args.transform is not None) > 1:
        used = (["--transform"] if args.transform is not None else []) + [option for option, _ in frames]
        raise ConfigError(f"give one of --transform and {args.frame_words} (given: {', '.join(used)})")
    if args.transform is not None:
        est = cmp.read_transform_argument(args.transform, "--transform", robot_type=robot_type,
                                          uncertainty=getattr(args, "uncertainty", "robot-frame"))
    elif frames:
        option, text = frames[0]
        est = cmp.estimate_of_frame(cmp.read_controller_frame(text, option, robot_type=robot_type), option)
    else:
        if getattr(args, "std_mm", None) is not None or getattr(args, "std_deg", None) is not None:
            raise ConfigError(f"--std-mm and --std-deg are the uncertainty of --transform or {args.frame_words}: "
                              "give one")
        return None
    if getattr(args, "std_mm", None) is not None or getattr(args, "std_deg", None) is not None:
        if est.covariance.any():
            raise ConfigError(f"--std-mm/--std-deg: {est.source} has its own covariance; give them only with a "
                              "transform given as numbers or a controller frame")
        est = cmp.TransformEstimate(est.pose, est.transform_name,
                                    cmp.covariance_from_std(args.std_mm or 0.0, args.std_deg or 0.0),
                                    est.source, est.note)
    return est


def cmd_compare(args) -> int:
    from spherecal.report import compare as cmp

    _imports_done()
    result, where = cmp.read_result_operand(args.a)
    a = cmp.TransformEstimate.of_result(result, str(where), args.uncertainty)
    given = _given_transform(args)
    if (args.b is None) == (given is None):
        raise ConfigError(f"compare A with one of: a second result (B), --transform or {args.frame_words}")
    if given is None:
        other, where_b = cmp.read_result_operand(args.b)
        given = cmp.TransformEstimate.of_result(other, str(where_b), args.uncertainty)
    c = cmp.compare(a, given, threshold_mm=args.threshold_mm, threshold_deg=args.threshold_deg,
                    significance_level=args.significance)
    _say(cmp.format_comparison(c))
    _session.summary.update(
        verdict={"level": "red" if c.drift else "green",
                 "headline": "drift: the difference exceeds a threshold and is significant" if c.drift
                 else "no drift", "reasons": []},
        transform=_transform_json(c.transform_name or "", c.b.pose) | {"source": c.b.source},
        reference=_transform_json(c.transform_name or "", c.a.pose) | {"source": c.a.source},
        comparison=c.as_dict(),
    )
    if c.drift and args.fail_on_drift:
        _err("drift found (exit 8): see the comparison above")
        return EXIT_DRIFT
    return EXIT_OK


def cmd_scan(args) -> int:
    from spherecal.config import load_config
    from spherecal.app.runner import run_scan

    _imports_done()
    loaded = load_config(args.config)
    _run_folder(Path(args.out) if args.out else loaded.output_dir)
    path, summary = run_scan(loaded, out_dir=Path(args.out) if args.out else None, log=_RUN_LOG,
                             progress_stream=_progress_stream(), yes=args.yes, ask=_ask)
    _say(f"wrote {summary.points} points from {summary.profiles} profiles to {path}")
    if summary.calibration_doubt:
        _err(f"{summary.calibration_doubt}: the points were mapped with it (exit 5); re-calibrate, or validate "
             "again once the cause is fixed")
        return EXIT_VALIDATION
    return EXIT_OK


def cmd_plugins(args) -> int:
    from spherecal.app.runner import make_host

    _say(make_host().format_description())
    return EXIT_OK


def cmd_completion(args) -> int:
    from spherecal.cli.completion import completion_script

    _say(completion_script(build_parser(), args.shell))
    return EXIT_OK


OUT_HELP = "the run's output folder: {what} (default: {default})"


def _common_options(p: argparse.ArgumentParser, default) -> None:
    """--debug, -v and -q, before or after the command (``default``: SUPPRESS, so that
    a subcommand's parser leaves a value given before the command alone)."""
    p.add_argument("--debug", action="store_true", default=default, help="show tracebacks of internal errors")
    p.add_argument("-v", "--verbose", action="count", default=default,
                   help="more messages on standard error (debug messages too)")
    p.add_argument("-q", "--quiet", action="store_true", default=default,
                   help="only warnings and errors on standard error (no progress); the result still goes to "
                   "standard output, and run.log records everything")


def build_parser(frame_options: dict[str, list[str]] | None = None) -> argparse.ArgumentParser:
    """The command line. ``frame_options``: the robot types' names for ``--controller-frame``
    (``{option: [robot type, ...]}``, default: the installed plugins')."""
    if frame_options is None:
        frame_options = _installed_frame_options()
    p = argparse.ArgumentParser(
        prog="spherecal",
        description="Calibrate a laser line sensor against a robot with a reference sphere.",
        epilog=__doc__.split("\n\n", 1)[1],
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument("--version", action="version", version=f"spherecal {__version__}")
    _common_options(p, argparse.SUPPRESS)
    p.set_defaults(debug=False, verbose=0, quiet=False, json=False)
    sub = p.add_subparsers(dest="command", required=True, metavar="COMMAND")
    common = argparse.ArgumentParser(add_help=False)
    _common_options(common, argparse.SUPPRESS)
    as_json = argparse.ArgumentParser(add_help=False)
    as_json.add_argument("--json", action="store_true", default=argparse.SUPPRESS,
                         help="print one JSON summary on standard output (verdict, transform, uncertainties, files "
                         "written, exit code) and nothing else; the human text goes to standard error (docs/cli.md)")

    c = sub.add_parser("calibrate", parents=[common, as_json], help="acquire (or replay) and calibrate, as the configuration says",
                       description="Plan, check, acquire into the journal, solve, and write the result, exports "
                       "and report. With [simulation] in the configuration, runs against simulated devices.")
    c.add_argument("config", help="configuration file (TOML)")
    c.add_argument("--dry-run", action="store_true", help="show and check the plan, move nothing")
    c.add_argument("--resume", action="store_true", help="continue an interrupted acquisition from its journal")
    c.add_argument("--manual", action="store_true", help="the operator jogs the robot; Enter captures")
    c.add_argument("-o", "--out", metavar="DIR", help=OUT_HELP.format(
        what="journal, result, exports, report and run.log are written there",
        default="output_dir of the configuration"))
    c.add_argument("--no-report", action="store_true", help="skip the HTML report")
    c.add_argument("--force", action="store_true", help="write result.json and the exports even when the result is "
                   "RED (the exit code is still 7)")
    c.add_argument("--operator", metavar="NAME", help="who runs the calibration, for the report and the result "
                   "(default: [report] operator of the configuration)")
    c.add_argument("--yes", action="store_true", help="confirm the motion of a real robot without being asked (default: print the plan and ask for a typed 'yes')")
    c.set_defaults(func=cmd_calibrate)

    s = sub.add_parser("solve", parents=[common, as_json], help="calibrate a recorded dataset (no devices)",
                       description="Calibrate a recorded dataset without devices and write the result, exports "
                       "and report. Flange poses are the reported base_from_flange; observations with joint "
                       "readings only go through the robot plugin's forward kinematics (--robot).")
    s.add_argument("dataset", help="dataset file (.jsonl)")
    s.add_argument("-o", "--out", metavar="DIR", help=OUT_HELP.format(
        what="result, exports, report and run.log are written there", default="<dataset>.calibration next to it"))
    s.add_argument("--fit-radius", action="store_true", help="estimate the sphere radius too")
    s.add_argument("--nominal", help="rough X as x,y,z,qw,qx,qy,qz (mm, w first) to settle ambiguous data")
    s.add_argument("--robot", metavar="TYPE", help="robot type whose kinematics computes flange poses from joints_deg "
                   "(default: the robot the dataset's provenance names; `spherecal plugins` lists them)")
    s.add_argument("--robot-config", metavar="FILE.toml", help="the robot's settings (its [robot] table, e.g. "
                   "the calibration configuration); default: the plugin's defaults")
    s.add_argument("--pose-from", choices=["reported", "joints"], default="reported",
                   help="reported (default): each observation's base_from_flange, kinematics only where it is "
                   "missing; joints: every flange pose from joints_deg through the robot's kinematics")
    s.add_argument("--station-rotation-tolerance-deg", type=_positive_float, metavar="DEG",
                   help="a shot turned more than this from its station's orientation is left out "
                   "(default: derived from the orientation read noise)")
    s.add_argument("--robot-error-model", choices=["auto", "kinematic", "station", "kinematic+station", "none"],
                   default="auto", help="the robot's systematic error (docs/estimation.md): auto (default) is "
                   "kinematic when joints and the robot's kinematics are known, else station; none for a calibrated "
                   "robot whose error is within its repeatability")
    s.add_argument("--identify-kinematics", action="store_true",
                   help="kinematic calibration: estimate the arm's identifiable geometric errors too (needs --robot "
                   "and joints_deg); writes robot_calibrated.urdf")
    s.add_argument("--no-report", action="store_true", help="skip the HTML report")
    s.add_argument("--force", action="store_true", help="write result.json and the exports even when the result is "
                   "RED (the exit code is still 7)")
    s.add_argument("--operator", metavar="NAME", help="who ran the calibration, for the report and the result")
    s.add_argument("--overwrite", action="store_true", help="replace the result, exports and report already in the "
                   "output folder (default: refuse)")
    s.set_defaults(func=cmd_solve)

    m = sub.add_parser("simulate", parents=[common], help="write a dataset from the simulated cell")
    m.add_argument("out", help="dataset file to write (.jsonl)")
    m.add_argument("--config", help="take the cell and plan from this configuration's [simulation] and [acquisition]")
    m.add_argument("--sensor", metavar="TYPE", help="the sensor type to simulate (its registered name, as in "
                   "`spherecal plugins`): the cell measures with its declared field of view and the plan fits it "
                   "(default: the only installed sensor type that declares one); not with --config, whose [sensor] "
                   "names it")
    # (defaults applied in cmd_simulate: with --config these options are refused, so their absence must show)
    d = _SIMULATE_DEFAULTS
    m.add_argument("--mounting", choices=["eye_in_hand", "eye_to_hand"], help=f"default {d['mounting']}")
    m.add_argument("--seed", type=_int_in(0, 2**63 - 1), help=f"default {d['seed']}")
    m.add_argument("--profiles", type=_int_in(4, 10_000),
                   help=f"profiles per station (4 to 10000, default {d['profiles']})")
    m.add_argument("--point-noise-mm", type=_non_negative_float, help=f"default {d['point_noise_mm']}")
    m.add_argument("--pose-noise-mm", type=_non_negative_float, help=f"default {d['pose_noise_mm']}")
    m.add_argument("--stray-fraction", type=_fraction,
                   help=f"share of profiles with stray points (0 to 1, default {d['stray_fraction']:g})")
    m.add_argument("--force", action="store_true", help="overwrite an existing file")
    m.set_defaults(func=cmd_simulate)

    v = sub.add_parser("validate", parents=[common, as_json], help="acceptance test of a calibration: P_F, P_S, SD, F against the MPEs",
                       description="Scan the sphere (and a ball bar and a flat, if configured) with the calibrated "
                       "system at views other than the calibration's; report the figures per position and their "
                       "maximum; exit 5 when one exceeds its MPE. The transform is the calibration's result.json, "
                       "or one spherecal did not compute (--transform, --controller-frame).")
    v.add_argument("config", help="configuration file (TOML) with a [validation] section")
    v.add_argument("-o", "--out", metavar="DIR", help=OUT_HELP.format(
        what="its result.json is validated, and the validation files, report and run.log are written there",
        default="output_dir of the configuration"))
    v.add_argument("--no-report", action="store_true", help="do not rewrite the HTML report")
    _transform_options(v, "to validate instead of the calibration's result.json (e.g. the controller's current "
                       "tool)", frame_options, with_std=False)
    v.add_argument("--yes", action="store_true", help="confirm the motion of a real robot without being asked (default: print the plan and ask for a typed 'yes')")
    v.set_defaults(func=cmd_validate)

    n = sub.add_parser("scan", parents=[common], help="scan an object with the calibrated system into a PLY point cloud",
                       description="Sweep the object of the [scan] section and stream its points, mapped into the "
                       "frame the object is fixed in (base in eye-in-hand), to a PLY file.")
    n.add_argument("config", help="configuration file (TOML) with a [scan] section")
    n.add_argument("-o", "--out", metavar="DIR", help=OUT_HELP.format(
        what="its result.json maps the points, and the PLY and run.log are written there",
        default="output_dir of the configuration"))
    n.add_argument("--yes", action="store_true", help="confirm the motion of a real robot without being asked (default: print the plan and ask for a typed 'yes')")
    n.set_defaults(func=cmd_scan)

    k = sub.add_parser("compare", parents=[common, as_json], help="the difference between two calibrations (or a calibration and a given "
                       "transform) and whether it is drift",
                       description="B relative to A in mm and degrees, about and along the axes of the transform's "
                       "target frame (flange or base), with its significance from both covariances (Mahalanobis "
                       "distance over the 6 parameters, and each component in sigma). Drift: a difference beyond "
                       "--threshold-mm or --threshold-deg that is also significant at --significance (without any "
                       "covariance the thresholds alone decide). Results of different transforms "
                       "(flange_from_sensor, base_from_sensor) are refused.")
    k.add_argument("a", metavar="A", help="the reference calibration: result.json or a run folder holding one")
    k.add_argument("b", metavar="B", nargs="?", help="the calibration to compare with A: result.json or a run folder")
    _transform_options(k, "instead of B", frame_options)
    k.add_argument("--threshold-mm", type=_non_negative_float, default=0.1, metavar="MM",
                   help="drift threshold on the translation difference's length, mm (default 0.1)")
    k.add_argument("--threshold-deg", type=_non_negative_float, default=0.05, metavar="DEG",
                   help="drift threshold on the rotation angle between the two, deg (default 0.05)")
    k.add_argument("--significance", type=_significance, default=0.01, metavar="ALPHA",
                   help="significance level of the difference (chi-square, 6 degrees of freedom; default 0.01)")
    k.add_argument("--uncertainty", choices=["robot-frame", "full"], default="robot-frame",
                   help="robot-frame (default): the calibrations' own uncertainty, relative to the robot's frame (the "
                   "robot's accuracy, shared by two calibrations on one robot, cancels); full: with the robot's "
                   "accuracy, for calibrations on different robots")
    k.add_argument("--fail-on-drift", action="store_true", help="exit 8 when drift is found (default: exit 0 "
                   "and say so)")
    k.set_defaults(func=cmd_compare)

    g = sub.add_parser("plugins", parents=[common], help="list installed robots, sensors and exporters with their configuration fields")
    g.set_defaults(func=cmd_plugins)

    o = sub.add_parser("completion", parents=[common], help="print a shell completion script (bash or zsh)",
                       description="Print a completion script for the shell: bash (source it, or put it in "
                       "~/.local/share/bash-completion/completions/spherecal) or zsh (save it as _spherecal in a "
                       "folder of $fpath). docs/cli.md, 'Shell completion'.")
    o.add_argument("shell", choices=["bash", "zsh"])
    o.set_defaults(func=cmd_completion)
    return p


def _journal_holds_shots(folder: Path | None) -> bool:
    """Does the calibration journal in ``folder`` hold at least one shot? (Read a line at
    a time, at most until the first observation.)"""
    from spherecal.app.runner import JOURNAL_NAME

    if folder is None or not (folder / JOURNAL_NAME).is_file():
        return False
    try:
        with open(folder / JOURNAL_NAME, "rb") as fh:
            return any(b"observation" in line[:32] for line in fh)
    except OSError:
        return False


def _after_failure(command: str) -> str:
    """What to do after a run stopped half-way, per command."""
    if command == "calibrate":
        if not _journal_holds_shots(_session.out_dir):
            return "; no shot was taken yet: nothing to resume, run the same command again"
        return "; what was taken is in the journal: continue with --resume"
    if command == "validate":
        return "; the shots taken are in the validation journal; run the validation again"
    if command == "scan":
        return "; the PLY holds the profiles taken so far; set [scan] ply to a new name and scan again"
    return ""


def console() -> int:
    """The ``spherecal`` program (its console script): :func:`main`, with Python's cyclic
    garbage collector held off while the command imports its modules. What the imports
    build lives as long as the process; collecting among it again and again as it grows,
    and once more at exit, was about 6 % of a small ``solve`` (issue 13's start-up). Each
    command calls :func:`_imports_done` once its modules are in, before it reads data or
    moves a device, and the collector runs as usual from there. :func:`main` itself (the
    library entry, tests) leaves the collector alone."""
    global _GC_HELD
    gc.disable()
    _GC_HELD = True
    try:
        return main()
    finally:
        _imports_done()


def _imports_done() -> None:
    """The end of a command's start-up under :func:`console`: the objects alive now
    (modules, classes, the parser) move to the collector's permanent generation
    (:func:`gc.freeze`: never scanned again) and the collector is switched back on.
    Does nothing elsewhere, or a second time."""
    global _GC_HELD
    if _GC_HELD:
        _GC_HELD = False
        gc.freeze()
        gc.enable()


def main(argv: list[str] | None = None) -> int:
    """Run one command; returns its exit code (module docstring). Logging is set up for
    the command's length only (:func:`_logging`): nothing stays installed afterwards."""
    global _session
    argv = sys.argv[1:] if argv is None else list(argv)
    # the robot plugins' names for --controller-frame: the host is built only for the commands that take one
    parser = build_parser(_installed_frame_options() if {"compare", "validate"} & set(argv) else {})
    args = parser.parse_args(argv)
    args._argv = argv
    from spherecal.io.runlog import RunRecord

    _session = _Session(json=args.json, quiet=args.quiet, record=RunRecord())
    _session.summary.update(schema=JSON_SCHEMA, spherecal=__version__, command=args.command)
    started = time.time()
    real_stdout = sys.stdout
    code = EXIT_INTERNAL
    try:
        with _logging(args), (contextlib.redirect_stdout(sys.stderr) if args.json else contextlib.nullcontext()):
            _log.debug("spherecal %s: spherecal %s", __version__, " ".join(args._argv))
            code = _run(args)
            if args.json:
                sys.stderr.flush()
            else:
                sys.stdout.flush()  # a reader that closed the pipe shows here, inside the handler below
            _close_record(args, code, started)
        if args.json:
            _session.summary.update(exit_code=code, exit_meaning=EXIT_MEANING.get(code, "unknown"))
            _session.summary.setdefault("error", None)
            print(_json_text(_session.summary), file=real_stdout)
            real_stdout.flush()
        return code
    except BrokenPipeError:
        _quiet_broken_stdout()
        return EXIT_PIPE
    finally:
        _session = _Session()


def _json_text(summary: dict) -> str:
    import json

    order = ["schema", "spherecal", "command", "exit_code", "exit_meaning", "error", "verdict", "transform",
             "uncertainty", "files", "out_dir"]
    ordered = {k: summary[k] for k in order if k in summary} | {k: v for k, v in summary.items() if k not in order}
    return json.dumps(_plain(ordered), indent=2, allow_nan=False)


def _plain(value):
    """``value`` as plain JSON types: numpy numbers and arrays as numbers and lists, paths
    as strings, and a NaN or infinite number as null (JSON has none)."""
    import math

    import numpy as np

    if isinstance(value, dict):
        return {str(k): _plain(v) for k, v in value.items()}
    if isinstance(value, (list, tuple, np.ndarray)):
        return [_plain(v) for v in value]
    if isinstance(value, np.generic):
        value = value.item()
    if isinstance(value, float) and not math.isfinite(value):
        return None
    if isinstance(value, Path):
        return str(value)
    if value is None or isinstance(value, (str, int, float, bool)):
        return value
    return str(value)


def _close_record(args, code: int, started: float) -> None:
    """The end of the run: the files written into the summary, and the run's record
    appended to run.log in its output folder (when the folder exists)."""
    out = _session.out_dir
    files = _files_written()
    record = _session.record
    from spherecal.io.runlog import RUN_LOG_NAME

    # the record goes into a folder this run made, wrote into, or that keeps a record already: a
    # folder refused as someone else's (it holds their result) is left untouched
    ours = out is not None and (files or not _session.out_existed or RUN_LOG_NAME in _session.before)
    if ours and record is not None:
        head = [f"=== spherecal {__version__} {args.command}, started "
                f"{record._stamp(started)}, exit code {code} ({EXIT_MEANING.get(code, 'unknown')}) after "
                f"{time.time() - started:.1f} s",
                f"command line: spherecal {' '.join(args._argv)}"]
        if files:
            head.append("files written: " + ", ".join(sorted(files)))
        record.lines[:0] = head
        try:
            written = record.append_to(out)
        except (OSError, FileWriteError, InputError) as exc:  # the record must not hide the run's own outcome
            print(f"spherecal: warning: {out / RUN_LOG_NAME} not written: {exc}", file=sys.stderr)
            written = None
        if written is not None:
            files.setdefault(RUN_LOG_NAME, str(written))
    _session.summary.update(files=files, out_dir=str(out) if out is not None else None)


@contextlib.contextmanager
def _logging(args):
    """For one command: logger ``spherecal`` at DEBUG, a console handler on standard
    error (INFO; DEBUG with -v; WARNING with -q) and the run's record (everything).
    spherecal's own Python warnings (a dataset file cut off mid-line:
    :class:`~spherecal.io.dataset.TruncatedFileWarning`) become a ``warning:`` line on that
    logger, once each however often the file is read, so that they reach run.log too;
    other warnings are shown as Python shows them."""
    import warnings

    root = logging.getLogger("spherecal")
    console = logging.StreamHandler(sys.stderr)
    console.setFormatter(logging.Formatter("%(message)s"))
    console.setLevel(logging.WARNING if args.quiet else logging.DEBUG if args.verbose else logging.INFO)
    saved = root.level
    root.setLevel(logging.DEBUG)
    root.addHandler(console)
    root.addHandler(_session.record)
    shown: set[str] = set()

    def show(message, category, filename, lineno, file=None, line=None):
        if not (getattr(category, "__module__", "") or "").startswith("spherecal."):
            return python_show(message, category, filename, lineno, file, line)
        text = str(message)
        if text not in shown:
            shown.add(text)
            _RUN_LOG(f"warning: {text}")

    with warnings.catch_warnings():
        python_show = warnings.showwarning
        warnings.showwarning = show
        try:
            yield
        finally:
            root.removeHandler(console)
            root.removeHandler(_session.record)
            root.setLevel(saved)


def _quiet_broken_stdout() -> None:
    """Standard output's reader went away (``spherecal plugins | head``): point it at
    /dev/null so that the interpreter's last flush does not fail again."""
    try:
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())
        os.close(devnull)
    except (OSError, ValueError, AttributeError):  # not a real file (a test's capture): nothing to protect
        pass


def _run(args) -> int:
    try:
        return args.func(args)
    except BrokenPipeError:
        raise
    except KeyboardInterrupt:
        _err("interrupted" + _after_failure(args.command))
        return EXIT_INTERRUPTED
    except ConfigError as exc:
        _err(str(exc))
        return EXIT_USAGE
    except FileWriteError as exc:
        _err(f"{exc}" + _after_failure(args.command))
        return EXIT_DATA
    except (InputError, DegenerateDataError, DatasetFileError, FileExistsError) as exc:
        _err(str(exc))
        return EXIT_DATA
    except DeviceError as exc:
        _err(f"{exc}\n" + _after_failure(args.command).lstrip("; "))
        return EXIT_DEVICE
    except PluginError as exc:
        _err(str(exc))
        return EXIT_PLUGIN
    except OSError as exc:
        if exc.filename:  # a file that cannot be read or written (a full disk, no permission): name it
            _err(f"{exc.filename}: {exc.strerror or exc}" + _after_failure(args.command))
            return EXIT_DATA
        return _internal(args, exc)
    except Exception as exc:  # noqa: BLE001
        return _internal(args, exc)


def _internal(args, exc: BaseException) -> int:
    if args.debug:
        traceback.print_exc()
    _err(f"internal error: {type(exc).__name__}: {exc} (run with --debug for the traceback; please report it)")
    if _session.record is not None:
        _session.record.note("".join(traceback.format_exception(exc)), "spherecal.cli")
    return EXIT_INTERNAL

