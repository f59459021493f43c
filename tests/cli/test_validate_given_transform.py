"""spherecal validate --transform / --tooldata: a transform spherecal did not compute
(the controller's current tool), validated on the simulated cell."""

import json

import numpy as np
import pytest

from spherecal.cli import EXIT_OK, EXIT_USAGE, EXIT_VALIDATION, main
from spherecal.config import load_config
from tests.cli.cells import simulated_cell


@pytest.fixture
def cfg_path(sim_config):
    # a clean cell (an exact arm); the sphere's four views only, 8 profiles each (a few seconds)
    return sim_config("sim-eye-in-hand.toml", exact_arm=True, **{
        r"^profiles_per_sweep = 24$": "profiles_per_sweep = 8",
        r"^\[validation\.(?:ball_bar|flat)\].*(?:\n(?!\[).*)*": "",
    })


def _numbers(pose) -> str:
    return ",".join(f"{v:.10f}" for v in (*pose.translation_mm, *pose.quaternion_wxyz))


@pytest.mark.slow
def test_the_true_transform_passes_and_one_1_mm_off_fails(cfg_path, capsys):
    out = cfg_path.parent / "out"
    true = simulated_cell(load_config(cfg_path).config).true_transform
    assert not (out / "result.json").exists()  # no calibration: the transform is given
    assert main(["validate", str(cfg_path), "--transform", _numbers(true)]) == EXIT_OK
    captured = capsys.readouterr()
    assert "validation passed" in captured.out
    assert "validating --transform" in captured.err
    v = json.loads((out / "validation.json").read_text())
    assert v["passed"] is True and v["transform_given"] is True
    np.testing.assert_allclose(v["transform"]["translation_mm"], true.translation_mm, atol=1e-9)
    assert not (out / "report.html").exists()  # the report is a calibration's: left alone

    t = np.asarray(true.translation_mm) + [1.0, 0.0, 0.0]
    q = true.quaternion_wxyz
    line = (f"PERS tooldata tLaser := [TRUE,[[{t[0]:.4f},{t[1]:.4f},{t[2]:.4f}],"
            f"[{q[0]:.8f},{q[1]:.8f},{q[2]:.8f},{q[3]:.8f}]],[1,[0,0,80],[1,0,0,0],0,0,0]];")
    assert main(["validate", str(cfg_path), "--tooldata", line]) == EXIT_VALIDATION
    captured = capsys.readouterr()
    assert "FAILED" in captured.out and "(tooldata tLaser)" in captured.err
    v = json.loads((out / "validation.json").read_text())
    assert v["passed"] is False
    # 1 mm along flange x moves the sphere by R_k (1, 0, 0) at view k: the centres spread
    assert v["figures"]["centre spread"]["max error (mm)"] > 0.3


def test_a_transform_of_the_other_mounting_is_refused(cfg_path, capsys):
    # a stationary tool is base_from_sensor; the configuration calibrates flange_from_sensor
    assert main(["validate", str(cfg_path), "--tooldata", "[FALSE,[[1250,-200,900],[0,1,0,0]]]"]) == EXIT_USAGE
    err = capsys.readouterr().err
    assert "is base_from_sensor" in err and "flange_from_sensor (eye_in_hand)" in err
