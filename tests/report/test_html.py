"""The HTML report and the verdict/advice behind it."""

import base64
import re

import numpy as np
import pytest

from spherecal.core.errors import InputError
from spherecal.estimation import solve
from spherecal.io.exporters import ExportNote
from spherecal.core.models import ObservationFlag, Pose
from spherecal.report.assess import Thresholds, advice, calibration_std, inconsistent_stations, verdict
from spherecal.report.html import FIGURE_NAMES, mapped_points, write_report
from spherecal.sim import NoiseModel, SweepPlan, simulate_dataset, standard_cell
from reference_sensor import reference_fov

PLAN = SweepPlan(profiles_per_station=6)
SHIFTED = 8  # observation whose pose is read 1 mm off


def _shift_pose(ds, index, offset_mm):
    obs = list(ds.observations)
    o = obs[index]
    pose = Pose.from_rt(o.base_from_flange.rotation_matrix, o.base_from_flange.translation + offset_mm)
    obs[index] = o.model_copy(update={"base_from_flange": pose})
    return ds.model_copy(update={"observations": obs})


@pytest.fixture(scope="module")
def bad_solution():
    """Eye-in-hand, stray points on a third of the profiles, one pose shifted by 1 mm."""
    cell = standard_cell("eye_in_hand", seed=3, noise=NoiseModel(stray_profile_fraction=0.3,
                                                                 strays_per_profile=8), fov=reference_fov())
    ds = _shift_pose(simulate_dataset(cell, PLAN), SHIFTED, [0.0, 1.0, 0.0])
    return solve(ds)


@pytest.fixture(scope="module")
def bad_report(bad_solution, tmp_path_factory):
    out = tmp_path_factory.mktemp("bad")
    validation = {
        "sphere centre repeatability (mm)": {"value": 0.031, "limit": 0.1, "passed": True},
        "probe point error (mm)": {"value": 0.42, "limit": 0.2, "passed": False},
        "check poses": 12,
    }
    path = write_report(bad_solution, out, title="Cell 3 <eye-in-hand>", validation=validation, notes=NOTES)
    return path, path.read_text(encoding="utf-8")


#: What the run's exporters say about the controller: a robot plugin's first, then ROS.
NOTES = (ExportNote("Toy controller", "On a toy controller this is <tool.frame>.", code="TOOL t := [1, 2, 3];"),
         ExportNote("ROS 2", "Publish it with the command below.", code="ros2 run tf2_ros static_transform_publisher"))


@pytest.fixture(scope="module")
def clean_solution():
    return solve(simulate_dataset(standard_cell("eye_to_hand", seed=3, fov=reference_fov()), PLAN))


# --- the file -----------------------------------------------------------------------------------------
@pytest.mark.slow
def test_report_is_written_with_its_figures(bad_report):
    path, text = bad_report
    assert path.name == "report.html" and text.startswith("<!DOCTYPE html>")
    assert not (path.parent / "report_residuals_per_centre.png").exists()  # profiles only: no centre figure
    for key in [k for k in FIGURE_NAMES if k != "residuals_per_centre"]:
        png = path.parent / f"report_{key}.png"
        data = png.read_bytes()
        assert data[:8] == b"\x89PNG\r\n\x1a\n" and len(data) > 5000
        # the same image is embedded in the page
        assert f'src="data:image/png;base64,{base64.b64encode(data).decode()}"' in text


def test_report_is_self_contained(bad_report):
    _, text = bad_report
    assert not re.search(r"""(?:src|href)\s*=\s*["']?\s*(?:https?:)?//""", text, re.IGNORECASE)
    assert "http://" not in text and "https://" not in text
    assert "<link" not in text and "@import" not in text
    # the only scripts are inline: the interactive view's data and its own code (no src, nothing fetched)
    assert re.findall(r"<script([^>]*)>", text) == [' type="application/json" id="view3d-data"', ""]
    # every src is a data URI and every href an anchor in the page
    assert all(s.startswith("data:image/png;base64,") for s in re.findall(r'src="([^"]*)"', text))
    anchors = re.findall(r'href="#([^"]+)"', text)
    assert anchors and all(f'id="{a}"' in text for a in anchors)
    assert re.findall(r'href="([^"]*)"', text) == [f"#{a}" for a in anchors]


def test_report_shows_the_key_numbers(bad_solution, bad_report):
    _, text = bad_report
    r = bad_solution.result
    assert "Cell 3 &lt;eye-in-hand&gt;" in text  # the title, escaped
    assert "flange_from_sensor" in text and "sensor_from_flange" in text
    for v in r.transform.translation_mm:
        assert f"{v:.4f}" in text
    for v in r.std_rotation_deg + r.std_translation_mm + r.std_sphere_centre_mm:
        assert f"{v:.4f}" in text
    assert f"{r.residuals.rms_mm:.4f}" in text
    for label, cons in r.diagnostics.station_consistency.items():
        assert f"<td>{label}</td>" in text and f"{cons['rms_mm']:.4f}" in text
    section = text[text.index('id="controller"'):text.index('id="advice"')]
    # the exporters' notes in their order, escaped: the report itself names no controller
    assert section.index("Toy controller") < section.index("ROS 2")
    assert "On a toy controller this is &lt;tool.frame&gt;." in section and "<pre>TOOL t := [1, 2, 3];</pre>" in section
    assert "static_transform_publisher" in section


def test_report_lists_the_flagged_observation_and_why(bad_solution, bad_report):
    _, text = bad_report
    flags = bad_solution.result.flagged
    assert [f.index for f in flags] == [SHIFTED]
    assert f"<td>{SHIFTED}</td>" in text
    assert bad_solution.result.flagged[0].reason.split("(")[0].strip() in text
    # the advice names the observation and the likely cause
    assert f"Observation(s) {SHIFTED} (station {flags[0].station}): likely pose read at the wrong moment" in text


def test_report_advises_on_stray_points(bad_solution, bad_report):
    _, text = bad_report
    assert bad_solution.result.residuals.n_points_rejected > 0
    assert "Stray points rejected" in text and f"{bad_solution.result.residuals.n_points_rejected} of" in text


def test_report_validation_table(bad_report):
    _, text = bad_report
    section = text[text.index('id="validation"'):text.index('id="details"')]
    assert "probe point error (mm)" in section and "0.4200" in section and "check poses" in section
    assert section.count('<tr class="bad">') == 1  # the row that did not pass


@pytest.mark.slow
def test_report_without_validation_and_other_mounting(clean_solution, tmp_path):
    path = write_report(clean_solution, tmp_path, filename="cal.html")
    text = path.read_text()
    assert 'id="validation"' not in text
    assert all((tmp_path / f"cal_{k}.png").is_file() == (k != "residuals_per_centre") for k in FIGURE_NAMES)
    assert "base_from_sensor" in text and "No exporter of this run says how to load the result" in text
    assert 'class="verdict green"' in text and "Nothing calls for action" in text


def test_report_rejects_what_is_not_a_solution(clean_solution, tmp_path):
    with pytest.raises(InputError, match="needs the Solution returned by spherecal.estimation.solve"):
        write_report(clean_solution.result, tmp_path)
    with pytest.raises(InputError, match="must be a plain file name ending in .html"):
        write_report(clean_solution, tmp_path, filename="../x.html")
    with pytest.raises(InputError, match="validation must be a mapping"):
        write_report(clean_solution, tmp_path, validation=[1, 2])
    with pytest.raises(InputError, match="notes must be a sequence of spherecal.io.exporters.ExportNote"):
        write_report(clean_solution, tmp_path, notes=["On a controller ..."])


def test_mapped_points_lie_on_the_fitted_sphere(clean_solution):
    ref = clean_solution.refined
    pts = mapped_points(clean_solution)
    assert len(pts) == clean_solution.problem.n_profiles
    dist = np.linalg.norm(np.vstack(pts) - ref.centre, axis=1) - ref.radius
    assert np.sqrt(np.mean(dist**2)) < 3 * clean_solution.result.residuals.rms_mm
    assert np.abs(dist).max() < 0.3


# --- verdict and advice ------------------------------------------------------------------------------------
def test_clean_data_is_green_with_nothing_to_do(clean_solution):
    v = verdict(clean_solution.result)
    assert v.level == "green" and all(level == "green" for level, _ in v.reasons)
    assert advice(clean_solution.result) == []


def test_wrong_sphere_radius_asks_to_check_it():
    ds = simulate_dataset(standard_cell("eye_in_hand", seed=3, fov=reference_fov()), PLAN)
    res = solve(ds.model_copy(update={"sphere_radius_mm": 19.0})).result  # certified 19.1
    v = verdict(res)
    assert v.level == "red"
    items = {a.key: a for a in advice(res)}
    assert "residual_rms_high" in items and "check the sphere radius" in items["residual_rms_high"].text.lower()
    assert "solve --fit-radius" in items["residual_rms_high"].text
    assert "=True" not in items["residual_rms_high"].text


def test_a_station_read_before_settling_is_named():
    ds = simulate_dataset(standard_cell("eye_to_hand", seed=3, fov=reference_fov()), PLAN)
    obs = [o.model_copy(update={"base_from_flange": Pose.from_rt(
        o.base_from_flange.rotation_matrix, o.base_from_flange.translation + [0.0, 0.15 * (o.index % 6), 0.0])})
        if o.station == "S2" else o for o in ds.observations]
    res = solve(ds.model_copy(update={"observations": obs})).result
    items = {a.key: a for a in advice(res)}
    if "S2" in res.diagnostics.station_consistency:  # kept: named as inconsistent
        assert list(inconsistent_stations(res)) == ["S2"]
        assert "S2" in items["station_inconsistent"].text and "before the" in items["station_inconsistent"].text
    else:  # its shifted shots left out one by one, then the station for want of shots: every one flagged
        s2 = [o.index for o in obs if o.station == "S2"]
        assert sorted(f.index for f in res.flagged if f.station == "S2") == s2
        assert "S2" in items["flagged"].text and "pose read at the wrong moment" in items["flagged"].text
    assert "residual_rms_high" not in items  # the station explains the residuals


def _with_std(result, rot=None, tr=None):
    """``result`` with the calibration's own standard deviations replaced (both the
    reported ones and those relative to the robot's frame, which the verdict grades)."""
    upd, re_upd = {}, {}
    if rot is not None:
        upd["std_rotation_deg"] = re_upd["std_rotation_deg_robot_frame"] = rot
    if tr is not None:
        upd["std_translation_mm"] = re_upd["std_translation_mm_robot_frame"] = tr
    if result.robot_error is not None:
        upd["robot_error"] = result.robot_error.model_copy(update=re_upd)
    return result.model_copy(update=upd)


def test_one_weak_rotation_axis_asks_for_a_tilt_about_it(clean_solution):
    res = _with_std(clean_solution.result, rot=(0.01, 0.09, 0.012))
    items = {a.key: a for a in advice(res)}
    assert set(k for k in items if k.startswith("rotation")) == {"rotation_axis_y"}
    assert "tilted by 20-30 deg about the base's y axis" in items["rotation_axis_y"].text
    assert verdict(res).level == "amber"
    # every axis alike: one piece of advice, not three
    res = _with_std(clean_solution.result, rot=(0.2, 0.21, 0.19))
    keys = [a.key for a in advice(res)]
    assert "rotation_uncertain" in keys and not any(k.startswith("rotation_axis") for k in keys)
    assert verdict(res).level == "red"


@pytest.mark.parametrize(
    "reason, cause",
    [
        ("only 10 points (needs 20): the line barely touches the sphere or misses it", "barely touches the sphere"),
        ("station S4 has only 3 usable profiles (needs 4): add profiles to its sweep", "too few usable profiles"),
        ("points do not lie on a circle (rms 0.800 mm): not the sphere?", "is not the sphere"),
        ("the points scatter about their circle by 0.540 mm (rms), more than max_circle_rms_mm = 0.5 mm allows",
         "the sensor's noise above the limit"),
        ("circle radius 25.000 mm exceeds the sphere radius 19.1 mm: wrong sphere radius", "wrong sphere radius"),
        ("inconsistent with the other profiles (chi2 53.8 on 3 dof, about 0.674 mm)", "pose read at the wrong moment"),
    ],
)
def test_flag_advice_names_the_likely_cause(clean_solution, reason, cause):
    flag = ObservationFlag(index=7, station="S3", reason=reason)
    res = clean_solution.result.model_copy(update={"flagged": [flag]})
    (item,) = [a for a in advice(res) if a.key == "flagged"]
    assert item.text.startswith(f"Observation(s) 7 (station S3): likely ") and cause in item.text


def test_thresholds_are_configurable(clean_solution):
    r = clean_solution.result
    strict = Thresholds(translation_std_amber_mm=0.5 * max(calibration_std(r)[1]), translation_std_red_mm=1.0)
    assert verdict(r, strict).level == "amber"
    assert [a.key for a in advice(r, strict)] == ["translation_uncertain"]
    with pytest.raises(ValueError, match="robot_repeatability_mm"):
        Thresholds(robot_repeatability_mm=0)
