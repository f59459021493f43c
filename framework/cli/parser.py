"""The ``spherecal`` command line's arguments: one parser, each command's options added
by its own function (docs/cli.md)."""

from __future__ import annotations

import argparse
import math

from spherecal import __version__
from spherecal.cli.output import EXIT_CODES_HELP

def _number(text: str, lo: float | None = None, hi: float | None = None, lo_open: bool = False) -> float:
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


#: The defaults of simulate's options for the standard cell (with --config these options
#: are refused, so the parser leaves them None and the simulate command fills them in).
SIMULATE_DEFAULTS = {"mounting": "eye_in_hand", "seed": 0, "profiles": 10, "point_noise_mm": 0.01,
                     "pose_noise_mm": 0.02, "stray_fraction": 0.0}


def flag(name: str) -> str:
    """The command-line flag of an argparse destination (``point_noise_mm`` -> ``--point-noise-mm``)."""
    return "--" + name.replace("_", "-")


OUT_HELP = "the run's output folder: {what} (default: {default})"
#: The help of --yes, for every command that moves a robot.
YES_HELP = "confirm the motion of a real robot without being asked (default: print the plan and ask for a typed 'yes')"


def _common_options(p: argparse.ArgumentParser, default) -> None:
    """--debug, -v and -q, before or after the command (``default``: SUPPRESS, so that
    a subcommand's parser leaves a value given before the command alone)."""
    p.add_argument("--debug", action="store_true", default=default, help="show tracebacks of internal errors")
    p.add_argument("-v", "--verbose", action="count", default=default,
                   help="more detail: calibrate and solve print every amber or red check and piece of advice and "
                   "then the parameter tables and the estimator's terms after their result (the report and run.log "
                   "hold them anyway); every command shows debug messages on standard error")
    p.add_argument("-q", "--quiet", action="store_true", default=default,
                   help="only warnings and errors on standard error (no progress); the result still goes to "
                   "standard output, and run.log records everything")


def build_parser(frame_options: dict[str, list[str]] | None = None) -> argparse.ArgumentParser:
    """The command line. ``frame_options``: the robot types' names for ``--controller-frame``
    (``{option: [robot type, ...]}``: :func:`spherecal.app.plugins.controller_frame_options`
    of the run's plugin host; default: none, only ``--controller-frame``)."""
    frame_options = frame_options or {}
    p = argparse.ArgumentParser(
        prog="spherecal",
        description="Calibrate a laser line sensor against a robot with a reference sphere.",
        epilog=EXIT_CODES_HELP,
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
    _calibrate(sub, common, as_json)
    _solve(sub, common, as_json)
    _simulate(sub, common, as_json)
    _validate(sub, common, as_json, frame_options)
    _scan(sub, common, as_json)
    _compare(sub, common, as_json, frame_options)
    _plugins(sub, common, as_json)
    _completion(sub, common, as_json)
    return p


def _calibrate(sub, common, as_json) -> None:
    """calibrate CONFIG: acquire (or replay) and calibrate."""
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
    c.add_argument("--yes", action="store_true", help=YES_HELP)
    c.add_argument("--step", action="store_true", help="ask before each station ('station S2: 10 shots from flange "
                   "(x, y, z) mm in base; go? [y/N/q]'): y goes, anything else stops with the journal kept and the "
                   "resume command printed; needs a terminal on standard input")


def _solve(sub, common, as_json) -> None:
    """solve DATASET: calibrate a recorded dataset."""
    s = sub.add_parser("solve", parents=[common, as_json], help="calibrate a recorded dataset (no devices)",
                       description="Calibrate a recorded dataset without devices and write the result, exports "
                       "and report. Flange poses are the reported base_from_flange; observations with joint "
                       "readings only go through the robot plugin's forward kinematics (--robot).")
    s.add_argument("dataset", help="dataset file (.jsonl), a recording in the stream form (.jsonl, version 3) or a "
                   "ROS 2 bag (its folder, .mcap or .db3; give the topics, --mounting and --sphere-radius-mm)")
    s.add_argument("-o", "--out", metavar="DIR", help=OUT_HELP.format(
        what="result, exports, report and run.log are written there", default="<dataset>.calibration next to it"))
    bag = s.add_argument_group("recordings (a pose stream and a profile stream on two clocks; docs/on-the-fly.md)")
    bag.add_argument("--clock-offset-ms", type=float, metavar="MS", help="a start for the clock offset, robot clock "
                     "minus sensor clock (default: searched from the data)")
    bag.add_argument("--profile-topic", metavar="TOPIC", help="a bag's profiles: sensor_msgs/msg/PointCloud2, metres, "
                     "one message per profile")
    bag.add_argument("--pose-topic", metavar="TOPIC", help="a bag's flange poses: geometry_msgs/msg/PoseStamped, "
                     "tf2_msgs/msg/TFMessage (with --base-frame and --flange-frame) or sensor_msgs/msg/JointState "
                     "(with --robot)")
    bag.add_argument("--mounting", choices=["eye_in_hand", "eye_to_hand"], help="a bag's mounting (a bag does not say)")
    bag.add_argument("--sphere-radius-mm", type=_positive_float, metavar="MM", help="the sphere's certified radius")
    bag.add_argument("--line-axis", choices=["y", "x"], default="y", help="the cloud axis the laser line runs along "
                     "(default y, the project's laser plane being the sensor's y-z plane; x for drivers that put it "
                     "along x)")
    bag.add_argument("--base-frame", metavar="FRAME", help="the robot's base frame: with a /tf pose topic, the "
                     "chain's start; else the PoseStamped frame_id it must be, or (joint states) the name the ROS "
                     "exports give it")
    bag.add_argument("--flange-frame", metavar="FRAME", help="the flange frame: with a /tf pose topic, the chain's "
                     "end; else the name the ROS exports give it (default tool0)")
    s.add_argument("--fit-radius", action=argparse.BooleanOptionalAction, default=None,
                   help="estimate the sphere radius too (default: no; a journal of calibrate: as its run did)")
    s.add_argument("--nominal", help="rough X as x,y,z,qw,qx,qy,qz (mm, w first) to settle ambiguous data "
                   "(default: none; a journal of calibrate: its run's nominal transform)")
    s.add_argument("--robot", metavar="TYPE", help="robot type whose kinematics computes flange poses from joints_deg "
                   "(default: the robot the dataset's provenance names; `spherecal plugins` lists them)")
    s.add_argument("--robot-config", metavar="FILE.toml", help="the robot's settings (its [robot] table, e.g. "
                   "the calibration configuration); default: the plugin's defaults")
    s.add_argument("--pose-from", choices=["reported", "joints"], default="reported",
                   help="reported (default): each observation's base_from_flange, kinematics only where it is "
                   "missing; joints: every flange pose from joints_deg through the robot's kinematics")
    s.add_argument("--station-rotation-tolerance-deg", type=_positive_float, metavar="DEG",
                   help="a shot turned more than this from its station's orientation is left out "
                   "(default: derived from the orientation read noise; a journal of calibrate: its run's setting)")
    s.add_argument("--robot-error-model", choices=["auto", "kinematic", "station", "kinematic+station", "none"],
                   help="the robot's systematic error (docs/estimation.md): auto (default; a journal of "
                   "calibrate: its run's setting) is kinematic when joints and the robot's kinematics are known, else "
                   "station; none for a calibrated robot whose error is within its repeatability")
    s.add_argument("--identify-kinematics", action=argparse.BooleanOptionalAction, default=None,
                   help="kinematic calibration: estimate the arm's identifiable geometric errors too (default: a journal of "
                   "calibrate: as its run did; needs --robot "
                   "and joints_deg); writes robot_calibrated.urdf")
    s.add_argument("--no-report", action="store_true", help="skip the HTML report")
    s.add_argument("--force", action="store_true", help="write result.json and the exports even when the result is "
                   "RED (the exit code is still 7)")
    s.add_argument("--operator", metavar="NAME", help="who ran the calibration, for the report and the result")
    s.add_argument("--overwrite", action="store_true", help="replace the result, exports and report already in the "
                   "output folder (default: refuse)")


def _simulate(sub, common, as_json) -> None:
    """simulate OUT: a dataset from the simulated cell."""
    m = sub.add_parser("simulate", parents=[common], help="write a dataset from the simulated cell")
    m.add_argument("out", help="dataset file to write (.jsonl): stop-and-go observations, or with --on-the-fly a "
                   "recording of pose and profile streams")
    m.add_argument("--config", help="take the cell and plan from this configuration's [simulation] and [acquisition]")
    m.add_argument("--sensor", metavar="TYPE", help="the sensor type to simulate (its registered name, as in "
                   "`spherecal plugins`): the cell measures with its declared field of view and the plan fits it "
                   "(default: the only installed sensor type that declares one); not with --config, whose [sensor] "
                   "names it")
    # (defaults applied by the simulate command: with --config these options are refused, so their absence must show)
    d = SIMULATE_DEFAULTS
    m.add_argument("--mounting", choices=["eye_in_hand", "eye_to_hand"], help=f"default {d['mounting']}")
    m.add_argument("--seed", type=_int_in(0, 2**63 - 1), help=f"default {d['seed']}")
    m.add_argument("--profiles", type=_int_in(4, 10_000),
                   help=f"profiles per station (4 to 10000, default {d['profiles']})")
    m.add_argument("--point-noise-mm", type=_non_negative_float, help=f"default {d['point_noise_mm']}")
    m.add_argument("--pose-noise-mm", type=_non_negative_float, help=f"default {d['pose_noise_mm']}")
    m.add_argument("--stray-fraction", type=_fraction,
                   help=f"share of profiles with stray points (0 to 1, default {d['stray_fraction']:g})")
    m.add_argument("--on-the-fly", action="store_true",
                   help="write an on-the-fly recording instead (dataset format version 3, stream form): at each "
                   "station continuous sweeps forth and back at 50 and 100 mm/s along two directions, a 250 Hz pose "
                   "stream on the robot's clock with smooth repeatability noise (the pose noise), losses and "
                   "jitter, a 300 Hz profile stream on the sensor's clock, the clocks 35 ppm apart; the true time "
                   "offset and drift go into its provenance. --profiles does not apply")
    m.add_argument("--force", action="store_true", help="overwrite an existing file")


def _validate(sub, common, as_json, frame_options) -> None:
    """validate CONFIG: the acceptance test of a calibration."""
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
    v.add_argument("--yes", action="store_true", help=YES_HELP)


def _scan(sub, common, as_json) -> None:
    """scan CONFIG: an object into a PLY point cloud."""
    n = sub.add_parser("scan", parents=[common], help="scan an object with the calibrated system into a PLY point cloud",
                       description="Sweep the object of the [scan] section and stream its points, mapped into the "
                       "frame the object is fixed in (base in eye-in-hand), to a PLY file.")
    n.add_argument("config", help="configuration file (TOML) with a [scan] section")
    n.add_argument("-o", "--out", metavar="DIR", help=OUT_HELP.format(
        what="its result.json maps the points, and the PLY and run.log are written there",
        default="output_dir of the configuration"))
    n.add_argument("--yes", action="store_true", help=YES_HELP)


def _compare(sub, common, as_json, frame_options) -> None:
    """compare A [B]: two calibrations, or one and a given transform."""
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


def _plugins(sub, common, as_json) -> None:
    """plugins: the installed plugins."""
    sub.add_parser("plugins", parents=[common],
                   help="list installed robots, sensors and exporters with their configuration fields")


def _completion(sub, common, as_json) -> None:
    """completion SHELL: a shell completion script."""
    o = sub.add_parser("completion", parents=[common], help="print a shell completion script (bash or zsh)",
                       description="Print a completion script for the shell: bash (source it, or put it in "
                       "~/.local/share/bash-completion/completions/spherecal) or zsh (save it as _spherecal in a "
                       "folder of $fpath). docs/cli.md, 'Shell completion'.")
    o.add_argument("shell", choices=["bash", "zsh"])
