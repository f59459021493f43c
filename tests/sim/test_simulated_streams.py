"""The simulated on-the-fly world (spherecal.sim.streams): its time relation, noise,
losses and sweeps, proved against the truth the simulator keeps."""

import json

import numpy as np
import pytest

from spherecal.config import ClockSettings, OnTheFlyPlan, PoseStreamSettings, SensorStreamSettings, StreamSimSettings
from spherecal.core import geometry as geo
from spherecal.core.models import Pose
from spherecal.core.streams import PoseStream, sensor_to_robot_time
from spherecal.sim import NoiseModel, RobotErrorModel, SweepPlan, plan_stations, standard_cell
from spherecal.sim.objects import BallBar, FlatPlate
from spherecal.sim.streams import (
    _cast_fan,
    _sphere_centres_in_sensor,
    plan_segments,
    simulate_recording,
    simulate_recording_with_truth,
)
from reference_sensor import reference_fov

QUICK = OnTheFlyPlan.quick()


def _cell(mounting="eye_in_hand", seed=3, arm=False, **kw):
    kin = None
    if arm:
        from spherecal.plugins.host import PluginHost

        kin = PluginHost(autoload=False).arm_kinematics({"type": "abb_irb2400"})
    return standard_cell(mounting, seed=seed, fov=reference_fov(), arm=kin,
                         robot_error=RobotErrorModel() if arm else None, **kw)


@pytest.fixture(scope="module", params=["eye_in_hand", "eye_to_hand"])
def quick(request):
    """A short recording of each mounting, no arm, with the truth."""
    return simulate_recording_with_truth(_cell(request.param), QUICK)


@pytest.fixture(scope="module")
def quick_arm():
    """A short recording with the IRB 2400's arm and its geometric error."""
    return simulate_recording_with_truth(_cell(arm=True), QUICK)


@pytest.fixture(scope="module")
def full():
    """The default plan (four stations, 48 s): long enough for the noise's statistics."""
    return simulate_recording_with_truth(_cell(), OnTheFlyPlan())


def _robot_times(rec):
    p = rec.provenance
    return sensor_to_robot_time(rec.profiles.t_sensor_s, p["true_offset_s"], p["true_drift"], p["t_sensor0_s"])


# the time relation -------------------------------------------------------------------------
def test_the_true_time_relation_finds_the_pose_each_profile_was_measured_at(quick):
    rec, truth = quick
    p = rec.provenance
    assert p["t_sensor0_s"] == rec.t_sensor0_s
    # each stamp maps to the robot-clock time of its exposure, to within the stamp's jitter (10 us SD)
    dt = _robot_times(rec) - truth.profile_robot_time_s
    assert np.abs(dt).max() < 5 * 1e-5
    assert 0.7e-5 < dt.std() < 1.3e-5
    # the pose stream there is the controller's pose at the exposure (its jitter of 20 us at <= 100 mm/s)...
    at = rec.poses.at(_robot_times(rec))
    assert at.ok.mean() > 0.99
    err = np.linalg.norm(at.t[at.ok] - truth.profile_reported_t_mm[at.ok], axis=1)
    assert err.max() < 0.015
    # ... and the true pose the profile was measured at is off it by the repeatability noise alone:
    # 0.02 mm per axis and 0.002 deg per axis
    err = np.linalg.norm(at.t[at.ok] - truth.profile_t_mm[at.ok], axis=1)
    assert 0.6 * np.sqrt(3) * 0.02 < np.sqrt(np.mean(err**2)) < 1.4 * np.sqrt(3) * 0.02
    assert err.max() < 6 * 0.02
    ang = np.degrees(np.linalg.norm(geo.rotvec_from_matrix(at.R[at.ok] @ np.swapaxes(truth.profile_R[at.ok], 1, 2)),
                                    axis=1))
    assert ang.max() < 6 * 0.002


def test_the_offset_and_drift_are_those_of_the_clocks_and_latencies():
    """Known answers: equal rates leave offset = robot epoch - sensor epoch - latency and
    no drift; rates give drift = (1 + rho_r) / (1 + rho_s) - 1, and the relation still
    holds at the end of the recording (a wrong drift would be off by drift x duration)."""
    clocks = ClockSettings(robot_epoch_s=12.5, robot_rate_error_ppm=0.0, sensor_epoch_s=1.7e9, sensor_rate_error_ppm=0.0)
    sensor = SensorStreamSettings(latency_s=0.003, extra_latency_s=0.004, stamp_jitter_s=0.0)
    rec, truth = simulate_recording_with_truth(_cell(), QUICK, StreamSimSettings(clocks=clocks, sensor=sensor))
    p = rec.provenance
    assert p["true_drift"] == 0.0
    assert p["true_offset_s"] == pytest.approx(12.5 - 1.7e9 - 0.007, abs=1e-6)
    assert p["true_offset_without_extra_latency_s"] == pytest.approx(12.5 - 1.7e9 - 0.003, abs=1e-6)
    assert np.abs(_robot_times(rec) - truth.profile_robot_time_s).max() < 1e-6  # the stamps' float64 resolution

    clocks = ClockSettings(robot_rate_error_ppm=80.0, sensor_rate_error_ppm=-70.0)
    rec, truth = simulate_recording_with_truth(_cell(), QUICK, StreamSimSettings(
        clocks=clocks, sensor=SensorStreamSettings(latency_s=0.002, stamp_jitter_s=0.0)))
    p = rec.provenance
    assert p["true_drift"] == pytest.approx((1 + 80e-6) / (1 - 70e-6) - 1, rel=1e-12)
    assert p["true_drift_ppm"] == pytest.approx(150.0, abs=0.02)
    assert np.abs(_robot_times(rec) - truth.profile_robot_time_s).max() < 1e-6
    late = rec.profiles.t_sensor_s - rec.t_sensor0_s
    assert late.max() > 8.0  # ... where ignoring the drift would be 1.2 ms off
    no_drift = rec.profiles.t_sensor_s + p["true_offset_s"]
    assert np.abs(no_drift - truth.profile_robot_time_s).max() > 1e-3


def test_with_the_arm_the_stream_reports_the_nominal_model_at_the_joints_it_sends(quick_arm):
    rec, truth = quick_arm
    cell = _cell(arm=True)
    arm = cell.arm
    q = rec.poses.joints_deg
    assert q is not None and q.shape == (rec.poses.n, 6)
    M = arm.nominal_flange_matrices(q)
    np.testing.assert_allclose(rec.poses.t_mm, M[:, :3, 3], atol=1e-9)
    np.testing.assert_allclose(rec.poses.R, M[:, :3, :3], atol=1e-12)
    for k in (0, rec.poses.n // 2, rec.poses.n - 1):  # the plugin's own forward kinematics
        np.testing.assert_allclose(arm.nominal_flange_pose(q[k]).as_matrix(), M[k], atol=1e-9)
    # the controller follows its straight lines: every sample of a sweep lies on the sweep's line
    for i in range(len(rec.sweeps)):
        pts = rec.poses.t_mm[rec.poses.sweep == i]
        d = np.asarray(rec.sweeps[i].direction)
        off = (pts - pts[0]) - np.outer((pts - pts[0]) @ d, d)
        assert np.abs(off).max() < 1e-3
    # the true flange is off by the arm's geometric error (the provenance's range), not by timing
    at = rec.poses.at(_robot_times(rec))
    assert np.abs(at.t[at.ok] - truth.profile_reported_t_mm[at.ok]).max() < 0.015
    err = np.linalg.norm(at.t[at.ok] - truth.profile_t_mm[at.ok], axis=1)
    lo, hi = rec.provenance["flange_error_mm_range"]
    assert 0.3 < lo and err.min() > lo - 0.15 and err.max() < hi + 0.15


# the noise ----------------------------------------------------------------------------------
def test_the_pose_noise_is_smooth_in_time(full):
    rec, truth = full
    x = truth.sample_noise  # every 4 ms of the robot's clock, lost samples included
    assert np.allclose(np.diff(truth.sample_T_s), 0.004 / (1 + 20e-6))

    def autocorr(v, lag):
        v = v - v.mean()
        return float(np.mean(v[:-lag] * v[lag:]) / np.mean(v * v))

    for axis in range(6):
        assert autocorr(x[:, axis], 1) > 0.85  # 4 ms: exp(-4 / 50) = 0.92
        assert abs(autocorr(x[:, axis], 50)) < 0.15  # 200 ms: exp(-4) = 0.02
    assert 0.017 < x[:, :3].std() < 0.023
    assert 0.8 < np.degrees(x[:, 3:].std()) / 0.002 < 1.2
    # the profiles see that same process: the true-minus-reported error of consecutive profiles agrees
    e = truth.profile_t_mm - truth.profile_reported_t_mm
    assert autocorr(e[:, 0], 1) > 0.85


def test_white_noise_would_fail_the_smoothness_check():
    """The check above can fail: with a correlation time far below the period the samples are white."""
    settings = StreamSimSettings(pose=PoseStreamSettings(noise_correlation_s=1e-4))
    _, truth = simulate_recording_with_truth(_cell(), QUICK, settings)
    v = truth.sample_noise[:, 0] - truth.sample_noise[:, 0].mean()
    assert abs(np.mean(v[:-1] * v[1:]) / np.mean(v * v)) < 0.1


# losses and jitter --------------------------------------------------------------------------
def test_losses_and_jitter_are_there_at_the_stated_rates():
    pose = PoseStreamSettings(drop_rate=0.02, burst_rate_per_s=0.5, burst_length=(3, 6), stamp_jitter_s=5e-5)
    sensor = SensorStreamSettings(rate_hz=400.0, stamp_jitter_s=2e-5, frame_drop_rate=0.03)
    clocks = ClockSettings()
    rec = simulate_recording(_cell(), OnTheFlyPlan(stations=2), StreamSimSettings(pose=pose, sensor=sensor,
                                                                                 clocks=clocks))
    ps, pr = rec.poses, rec.profiles
    duration = rec.provenance["duration_s"]
    # lost pose samples: the gaps in the sequence numbers
    taken = int(ps.seq[-1] - ps.seq[0] + 1)
    gap = np.diff(ps.seq) - 1
    singles = int(np.sum(gap == 1))
    bursts = int(np.sum(gap >= 3))
    expected_bursts = 0.5 * duration
    assert abs(bursts - expected_bursts) < 4 * np.sqrt(expected_bursts) + 1
    assert abs(singles - 0.02 * taken) < 4 * np.sqrt(0.02 * taken)
    assert gap.max() <= 6 + 2  # a burst next to a single loss at most
    assert len(ps.gaps()) >= bursts  # a burst of three or more is a gap the stream refuses to bridge
    # stamp jitter: the stamps' departure from the clock's exact period
    period = 0.004
    resid = ps.t_robot_s - period * (ps.seq - ps.seq[0])
    resid -= np.median(resid)
    assert 0.85 * 5e-5 < resid.std() < 1.15 * 5e-5
    # the profiler: frames lost at their rate, stamps jittered at theirs
    frames = int(pr.frame[-1] - pr.frame[0] + 1)
    lost = frames - pr.n
    assert abs(lost - 0.03 * frames) < 4 * np.sqrt(0.03 * frames)
    resid = pr.t_sensor_s - (pr.frame - pr.frame[0]) / 400.0
    resid -= np.median(resid)
    assert 0.85 * 2e-5 < resid.std() < 1.15 * 2e-5
    # the two clocks' nominal periods, measured against each other: the drift between them
    assert np.all(np.diff(ps.t_robot_s) > 0) and np.all(np.diff(pr.t_sensor_s) > 0)


def test_the_same_seed_gives_the_same_recording():
    a = simulate_recording(_cell(seed=5), QUICK)
    b = simulate_recording(_cell(seed=5), QUICK)
    for x, y in ((a.poses.t_robot_s, b.poses.t_robot_s), (a.poses.t_mm, b.poses.t_mm), (a.poses.seq, b.poses.seq),
                 (a.profiles.t_sensor_s, b.profiles.t_sensor_s), (a.profiles.points_yz_mm, b.profiles.points_yz_mm)):
        np.testing.assert_array_equal(x, y)
    assert a.provenance == b.provenance
    c = simulate_recording(_cell(seed=5), QUICK, StreamSimSettings(seed=6))
    assert not np.array_equal(a.poses.t_robot_s, c.poses.t_robot_s)
    d = simulate_recording(_cell(seed=6), QUICK)
    assert not np.array_equal(a.profiles.points_yz_mm, d.profiles.points_yz_mm)


# the sweeps ---------------------------------------------------------------------------------
def test_profiles_hit_the_sphere_in_the_middle_of_every_sweep_and_miss_it_at_its_ends(quick, quick_arm):
    for rec, _ in (quick, quick_arm):
        _hit_in_the_middle(rec)


def _hit_in_the_middle(rec):
    counts = rec.profiles.counts
    for i in range(len(rec.sweeps)):
        j = np.flatnonzero(rec.profiles.sweep == i)
        assert len(j) > 50
        middle = j[len(j) // 3:2 * len(j) // 3]
        assert np.all(counts[middle] >= 100), (i, counts[middle].min())
        ends = np.concatenate([j[:5], j[-5:]])
        assert np.all(counts[ends] == 0), i
    assert np.all(counts[rec.profiles.sweep == -1][:3] == 0)  # the lead-in: standing off the sphere


def test_sweeps_go_forth_and_back_at_both_speeds_along_two_directions_per_station(quick):
    rec, truth = quick
    sw = rec.sweeps
    assert len(sw) == 8 and {s.station for s in sw} == {"S1"}
    assert sorted({s.speed_mm_s for s in sw}) == [50.0, 100.0]
    dirs = np.array([s.direction for s in sw])
    for k in range(0, 8, 2):  # forth then back
        assert sw[k].speed_mm_s == sw[k + 1].speed_mm_s
        assert dirs[k] @ dirs[k + 1] == pytest.approx(-1.0, abs=1e-12)
    assert abs(dirs[0] @ dirs[4]) < 0.95  # two directions
    # the sensor's x (laser plane normal) in base: each direction has a component along it
    X = rec.provenance["true_transform"]
    R_x = geo.matrix_from_quat_wxyz(np.asarray(X["quaternion_wxyz"]))
    for i, s in enumerate(sw):
        k = np.flatnonzero(rec.poses.sweep == i)[0]
        R_bs = rec.poses.R[k] @ R_x if rec.mounting == "eye_in_hand" else R_x
        assert abs(R_bs[:, 0] @ dirs[i]) >= 0.25 * 0.99
    # the stream's velocity (at the samples' true instants, free of the stamps' jitter): cruise at the
    # sweep's speed along its direction, with trapezoidal ramps
    T = truth.sample_T_s[truth.sample_kept]
    for i, s in enumerate(sw):
        k = np.flatnonzero(rec.poses.sweep == i)
        t, p = T[k], rec.poses.t_mm[k]
        v = np.diff(p, axis=0) / np.diff(t)[:, None]
        speed = v @ np.asarray(s.direction)
        assert speed.max() == pytest.approx(s.speed_mm_s, rel=2e-3)
        assert np.all(speed > -1e-6)
        acc = np.abs(np.diff(speed) / np.diff(t)[1:])
        assert 0.8 * 800 < np.percentile(acc, 99) < 1.2 * 800
    # the sphere is crossed at cruise speed: every profile that sees it is taken at the sweep's speed
    cruise = {s.sweep: (s.T0_s + s.speed_mm_s / s.acceleration_mm_s2, s.T1_s - s.speed_mm_s / s.acceleration_mm_s2)
              for s in truth.segments if s.kind == "sweep"}
    seen = np.flatnonzero(rec.profiles.counts > 0)
    assert np.all(rec.profiles.sweep[seen] >= 0)
    for j in seen:
        a, b = cruise[rec.profiles.sweep[j]]
        assert a < truth.profile_T_s[j] < b


def test_the_segments_cross_the_stations_of_the_stop_and_go_plan():
    """Each station's sweeps keep its orientation, and their middle puts the sphere
    centre where the stop-and-go plan puts it in the sensor frame (the laser plane)."""
    cell = _cell()
    plan = SweepPlan(lateral_amplitude_mm=0.0, profiles_per_station=5)
    segments, sweeps = plan_segments(cell, plan, OnTheFlyPlan(stations=2))
    stations = dict(plan_stations(cell.mounting, cell.true_transform, cell.sphere_centre_mm, cell.sphere_radius_mm,
                                  plan, field_of_view=cell.fov))
    for seg in segments:
        if seg.kind != "sweep":
            continue
        target = stations[seg.station][2]  # the middle of the stop-and-go sweep: the centre in the laser plane
        np.testing.assert_allclose(seg.R0, target.rotation_matrix, atol=1e-12)
        mid = 0.5 * (seg.t0_mm + seg.t1_mm)
        c_mid = _sphere_centres_in_sensor(cell, seg.R0[None], mid[None])[0]
        c_ref = cell.sphere_centre_in_sensor(target)
        np.testing.assert_allclose(c_mid, c_ref, atol=1e-9)
    assert len(sweeps) == 16


@pytest.mark.parametrize("mounting", ["eye_in_hand", "eye_to_hand"])
def test_casting_many_poses_at_once_sees_what_the_cell_sees_pose_by_pose(mounting):
    """The batch ray cast against SimulatedCell.cast_fan, on the sphere alone and on a
    scene where a plate under the sphere and a ball bar beside it are seen and occlude."""
    quiet = NoiseModel(point_noise_mm=0.0, pose_translation_noise_mm=0.0)
    cell = _cell(mounting, noise=quiet)
    poses = [p for _, ps in plan_stations(cell.mounting, cell.true_transform, cell.sphere_centre_mm,
                                         cell.sphere_radius_mm, SweepPlan(profiles_per_station=20),
                                         field_of_view=cell.fov) for p in ps]
    R = np.array([p.rotation_matrix for p in poses])
    t = np.array([p.translation for p in poses])

    def same(cell):
        pts, start = _cast_fan(cell, R, t)
        seen = 0
        for j, p in enumerate(poses):
            ref = cell.ideal_profile(p)
            assert start[j + 1] - start[j] == len(ref), j
            np.testing.assert_allclose(pts[start[j]:start[j + 1]], ref, atol=1e-9)
            seen += len(ref) > 0
        return seen, len(pts)

    assert same(cell)[0] > 0.9 * len(poses)
    c = cell.sphere_centre_mm
    frame = "base" if mounting == "eye_in_hand" else "flange"
    # the plate on the sphere's far side from the sensor: below it in base, towards the flange on the flange
    cell.add_object(FlatPlate(Pose.from_rt(np.eye(3), c - [0.0, 0.0, 30.0]), 200.0, 200.0, frame=frame))
    cell.add_object(BallBar(c + [0.0, 32.0, 0.0], c + [0.0, 120.0, 0.0], 8.0, frame=frame))
    _, n_points = same(cell)
    assert n_points > same(_cell(mounting, noise=quiet))[1] * 1.2  # the other objects are seen too


# the recording ------------------------------------------------------------------------------
def test_the_recording_is_complete_and_its_provenance_is_json(quick):
    rec, truth = quick
    assert isinstance(rec.poses, PoseStream) and rec.poses.joints_deg is None  # no arm: no joints
    assert rec.sphere_radius_mm == pytest.approx(19.1)
    p = json.loads(json.dumps(rec.provenance))
    for key in ("true_offset_s", "true_drift", "t_sensor0_s", "true_transform", "true_sphere_centre_mm", "noise",
                "plan", "on_the_fly_plan", "stream_settings", "time_definition"):
        assert key in p
    assert p["profiles"]["exposed"] == rec.profiles.n  # empty profiles kept: one per exposure
    assert 0 < p["profiles"]["seeing_something"] < rec.profiles.n
    assert np.all(np.diff(rec.profiles.frame) == 1)
    assert rec.provenance["duration_s"] < 10  # the quick plan
    # sweep indices on samples and profiles agree with the sweeps' true time spans
    spans = {s.sweep: (s.T0_s, s.T1_s) for s in truth.segments if s.kind == "sweep"}
    T = truth.sample_T_s[truth.sample_kept]
    for i, (a, b) in spans.items():
        inside = (T > a + 1e-9) & (T < b - 1e-9)
        assert np.all(rec.poses.sweep[inside] == i)
        inside = (truth.profile_T_s > a + 1e-9) & (truth.profile_T_s < b - 1e-9)
        assert np.all(rec.profiles.sweep[inside] == i)


@pytest.mark.parametrize("update, match", [
    ({"directions_in_sensor": [(0.2, 1.0, 0.0)]}, r"component along the sensor's x .* below 0.25"),
    ({"directions_in_sensor": [(0.0, 0.0, 0.0)]}, "non-zero finite vector"),
    ({"speeds_mm_s": (50.0, -10.0)}, r"speed -10.0 mm/s"),
    ({"speeds_mm_s": ()}, "at least 1"),
])
def test_a_bad_plan_is_refused_naming_the_field(update, match):
    with pytest.raises(ValueError, match=match):
        OnTheFlyPlan(**update)


def test_the_arm_s_vectorised_poses_are_its_pose_by_pose_ones():
    from spherecal.plugins.host import PluginHost

    kin = PluginHost(autoload=False).arm_kinematics({"type": "abb_irb2400"})
    cell = standard_cell("eye_in_hand", seed=2, fov=reference_fov(), arm=kin,
                         robot_error=RobotErrorModel(joint_compliance_deg_per_m=(0.01, 0.03)))
    q = np.random.default_rng(1).uniform(-40.0, 40.0, (6, 6))
    nominal, true = cell.arm.nominal_flange_matrices(q), cell.arm.true_flange_matrices(q)
    for k in range(len(q)):
        np.testing.assert_allclose(nominal[k], cell.arm.nominal_flange_pose(q[k]).as_matrix(), atol=1e-9)
        np.testing.assert_allclose(true[k], cell.arm.true_flange_pose(q[k]).as_matrix(), atol=1e-9)
    assert np.abs(true[:, :3, 3] - nominal[:, :3, 3]).max() > 0.1  # the arm's error and sag are in
