"""A recording's advice and report (on the fly: a result with ``timing``): no advice to
stop the robot (its poses are read while it moves), a kinematic calibration named as the
stop-and-go run it is, the widening of the pose noise for the residuals' correlation in
time named as such, and the clock relation in the report as the terminal states it."""

import html
import math

import pytest

from spherecal.config import CalibrationOptions, OnTheFlyPlan, StreamSimSettings
from spherecal.core.models import KinematicParameter, RobotErrorSummary
from spherecal.estimation.on_the_fly import solve_recording
from spherecal.estimation.screening import likely_cause_of_inconsistent_profile
from spherecal.report.assess import Thresholds, advice, robot_error_dominates
from spherecal.report.html import sections, write_report
from spherecal.report.terminal import timing_lines
from spherecal.report.validation_advice import robot_cause
from spherecal.sim import standard_cell
from spherecal.sim.streams import simulate_recording
from reference_sensor import reference_fov

#: What advice for stop-and-go data says and a recording's must not: stop the robot to read it.
STOP_WORDS = ("stopped", "fine point", "WaitRob", "settled")


@pytest.fixture(scope="module")
def recorded():
    """A recording at 100 profiles a second with smooth robot noise (0.02 mm): its
    residuals correlated in time over several profiles, a few profiles at the sphere's
    edge left out as expected on the fly."""
    cell = standard_cell("eye_in_hand", seed=3, fov=reference_fov())
    settings = StreamSimSettings(sensor={"rate_hz": 100.0}, seed=3,
                                 pose={"translation_noise_mm": 0.02, "rotation_noise_deg": 0.002})
    recording = simulate_recording(cell, OnTheFlyPlan(crossing_fraction=1.15, pause_s=0.05), settings)
    return solve_recording(recording, CalibrationOptions())


def _stop_words(items) -> list[str]:
    return [f"{a.key}: {word}" for a in items for word in STOP_WORDS if word in a.text]


def test_a_recordings_edge_profiles_are_said_to_be_expected_not_to_stop_the_robot(recorded):
    result = recorded.result
    edge = [f for f in result.flagged if "expected and left out" in f.reason]
    assert edge, "the recording should leave out profiles at the sphere's edge"
    (flagged,) = [a for a in advice(result) if a.key == "flagged"]
    assert not _stop_words([flagged]), flagged.text
    assert "so such profiles are expected: nothing to change unless they are many" in flagged.text
    # the same flags read as stop-and-go data get stop-and-go's advice: the difference is the recording's
    as_stop_and_go = result.model_copy(update={"timing": None})
    assert _stop_words([a for a in advice(as_stop_and_go) if a.key == "flagged"])


def test_a_recordings_mispaired_profile_is_told_to_check_the_streams(recorded):
    """A profile inconsistent away from the sphere's edge (its plane through the centre):
    a stream out of step, not a pose read before the robot stopped."""
    result = recorded.result
    reason = ("inconsistent with the other profiles: 40 of 50 points lie far from the sphere: "
              + likely_cause_of_inconsistent_profile([0.0, 0.0, 80.0], result.sphere_radius_mm, recording=True))
    flag = result.flagged[0].model_copy(update={"reason": reason})
    (flagged,) = [a for a in advice(result.model_copy(update={"flagged": [flag]})) if a.key == "flagged"]
    assert not _stop_words([flagged]), flagged.text
    assert "stamps each profile at its exposure" in flagged.text and "clock relation" in flagged.text


def _arm_error() -> RobotErrorSummary:
    """The arm's geometry modelled from the streamed joints and integrated out, its error
    dominating a point's (the eye-to-hand example on the fly)."""
    params = [KinematicParameter(name=f"joint_{j}.zero_offset", unit="deg", value=0.0, std=0.02,
                                 identifiable=j > 1, identified=False) for j in range(1, 5)]
    return RobotErrorSummary(
        model="kinematic", kinematic_parameters=params, station_rotation_deg=0.0013, station_translation_mm=0.026,
        estimated=True, common_rotation_deg=0.0, common_translation_mm=0.0,
        std_rotation_deg_robot_frame=(0.005, 0.004, 0.006), std_translation_mm_robot_frame=(0.004, 0.005, 0.007),
        point_error_k2_mm=1.187, point_error_parts_rms_mm={"robot_station_to_station_mm": 0.587,
                                                           "sensor_noise_mm": 0.014, "transform_mm": 0.004},
        dominant="robot_station_to_station_mm")


def test_a_recordings_arm_error_advice_names_a_stop_and_go_kinematic_run(recorded):
    """calibrate refuses identify_kinematics' planner on the fly: the advice names the
    stop-and-go run that works, and so does a failed validation's remedy."""
    result = recorded.result.model_copy(update={"robot_error": _arm_error()})
    assert robot_error_dominates(result)
    (arm,) = [a for a in advice(result) if a.key == "robot_error_dominates"]
    assert 'mode = "stop_and_go" with [calibration] identify_kinematics = true' in arm.text, arm.text
    assert "not on the fly" in arm.text and "data see 3 of its 4 geometric parameters" in arm.text
    figures = {"SD": {"max error (mm)": 0.19, "MPE (mm)": 0.1, "passed": False}}
    cause = robot_cause(result, figures)
    assert 'mode = "stop_and_go"' in cause.remedy and "accept these figures" in cause.remedy
    # stop-and-go data keep their advice: identify_kinematics in the same run
    (plain,) = [a for a in advice(result.model_copy(update={"timing": None})) if a.key == "robot_error_dominates"]
    assert "stop_and_go" not in plain.text and "[calibration] identify_kinematics = true:" in plain.text


def test_a_recordings_time_correlated_pose_noise_is_named_not_blamed_on_the_robot(recorded):
    """The fit widened the pose noise per profile by the square root of the profiles that
    share the robot's error; above twice a repeatability that the widened figure exceeds
    but the figure per independent look does not, the advice names the correlation in
    time and asks for nothing."""
    result = recorded.result
    pose_mm = float(result.diagnostics.noise["pose_translation_noise_mm"])
    shots = result.diagnostics.refinement["time_correlation"]["integrated_autocorrelation_shots"]
    look_mm = pose_mm / math.sqrt(shots)
    assert shots > 2.25  # (so that a repeatability between the two figures exists)
    between = Thresholds(robot_repeatability_mm=pose_mm / 3)
    said = advice(result, between)
    assert not _stop_words(said), said
    (note,) = [a for a in said if a.key == "pose_noise_time_correlated"]
    assert note.level == "green" and "pose_noise_high" not in [a.key for a in said]
    assert f"correlated in time over {shots:.1f} consecutive profiles" in note.text
    assert "time_correlation" in note.text and f"about {look_mm:.3f} mm" in note.text
    # poses that scatter per independent look too: amber, with what a recording can check
    noisy = advice(result, Thresholds(robot_repeatability_mm=look_mm / 3))
    (high,) = [a for a in noisy if a.key == "pose_noise_high"]
    assert high.level == "amber" and not _stop_words([high]), high.text
    assert "pose stream" in high.text and "clock relation" in high.text


def test_the_report_states_the_clock_relation_as_the_terminal_does(recorded, tmp_path):
    result = recorded.result
    timing = result.timing
    text = write_report(recorded, tmp_path).read_text(encoding="utf-8")
    section = text[text.index('<h2 id="clock">'):text.index('<h2 id="identity">')]
    for line in timing_lines(timing):
        assert html.escape(line.strip(), quote=True) in section, line
    assert "t_robot = t_sensor + offset + drift (t_sensor - " in section and f"{timing.t_sensor0_s:.6f} s" in section
    assert f"offset {timing.offset_ms:.4f} +/- {timing.offset_std_ms:.4f} ms (robot clock minus sensor clock" in section
    assert f"drift {timing.drift_ppm:.3f} +/- {timing.drift_std_ppm:.3f} ppm" in section
    assert html.escape(timing.identifiability, quote=True) in section and '<a href="#clock">' in text
    assert "NOT MEASURED" not in section  # (measured poses)
    computed = result.model_copy(update={"timing": timing.model_copy(update={
        "poses_assumed": "computed along the programmed line", "drift_estimated": False})})
    said = sections.clock_html(computed)
    assert "<b>robot poses NOT MEASURED: computed along the programmed line</b>" in said
    assert f"drift held at {timing.drift_ppm:.3f} ppm" in said
    assert sections.clock_html(result.model_copy(update={"timing": None})) == ""
