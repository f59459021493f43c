"""The simulated cell's time and its devices' random streams: a simulated controller's
moves take simulated time (never real time), and each device draws from a stream of its
own, so a seeded run is the same whatever order the devices draw in."""

import time

import numpy as np
import pytest

from spherecal.core import geometry as geo
from spherecal.core.models import Pose
from spherecal.devices import line_protocol as P
from spherecal.sim import NoiseModel, RobotErrorModel, plan_stations, standard_cell
from spherecal.sim.controller import SimulatedController
from spherecal.sim.rngs import device_rng, stable_key
from spherecal.sim.settings import SimulatedControllerSettings
from spherecal.sim.timeline import trapezoid_duration_s
from reference_sensor import reference_fov

DOWN = geo.matrix_from_rotvec(np.radians([180.0, 0.0, 0.0]))
HOME = (0.0, 20.0, 10.0, 0.0, 60.0, 0.0)


def _kin():
    from spherecal.plugins.host import PluginHost

    return PluginHost(autoload=False).arm_kinematics({"type": "abb_irb2400"})


def _controller(seed=1, robot_error=None, noise_per_pose=False, **settings):
    cell = standard_cell("eye_in_hand", seed=seed, fov=reference_fov(), noise=NoiseModel(pose_translation_noise_mm=0.02))
    cell.robot_error = robot_error
    cell.noise_per_pose = noise_per_pose
    ctl = SimulatedController(_kin(), SimulatedControllerSettings(home_joints_deg=HOME, single_precision=False,
                                                                  **settings), cell, 6)
    return cell, ctl


def _move(ctl, seq, pose, speed):
    assert P.decode_reply(ctl.handle(P.target_request(seq, pose))).kind == "OK"
    reply = P.decode_reply(ctl.handle(P.movl_request(seq + 1, speed, seq, 30.0)))
    assert reply.kind == "OK", reply


def _getp(ctl, seq=99) -> Pose:
    return P.parse_pose_reply(P.decode_reply(ctl.handle(P.getp_request(seq))))


def test_a_move_takes_simulated_time_and_no_real_time():
    cell, ctl = _controller(acceleration_mm_s2=1000.0, settle_s=0.3)
    start = Pose.from_rt(DOWN, [1100.0, 150.0, 800.0])
    _move(ctl, 1, start, 200.0)
    T0 = cell.clock.now_s
    wall = time.monotonic()
    _move(ctl, 3, Pose.from_rt(DOWN, [1100.0, 150.0, 500.0]), 10.0)  # 300 mm at 10 mm/s: 30 s of robot time
    assert time.monotonic() - wall < 1.0
    assert cell.clock.now_s - T0 == pytest.approx(300.0 / 10.0 + 10.0 / 1000.0 + 0.3, rel=1e-9)
    assert ctl.last_move["motion_s"] == pytest.approx(trapezoid_duration_s(300.0, 10.0, 1000.0), rel=1e-12)
    # mid-move the flange was half-way down, on the cell's timeline the sensor simulators read
    _, t, q = cell.timeline.reported_at([T0 + ctl.last_move["motion_s"] / 2])
    np.testing.assert_allclose(t[0], [1100.0, 150.0, 650.0], atol=1e-3)
    assert q is not None and q.shape == (1, 6)
    # now, at the standstill, the timeline's report is what GETP says (no pose noise in the settings)
    cell.noise = NoiseModel(pose_translation_noise_mm=0.0)
    _, t_now, q_now = cell.timeline.reported_at([cell.clock.now_s])
    np.testing.assert_allclose(t_now[0], _getp(ctl).translation, atol=1e-6)
    np.testing.assert_allclose(q_now[0], ctl.joints_deg, atol=1e-9)


def test_with_the_arms_error_the_timeline_flange_is_where_the_cell_measures():
    cell, ctl = _controller(robot_error=RobotErrorModel())
    _move(ctl, 1, Pose.from_rt(DOWN, [1050.0, 50.0, 700.0]), 100.0)
    R, t, _ = cell.timeline.pose_at([cell.clock.now_s])
    np.testing.assert_allclose(t[0], cell.current_base_from_flange.translation, atol=1e-6)
    np.testing.assert_allclose(R[0], cell.current_base_from_flange.rotation_matrix, atol=1e-9)


def test_a_jog_and_a_shot_are_on_the_timeline_and_the_clock():
    cell, ctl = _controller()
    T0 = cell.clock.now_s
    cell.measure_profile()
    assert cell.clock.now_s - T0 == pytest.approx(cell.exposure_s)
    cell.measure_profile(cell.current_base_from_flange)  # a profile at a given pose is no shot: no time
    assert cell.clock.now_s - T0 == pytest.approx(cell.exposure_s)
    ctl.jog((10.0, 25.0, 5.0, 0.0, 55.0, 0.0))
    _, _, q = cell.timeline.reported_at([cell.clock.now_s])
    np.testing.assert_allclose(q[0], (10.0, 25.0, 5.0, 0.0, 55.0, 0.0))


def test_a_device_stream_is_stable_and_its_own():
    """The key of a name is the same in every process (a fixed hash, not Python's); two
    devices of one seed draw different numbers; one device's stream depends on the seed."""
    assert stable_key("controller") == stable_key("controller") == 12210627
    a = device_rng(7, "controller").normal(size=4)
    np.testing.assert_array_equal(a, device_rng(7, "controller").normal(size=4))
    assert not np.allclose(a, device_rng(7, "sensor").normal(size=4))
    assert not np.allclose(a, device_rng(8, "controller").normal(size=4))
    with pytest.raises(ValueError, match="non-empty name"):
        device_rng(7, "")


@pytest.mark.parametrize("noise_per_pose", [False, True])
def test_a_seeded_run_is_the_same_when_the_sensor_draws_more_in_between(noise_per_pose):
    """Two runs of one seed: in the second the sensor is asked for an extra profile before
    each pose reading. The controller's readings and the profiles of the first run are
    the same in both (with one generator for every device, the extra draws would shift
    the controller's pose noise)."""
    cell = _controller(seed=11)[0]
    targets = plan_stations(cell.mounting, cell.true_transform, cell.sphere_centre_mm, cell.sphere_radius_mm,
                            field_of_view=cell.fov)[0][1][:3]  # the sensor sees the sphere at each

    def run(extra: bool):
        cell, ctl = _controller(seed=11, noise_per_pose=noise_per_pose)
        poses, profiles = [], []
        for k, target in enumerate(targets):
            _move(ctl, 10 * k + 1, target, 100.0)
            if extra:
                cell.measure_profile()
            poses.append(_getp(ctl).translation)
            profiles.append(cell.measure_profile() if not extra or not noise_per_pose else None)
        return np.array(poses), profiles

    poses, profiles = run(False)
    poses_extra, _ = run(True)
    assert all(len(p) > 100 for p in profiles if p is not None)
    np.testing.assert_array_equal(poses, poses_extra)
    assert np.ptp(poses - np.array([t.translation for t in targets]), axis=0).max() > 1e-3  # there is noise
    if noise_per_pose:  # per standstill the sensor's first profile is the same whatever the controller drew
        cell, ctl = _controller(seed=11, noise_per_pose=True)
        _move(ctl, 1, targets[0], 100.0)
        first = cell.measure_profile()
        _getp(ctl)
        cell2, ctl2 = _controller(seed=11, noise_per_pose=True)
        _move(ctl2, 1, targets[0], 100.0)
        _getp(ctl2)
        np.testing.assert_array_equal(first, cell2.measure_profile())
