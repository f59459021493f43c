"""Calibration from a recording: the clock relation found from nothing and estimated with
the transform, against the simulated truth; what the data cannot tell said as such; gaps
in the pose stream never bridged."""

from dataclasses import replace

import numpy as np
import pytest

from spherecal.config import CalibrationOptions, OnTheFlyPlan, StreamSimSettings
from spherecal.core import geometry as geo
from spherecal.core.models import Pose
from spherecal.core.streams import PoseStream, ProfileStream
from spherecal.estimation.on_the_fly import offset_candidates, solve_recording, timing_with_geometry_known
from spherecal.report.assess import verdict
from spherecal.sim import standard_cell
from spherecal.sim.streams import simulate_recording
from reference_sensor import reference_fov

PLAN = OnTheFlyPlan(crossing_fraction=1.15, pause_s=0.05)


def _recording(mounting="eye_in_hand", seed=0, noise_mm=0.0, plan=PLAN, rate_hz=100.0, **sensor):
    cell = standard_cell(mounting, seed=seed, fov=reference_fov())
    settings = StreamSimSettings(sensor={"rate_hz": rate_hz, **sensor}, seed=seed,
                                 pose={"translation_noise_mm": noise_mm, "rotation_noise_deg": noise_mm / 10})
    return simulate_recording(cell, plan, settings)


def _errors(recording, result):
    prov = recording.provenance
    truth = Pose.model_validate(prov["true_transform"])
    return (result.timing.offset_ms - 1e3 * prov["true_offset_s"], result.timing.drift_ppm - 1e6 * prov["true_drift"],
            geo.rotation_angle_deg(truth.rotation_matrix, result.transform.rotation_matrix),
            float(np.linalg.norm(truth.translation - result.transform.translation)))


@pytest.mark.parametrize("mounting", ["eye_in_hand", "eye_to_hand"])
def test_noise_free_recording_gives_the_clocks_and_the_transform(mounting):
    """Clocks 1.77e9 s apart (robot from power-on, sensor from 1970) and 35 ppm apart:
    found from nothing, and fitted to a hundredth of a millisecond."""
    rec = _recording(mounting)
    assert abs(rec.provenance["true_offset_s"]) > 1e9
    result = solve_recording(rec, CalibrationOptions()).result
    e_off, e_drift, e_rot, e_trans = _errors(rec, result)
    assert abs(e_off) < 0.01 and abs(e_drift) < 0.5
    assert e_rot < 0.002 and e_trans < 0.002
    assert result.timing.identifiable and result.timing.drift_estimated
    assert verdict(result).level != "red"


def test_smooth_pose_noise_widens_the_spread_and_the_offset_stays_within_it():
    """Repeatability noise smooth over 50 ms, shared by the profiles of 50 ms: the fit
    widens its covariance by the residuals' correlation in time; the offset's error stays
    at the floor the noise leaves (the same fit with the true geometry)."""
    rec = _recording(seed=3, noise_mm=0.02)
    sol = solve_recording(rec, CalibrationOptions())
    result = sol.result
    e_off, e_drift, _, _ = _errors(rec, result)
    widened = result.diagnostics.refinement["time_correlation"]["integrated_autocorrelation_shots"]
    assert widened > 2.0
    assert abs(e_off) < 0.25 and abs(e_off) < 4 * result.timing.offset_std_ms
    assert abs(e_drift) < 4 * result.timing.drift_std_ppm
    prov = rec.provenance
    truth = Pose.model_validate(prov["true_transform"])
    oracle_off, _ = timing_with_geometry_known(rec, sol, truth.rotation_matrix, truth.translation,
                                               np.asarray(prov["true_sphere_centre_mm"]))
    assert abs(e_off) < abs(oracle_off - 1e3 * prov["true_offset_s"]) + 2 * result.timing.offset_std_ms


def test_sweeps_in_one_direction_at_one_speed_leave_the_offset_unidentified_and_say_what_to_add():
    """Forth sweeps only, one speed: an offset moves every profile along its sweep as a
    shifted sphere would. The result says so (amber, naming the sweeps to add), and its
    offset is not a confident wrong one (within its stated spread)."""
    rec = _recording(plan=PLAN.model_copy(update={"speeds_mm_s": (100.0,)}))
    ps = rec.profiles
    rows = np.flatnonzero(ps.sweep % 2 == 0)  # the forth sweep of each pair
    forth = ProfileStream.from_profiles(ps.t_sensor_s[rows], [ps.profile(j) for j in rows], frame=ps.frame[rows],
                                        sweep=ps.sweep[rows])
    rec = replace(rec, profiles=forth)
    result = solve_recording(rec, CalibrationOptions()).result
    timing = result.timing
    assert not timing.identifiable
    assert "opposite direction" in timing.identifiability and "second speed" in timing.identifiability
    assert verdict(result).level in ("amber", "red")
    e_off, _, _, _ = _errors(rec, result)
    assert abs(e_off) < 3 * timing.offset_std_ms


def test_profiles_in_a_gap_of_the_pose_stream_are_left_out_and_named():
    """A 100 ms hole in the pose stream in the middle of a sweep: the profiles in it have
    no measured pose; they are flagged with the gap's times, never interpolated across."""
    rec = _recording()
    poses = rec.poses
    sweep_samples = np.flatnonzero(poses.sweep == 2)
    mid = sweep_samples[len(sweep_samples) // 2]
    hole = (poses.t_robot_s > poses.t_robot_s[mid]) & (poses.t_robot_s < poses.t_robot_s[mid] + 0.1)
    keep = ~hole
    cut = PoseStream(poses.t_robot_s[keep], poses.R[keep], poses.t_mm[keep],
                     None if poses.joints_deg is None else poses.joints_deg[keep],
                     None if poses.seq is None else poses.seq[keep], None if poses.sweep is None else poses.sweep[keep])
    result = solve_recording(replace(rec, poses=cut), CalibrationOptions()).result
    in_gap = [f for f in result.flagged if "gap of the pose stream" in f.reason]
    assert 3 <= len(in_gap) <= 15  # about 100 ms at 100 Hz (the samples around the hole bound it), on the sphere
    assert all("robot clock" in f.reason for f in in_gap)
    e_off, _, _, e_trans = _errors(rec, result)
    assert abs(e_off) < 0.01 and e_trans < 0.002


def test_offset_candidates_span_any_difference_of_epochs():
    """The search looks over every offset that lays the two streams side by side: the
    true offset (decades of seconds) lies in the best candidate interval."""
    rec = _recording()
    seen = rec.profiles.counts >= 10
    lo, hi = offset_candidates(rec, seen)[0]
    true_ms = 1e3 * rec.provenance["true_offset_s"]
    assert lo <= true_ms <= hi and hi - lo < 1000.0


def test_a_recording_that_never_sees_the_sphere_is_refused_naming_it():
    rec = _recording()
    ps = rec.profiles
    empty = ProfileStream(ps.t_sensor_s, np.zeros((0, 2)), np.zeros(ps.n + 1, dtype=np.int64), ps.frame, ps.sweep)
    from spherecal.core.errors import DegenerateDataError

    with pytest.raises(DegenerateDataError, match="none of the .* profiles shows the sphere"):
        solve_recording(replace(rec, profiles=empty), CalibrationOptions())


def test_streams_stamped_by_one_clock_hold_the_drift_at_zero():
    """Both streams stamped by the recording computer (a bag whose drivers stamp on
    receipt): no drift can be seen, none is estimated, the result says so."""
    rec = replace(_recording(), clocks={"robot": "recording computer", "sensor": "recording computer"})
    result = solve_recording(rec, CalibrationOptions()).result
    assert not result.timing.drift_estimated and result.timing.drift_ppm == 0.0
    assert result.timing.drift_std_ppm == 0.0


def test_a_diameter_given_as_the_radius_is_named():
    """Sweeps through the sphere show circles up to its radius: circles of half the radius
    given at most say the diameter was given."""
    from spherecal.core.errors import InputError

    rec = _recording()
    with pytest.raises(InputError, match="diameter given as the radius"):
        solve_recording(replace(rec, sphere_radius_mm=2 * rec.sphere_radius_mm), CalibrationOptions())


def test_a_given_offset_is_a_start_near_the_truth_and_refused_far_from_it():
    """--clock-offset-ms: a start within 50 ms is refined to the truth; one 2 s off is
    refused naming the option and where the data put the offset."""
    from spherecal.core.errors import InputError

    rec = _recording()
    true_ms = 1e3 * rec.provenance["true_offset_s"]
    result = solve_recording(rec, CalibrationOptions(), offset_ms=true_ms + 20.0).result
    assert abs(result.timing.offset_ms - true_ms) < 0.01
    with pytest.raises(InputError, match=r"--clock-offset-ms .*the offset given is wrong"):
        solve_recording(rec, CalibrationOptions(), offset_ms=true_ms + 2000.0)


def test_a_nominal_given_for_a_recording_is_compared_with_the_result():
    """As for stop-and-go: the result's distance from the nominal, and a quaternion
    written scalar last named."""
    rec = _recording("eye_to_hand", seed=1)
    X = Pose.model_validate(rec.provenance["true_transform"])
    w, x, y, z = X.quaternion_wxyz
    swapped = Pose(translation_mm=X.translation_mm, quaternion_wxyz=(x, y, z, w))
    result = solve_recording(rec, CalibrationOptions(nominal_transform=swapped)).result
    nominal = result.diagnostics.nominal_transform
    assert nominal["rotation_deg"] > 90 and nominal["translation_mm"] < 0.01 and nominal["quaternion_scalar_last"]
    assert verdict(result).level == "red"


def test_a_long_refinement_says_that_it_still_runs(monkeypatch):
    """A fit of minutes (millions of points, the arm's kinematic model) must not look hung:
    the solve's progress hears from the joint refinement every PROGRESS_EVERY_S seconds
    (here every step), counted from the first refinement of the solve."""
    from spherecal.estimation.refine import driver

    monkeypatch.setattr(driver, "PROGRESS_EVERY_S", 0.0)
    said = []
    solve_recording(_recording(), CalibrationOptions(), progress=said.append)
    still = [m for m in said if m.startswith("  joint refinement still running: ")]
    assert still and all(m.endswith("steps so far") for m in still)
