"""wobj0 is the world frame, not the robot base.

The RAPID server reads poses as tool0 in wobj0 (world); the plugin's kinematics,
workspace box and path checks work in the robot base. A controller with a base frame
(riser, inverted mount, multi-robot cell) is refused on connect, before anything moves,
with a message that says what to do. The simulated controller takes a base frame
(``simulated.base_frame``) and then reports and takes poses in world, as a real one."""

import math
import re
from pathlib import Path

import numpy as np
import pytest

from spherecal.cli import EXIT_DEVICE, main
from spherecal.devices.contract import DeviceContext
from spherecal.core.errors import DeviceError
from spherecal.core.models import Pose
from spherecal.robots.abb_irb2400 import plugin
from spherecal.robots.abb_irb2400 import protocol as P
from spherecal.robots.abb_irb2400.config import AbbIrb2400Config, SimulatedControllerSettings
from spherecal.robots.abb_irb2400.driver import AbbIrb2400Robot
from spherecal.robots.abb_irb2400.kinematics import kinematics_for
from spherecal.robots.abb_irb2400.simulator import SimulatedIrb2400, start_simulator
from spherecal.sim.cell import NoiseModel, standard_cell
from reference_sensor import reference_fov

EXAMPLES = Path(__file__).resolve().parents[2] / "examples"
S45 = math.sqrt(0.5)


@pytest.mark.parametrize("base_frame", [
    Pose(translation_mm=(0.0, 0.0, 500.0), quaternion_wxyz=(1.0, 0.0, 0.0, 0.0)),  # on a 500 mm riser
    Pose(translation_mm=(0.0, 0.0, 2400.0), quaternion_wxyz=(0.0, 1.0, 0.0, 0.0)),  # hung from a gantry
    Pose(translation_mm=(3000.0, 1500.0, 0.0), quaternion_wxyz=(S45, 0.0, 0.0, S45)),  # the second robot of a cell
], ids=["riser", "inverted", "second-robot"])
def test_a_base_frame_is_refused_on_connect(irb2400_controllers, base_frame):
    cell = standard_cell(seed=1, fov=reference_fov())
    cfg = AbbIrb2400Config(timeout_s=0.5, simulated={"transport": "pty", "base_frame": base_frame})
    with pytest.raises(DeviceError, match=r"wobj0 is the world frame: the controller has a base frame \(a riser, an "
                                          r"inverted mount, a multi-robot cell\).* Nothing was moved\. Calibrate with "
                                          r"the robot's base frame equal to the world frame") as info:
        plugin.create_robot(cfg, DeviceContext(cell=cell, log=lambda m: None))
    (server,) = irb2400_controllers
    assert server.controller.moves == 0 and not server.running  # nothing moved; the link was closed
    # the message gives the base frame the readings imply: the configured one
    found = re.search(r"translation \[(.*?)\] mm, quaternion \(w, x, y, z\) \[(.*?)\]", str(info.value))
    t, q = (np.array([float(v) for v in g.split(",")]) for g in found.groups())
    np.testing.assert_allclose(t, base_frame.translation_mm, atol=0.2)
    np.testing.assert_allclose(q, base_frame.quaternion_wxyz, atol=2e-4)


def test_the_simulated_base_frame_is_world_from_base():
    """What the refusal rests on: with a base frame the controller's pose is in world,
    the plugin's forward kinematics in base (where the cell is), and a target is taken
    in world."""
    cell = standard_cell(seed=1, noise=NoiseModel(pose_translation_noise_mm=0.0), fov=reference_fov())
    world_from_base = Pose(translation_mm=(0.0, 0.0, 500.0), quaternion_wxyz=(1.0, 0.0, 0.0, 0.0))
    settings = SimulatedControllerSettings(base_frame=world_from_base, single_precision=False)
    kin = kinematics_for(AbbIrb2400Config().geometry, True)
    controller = SimulatedIrb2400(kin, settings, cell)
    reported = P.parse_pose_reply(P.decode_reply(controller.handle(P.getp_request(1))))
    base_pose = kin.flange_pose_from_joints(controller.joints_deg)
    np.testing.assert_allclose(reported.as_matrix(), (world_from_base @ base_pose).as_matrix(), atol=1e-3)
    target_in_base = Pose.from_rt(base_pose.rotation_matrix, base_pose.translation + [-200.0, 100.0, -300.0])
    assert P.decode_reply(controller.handle(P.target_request(2, world_from_base @ target_in_base))).kind == "OK"
    assert P.decode_reply(controller.handle(P.movl_request(3, 100.0, 2))).kind == "OK"
    np.testing.assert_allclose(cell.current_base_from_flange.as_matrix(), target_in_base.as_matrix(), atol=1e-3)


def test_within_the_tolerance_the_connection_is_made(irb2400_controllers):
    base_frame = Pose(translation_mm=(1.0, -1.0, 0.5), quaternion_wxyz=(1.0, 0.0, 0.0, 0.0))
    cfg = AbbIrb2400Config(timeout_s=0.5, simulated={"transport": "pty", "base_frame": base_frame})
    robot = plugin.create_robot(cfg, DeviceContext(cell=standard_cell(seed=1, fov=reference_fov()), log=lambda m: None))
    robot.close()


def test_a_wrong_joint_convention_is_caught_by_the_same_check():
    """No base frame, but the PC's model is not the controller's (j23_coupled wrong)."""
    settings = SimulatedControllerSettings(transport="pty", home_joints_deg=(0.0, 20.0, 0.0, 0.0, 70.0, 0.0))
    server = start_simulator(kinematics_for(AbbIrb2400Config().geometry, True), settings)
    robot = AbbIrb2400Robot(AbbIrb2400Config(j23_coupled=False, timeout_s=0.5), url=server.url, on_close=server.stop)
    with robot, pytest.raises(DeviceError, match=r"check robot\.geometry and robot\.j23_coupled against the arm"):
        robot.check_base_frame()


def test_calibrate_refuses_a_controller_with_a_base_frame(tmp_path, capsys):
    text = (EXAMPLES / "sim-eye-in-hand.toml").read_text()
    text = re.sub(r'(?m)^output_dir = .*$', 'output_dir = "out"', text)
    text += ('\n[robot.simulated.base_frame]\ntranslation_mm = [0.0, 0.0, 500.0]\n'
             'quaternion_wxyz = [1.0, 0.0, 0.0, 0.0]\n')
    path = tmp_path / "riser.toml"
    path.write_text(text)
    assert main(["calibrate", str(path), "--no-report"]) == EXIT_DEVICE
    err = capsys.readouterr().err
    assert "tool0 in wobj0 500.0 mm and 0.00 deg away" in err and "Nothing was moved" in err
    assert not (tmp_path / "out" / "journal.jsonl").exists()
