"""The abb_irb2400 plugin with a calibrated model (``calibrated_model``, a URDF): the
configuration checks it, the kinematics use it, and the driver applies it on the PC
side so that the simulated arm with a real arm's geometric error reaches the commanded
poses and reports its true ones."""

from __future__ import annotations

import numpy as np
import pytest

from spherecal.core import geometry as geo
from spherecal.devices.contract import DeviceContext
from spherecal.core.errors import ConfigError
from spherecal.core.models import Pose
from spherecal.plugins.host import PluginHost
from spherecal.robots.abb_irb2400 import plugin
from spherecal.robots.abb_irb2400.config import AbbIrb2400Config
from spherecal.robots.abb_irb2400.kinematics import CalibratedIrb2400Kinematics, UnreachableError, kinematics_for
from spherecal.sim.cell import standard_cell
from spherecal.sim.robot_error import RobotErrorModel, SimulatedArm
from spherecal.core.urdf import chain_to_urdf, fold_zero_offsets, write_urdf
from reference_sensor import reference_fov

#: Controller joints (deg) of a few targets around the standard cell's sphere, away
#: from singularities, plus ones near the limits of axes 4 and 6.
JOINT_SETS = np.array([
    [5.0, 20.0, 5.0, 10.0, 60.0, -20.0],
    [-15.0, 35.0, -10.0, -40.0, 75.0, 30.0],
    [25.0, 10.0, 20.0, 60.0, 40.0, 120.0],
    [0.0, 45.0, -25.0, 0.0, 85.0, 0.0],
    [40.0, -20.0, 30.0, -150.0, -50.0, 350.0],
])


@pytest.fixture(scope="module")
def host():
    return PluginHost()


def _true_model(tmp_path, seed=3):
    """A simulated arm with a real arm's error, and its true geometry as a URDF."""
    arm = SimulatedArm(kinematics_for(), RobotErrorModel(), seed)
    path = write_urdf(tmp_path / "robot_calibrated.urdf", fold_zero_offsets(arm.true_chain, arm.zero_offsets_rad),
                      "abb_irb2400_calibrated")
    return arm, path


def _pose_error(a: Pose, b: Pose) -> tuple[float, float]:
    return (float(np.linalg.norm(a.translation - b.translation)),
            float(np.radians(geo.rotation_angle_deg(a.rotation_matrix, b.rotation_matrix))))


def test_nominal_geometry_as_a_calibrated_model_changes_nothing(tmp_path):
    nominal = kinematics_for()
    path = tmp_path / "nominal.urdf"
    path.write_text(chain_to_urdf(nominal.chain, "abb_irb2400"))
    cal = AbbIrb2400Config(calibrated_model=path).kinematics()
    assert isinstance(cal, CalibratedIrb2400Kinematics)
    for q in JOINT_SETS:
        np.testing.assert_allclose(cal.flange_matrix_from_joints(q), nominal.flange_matrix_from_joints(q), atol=1e-9)
        pose = nominal.flange_pose_from_joints(q)
        np.testing.assert_allclose(cal.joints_from_flange_pose(pose, q + 3.0), nominal.joints_from_flange_pose(pose, q + 3.0),
                                   atol=1e-9)


def test_kinematics_are_the_calibrated_models(tmp_path):
    arm, path = _true_model(tmp_path)
    cfg = AbbIrb2400Config(calibrated_model=path)
    kin = plugin.arm_kinematics(cfg)
    for q in JOINT_SETS:
        true = arm.true_flange_pose(q)
        assert max(_pose_error(plugin.flange_pose_from_joints(cfg, q), true)) < 1e-9
        assert _pose_error(arm.nominal_flange_pose(q), true)[0] > 0.2  # the model error is real
        # inverse kinematics on the calibrated chain, from a seed a few degrees off
        sol = kin.joints_from_flange_pose(true, seed_joints_deg=q + 2.0)
        np.testing.assert_allclose(sol, q, atol=1e-8)
    assert np.abs(kin.chain.flange_matrices(np.zeros(6)) - arm.true_chain.flange_matrices(arm.zero_offsets_rad)).max() < 1e-9
    with pytest.raises(UnreachableError, match="calibrated model"):
        kin.joints_from_flange_pose(Pose.from_rt(np.eye(3), [3000.0, 0.0, 0.0]))


def test_the_pose_sent_to_the_controller_brings_the_true_flange_to_the_target(tmp_path):
    """Without the wire's rounding: the controller turns the nominal pose sent into
    joints with its nominal model; the arm's true geometry puts the flange at the target."""
    arm, path = _true_model(tmp_path)
    kin = AbbIrb2400Config(calibrated_model=path).kinematics()
    for q0 in JOINT_SETS:
        target = arm.true_flange_pose(q0 + 1.5)
        q, command = kin.controller_target(target, seed_joints_deg=q0)
        reached = arm.true_flange_pose(arm.joints_for(command, q0))
        dist, angle = _pose_error(reached, target)
        assert dist < 1e-6 and angle < 1e-9, (dist, angle)
        assert _pose_error(arm.true_flange_pose(arm.joints_for(target, q0)), target)[0] > 0.2  # uncorrected


def _run(cell, config: dict, host, targets):
    """Move the simulated robot to each target; the true pose reached and the pose read."""
    robot = host.create_robot({"type": "abb_irb2400", "timeout_s": 2.0, **config}, DeviceContext(cell=cell, log=lambda m: None))
    out = []
    try:
        for target in targets:
            robot.move_linear(target, 200.0)
            out.append((cell.current_base_from_flange, robot.read_flange_pose(), robot.read_joints_deg()))
    finally:
        robot.close()
    return out


def test_simulated_arm_reaches_commanded_poses_and_reports_true_ones(tmp_path, host):
    """Through the plugin, the driver, the line protocol and the simulated controller
    (which keeps the nominal model) to a simulated arm with a real arm's error."""
    cell = standard_cell(seed=3, robot_error=RobotErrorModel(), arm=kinematics_for(), fov=reference_fov())
    arm = cell.arm
    path = write_urdf(tmp_path / "true.urdf", fold_zero_offsets(arm.true_chain, arm.zero_offsets_rad), "true_arm")
    targets = [arm.true_flange_pose(q) for q in JOINT_SETS[:4]]

    got = _run(cell, {"calibrated_model": str(path)}, host, targets)
    for target, (true, read, joints) in zip(targets, got):
        # the wire carries 0.001 mm, quaternions to 1e-6 and joints to 1e-4 deg: micrometres
        dist, angle = _pose_error(true, target)
        assert dist < 2e-3 and angle < 3e-6, (dist, angle)
        dist, angle = _pose_error(read, true)
        assert dist < 5e-3 and angle < 1e-5, (dist, angle)
        # what is read is exactly the true geometry at the joints read
        assert max(_pose_error(read, arm.true_flange_pose(joints))) < 1e-9

    # the same moves without the calibrated model miss by the arm's error
    cell2 = standard_cell(seed=3, robot_error=RobotErrorModel(), arm=kinematics_for(), fov=reference_fov())
    for target, (true, read, _) in zip(targets, _run(cell2, {}, host, targets)):
        assert _pose_error(true, target)[0] > 0.2 and _pose_error(read, true)[0] > 0.2


def test_configuration_checks_the_model(tmp_path, host):
    _, path = _true_model(tmp_path)
    # a relative path resolves against the folder the host is given
    cfg = host.validate_robot_config("abb_irb2400", {"calibrated_model": "robot_calibrated.urdf"}, base_dir=tmp_path)
    assert cfg.calibrated_model == path.resolve()
    assert host.validate_robot_config("abb_irb2400", {"calibrated_model": str(path), "pose_source": "joints"})

    def bad(section, *needles):
        with pytest.raises(ConfigError) as info:
            host.validate_robot_config("abb_irb2400", section, base_dir=tmp_path)
        for needle in ("robot.calibrated_model", *needles):
            assert needle in str(info.value), str(info.value)

    with pytest.raises(ConfigError, match="pose_source"):
        host.validate_robot_config("abb_irb2400", {"calibrated_model": str(path), "pose_source": "controller"})
    bad({"calibrated_model": "absent.urdf"}, str(tmp_path / "absent.urdf"))
    (tmp_path / "renamed.urdf").write_text(path.read_text().replace("joint_3", "axis_3"))
    bad({"calibrated_model": "renamed.urdf"}, "renamed.urdf", "joint_3")
    (tmp_path / "flange.urdf").write_text(path.read_text().replace('"tool0"', '"flange"'))
    bad({"calibrated_model": "flange.urdf"}, "flange.urdf", "'tool0'")
    # a model far from the nominal IRB 2400 (here: the upper arm 100 mm longer) is refused
    other = kinematics_for().chain
    P = other.placements.copy()
    P[2, 2, 3] += 100.0
    write_urdf(tmp_path / "other.urdf", type(other)(P, other.axes, other.flange_placement), "other")
    bad({"calibrated_model": "other.urdf"}, "other.urdf", "away from the nominal")


def test_model_joint_limits_for_a_urdf_cover_every_controller_configuration(tmp_path):
    kin = kinematics_for()
    limits = np.degrees(kin.model_joint_limits_rad())
    np.testing.assert_allclose(limits[2], (-60.0 - 110.0, 65.0 + 100.0))
    np.testing.assert_allclose(limits[[0, 1, 3, 4, 5]], np.column_stack([kin.lower_deg, kin.upper_deg])[[0, 1, 3, 4, 5]])
    q = np.random.default_rng(2).uniform(kin.lower_deg, kin.upper_deg, (500, 6))
    model = np.degrees(np.array([kin.model_joints_rad(x) for x in q]))
    assert np.all(model >= limits[:, 0]) and np.all(model <= limits[:, 1])
    text = chain_to_urdf(kin.chain, "abb_irb2400", joint_limits_rad=kin.model_joint_limits_rad())
    assert 'lower="-2.96705972839036' in text  # -170 deg on joint_3
