"""Driver for the IRB 2400 running ``SpherecalServer.mod`` (spherecal line protocol).

Two links, one driver: a serial line (``SpherecalSerial.mod`` on the controller), opened
with ``serial.serial_for_url`` (a device such as ``/dev/ttyS0``, ``COM1`` or a
pseudo-terminal, or another pyserial URL), or a TCP connection to the IRC5 socket server
(``SpherecalSocket.mod``) when the port is ``socket://host:port`` (the core's
:class:`~spherecal.plugins.TcpLink`). Framing, timeouts, resends and the stale-reply
rules below are the same code for both.

Every exchange is one request and one reply carrying the same sequence number.
Replies whose seq does not match the request (late replies of an earlier attempt) are
discarded; a corrupted line (checksum or syntax) or a timeout makes the driver resend
the request with a fresh seq, up to ``retries`` times, then raise
:class:`~spherecal.plugins.DeviceError` saying what went wrong. A lost link raises
DeviceError at once (over TCP: the controller closed the connection, or it broke), and
the driver never reconnects by itself: the robot must be created again, which starts a
new connection (and, for the socket server, a new session that has no staged target).
Requests are idempotent (a MOVL names its staged target, and the controller moves to a
target once), so a resend never makes the robot move twice.

Replies of an earlier session: on open the driver discards whatever waits on the link,
and the first exchange is a PING carrying a token drawn at random for this connection.
The server answers in order, so every reply of an earlier session still on its way comes
before the PONG that echoes the token: until that PONG every line is discarded, and no
other request is sent before it (protocol version 3).

Speed, workspace and joint limits (the latter through inverse kinematics) are checked
before anything is sent. The protocol, the link and the checks are brand-free and live in
the plugin API (``spherecal.plugins.line_protocol``, :class:`spherecal.plugins.LineRobot`); this module
adds the IRB 2400's names and its calibrated model.

With a calibrated model (``config.calibrated_model``) the driver applies it on the PC
side, as the controller keeps its nominal model: a target pose P becomes the joints q
that reach P on the calibrated model, and the controller is sent the nominal model's
pose of q (it turns that back into q); the flange pose is read as joints (GETJ) through
the calibrated model. The line protocol carries poses to 0.001 mm and quaternions to
1e-6, joints to 1e-4 deg: that resolution, not the model, limits how closely a target
is reached and a pose read (a few micrometres).
"""

from __future__ import annotations

from typing import Callable

import numpy as np

from spherecal.plugins import MIN_SPEED_MM_S  # noqa: F401 - re-exported
from spherecal.plugins import DeviceError, LineRobot, Pose, initial_seq
from spherecal.plugins import line_protocol as lineproto

from .config import AbbIrb2400Config
from .kinematics import CalibratedIrb2400Kinematics, Irb2400Kinematics


def _initial_seq() -> int:
    """A random sequence number to start a session from (the first request carries the
    next one)."""
    return initial_seq()


class AbbIrb2400Robot(LineRobot):
    """A connected IRB 2400 (implements :class:`spherecal.plugins.Robot`).

    Poses are ``base_from_flange`` (tool0 in wobj0), mm, quaternion (w, x, y, z).
    Joints are degrees in the controller convention (``CJointT()``)."""

    name = "IRB 2400"
    server_hint = "that SpherecalServer is running on the controller"
    socket_hint = "that SpherecalSocket runs on the controller and listens on this address"
    version_hint = "load the SpherecalServer.mod shipped with this package"

    def __init__(
        self,
        config: AbbIrb2400Config,
        *,
        url: str | None = None,
        kinematics: Irb2400Kinematics | None = None,
        on_close: Callable[[], None] | None = None,
        tool_point_mm=None,
    ):
        if kinematics is None:
            kinematics = config.kinematics()
        #: The calibrated model applied on the PC side, or None (nominal model only).
        self.calibrated = kinematics if isinstance(kinematics, CalibratedIrb2400Kinematics) else None
        #: The controller's own model: the nominal one.
        self.nominal_kin = self.calibrated.nominal if self.calibrated is not None else kinematics
        super().__init__(config, kinematics, url=url, on_close=on_close, tool_point_mm=tool_point_mm,
                         n_joints=6, seq_start=_initial_seq())

    def pose_from_joints_only(self) -> bool:
        """With a calibrated model the flange pose comes from the joints through it (the
        controller's own pose is its nominal model's)."""
        return self.calibrated is not None

    def check_base_frame(self) -> None:
        """Refuse a controller whose wobj0 (world) is not the robot base.

        The server reads poses as tool0 in wobj0, which is the WORLD frame; this plugin's
        kinematics, workspace box and path checks work in the robot BASE frame. They are
        one frame only when the controller's base frame is identity; a riser, an inverted
        mount or a multi-robot cell configures another. So the controller's pose (GETP)
        is compared with the controller's own (nominal) model at the joints it reports
        (GETJ): more than ``base_frame_tolerance_mm`` / ``_deg`` apart raises
        DeviceError, saying what to do; nothing has moved. The same check catches a
        ``geometry`` or ``j23_coupled`` that does not match the arm."""
        off = self.controller_frame_offset(self.nominal_kin)
        cfg = self.config
        if off.within(cfg.base_frame_tolerance_mm, cfg.base_frame_tolerance_deg):
            return
        raise DeviceError(
            f"{self.name} on {self.url}: the controller reports tool0 in wobj0 {off.offset_mm:.1f} mm and "
            f"{off.angle_deg:.2f} deg away from where this plugin's model puts the flange at the joints it reports "
            f"({off.joints_text()} deg), beyond robot.base_frame_tolerance_mm = "
            f"{cfg.base_frame_tolerance_mm:g} / _deg = {cfg.base_frame_tolerance_deg:g}. wobj0 is the world frame: "
            f"the controller has a base frame (a riser, an inverted mount, a multi-robot cell), here about "
            f"world_from_base = {off.frame_text()}, but spherecal plans, checks "
            "the workspace and the paths, and moves in the robot base frame, so its checks would not hold. Nothing "
            "was moved. Calibrate with the robot's base frame equal to the world frame (system parameters, topic "
            "Motion, type Robot, the base frame), or, if the base frame is already identity, check robot.geometry "
            "and robot.j23_coupled against the arm (an Absolute Accuracy controller may need a larger tolerance)"
        )

    def controller_pose(self, base_from_flange: Pose, target_joints_deg=None) -> Pose:
        """The pose to send the controller for the flange to reach ``base_from_flange``:
        the pose itself with the nominal model; with a calibrated model, the nominal
        model's pose of the joints that reach it on the calibrated model
        (``target_joints_deg`` when already solved, else solved from the last joints).
        The path between is then the controller's straight line in its nominal model,
        within a few mm of a true straight line."""
        if self.calibrated is None:
            return base_from_flange
        if target_joints_deg is None:
            seed = self.last_joints_deg if self.last_joints_deg is not None else np.zeros(6)
            target_joints_deg = self.calibrated.joints_from_flange_pose(base_from_flange, seed_joints_deg=seed)
        return self.nominal_kin.flange_pose_from_joints(target_joints_deg, check_limits=False)

    def identity(self) -> dict[str, str]:
        """What this robot is (spherecal.plugins.device_identity): the model, the serial
        number from the configuration (the protocol does not report it) and the
        controller program it talks to."""
        found = {"manufacturer": "ABB", "model": "IRB 2400",
                 "controller": f"SpherecalServer.mod, protocol version {lineproto.PROTOCOL_VERSION}, on {self.url}"}
        if self.config.serial_number:
            found["serial_number"] = self.config.serial_number
        return found
