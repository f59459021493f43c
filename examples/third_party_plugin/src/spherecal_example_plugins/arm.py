"""Robot type ``example_arm``: a six-axis arm whose controller speaks XA/1 over TCP.

The driver (:class:`ExampleArm`) speaks the protocol (:mod:`.xa_protocol`) and nothing
else; every check before a move (speed at the tool point, the workspace box, reach along
the path from the joints read now, the first move, the controller's frame) is the core's
:class:`spherecal.plugins.MotionSafety`. On a simulated cell the factory starts the
simulated controller (:mod:`.arm_sim`) and the same driver connects to it. It streams
its pose while it moves (:class:`spherecal.plugins.PoseStreamingRobot`, for an on-the-fly
acquisition): XA/1's ``STREAM``, the samples arriving on the same connection.

Poses are ``base_from_flange``: translation in mm, quaternion (w, x, y, z), as everywhere
in spherecal (docs/conventions.md); joints in degrees, the controller's.
"""

from __future__ import annotations

import socket

import numpy as np
from pydantic import ConfigDict, Field

from spherecal.plugins import (DeviceContext, DeviceError, MotionLimits, MotionSafety, Pose, PoseStream,
                               PoseStreamClockError, PoseStreamCounts, PoseStreamError, PoseStreamStalled, RobotType,
                               WorkspaceBox, hookimpl, rotation_angle_deg)

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
    stream_period_ms: int = Field(4, ge=1, le=100, description="the pose stream's sample period, ms of the "
                                  "controller's clock")
    stream_stall_s: float = Field(0.1, gt=0, le=10, description="longest time without a pose sample (controller "
                                  "clock) before the stream counts as stalled, s")
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
        self._samples: list[list[float]] | None = None  # the running pose stream's SAMPLE lines
        self._counts = PoseStreamCounts()

    def _read_line(self, request: bytes) -> tuple[str, list]:
        try:
            while b"\n" not in self._buffer:
                chunk = self._sock.recv(65536)
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
            return XA.parse(line + b"\n", {**XA.REPLIES, "FAIL": None})
        except XA.XaError as exc:
            raise DeviceError(f"{self.name}: the controller's reply is not XA/1: {exc}") from None

    def _ask(self, request: bytes, reply: str) -> list:
        """Send ``request`` and return the numbers of its ``reply``; the pose stream's
        samples that come before it are kept."""
        self.check_open()
        try:
            self._sock.sendall(request)
        except OSError as exc:
            raise DeviceError(f"{self.name}: connection lost ({exc})") from None
        verb, values = self._read_line(request)
        while verb == "SAMPLE":
            if self._samples is None:
                raise DeviceError(f"{self.name}: the controller sends pose samples, but no stream was started")
            self._samples.append(values)
            verb, values = self._read_line(request)
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

    # the pose stream (PoseStreamingRobot) ----------------------------------------------------
    def can_stream_poses(self) -> bool:
        return True  # XA/1 always streams

    def start_pose_stream(self) -> None:
        """Start the stream; return once its first sample came and agrees with the controller's pose."""
        if self._samples is not None:
            raise PoseStreamError(f"{self.name}: a pose stream is already running; stop it first")
        self._samples = []
        try:
            self._ask(XA.line("STREAM", self.config.stream_period_ms), "STREAMING")
            if not self._samples:
                raise PoseStreamError(f"{self.name}: the pose stream started but sent no sample")
            first, pose = np.asarray(self._samples[0]), self.read_controller_pose()
            d_mm = np.linalg.norm(first[2:5] - pose.translation_mm)
            d_deg = rotation_angle_deg(Pose.from_xyz_quat_wxyz(first[2:5], first[5:9]).rotation_matrix,
                                       pose.rotation_matrix)
            if d_mm > FRAME_TOLERANCE_MM or d_deg > FRAME_TOLERANCE_DEG:
                raise PoseStreamError(f"{self.name}: the stream's first sample is {d_mm:.2f} mm and {d_deg:.2f} deg "
                                      "from the controller's pose: it streams another frame")
        except DeviceError as exc:
            self._samples = None
            try:
                self._ask(XA.line("UNSTREAM"), "UNSTREAMED")
            except DeviceError:
                pass
            if isinstance(exc, PoseStreamError):
                raise
            raise PoseStreamError(str(exc)) from None

    def stop_pose_stream(self) -> PoseStream:
        """Stop the stream; every sample since the start, or the fault that ended it with
        the samples before it (a stall: no sample for ``stream_stall_s``; a clock jump)."""
        if self._samples is None:
            raise PoseStreamError(f"{self.name}: no pose stream is running (start_pose_stream first)")
        try:
            t_stop_s, failed = self._ask(XA.line("UNSTREAM"), "UNSTREAMED")[0], None
        except DeviceError as exc:
            t_stop_s, failed = None, (PoseStreamError, f"stopping it failed: {exc}")
        rows, self._samples = np.asarray(self._samples, dtype=float).reshape(-1, 15), None
        seq, t = np.round(rows[:, 0]).astype(np.int64), rows[:, 1]
        n, fault = _samples_kept(seq, t, self.config.stream_period_ms * 1e-3, self.config.stream_stall_s)
        if fault is None and n and t_stop_s is not None and t_stop_s - t[n - 1] > self.config.stream_stall_s:
            fault = (PoseStreamStalled, f"no sample for the last {t_stop_s - t[n - 1]:.3f} s")
        fault = failed or fault
        self._counts = PoseStreamCounts(received=n, lost=int(seq[n - 1] - seq[0] + 1 - n) if n else 0)
        stream = None if n < 2 else PoseStream.from_quaternions(t[:n], rows[:n, 2:5], rows[:n, 5:9], rows[:n, 9:],
                                                                seq[:n])
        if fault is None and stream is None:
            fault = (PoseStreamError, f"{n} sample(s) came, a stream needs two")
        if fault is not None:
            raise fault[0](f"{self.name}: the pose stream ended: {fault[1]}", stream, self._counts)
        return stream

    def pose_stream_counts(self) -> PoseStreamCounts:
        """The running stream's samples so far, or the last stream's counts."""
        return PoseStreamCounts(received=len(self._samples)) if self._samples is not None else self._counts

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


def _samples_kept(seq: np.ndarray, t_robot_s: np.ndarray, period_s: float, stall_s: float):
    """How many samples to keep, and the fault at the first one not kept (None: all kept):
    a gap longer than ``stall_s``, or stamps that do not follow the sequence numbers."""
    for i in range(1, len(seq)):
        dt, dseq = t_robot_s[i] - t_robot_s[i - 1], seq[i] - seq[i - 1]
        if dt > stall_s:
            return i, (PoseStreamStalled, f"no sample for {dt:.3f} s after sample {seq[i - 1]}")
        if dseq < 1 or abs(dt - dseq * period_s) > period_s / 2:
            return i, (PoseStreamClockError, f"the clock went {dt:+.4f} s over {dseq} sample(s) at sample {seq[i]}")
    return len(seq), None


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
