"""The report's robot error section and what it says of a kinematic calibration: the
estimator's terms the terminal leaves to -v (which model and why, the likelihood ratio,
the arm's parameters marginalised with their prior spread, the point error's parts), and
for a calibrated arm the accuracy that holds only through the calibrated model, the
nominal model's figure, the identified parameters and the calibrated URDF."""

from __future__ import annotations

import html
import re
from dataclasses import replace

import pytest

from spherecal.estimation import solve
from spherecal.plugins.host import PluginHost
from spherecal.report.html import write_report
from spherecal.sim import RobotErrorModel, SweepPlan, simulate_dataset, standard_cell
from kinematic_results import as_kinematic_calibration
from reference_sensor import reference_fov


@pytest.fixture(scope="module")
def arm_solution():
    """The eye-in-hand cell with an arm off its model by a real arm's error, four stations
    with joints: the marginalised kinematic model, as 'auto' chooses it."""
    kin = PluginHost().arm_kinematics({"type": "abb_irb2400"})
    cell = standard_cell("eye_in_hand", seed=3, robot_error=RobotErrorModel(), arm=kin,
                         fov=reference_fov(n_columns=160))
    return solve(simulate_dataset(cell, SweepPlan(profiles_per_station=4)), kinematics=kin)


def _text(path) -> str:
    """The report's visible text, tags and the inline script and style left out."""
    t = path.read_text(encoding="utf-8")
    t = re.sub(r"<(script|style)\b.*?</\1>", " ", t, flags=re.S)
    return " ".join(html.unescape(re.sub(r"<[^>]+>", " ", t)).split())


def _section(text: str, start: str, end: str) -> str:
    i = text.index(start)
    return text[i:text.index(end, i)]


def test_the_report_holds_the_estimator_terms_the_terminal_leaves_to_v(arm_solution, tmp_path):
    err = arm_solution.result.robot_error
    assert err.model == "kinematic" and "likelihood ratio" in err.model_choice
    text = _text(write_report(arm_solution, tmp_path))
    assert text.index("A point measured at a new pose A point measured at a new pose, with the robot as it is: "
                      f"expected error {err.point_error_k2_mm:.3f} mm (k = 2)") < text.index("Verdict:")
    robot = _section(text, "Robot error Model:", "Stations")
    assert "geometric parameters seen by the data, all marginalised (their prior spread x 1.00" in robot
    assert err.model_choice in robot  # auto's choice and its likelihood ratio
    assert "The stations disagree by " in robot
    for part, value in err.point_error_parts_rms_mm.items():
        assert f"{value:.4f}" in robot, part
    assert f"expected error, k = 2 {err.point_error_k2_mm:.4f}" in robot
    assert "nominal arm model" not in text and "KINEMATIC CALIBRATION" not in text
    assert 'href="#robot"' in (tmp_path / "report.html").read_text()


def test_a_kinematic_calibration_s_report_says_where_its_accuracy_holds(arm_solution, tmp_path):
    """Both figures above the verdict, the nominal model's first, marked; the identified
    parameters (and no other) with their 1-sigma; the calibrated URDF linked and shown
    when written, and said not written otherwise."""
    solution = replace(arm_solution, result=as_kinematic_calibration(arm_solution.result))
    urdf = tmp_path / "robot_calibrated.urdf"
    urdf.write_text('<?xml version="1.0"?>\n<robot name="spherecal_calibrated_robot"/>\n')
    path = write_report(solution, tmp_path, calibrated_urdf=urdf)
    raw, text = path.read_text(), _text(path)
    top = text[:text.index("Verdict:")]
    assert top.index("on the controller's nominal arm model (the exported transform without the calibrated model): "
                     "expected error 0.362 mm (k = 2)") < top.index("Through spherecal's calibrated arm model "
                                                                   "(robot_calibrated.urdf): expected error 0.075 mm")
    assert "this accuracy holds only where poses go through that model" in top
    robot = _section(text, "Robot error Model:", "Stations")
    assert "expected error on the controller's nominal arm model, k = 2 0.3620" in robot
    assert ("KINEMATIC CALIBRATION: this transform goes with spherecal's calibrated arm model (robot_calibrated.urdf); "
            "a point measured at a new pose is within 0.075 mm (k = 2) only where poses go through that model; on the "
            "controller's nominal model expect 0.362 mm (k = 2)") in robot
    assert "joint_2.zero_offset 0.0321 0.0012 deg" in robot and "joint_3.z -0.2140 0.0087 mm" in robot
    assert "joint_1.zero_offset" not in robot and "the other 1 parameters are held at their nominal values" in robot
    assert '<a href="robot_calibrated.urdf">robot_calibrated.urdf</a>' in raw
    assert html.escape('<robot name="spherecal_calibrated_robot"/>', quote=True) in raw
    unwritten = _text(write_report(solution, tmp_path / "red"))
    assert "robot_calibrated.urdf was not written" in unwritten
