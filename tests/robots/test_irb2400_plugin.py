"""The abb_irb2400 plugin: registration, configuration, the simulated factory path."""

import numpy as np
import pytest

from spherecal.devices.contract import DeviceContext, Robot, RobotType
from spherecal.core.errors import ConfigError, DeviceError
from spherecal.plugins.testing import RobotHarness
from spherecal.robots.abb_irb2400 import plugin
from spherecal.robots.abb_irb2400.config import AbbIrb2400Config
from spherecal.robots.abb_irb2400.driver import AbbIrb2400Robot
from spherecal.sim.cell import NoiseModel, standard_cell
from reference_sensor import reference_fov


class _Registry:
    def __init__(self):
        self.robots = []

    def add_robot(self, robot_type):
        self.robots.append(robot_type)


def test_registers_one_robot_type():
    registry = _Registry()
    plugin.spherecal_register_devices(registry)
    (rt,) = registry.robots
    assert isinstance(rt, RobotType)
    assert (rt.name, rt.config_model, rt.factory) == ("abb_irb2400", AbbIrb2400Config, plugin.create_robot)
    pose = rt.flange_pose_from_joints(AbbIrb2400Config(), np.zeros(6))
    np.testing.assert_allclose(pose.translation_mm, (940.0, 0.0, 1455.0), atol=1e-9)
    np.testing.assert_allclose(pose.quaternion_wxyz, (0.70711, 0, 0.70711, 0), atol=1e-5)


def test_kinematics_follow_the_coupling_setting():
    q = np.array([0.0, 30.0, 0.0, 0.0, 0.0, 0.0])
    coupled = plugin.flange_pose_from_joints(AbbIrb2400Config(), q)
    serial = plugin.flange_pose_from_joints(AbbIrb2400Config(j23_coupled=False), q)
    np.testing.assert_allclose(coupled.rotation_matrix[:, 2], (1, 0, 0), atol=1e-12)
    assert serial.translation_mm[2] < coupled.translation_mm[2] - 300


def test_every_config_field_has_a_description():
    def walk(model, prefix=""):
        for name, info in model.model_fields.items():
            assert info.description, f"{prefix}{name} has no description"
            ann = info.annotation
            if isinstance(ann, type) and hasattr(ann, "model_fields"):
                walk(ann, f"{prefix}{name}.")

    walk(AbbIrb2400Config)


def test_registered_through_the_entry_point(spherecal_host):
    rt = spherecal_host.registry.robot_type("abb_irb2400")
    assert rt.factory is plugin.create_robot


@pytest.mark.parametrize(
    "section, message",
    [
        ({"type": "abb_irb2400", "timeout": 1}, "did you mean 'timeout_s'"),
        ({"type": "abb_irb2400", "pose_source": "encoder"}, "robot.pose_source"),
        ({"type": "abb_irb2400", "workspace": {"min_mm": [0, 0, 0], "max_mm": [1, 1, 0]}},
         "min_mm z = 0.0 must be below max_mm z = 0.0"),
        ({"type": "abb_irb2400", "max_speed_mm_s": 0}, "robot.max_speed_mm_s"),
    ],
)
def test_bad_configuration_is_a_config_error(spherecal_host, section, message):
    with pytest.raises(ConfigError, match=message):
        spherecal_host.validate_robot_config("abb_irb2400", section)


def test_simulated_factory_runs_the_real_driver_over_pyserial():
    cell = standard_cell(seed=1, fov=reference_fov())
    messages = []
    cfg = AbbIrb2400Config(timeout_s=0.2, simulated={"transport": "pty"})
    robot = plugin.create_robot(cfg, DeviceContext(cell=cell, log=messages.append))
    try:
        assert isinstance(robot, AbbIrb2400Robot) and isinstance(robot, Robot)
        assert robot.url == robot.simulator.url and "simulated controller serving on" in messages[0]
        # the simulator put the cell's flange where its joints are
        home = plugin.flange_pose_from_joints(cfg, robot.read_joints_deg())
        np.testing.assert_allclose(cell.current_base_from_flange.as_matrix(), home.as_matrix(), atol=1e-3)
    finally:
        robot.close()
    assert not robot.simulator.running
    robot.close()  # twice is fine


def test_passes_the_robot_harness(spherecal_host, spherecal_stations):
    # pose noise in rotation, so the harness allows for the protocol's 6-decimal quaternions
    cell = standard_cell(seed=0, noise=NoiseModel(pose_translation_noise_mm=0.02,
                                                  pose_rotation_noise_deg=0.002), fov=reference_fov())
    robot = spherecal_host.create_robot({"type": "abb_irb2400", "timeout_s": 0.5}, DeviceContext(cell=cell))
    harness = RobotHarness(cell, spherecal_stations, move_tolerance_mm=1e-3, move_tolerance_deg=2e-4)
    cfg = AbbIrb2400Config()
    report = harness.check(robot, flange_pose_from_joints=lambda j: plugin.flange_pose_from_joints(cfg, j))
    assert report.n_moves >= 3
    # joints travel with 4 decimals: 5e-5 deg on a 1.7 m lever is 1.5 um per joint
    assert report.max_kinematics_error_mm < 5e-3
    assert not robot.simulator.running


def test_real_port_that_does_not_exist_is_a_device_error():
    with pytest.raises(DeviceError, match=r"cannot open '/dev/spherecal-no-such-port'"):
        plugin.create_robot(AbbIrb2400Config(port="/dev/spherecal-no-such-port"), DeviceContext(cell=None))
