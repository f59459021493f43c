"""Robot type ``example_arm``: a six-axis arm whose controller speaks XA/1 over TCP.

The driver (:class:`ExampleArm`) speaks the protocol (:mod:`.xa_protocol`) and nothing
else; every check before a move (speed at the tool point, the workspace box, reach along
the path from the joints read now, the first move, the controller's frame) is the core's
:class:`spherecal.plugins.MotionSafety`. On a simulated cell the factory starts the
simulated controller (:mod:`.arm_sim`) and the same driver connects to it.

Poses are ``base_from_flange``: translation in mm, quaternion (w, x, y, z), as everywhere
in spherecal (docs/conventions.md); joints in degrees, the controller's.
"""

from __future__ import annotations

import socket

import numpy as np
from pydantic import ConfigDict, Field

from spherecal.plugins import (DeviceContext, DeviceError, MotionLimits, MotionSafety, Pose, RobotType,
                               WorkspaceBox, hookimpl)

from . import xa_protocol as XA
from .arm_kinematics import HOME_JOINTS_DEG, ExampleArmKinematics

TYPE_NAME = "example_arm"
#: how far the controller's pose may lie from the model's pose of its joints on connecting
FRAME_TOLERANCE_MM, FRAME_TOLERANCE_DEG = 1.0, 0.1


class ExampleArmConfig(MotionLimits):
    """Configuration section of an ``example_arm`` robot::

        [robot]
        type = "example_arm"
        host = "192.168.0.20"
        port = 30010
        max_speed_mm_s = 250

    The limits are the core's :class:`~spherecal.plugins.MotionLimits` (``max_speed_mm_s``,
    ``orientation_speed_deg_s``, ``path_check_samples``, ``workspace``); the box defaults
    to the arm's reach around its base."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    host: str = Field("127.0.0.1", description="the controller's address (ignored on a simulated cell)")
    port: int = Field(30010, ge=1, le=65535, description="the controller's XA/1 TCP port (no unit)")
    timeout_s: float = Field(5.0, gt=0, le=600, description="longest wait for a reply (a move's included), s")
    workspace: WorkspaceBox = Field(
        default=WorkspaceBox(min_mm=(-1600.0, -1600.0, -200.0), max_mm=(1600.0, 1600.0, 2000.0)),
        description="the box the flange centre stays in, base frame, mm",
    )


class ExampleArm(MotionSafety):
    """The :class:`spherecal.plugins.Robot` of ``example_arm``: XA/1 over TCP, checked by
    :class:`~spherecal.plugins.MotionSafety` before every move."""

    name = "example arm"

    def __init__(self, config: ExampleArmConfig, address: tuple[str, int], tool_point_mm=None, on_close=None):
        super().__init__(config, ExampleArmKinematics(), tool_point_mm=tool_point_mm)
        self._on_close = on_close
        try:
            self._sock = socket.create_connection(address, timeout=config.timeout_s)
        except OSError as exc:
            self.close()
            raise DeviceError(f"{self.name}: cannot connect to {address[0]}:{address[1]} ({exc}); check that the "
                              "controller is on and serving XA/1, and robot.host / robot.port") from None
        self._buffer = b""
        self.last_pose_t_robot_s: float | None = None  #: the controller's clock at the last POSE read

    def _ask(self, request: bytes, reply: str) -> list:
        self.check_open()
        try:
            self._sock.sendall(request)
            while b"\n" not in self._buffer:
                chunk = self._sock.recv(4096)
                if not chunk:
                    raise DeviceError(f"{self.name}: the controller closed the connection")
                self._buffer += chunk
        except socket.timeout:
            raise DeviceError(f"{self.name}: no reply to {request.split()[0].decode()} within "
                              f"{self.config.timeout_s:g} s (robot.timeout_s)") from None
        except OSError as exc:
            raise DeviceError(f"{self.name}: connection lost ({exc})") from None
        line, _, self._buffer = self._buffer.partition(b"\n")
        try:
            verb, values = XA.parse(line + b"\n", {**XA.REPLIES, "FAIL": None})
        except XA.XaError as exc:
            raise DeviceError(f"{self.name}: the controller's reply is not XA/1: {exc}") from None
        if verb == "FAIL":
            raise DeviceError(f"{self.name}: the controller refused {request.split()[0].decode()}: {' '.join(values)}")
        if verb != reply:
            raise DeviceError(f"{self.name}: expected {reply} in reply, got {verb}")
        return values

    # what MotionSafety reads --------------------------------------------------------------
    def check_open(self) -> None:
        if getattr(self, "_sock", None) is None:
            raise DeviceError(f"{self.name}: the robot has been closed; create a new one")

    def read_joints_deg(self) -> np.ndarray:
        self.last_joints_deg = np.asarray(self._ask(XA.line("JOINTS"), "JOINTS"))
        return self.last_joints_deg

    def read_controller_pose(self) -> Pose:
        t_robot_s, *pose = self._ask(XA.line("POSE"), "POSE")
        self.last_pose_t_robot_s = t_robot_s
        return Pose.from_xyz_quat_wxyz(pose[:3], pose[3:])

    # the Robot protocol --------------------------------------------------------------------
    def read_flange_pose(self) -> Pose:
        """The flange pose now, as the controller reports it (base_from_flange, mm, (w, x, y, z))."""
        return self.read_controller_pose()

    def move_linear(self, base_from_flange: Pose, speed_mm_s: float) -> None:
        """Check the move (MotionSafety: InputError before anything is sent), then MOVE at
        the speeds that keep the tool point within ``speed_mm_s``; returns in position."""
        start, _ = self.check_move_from_here(base_from_flange, speed_mm_s)
        v_mm_s, v_deg_s, _ = self.move_speeds(start, base_from_flange, speed_mm_s)
        self._ask(XA.line("MOVE", *base_from_flange.translation_mm, *base_from_flange.quaternion_wxyz,
                          v_mm_s, v_deg_s, decimals=9), "DONE")

    def identity(self) -> dict[str, str]:
        manufacturer, model, serial, firmware = self._ask(XA.line("HELLO"), "HELLO")
        return {"manufacturer": manufacturer, "model": model, "serial_number": serial, "firmware": firmware}

    def close(self) -> None:
        """Release the connection (and stop a simulated controller). Safe to call twice."""
        sock, self._sock = getattr(self, "_sock", None), None
        if sock is not None:
            sock.close()
        on_close, self._on_close = self._on_close, None
        if on_close is not None:
            on_close()


def create_robot(config: ExampleArmConfig, context: DeviceContext) -> ExampleArm:
    """A connected ``example_arm``: on ``config.host``/``port``, or on a simulated
    controller started on ``context.cell``. Refused (DeviceError) when the controller
    works in another frame than the arm's base."""
    address, server = (config.host, config.port), None
    if context.cell is not None:
        from .arm_sim import start_simulated_controller

        server = start_simulated_controller(ExampleArmKinematics(), context.cell)
        address = server.address
        context.log(f"{TYPE_NAME}: simulated controller serving XA/1 on {address[0]}:{address[1]}")
    robot = ExampleArm(config, address, context.tool_point_mm, on_close=None if server is None else server.stop)
    robot.simulator = server  # the simulated controller's server (None on hardware), for tests
    try:
        robot.check_controller_frame(robot.kin, FRAME_TOLERANCE_MM, FRAME_TOLERANCE_DEG,
                                     "Set the controller's base and tool frames to none (tool0 in the base).")
    except BaseException:
        robot.close()
        raise
    return robot


@hookimpl
def spherecal_register_devices(registry) -> None:
    kinematics = ExampleArmKinematics()
    registry.add_robot(RobotType(
        name=TYPE_NAME,
        config_model=ExampleArmConfig,
        factory=create_robot,
        description="six-axis arm on the XA/1 TCP protocol, simulated on a simulated cell (example plugin)",
        flange_pose_from_joints=lambda config, joints_deg: kinematics.flange_pose_from_joints(joints_deg),
        arm_kinematics=lambda config: kinematics,
        home_joints_deg=tuple(HOME_JOINTS_DEG),  # where the core seeds IK before the arm is connected
    ))
