"""The built-in ``urdf`` robot type: a UR5 from example-robot-data's URDF honours the robot
protocol on the simulated cell through the line protocol, refuses what it must before
anything moves, talks to a socket server over socket:// (sessions, a connection closed
mid-request), and its configuration errors name the field; an IRB 2400 URDF written
from the published geometry, with the coupled-axis joint map, agrees with the native IRB
2400 model to 1e-9 mm over 1,000 random joint sets; a kinematic calibration's
robot_calibrated.urdf reads back through this type and reproduces the calibrated poses."""

from __future__ import annotations

from importlib import metadata

import numpy as np
import pytest

from spherecal.devices.contract import DeviceContext
from spherecal.core.errors import ConfigError, DeviceError, InputError
from spherecal.core.kinematics import chain_with_errors
from spherecal.core.models import Pose
from spherecal.plugins.host import PluginHost
from spherecal.sim import NoiseModel, RobotErrorModel, plan_stations, simulate_dataset, standard_cell
from spherecal.core.urdf import chain_to_urdf
from reference_sensor import reference_fov

#: The IRB 2400's parallel linkage as a joint map: q3_model = q3_controller - q2_controller.
IRB_COUPLING = [[1, 0, 0, 0, 0, 0], [0, 1, 0, 0, 0, 0], [0, -1, 1, 0, 0, 0],
                [0, 0, 0, 1, 0, 0], [0, 0, 0, 0, 1, 0], [0, 0, 0, 0, 0, 1]]


def _example_robot_data(path_end: str) -> str:
    files = metadata.files("example-robot-data") or []
    for f in files:
        if str(f).endswith(path_end):
            return str(f.locate())
    pytest.fail(f"example-robot-data has no {path_end}")


@pytest.fixture(scope="module")
def ur5_urdf() -> str:
    return _example_robot_data("ur_description/urdf/ur5_robot.urdf")


@pytest.fixture(scope="module")
def host() -> PluginHost:
    return PluginHost()


def _ur5(ur5_urdf, **extra) -> dict:
    return {"type": "urdf", "urdf": ur5_urdf, "base_link": "base", "flange_link": "tool0", **extra}


@pytest.fixture(scope="module")
def ur5_kin(host, ur5_urdf):
    return host.arm_kinematics(_ur5(ur5_urdf))


def test_spherecal_plugins_lists_urdf(host):
    text = host.format_description()
    assert "urdf: built-in, spherecal.robots.urdf_robot.plugin" in text
    assert "robot type 'urdf'" in text and "joint_map.matrix" in text


def test_ur5_kinematics_and_limits_come_from_its_urdf(ur5_kin):
    assert ur5_kin.controller_joint_names == ("shoulder_pan_joint", "shoulder_lift_joint", "elbow_joint",
                                              "wrist_1_joint", "wrist_2_joint", "wrist_3_joint")
    lim = np.degrees(ur5_kin.model_joint_limits_rad())
    np.testing.assert_allclose(lim[2], [-180.0, 180.0], atol=1e-6)  # the elbow; the others +-360
    np.testing.assert_allclose(lim[[0, 1, 3, 4, 5]], np.tile([-360.0, 360.0], (5, 1)), atol=1e-6)
    # the UR5's published figures: shoulder 89.159 mm up, upper arm 425, forearm 392.25 mm
    T = ur5_kin.flange_matrix_from_joints([0.0, -90.0, 0.0, -90.0, 0.0, 0.0])  # arm straight up
    assert T[2, 3] == pytest.approx(89.159 + 425.0 + 392.25 + 94.65, abs=1e-6)
    assert 900.0 < ur5_kin.reach_mm < 1000.0
    with pytest.raises(InputError, match=r"joint 3 \(elbow_joint\) model value 200.0000 deg is outside its URDF range"):
        ur5_kin.check_joint_limits([0, 0, 200, 0, 0, 0])


def test_ur5_inverse_kinematics_returns_the_joints_nearest_the_seed(ur5_kin):
    from spherecal.core.urdf import chain_jacobian

    rng = np.random.default_rng(4)
    n_checked = 0
    for q in rng.uniform(-150.0, 150.0, (60, 6)):
        pose = ur5_kin.flange_pose_from_joints(q)
        sol = ur5_kin.joints_from_flange_pose(pose, seed_joints_deg=q + rng.normal(0.0, 3.0, 6))
        np.testing.assert_allclose(ur5_kin.flange_matrix_from_joints(sol), pose.as_matrix(), atol=1e-8)
        # away from singularities (where a family of solutions lies equally near any seed)
        # the solution is the seed's own
        _, J = chain_jacobian(ur5_kin.chain, ur5_kin.model_joints_rad(q))
        if np.linalg.svd(J * np.array([1, 1, 1, 1000, 1000, 1000])[:, None], compute_uv=False)[-1] > 50.0:
            np.testing.assert_allclose(sol, q, atol=1e-6)
            n_checked += 1
    assert n_checked >= 30
    with pytest.raises(InputError, match="out of reach of the arm of .*ur5_robot.urdf"):
        ur5_kin.joints_from_flange_pose(Pose.from_rt(np.eye(3), [2000.0, 0.0, 0.0]), np.zeros(6))


@pytest.mark.slow
@pytest.mark.parametrize("mounting", ["eye_in_hand", "eye_to_hand"])
def test_simulated_ur5_honours_the_robot_protocol(host, ur5_urdf, ur5_kin, mounting):
    from spherecal.plugins.testing import RobotHarness

    cell = standard_cell(mounting, seed=0, arm=ur5_kin, fov=reference_fov())
    cell.arm = None  # the simulated controller attaches its own
    stations = plan_stations(cell.mounting, cell.true_transform, cell.sphere_centre_mm, cell.sphere_radius_mm,
                             field_of_view=cell.fov)
    # the controller's pose (GETP, 6-decimal quaternion) meets the harness's rounding
    # allowance; the pose from joints (pose_source = "joints", joints carried at 1e-4
    # deg) is checked as the kinematics: within a few micrometres
    section = _ur5(ur5_urdf, pose_source="controller",
                   simulated={"home_joints_deg": [180.0, -90.0, 90.0, -90.0, -90.0, 0.0]})
    robot = host.create_robot(section, DeviceContext(cell=cell, log=lambda m: None))
    fk = host.robot_kinematics(section)
    report = RobotHarness(cell, stations).check(robot, flange_pose_from_joints=fk)
    assert report.n_moves >= 8
    assert report.max_kinematics_error_mm < 0.01


def test_nothing_moves_when_a_check_fails(host, ur5_urdf, ur5_kin):
    cell = standard_cell("eye_in_hand", seed=0, arm=ur5_kin, fov=reference_fov())
    cell.arm = None
    target = plan_stations(cell.mounting, cell.true_transform, cell.sphere_centre_mm, cell.sphere_radius_mm,
                             field_of_view=cell.fov)[0][1][0]
    section = _ur5(ur5_urdf, max_speed_mm_s=100.0, workspace={"min_mm": [-900, -900, -100], "max_mm": [900, 900, 900]},
                   simulated={"home_joints_deg": [180.0, -90.0, 90.0, -90.0, -90.0, 0.0]})
    with host.create_robot(section, DeviceContext(cell=cell, log=lambda m: None)) as robot:
        ctl = robot.simulator.controller
        home = cell.current_base_from_flange
        far = Pose.from_rt(target.rotation_matrix, [850.0, 0.0, 850.0])  # in the box, out of reach
        outside = Pose.from_rt(target.rotation_matrix, [0.0, 0.0, 1000.0])
        for pose, speed, error, match in [
            (target, 150.0, InputError, "exceeds the configured max_speed_mm_s = 100.0"),
            (target, 0.0, InputError, "must be a positive number"),
            (outside, 50.0, InputError, r"outside the configured workspace box"),
            (far, 50.0, InputError, r"target: flange pose .* out of reach"),
        ]:
            with pytest.raises(error, match=match):
                robot.move_linear(pose, speed)
            with pytest.raises(error, match=match):
                robot.check_target(pose, speed)
        assert ctl.moves == 0 and "MOVL" not in ctl.requests and cell.current_base_from_flange is home
        robot.move_linear(target, 50.0)
        assert ctl.moves == 1
    # the controller refuses an out-of-reach target on its own too (ERR 5, nothing moves)
    from spherecal.devices import line_protocol as P

    reply = P.decode_reply(ctl.handle(P.target_request(1, far)))
    assert reply.kind == "OK"
    reply = P.decode_reply(ctl.handle(P.movl_request(2, 50.0, 1, 10.0)))
    assert (reply.kind, P.parse_error_reply(reply)[0]) == ("ERR", P.ErrorCode.UNREACHABLE) and ctl.moves == 1


def test_a_dead_link_is_a_device_error_naming_the_port(host, ur5_urdf):
    with pytest.raises(DeviceError, match=r"urdf robot \(ur5_robot.urdf\): cannot open '/dev/spherecal-no-such-port'"):
        host.create_robot(_ur5(ur5_urdf, port="/dev/spherecal-no-such-port"), DeviceContext())


def test_the_ur5_over_a_socket_server(host, ur5_urdf):
    """The socket:// link on the urdf type, from the core alone: the TCP link, a
    socket server's sessions (a target staged over one connection is refused over the
    next) and a controller that closes the connection after serving a MOVL and before
    its reply (the robot says so at once and sends nothing again)."""
    from spherecal.devices import line_protocol as P
    from spherecal.robots.urdf_robot.plugin import UrdfRobot
    from spherecal.sim.controller import start_controller

    home_joints = [180.0, -90.0, 90.0, -90.0, -90.0, 0.0]
    config = host.validate_robot_config("urdf", {k: v for k, v in _ur5(
        ur5_urdf, port="socket://robot-controller:30010", timeout_s=1.0, retries=2,
        simulated={"transport": "socket", "home_joints_deg": home_joints}).items() if k != "type"})
    assert config.transport == "socket"
    kin = config.kinematics()
    home = kin.flange_pose_from_joints(home_joints)
    a = Pose.from_rt(home.rotation_matrix, home.translation + [20.0, 0.0, -20.0])
    b = Pose.from_rt(home.rotation_matrix, home.translation + [0.0, 30.0, -20.0])
    with start_controller(kin, config.simulated, None, kin.n_joints) as server:
        with UrdfRobot(config, kin, url=server.url) as robot:
            assert robot.transport == "socket"
            robot._exchange("TGT", lambda seq: P.target_request(seq, a), "OK")
            staged = robot._seq
        with UrdfRobot(config, kin, url=server.url) as robot:  # a new connection, a new session
            with pytest.raises(DeviceError, match=r"refused MOVL .*ERR 4 no_target: target \d+ was staged over an "
                                                  r"earlier connection"):
                robot._exchange("MOVL", lambda seq: P.movl_request(seq, 50.0, staged, 10.0), "OK")
            assert server.controller.moves == 0
            robot.move_linear(a, 50.0)
            server.faults.only_kinds = ("MOVL",)
            server.faults.close_before_reply = 1
            with pytest.raises(DeviceError, match=r"urdf robot \(ur5_robot.urdf\) on socket://127.0.0.1:\d+: connection "
                                                  r"lost \(.*the controller closed the connection\); nothing is sent "
                                                  r"again: check the network"):
                robot.move_linear(b, 50.0)
            assert robot.resends == 0
        assert server.connections == 2 and server.controller.moves == 2
        assert server.controller.requests[-3:] == ["GETJ", "TGT", "MOVL"]  # nothing after the dropped MOVL
        np.testing.assert_allclose(server.controller.true_flange_pose().translation_mm, b.translation_mm, atol=1e-3)
        port = server.url.rsplit(":", 1)[1]
    with pytest.raises(DeviceError, match=rf"cannot open 'socket://127.0.0.1:{port}' \(.*refused.*\); check "
                                          r"robot.port and that the controller's socket server listens"):
        UrdfRobot(config, kin, url=f"socket://127.0.0.1:{port}")  # the server has stopped


@pytest.mark.parametrize("extra, match", [
    ({"urdf": "no-such-robot.urdf"}, r"robot: .*no-such-robot.urdf: cannot read the URDF file"),
    ({"flange_link": "hand"}, r"no link named 'hand' \(flange_link\)"),
    ({"joints": ["shoulder_pan_joint", "elbow_joint"]}, r"joints: expected the 6 joints from 'base' to 'tool0'"),
    ({"joints": ["a", "b", "c", "d", "e", "f"]}, r"joints must name each revolute joint .* once, in controller order"),
    ({"joint_map": {"matrix": [[1, 0], [0, 1]]}}, r"joint_map.matrix: expected 6 rows of 6 values"),
    ({"joint_map": {"matrix": [[1] * 6] * 6}}, r"joint_map: matrix .* is singular"),
    ({"joint_map": {"offset_deg": [1e9] * 6}}, r"robot.joint_map.offset_deg: .*at most 100000"),
    ({"max_speed_mm_s": 0}, r"robot.max_speed_mm_s: Input should be greater than 0"),
    ({"simulated": {"home_joints_deg": [0, 0, 270, 0, 0, 0]}}, r"simulated.home_joints_deg: joint 3 \(elbow_joint\)"),
    ({"workspace": {"min_mm": [0, 0, 0], "max_mm": [0, 1, 1]}}, r"min_mm x = 0.0 must be below max_mm x = 0.0"),
    ({"port": "socket://robot"}, r"robot.port: .*'socket://robot': write a TCP port as socket://host:port"),
    ({"port": "socket://robot:70000"}, r"robot.port: .*the TCP port '70000' must be a number 1..65535"),
    ({"simulated": {"transport": "ethercat"}}, r"robot.simulated.transport: Input should be 'tcp', 'pty' or 'socket'"),
])
def test_configuration_errors_name_the_field(host, ur5_urdf, extra, match):
    with pytest.raises(ConfigError, match=match):
        host.validate_robot_config("urdf", {k: v for k, v in _ur5(ur5_urdf, **extra).items() if k != "type"})


def test_a_relative_urdf_path_resolves_against_the_configuration_folder(host, ur5_urdf, tmp_path):
    (tmp_path / "cell").mkdir()
    (tmp_path / "cell" / "arm.urdf").write_text(open(ur5_urdf, encoding="utf-8").read(), encoding="utf-8")
    cfg = host.validate_robot_config("urdf", {"urdf": "arm.urdf", "base_link": "base"}, base_dir=tmp_path / "cell")
    assert cfg.urdf == (tmp_path / "cell" / "arm.urdf").resolve()


# --- the IRB 2400 through this type -----------------------------------------------------------
@pytest.fixture(scope="module")
def irb():
    return PluginHost().arm_kinematics({"type": "abb_irb2400"})


def _irb_section(path, **extra) -> dict:
    return {"type": "urdf", "urdf": str(path), "joint_map": {"matrix": IRB_COUPLING}, **extra}


def test_irb2400_urdf_agrees_with_the_native_model(host, irb, tmp_path_factory):
    """The URDF written from the published geometry (the native model's chain and its
    model-convention limits), read through the urdf type with the coupled-axis joint map:
    flange poses agree with the native IRB 2400 model to 1e-9 mm over 1,000 random joint
    sets within the controller's limits, and so does the inverse kinematics."""
    path = tmp_path_factory.mktemp("irb") / "irb2400.urdf"
    path.write_text(chain_to_urdf(irb.chain, "abb_irb2400", joint_limits_rad=irb.model_joint_limits_rad()))
    section = _irb_section(path, joint_limits_deg=np.column_stack([irb.lower_deg, irb.upper_deg]).tolist())
    kin = host.arm_kinematics(section)
    Q = np.random.default_rng(11).uniform(irb.lower_deg, irb.upper_deg, (1000, 6))
    worst_mm = worst_rot = 0.0
    for q in Q:
        a, b = kin.flange_matrix_from_joints(q), irb.flange_matrix_from_joints(q)
        worst_mm = max(worst_mm, float(np.abs(a[:3, 3] - b[:3, 3]).max()))
        worst_rot = max(worst_rot, float(np.abs(a[:3, :3] - b[:3, :3]).max()))
    assert worst_mm < 1e-9 and worst_rot < 1e-12, (worst_mm, worst_rot)
    for q in Q[:30]:
        pose = irb.flange_pose_from_joints(q)
        np.testing.assert_allclose(kin.joints_from_flange_pose(pose, q + 2.0), q, atol=1e-7)
    # the controller's own limit on the coupled axis is checked as it checks it
    with pytest.raises(InputError, match=r"joint 3 \(joint_3\) = 70.0000 deg is outside its range -60 .. 65"):
        kin.check_joint_limits([0, 0, 70, 0, 0, 0])


def test_calibrated_model_reads_back_through_the_urdf_type(host, irb, tmp_path):
    """robot_calibrated.urdf from a kinematic calibration on the simulated IRB 2400 (as
    examples/sim-kinematic-eye-in-hand.toml writes it) reads back through the urdf type
    and reproduces the calibrated flange poses of controller joints."""
    from spherecal.estimation import CalibrationOptions, solve
    from spherecal.app.solving import write_calibrated_urdf
    from spherecal.sim import SweepPlan

    rng = np.random.default_rng(7)
    tilts = [(float(a), float(b), float(c)) for a, b, c in
             zip(rng.uniform(-45, 45, 12), rng.uniform(-45, 45, 12), rng.uniform(-90, 90, 12))]
    plan = SweepPlan(profiles_per_station=6, tilts_deg=tilts, station_offsets_mm=[(0.0, 0.0), (8.0, -15.0)])
    cell = standard_cell("eye_in_hand", seed=5, noise=NoiseModel(point_noise_mm=0.01, pose_translation_noise_mm=0.02),
                         robot_error=RobotErrorModel(), arm=irb, fov=reference_fov())
    sol = solve(simulate_dataset(cell, plan), CalibrationOptions(pose_translation_noise_mm=0.02,
                                                                 identify_kinematics=True), kinematics=irb)
    path = write_calibrated_urdf(sol, irb, tmp_path)
    ke = sol.refined.diagnostics["kinematic_effects"]
    calibrated = chain_with_errors(irb.chain, np.where(ke["identified"], sol.refined.kinematic_errors, 0.0))
    assert sum(ke["identified"]) > 0
    kin = host.arm_kinematics(_irb_section(path))
    assert kin.controller_joint_names == tuple(f"joint_{i}" for i in range(1, 7))
    Q = np.random.default_rng(2).uniform(irb.lower_deg, irb.upper_deg, (200, 6))
    want = calibrated.flange_matrices(np.array([irb.model_joints_rad(q) for q in Q]))
    got = np.array([kin.flange_matrix_from_joints(q, check_limits=False) for q in Q])
    assert np.abs(got[:, :3, 3] - want[:, :3, 3]).max() < 1e-9
    # and differs from the nominal model: the calibration is really in the file
    nominal = np.array([irb.flange_matrix_from_joints(q) for q in Q])
    assert np.abs(got[:, :3, 3] - nominal[:, :3, 3]).max() > 0.1


def test_the_shipped_ur5_urdf_is_example_robot_datas(host, ur5_urdf):
    """examples/robots/ur5.urdf (written by spherecal from the published geometry) and
    example-robot-data's UR5 give the same flange poses to 1e-9 mm."""
    from pathlib import Path

    shipped = Path(__file__).resolve().parents[2] / "examples" / "robots" / "ur5.urdf"
    a = host.arm_kinematics(_ur5(str(shipped)))
    b = host.arm_kinematics(_ur5(ur5_urdf))
    Q = np.radians(np.random.default_rng(3).uniform(-180.0, 180.0, (1000, 6)))
    assert np.abs(a.chain.flange_matrices(Q)[:, :3, 3] - b.chain.flange_matrices(Q)[:, :3, 3]).max() < 1e-9
    np.testing.assert_array_equal(a.model_joint_limits_rad(), b.model_joint_limits_rad())


def test_a_controller_working_in_another_frame_than_the_urdfs_base_is_refused_before_anything_moves(host, ur5_urdf,
                                                                                                      ur5_kin):
    """A base frame on the controller (a riser: the world 500 mm below the base) puts
    GETP and TGT in the world: the poses it reports lie 500 mm from the URDF's pose of
    its joints, and the connection is refused, naming the offset and what to do; a
    difference within the tolerance (an accuracy-compensated controller) is accepted."""
    home = {"home_joints_deg": [180.0, -90.0, 90.0, -90.0, -90.0, 0.0]}

    def connect(base_frame, **extra):
        cell = standard_cell("eye_in_hand", seed=0, arm=ur5_kin, fov=reference_fov())
        cell.arm = None
        section = _ur5(ur5_urdf, simulated={**home, "base_frame": base_frame}, **extra)
        return cell, lambda: host.create_robot(section, DeviceContext(cell=cell, log=lambda m: None))

    riser = {"translation_mm": [0.0, 0.0, 500.0], "quaternion_wxyz": [1.0, 0.0, 0.0, 0.0]}
    cell, create = connect(riser)
    with pytest.raises(DeviceError) as info:
        create()
    text = str(info.value)
    assert "reports the flange (GETP) 500.0 mm and 0.00 deg away from where the URDF puts 'tool0' in 'base'" in text
    assert "controller_from_urdf = translation [0.0, 0.0, 500.0] mm" in text and "Nothing was moved" in text
    # the arm stands where the controller started it (its home joints): it never moved
    at_home = ur5_kin.flange_pose_from_joints(home["home_joints_deg"], check_limits=False)
    np.testing.assert_allclose(cell.current_base_from_flange.as_matrix(), at_home.as_matrix(), atol=1e-6)
    turned = {"translation_mm": [0.0, 0.0, 0.0], "quaternion_wxyz": [0.9998477, 0.0, 0.0, 0.0174524]}  # 2 deg about z
    with pytest.raises(DeviceError, match=r"mm and 2\.00 deg away"):
        connect(turned)[1]()
    # 2 mm: within the default 5 mm (a controller's own accuracy compensation), refused at 1 mm
    small = {"translation_mm": [2.0, 0.0, 0.0], "quaternion_wxyz": [1.0, 0.0, 0.0, 0.0]}
    with connect(small)[1]() as robot:
        off = robot.controller_frame_offset(robot.kin)
        # (within the cell's pose noise, 0.02 mm per axis)
        assert off.offset_mm == pytest.approx(2.0, abs=0.1) and off.angle_deg < 0.01
    with pytest.raises(DeviceError, match=r"2\.0 mm and 0\.00 deg away .*robot.base_frame_tolerance_mm = 1 "):
        connect(small, base_frame_tolerance_mm=1.0)[1]()
    with connect(None)[1]() as robot:  # no base frame: the controller's pose is the URDF's
        assert robot.controller_frame_offset(robot.kin).offset_mm < 0.1  # (the cell's pose noise, 0.02 mm)
