"""spherecal compare: results, run folders, numbers and controller lines; exit codes."""

import numpy as np
import pytest

from spherecal.io import dataset as dataio
from spherecal.core import geometry as geo
from spherecal.cli import EXIT_DATA, EXIT_DRIFT, EXIT_OK, EXIT_USAGE, main
from spherecal.estimation import calibrate
from spherecal.core.models import Pose
from spherecal.sim import SweepPlan, simulate_dataset, standard_cell
from reference_sensor import reference_fov


@pytest.fixture(scope="module")
def results(tmp_path_factory):
    """A result, the same result moved by 0.25 deg about flange z and 0.4 mm along x
    (a run folder), and an eye-to-hand result."""
    root = tmp_path_factory.mktemp("compare")
    r = calibrate(simulate_dataset(standard_cell("eye_in_hand", seed=7, fov=reference_fov()),
                                   SweepPlan(profiles_per_station=6)))
    X = r.transform
    moved = Pose.from_rt(geo.matrix_from_rotvec([0, 0, np.radians(0.25)]) @ X.rotation_matrix,
                         X.translation + [0.4, 0, 0])
    dataio.write_result(root / "a.json", r)
    (root / "run_b").mkdir()
    dataio.write_result(root / "run_b" / "result.json", r.model_copy(update={"transform": moved}))
    e = calibrate(simulate_dataset(standard_cell("eye_to_hand", seed=7, fov=reference_fov()),
                                   SweepPlan(profiles_per_station=6)))
    dataio.write_result(root / "eth.json", e)
    return root, X, moved


def test_drift_between_a_result_and_a_run_folder(results, capsys):
    root, _, _ = results
    assert main(["compare", str(root / "a.json"), str(root / "run_b")]) == EXIT_OK
    out = capsys.readouterr().out
    assert "flange_from_sensor: B relative to A" in out
    assert "rotation:    0.2500 deg; about x, y, z: +0.0000, +0.0000, +0.2500 deg" in out
    assert "translation: 0.4000 mm; along x, y, z: +0.4000, +0.0000, +0.0000 mm" in out
    assert "Mahalanobis distance" in out and "drift: YES" in out
    assert main(["compare", str(root / "a.json"), str(root / "run_b"), "--fail-on-drift"]) == EXIT_DRIFT
    assert "drift found (exit 8)" in capsys.readouterr().err
    # thresholds above the difference: no drift, exit 0 even with --fail-on-drift
    assert main(["compare", str(root / "a.json"), str(root / "run_b"), "--fail-on-drift",
                 "--threshold-mm", "0.5", "--threshold-deg", "0.3"]) == EXIT_OK
    assert "drift: no" in capsys.readouterr().out


def test_a_result_against_itself_is_no_drift(results, capsys):
    root, _, _ = results
    assert main(["compare", str(root / "a.json"), str(root / "a.json"), "--fail-on-drift"]) == EXIT_OK
    out = capsys.readouterr().out
    assert "Mahalanobis distance 0.00" in out and "drift: no" in out


def test_a_transform_given_as_numbers_and_as_a_tooldata_line(results, capsys):
    root, X, moved = results
    t, q = moved.translation_mm, moved.quaternion_wxyz
    numbers = ",".join(f"{v:.10f}" for v in (*t, *q))
    assert main(["compare", str(root / "a.json"), "--transform", numbers, "--fail-on-drift"]) == EXIT_DRIFT
    out = capsys.readouterr().out
    assert "translation: 0.4000 mm" in out and f"B: --transform {numbers}" in out
    line = (f"[TRUE,[[{t[0]:.6f},{t[1]:.6f},{t[2]:.6f}],[{q[0]:.9f},{q[1]:.9f},{q[2]:.9f},{q[3]:.9f}]],"
            "[1,[0,0,80],[1,0,0,0],0,0,0]]")
    assert main(["compare", str(root / "a.json"), "--tooldata", line]) == EXIT_OK
    out = capsys.readouterr().out
    assert "rotation:    0.2500 deg" in out and "translation: 0.4000 mm" in out and "(tooldata)" in out
    # with a stated uncertainty of B so large that 0.4 mm and 0.25 deg are within it: no drift
    assert main(["compare", str(root / "a.json"), "--tooldata", line, "--std-mm", "1", "--std-deg", "0.5",
                 "--fail-on-drift"]) == EXIT_OK
    assert "not significant at 0.01" in capsys.readouterr().out


def test_a_transform_file(results, tmp_path, capsys):
    root, X, _ = results
    f = tmp_path / "tool.txt"
    f.write_text("# the controller's current tool, mm and w first\n"
                 + " ".join(f"{v:.10f}" for v in (*X.translation_mm, *X.quaternion_wxyz)) + "\n")
    assert main(["compare", str(root / "a.json"), "--transform", str(f), "--fail-on-drift"]) == EXIT_OK
    assert "translation: 0.0000 mm" in capsys.readouterr().out


def test_different_transforms_are_refused(results, capsys):
    root, _, _ = results
    assert main(["compare", str(root / "a.json"), str(root / "eth.json")]) == EXIT_DATA
    err = capsys.readouterr().err
    assert "cannot compare different transforms" in err and "flange_from_sensor" in err and "base_from_sensor" in err
    # a stationary tool (base_from_sensor) against a flange_from_sensor result
    assert main(["compare", str(root / "a.json"), "--tooldata", "[FALSE,[[1,2,3],[1,0,0,0]]]"]) == EXIT_DATA
    assert "base_from_sensor" in capsys.readouterr().err


@pytest.mark.parametrize("extra, message", [
    ([], "compare A with one of: a second result (B), --transform or --tooldata"),
    (["--transform", "1,2,3,1,0,0"], "--transform takes x,y,z,qw,qx,qy,qz"),
    (["--tooldata", "[TRUE,[[1,2,3],[1,0,0]]]"], "--tooldata: tooldata tframe.rot: expected 4 numbers, got 3"),
    (["--tooldata", "tool0"], "is not a frame any installed robot plugin reads"),
    (["--transform", "1,2,3,1,0,0,0", "--tooldata", "[TRUE,[[1,2,3],[1,0,0,0]]]"], "give one of --transform"),
    (["--controller-frame", "[TRUE,[[1,2,3],[1,0,0,0]]]", "--tooldata", "[TRUE,[[1,2,3],[1,0,0,0]]]"],
     "(given: --controller-frame, --tooldata)"),
    (["--controller-frame", "[TRUE,[[1,2,3],[1,0,0]]]"], "--controller-frame: tooldata tframe.rot: expected 4"),
    (["--std-mm", "0.1"], "--std-mm and --std-deg are the uncertainty of --transform or --tooldata"),
])
def test_usage_errors_exit_2(results, capsys, extra, message):
    root, _, _ = results
    assert main(["compare", str(root / "a.json"), *extra]) == EXIT_USAGE
    assert message in capsys.readouterr().err


def test_a_folder_without_a_result(results, tmp_path, capsys):
    root, _, _ = results
    assert main(["compare", str(root / "a.json"), str(tmp_path)]) == EXIT_DATA
    assert "is a folder without a result.json" in capsys.readouterr().err


def test_the_generic_controller_frame_option_reads_as_the_robot_types_own_name(results, capsys):
    """--controller-frame is the core's option; --tooldata the ABB plugin's name for it
    (RobotType.frame_option): both go to the same reader and give the same comparison."""
    root, _, moved = results
    t, q = moved.translation_mm, moved.quaternion_wxyz
    line = (f"[TRUE,[[{t[0]:.6f},{t[1]:.6f},{t[2]:.6f}],[{q[0]:.9f},{q[1]:.9f},{q[2]:.9f},{q[3]:.9f}]],"
            "[1,[0,0,80],[1,0,0,0],0,0,0]]")
    outs = []
    for option in ("--controller-frame", "--tooldata"):
        assert main(["compare", str(root / "a.json"), option, line]) == EXIT_OK
        outs.append(capsys.readouterr().out)
    assert "translation: 0.4000 mm" in outs[0]
    assert outs[0].replace("--controller-frame", "--tooldata") == outs[1]


def test_a_robot_types_frame_option_is_offered_and_named_in_messages(capsys):
    from spherecal.cli import build_parser

    parser = build_parser({"tool-frame": ["acme_arm"], "tooldata": ["abb_irb2400"]})
    args = parser.parse_args(["compare", "a.json", "--tool-frame", "LINE"])
    assert args.controller_frame == [("--tool-frame", "LINE")]
    assert args.frame_words == "--tool-frame / --tooldata / --controller-frame"
    assert build_parser({}).parse_args(["compare", "a.json"]).frame_words == "--controller-frame"
    with pytest.raises(SystemExit):  # without the robot type, its name is not an option
        build_parser({}).parse_args(["compare", "a.json", "--tool-frame", "LINE"])
    assert "unrecognized arguments: --tool-frame" in capsys.readouterr().err


def test_the_reserved_option_names_hold_every_option_of_compare_and_validate():
    """A robot type's frame_option is refused when it is one of RESERVED_OPTION_NAMES: that
    list must hold every option the two commands have."""
    from spherecal.cli import build_parser
    from spherecal.devices.contract import RESERVED_OPTION_NAMES

    parser = build_parser({})
    sub = next(a for a in parser._actions if a.__class__.__name__ == "_SubParsersAction")
    for command in ("compare", "validate"):
        names = {o[2:] for a in sub.choices[command]._actions for o in a.option_strings if o.startswith("--")}
        assert names <= RESERVED_OPTION_NAMES, names - RESERVED_OPTION_NAMES
    assert {o[2:] for a in parser._actions for o in a.option_strings if o.startswith("--")} <= RESERVED_OPTION_NAMES


def test_the_core_names_no_controller_brand_data_type():
    """The core knows no robot brand: the ABB data types are the ABB plugin's words."""
    from pathlib import Path

    import spherecal

    core = Path(spherecal.__file__).parent
    hits = [str(p.relative_to(core)) for p in core.rglob("*.py")
            if p.is_file() and not {"robots", "sensors", "plugins"} & set(p.relative_to(core).parts)
            and any(w in p.read_text(encoding="utf-8").lower() for w in ("tooldata", "wobjdata"))]
    assert hits == []
