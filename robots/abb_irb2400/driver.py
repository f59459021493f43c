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

Pose streaming (``config.egm``; :class:`spherecal.plugins.PoseStreamingRobot`): over
Externally Guided Motion the controller streams the measured flange pose every 4 ms
over UDP while ordinary moves run. :meth:`AbbIrb2400Robot.start_pose_stream` opens the
receiver (:class:`~.egm_receiver.EgmReceiver`), sends ``SSTART`` and waits for the
first sample, which must agree with the controller's own pose (``GETP``, within
``base_frame_tolerance_mm`` / ``_deg``): a stream in another frame is refused before
anything moves. :meth:`AbbIrb2400Robot.stop_pose_stream` sends ``SSTOP``, takes the
samples still on their way and returns the :class:`~spherecal.plugins.PoseStream`
(the controller's stamps and sequence numbers), or raises the fault that ended the
stream with what was kept. With a calibrated model (or ``pose_source = "joints"``) the
stream's poses come from its joints through the model, as every other pose does.

Without EGM (an S4C+), ``config.pose_stream`` (mode ``programmed_line``) offers the same
contract with poses computed along each move's programmed line, timed by the
controller's stamps of its start and end (:mod:`.line_stream`, :mod:`.programmed_line`):
not measured, which the stream's ``assumption`` says.
"""

from __future__ import annotations

from dataclasses import replace
from typing import TYPE_CHECKING, Callable

import numpy as np

from spherecal.plugins import MIN_SPEED_MM_S  # noqa: F401 - re-exported
from spherecal.plugins import (DeviceError, LineRobot, Pose, PoseStreamCounts, PoseStreamError, initial_seq,
                               rotation_angle_deg)
from spherecal.plugins import line_protocol as lineproto

from . import protocol as SP
from .config import AbbIrb2400Config, EgmSettings
from .kinematics import CalibratedIrb2400Kinematics, Irb2400Kinematics
from .line_stream import ProgrammedLineStreaming

if TYPE_CHECKING:  # pragma: no cover - the streams' model is loaded when a stream is taken
    from spherecal.plugins import PoseStream


def _initial_seq() -> int:
    """A random sequence number to start a session from (the first request carries the
    next one)."""
    return initial_seq()


class AbbIrb2400Robot(ProgrammedLineStreaming, LineRobot):
    """A connected IRB 2400 (implements :class:`spherecal.plugins.Robot`).

    Poses are ``base_from_flange`` (tool0 in wobj0), mm, quaternion (w, x, y, z).
    Joints are degrees in the controller convention (``CJointT()``)."""

    name = "IRB 2400"
    server_hint = "that SpherecalServer is running on the controller"
    socket_hint = "that SpherecalSocket runs on the controller and listens on this address"
    version_hint = "load the SpherecalServer.mod shipped with this package"
    extra_replies = SP.LINE_REPLY_ARGS  #: the T reply of LTIME (the programmed-line stream)

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

    # pose streaming (EGM) -------------------------------------------------------------------
    _egm = None  #: the running stream's receiver, or None
    _egm_counts = PoseStreamCounts()  #: the last stream's counts
    simulator = None  #: the simulated controller's server in simulated runs (the plugin sets it)

    def can_stream_poses(self) -> bool:
        """Whether pose streaming is configured (``robot.egm``, or ``robot.pose_stream``:
        computed along the programmed line)."""
        return self.config.egm is not None or self.config.pose_stream is not None

    def _egm_settings(self) -> EgmSettings:
        if self.config.egm is None:
            raise PoseStreamError(
                f"{self.name}: pose streaming is not configured: add a [robot.egm] section (port = the UDP port this "
                "PC listens on, the remote port of the controller's UDPUC device) and load SpherecalEgm.mod on an "
                "IRC5 with the Externally Guided Motion option (docs/robot-abb-irb2400.md, 'Pose streaming'); "
                "without EGM (an S4C+), [robot.pose_stream] mode = \"programmed_line\" with SpherecalLine.mod "
                "computes the poses from the programmed line ('Programmed-line poses')")
        return self.config.egm

    def start_pose_stream(self) -> None:
        """Start the EGM stream and return once its first sample has come and agrees with
        the controller's own pose (see the module's docstring). Raises PoseStreamError,
        saying what to check, when it cannot; nothing moves."""
        from .egm_receiver import EgmReceiver

        if self.config.pose_stream is not None:
            return self.start_line_stream()
        settings = self._egm_settings()
        self.check_open()
        if self._egm is not None:
            raise PoseStreamError(f"{self.name}: a pose stream is already running; stop it first")
        receiver = EgmReceiver(settings, name=f"{self.name} on {self.url}").open()
        if self.simulator is not None:  # the simulated UDPUC device sends to this receiver
            self.simulator.controller.egm.destination = ("127.0.0.1", receiver.port)
        try:
            self._exchange("SSTART", lambda seq: SP.stream_start_request(seq, settings.sample_period_ms), "OK")
        except DeviceError as exc:
            receiver.close()
            raise PoseStreamError(
                f"{exc}. The server must be SpherecalServer.mod of this package with SpherecalEgm.mod loaded beside "
                "it, on an IRC5 with the Externally Guided Motion option (689-1) and the UDPUC device configured "
                "(docs/robot-abb-irb2400.md, 'Pose streaming')") from exc
        self._egm = receiver
        if not receiver.wait_first(settings.first_sample_timeout_s):
            port = receiver.port
            self._abandon_stream()
            raise PoseStreamError(
                f"{self.name}: the controller started the EGM stream but no sample reached UDP "
                f"{settings.address}:{port} within {settings.first_sample_timeout_s:g} s "
                "(robot.egm.first_sample_timeout_s). Check the UDPUC device's remote address (this PC's address on "
                "the robot's network) and remote port (robot.egm.port), and that the PC's firewall lets UDP in")
        try:
            self._check_stream_frame(receiver)
        except PoseStreamError:
            self._abandon_stream()
            raise

    def _check_stream_frame(self, receiver) -> None:
        """The newest sample's pose against the controller's own (GETP), the arm standing."""
        sample = receiver.newest()
        controller = self.read_controller_pose()
        streamed = Pose.from_xyz_quat_wxyz(sample.translation_mm, sample.quaternion_wxyz)
        offset_mm = float(np.linalg.norm(streamed.translation - controller.translation))
        angle_deg = float(rotation_angle_deg(controller.rotation_matrix, streamed.rotation_matrix))
        cfg = self.config
        if offset_mm <= cfg.base_frame_tolerance_mm and angle_deg <= cfg.base_frame_tolerance_deg:
            return
        raise PoseStreamError(
            f"{self.name}: the EGM stream reports the flange {offset_mm:.2f} mm and {angle_deg:.3f} deg away from "
            f"the controller's tool0 in wobj0 (GETP), beyond robot.base_frame_tolerance_mm = "
            f"{cfg.base_frame_tolerance_mm:g} / _deg = {cfg.base_frame_tolerance_deg:g}: the stream is in another "
            "tool or work object. Check EGMActPose in SpherecalEgm.mod (tool0, wobj0). The stream was stopped; "
            "nothing moved")

    def _abandon_stream(self) -> None:
        """Stop the controller's stream and drop the receiver (a failed start)."""
        receiver, self._egm = self._egm, None
        try:
            self._exchange("SSTOP", SP.stream_stop_request, "OK")
        except DeviceError:
            pass  # the start already failed: say that, not this
        finally:
            if receiver is not None:
                self._egm_counts = receiver.counts()
                receiver.close()

    def stop_pose_stream(self) -> PoseStream:
        """Stop the EGM stream and return every sample since the start (sequence order,
        controller stamps, ``seq`` unwrapped). Raises the fault that ended the stream
        (PoseStreamStalled, PoseStreamClockError) or a failed stop as PoseStreamError,
        with the samples kept in its ``stream``."""
        if self.config.pose_stream is not None:
            return self.stop_line_stream()
        receiver = self._egm
        if receiver is None:
            raise PoseStreamError(f"{self.name}: no pose stream is running (start_pose_stream first)")
        self._egm = None
        period_s = receiver.settings.sample_period_ms * 1e-3
        failure: DeviceError | None = None
        try:
            self._exchange("SSTOP", SP.stream_stop_request, "OK")
        except DeviceError as exc:
            failure = exc
        finally:
            receiver.finish(quiet_s=max(5 * period_s, 0.02))
            self._egm_counts = receiver.counts()
        try:
            stream = self._stream_poses(receiver.stream())
        except PoseStreamError as exc:
            if exc.stream is not None:
                exc.stream = self._stream_poses(exc.stream)
            raise
        if failure is not None:
            raise PoseStreamError(f"{self.name}: the EGM stream could not be stopped: {failure}", stream,
                                  self._egm_counts) from failure
        return stream

    def pose_stream_counts(self) -> PoseStreamCounts:
        """What the running stream has delivered so far, or the last stream's counts."""
        if self.config.pose_stream is not None:
            return self.line_stream_counts()
        return self._egm.counts() if self._egm is not None else self._egm_counts

    def _stream_poses(self, stream: PoseStream) -> PoseStream:
        """The stream as this robot gives poses: with a calibrated model (or ``pose_source
        = "joints"``) the flange poses come from the streamed joints through the model."""
        if not (self.config.pose_source == "joints" or self.pose_from_joints_only()):
            return stream
        if stream.joints_deg is None:
            raise PoseStreamError(f"{self.name}: the EGM stream carries no joints, and poses must come from the "
                                  "joints here (a calibrated model, or pose_source = 'joints')", None,
                                  self._egm_counts)
        poses = [self.kin.flange_pose_from_joints(q, check_limits=False) for q in stream.joints_deg]
        return replace(stream, R=np.array([p.rotation_matrix for p in poses]),
                       t_mm=np.array([p.translation for p in poses]))

    def close(self) -> None:
        """Stop a running pose stream (best effort), then close the link."""
        self._close_line_stream()
        receiver, self._egm = self._egm, None
        if receiver is not None:
            try:
                if not self._closed:
                    self._exchange("SSTOP", SP.stream_stop_request, "OK")
            except DeviceError:
                pass  # closing: the link may be gone already
            finally:
                receiver.close()
        super().close()
