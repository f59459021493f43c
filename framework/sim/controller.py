"""A simulated robot controller that serves the spherecal line protocol
(:mod:`spherecal.devices.line_protocol`) over a real link, brand-free, in one of three flavours
(``SimulatedControllerSettings.transport``):

* ``tcp``: a serial server's line carried over TCP on 127.0.0.1 (``socket://``), as a
  serial device server would; a serial line has no sessions, so a reconnecting robot
  finds the controller as it left it;
* ``pty``: a serial server on a pseudo-terminal pair (the robot opens the slave device
  path);
* ``socket``: a controller's socket server on 127.0.0.1 (``socket://``): one connection
  at a time (others wait in the listen backlog), and every accepted connection is a new
  session, in which no target is staged.

:class:`SimulatedController` is the controller logic (one request line in, one reply line
out) on a robot plugin's kinematics (:class:`~spherecal.core.kinematics.ArmKinematics` plus
``check_joint_limits(joints_deg, what)``); :class:`ControllerServer` runs it in a thread
behind a transport and injects faults at runtime through :class:`Faults` (reply delay,
dropped requests or replies, truncated replies, corrupted bytes, the connection closed
mid-request, a disconnect).

Moves: a ``MOVL`` target becomes joints by the kinematics' inverse (the solution nearest
the current joints, as a controller's linear move keeps its configuration); the true
flange pose (the forward kinematics of those joints, through the cell's arm with its
geometric error when it has one) goes to ``cell.move_flange_to`` when a SimulatedCell is
given. A staged target is moved to once, and only in the link session that staged it
(over a socket server, a new connection cannot move to a target staged over an earlier
one: ``ERR 4``): a ``MOVL`` naming a target already reached answers OK without moving.
``GETJ`` reports controller-convention joints (plus optional noise); ``GETP`` the
nominal forward kinematics of the joints through the pose noise. A configured base frame
(``settings.base_frame``, world_from_base: a riser, an inverted mount, a multi-robot
cell) puts ``GETP`` and ``TGT`` in the world frame, while the joints, the kinematics and
the cell stay in the robot base.
Time: every move takes simulated time on the cell's timeline
(:class:`~spherecal.sim.timeline.MotionTimeline`; without a cell, the controller's own):
a trapezoid over the move from its speed and ``acceleration_mm_s2``, then ``settle_s``
at the fine point, after which the ``MOVL`` is answered and the clock stands at the
move's end. Nothing waits in real time unless ``motion_time_scale`` asks for it. The
pose noise of ``GETP`` comes from the controller's own random stream
(``cell.standstill_rng("controller")``), never from the sensor's.
Safety, as a controller: a speed above ``max_controller_speed_mm_s`` or a target out of
reach or beyond a joint limit is refused with an ``ERR`` and nothing moves; nothing moves
but on a ``MOVL``.
"""

from __future__ import annotations

import os
import select
import socket
import threading
import time
from dataclasses import dataclass
from typing import TYPE_CHECKING, Literal

import numpy as np

from spherecal.core import geometry as geo
from spherecal.devices import line_protocol as P
from spherecal.core.errors import DeviceError, InputError
from spherecal.core.kinematics import declared_home_joints_deg
from spherecal.core.models import Pose
from spherecal.sim.settings import SimulatedControllerSettings
from spherecal.sim.timeline import MotionTimeline, SimClock

if TYPE_CHECKING:  # pragma: no cover
    from spherecal.sim.cell import SimulatedCell

_POLL_S = 0.02


def _f32(values) -> np.ndarray:
    return np.asarray(values, dtype=np.float32).astype(float)


class SimulatedController:
    """Controller logic: state (joints, staged target) and one reply per request."""

    def __init__(
        self,
        kinematics,
        settings: SimulatedControllerSettings | None = None,
        cell: "SimulatedCell | None" = None,
        n_joints: int = 6,
    ):
        self.kin = kinematics
        self.settings = settings or SimulatedControllerSettings()
        self.cell = cell
        self.n_joints = int(n_joints)
        self.rng = np.random.default_rng(self.settings.seed)
        home = self.settings.home_joints_deg
        standing = getattr(cell, "arm_start_joints_deg", None)
        # where the configuration says the arm stands (a jog simulated) wins; else where a
        # resumed run's journal left it; else the settings' default, the arm's declared
        # home, zero joints
        given = "home_joints_deg" in getattr(self.settings, "model_fields_set", ())
        if standing is not None and not given:
            home = standing
        elif home is None:
            declared = declared_home_joints_deg(kinematics) if hasattr(kinematics, "chain") else None
            home = np.zeros(self.n_joints) if declared is None else declared
        home = np.asarray(home, dtype=float)
        if home.shape != (self.n_joints,):
            raise InputError(f"simulated.home_joints_deg: expected {self.n_joints} joint values, got {home.size}")
        self.joints_deg = self.kin.check_joint_limits(home, "home_joints_deg")
        self.staged: tuple[int, Pose] | None = None
        self.moves = 0
        self.last_move: dict | None = None  # the last MOVL executed: distance, angle, speeds, duration
        self.requests: list[str] = []  # kinds of the requests served, in order
        self._wait = time.sleep
        # The controller reports the same pose for as long as the robot stands still: the
        # pose noise is the robot's positioning error, drawn once per move, not per read.
        self._reported: Pose | None = None
        self._reported_joints: np.ndarray | None = None
        # The arm's true geometry: the cell's (with its geometric error) when it has one.
        self.arm = None
        if cell is not None:
            self.arm = cell.arm if cell.arm is not None else (
                cell.attach_arm(self.kin) if cell.robot_error is not None else None)
            cell.move_flange_to(self.true_flange_pose())
        #: The arm's motion over simulated time: the cell's, or the controller's own.
        self.timeline = cell.timeline if cell is not None else MotionTimeline(clock=SimClock())
        self.timeline.arm = self.arm if self.arm is not None else _exact_arm(self.kin)
        self.timeline.acceleration_mm_s2 = self.settings.acceleration_mm_s2
        self.timeline.settle_s = self.settings.settle_s
        self.timeline.jump(self.nominal_flange_pose(), self.joints_deg)

    @property
    def clock(self) -> SimClock:
        """The simulated world's clock (the cell's, or the controller's own)."""
        return self.timeline.clock

    def true_flange_pose(self) -> Pose:
        """``base_from_flange`` where the simulated robot really is: its true geometry
        (with the cell's robot error) at its joints."""
        if self.arm is not None:
            return self.arm.true_flange_pose(self.joints_deg)
        return self.nominal_flange_pose()

    def nominal_flange_pose(self) -> Pose:
        """What the controller computes at its joints: the nominal model's pose."""
        return self.kin.flange_pose_from_joints(self.joints_deg, check_limits=False)

    _reached: int | None = None  #: seq of the staged target once it has been moved to
    #: the link session: 1 on a serial line; on a socket server, one more with every
    #: accepted connection
    session: int = 1
    _staged_session: int | None = None  #: the session the staged target was staged in

    def new_session(self) -> None:
        """The socket server accepted a new connection: a new session, in which a target
        staged over an earlier connection is not moved to (``ERR 4``)."""
        self.session += 1

    def handle(self, line: bytes) -> bytes:
        """The reply to one request line (both with their LF)."""
        return self._serve(line)

    def jog(self, joints_deg) -> None:
        """The operator jogs the arm to ``joints_deg`` (controller convention): a new
        standstill, so the next reading draws a new position error. No request is
        served and the staged target stays."""
        self.joints_deg = self.kin.check_joint_limits(joints_deg, "jog: joints_deg")
        self._reported = self._reported_joints = None
        self.timeline.jump(self.nominal_flange_pose(), self.joints_deg)
        if self.cell is not None:
            self.cell.move_flange_to(self.true_flange_pose())

    def _target_reached(self, target_seq: int) -> bool:
        """Has the target staged under ``target_seq`` been moved to already?"""
        return self._reached == target_seq

    # replies -------------------------------------------------------------------------
    def _serve(self, line: bytes) -> bytes:
        """The reply line to one request line (both with their LF)."""
        try:
            msg = P.decode_request(line)
        except P.ChecksumError:
            return P.error_reply(None, P.ErrorCode.CHECKSUM, "bad checksum")
        except P.ProtocolError as exc:
            return P.error_reply(None, P.ErrorCode.SYNTAX, str(exc))
        self.requests.append(msg.kind)
        try:
            return self._dispatch(msg)
        except P.ProtocolError as exc:
            return P.error_reply(msg.seq, P.ErrorCode.SYNTAX, str(exc))
        except Exception as exc:  # noqa: BLE001 - a controller answers, it does not die
            return P.error_reply(msg.seq, P.ErrorCode.MOTION, f"{type(exc).__name__}: {exc}")

    def _dispatch(self, msg: P.Message) -> bytes:
        s = self.settings
        if msg.kind == "PING":
            return P.pong_reply(msg.seq, P.ping_token(msg))
        if msg.kind == "GETJ":
            if self._reported_joints is None:
                noise = self.rng.normal(0, s.joint_noise_deg, self.n_joints) if s.joint_noise_deg > 0 else 0.0
                self._reported_joints = self.joints_deg + noise
            q = self._reported_joints
            return P.joints_reply(msg.seq, _f32(q) if s.single_precision else q, self.n_joints)
        if msg.kind == "GETP":
            if self._reported is None:
                self._reported = self._reported_pose()
            pose = self._reported
            if s.single_precision:
                t, q = _f32(pose.translation_mm), _f32(pose.quaternion_wxyz)
                pose = Pose.from_xyz_quat_wxyz(t, q / np.linalg.norm(q))
            return P.pose_reply(msg.seq, pose)
        if msg.kind == "TGT":
            target = P.parse_target_request(msg)
            if s.base_frame is not None:  # taken in the world frame; kept in base, where the joints are solved
                target = s.base_frame.inverse() @ target
            self.staged = (msg.seq, target)
            self._staged_session = self.session
            self._reached = None
            return P.ok_reply(msg.seq)
        if msg.kind == "MOVL":
            return self._move(msg)
        raise P.ProtocolError(f"unhandled request {msg.kind}")  # pragma: no cover

    def _reported_pose(self) -> Pose:
        """What ``GETP`` reports: the model's pose of the actual joints through the pose
        noise, in the world frame when a base frame is configured."""
        pose = self._pose_with_noise()
        base = self.settings.base_frame
        return pose if base is None else base @ pose

    def _pose_with_noise(self) -> Pose:
        true = self.nominal_flange_pose()  # a controller reports its model's pose of the actual joints
        s = self.settings
        if s.pose_noise == "cell":
            return self.cell.report_pose(true, self.cell.standstill_rng("controller")) if self.cell is not None else true
        R, t = true.rotation_matrix, true.translation
        if s.pose_rotation_noise_deg > 0:
            R = geo.matrix_from_rotvec(self.rng.normal(0, np.radians(s.pose_rotation_noise_deg), 3)) @ R
        if s.pose_translation_noise_mm > 0:
            t = t + self.rng.normal(0, s.pose_translation_noise_mm, 3)
        return Pose.from_rt(R, t)

    def _move(self, msg: P.Message) -> bytes:
        speed, target_seq = P.parse_movl_request(msg)
        v_ori = P.movl_orientation_speed(msg)
        if not 0 < speed <= self.settings.max_controller_speed_mm_s:
            return P.error_reply(
                msg.seq, P.ErrorCode.RANGE, f"speed {speed} outside 0..{self.settings.max_controller_speed_mm_s}"
            )
        if not 0 < v_ori <= P.MAX_ORIENTATION_SPEED_DEG_S:
            return P.error_reply(msg.seq, P.ErrorCode.RANGE,
                                 f"orientation speed {v_ori} outside 0..{P.MAX_ORIENTATION_SPEED_DEG_S:g}")
        if self.staged is None or self.staged[0] != target_seq:
            have = "none" if self.staged is None else self.staged[0]
            return P.error_reply(msg.seq, P.ErrorCode.NO_TARGET, f"no target {target_seq} staged (have {have})")
        if self._staged_session != self.session:
            return P.error_reply(msg.seq, P.ErrorCode.NO_TARGET,
                                 f"target {target_seq} was staged over an earlier connection")
        if self._target_reached(target_seq):
            # moved there already (a MOVL resent after a lost reply, or left in the buffer):
            # never move to the same target twice, the arm may have been jogged since
            return P.ok_reply(msg.seq)
        target = self.staged[1]
        try:
            joints = self.kin.joints_from_flange_pose(target, seed_joints_deg=self.joints_deg)
        except InputError:  # the kinematics' "out of reach" (UnreachableError and kin)
            return P.error_reply(msg.seq, P.ErrorCode.UNREACHABLE, "target out of reach or beyond a joint limit")
        start = self.true_flange_pose()
        distance = float(np.linalg.norm(target.translation - start.translation))
        angle = float(np.degrees(np.linalg.norm(geo.rotvec_from_matrix(start.rotation_matrix.T @ target.rotation_matrix))))
        duration = max(distance / speed, angle / v_ori)  # as speeddata's v_tcp and v_ori limit a MoveL
        timing = self.timeline.move_linear(target, speed, v_ori, joints_deg=joints)
        self.last_move = {"distance_mm": distance, "angle_deg": angle, "speed_mm_s": speed,
                          "orientation_speed_deg_s": v_ori, "duration_s": duration,
                          "start_s": timing.start_s, "motion_s": timing.motion_s, "settle_s": timing.settle_s}
        if self.settings.motion_time_scale > 0:
            self._wait(self.settings.motion_time_scale * duration)
        self.joints_deg = joints
        self._reported = self._reported_joints = None  # a new standstill: new position error
        self.moves += 1
        self._reached = target_seq
        if self.cell is not None:
            self.cell.move_flange_to(self.true_flange_pose())
        return P.ok_reply(msg.seq)


def _exact_arm(kinematics):
    """An arm exactly its nominal model, for the timeline's joints when the cell's arm has
    no geometric error (None for kinematics that describe no serial chain)."""
    if getattr(kinematics, "chain", None) is None:
        return None
    from spherecal.config import RobotErrorModel
    from spherecal.sim.robot_error import SimulatedArm

    none = RobotErrorModel(joint_zero_offset_deg=(0, 0), link_length_mm=(0, 0), link_offset_mm=(0, 0),
                           axis_tilt_deg=(0, 0))
    return SimulatedArm(kinematics, none, 0)


@dataclass
class Faults:
    """Faults to inject, changeable while the server runs. Counters apply to the next
    N requests or replies and count down."""

    reply_delay_s: float = 0.0  #: wait this long before every reply
    late_replies: int = 0  #: delay the next N replies by late_reply_delay_s (on top)
    late_reply_delay_s: float = 0.0  #: extra delay of a late reply, s
    drop_requests: int = 0  #: ignore the next N requests (no reply)
    corrupt_requests: int = 0  #: flip one byte in the next N requests as they arrive
    drop_replies: int = 0  #: serve but do not send the next N replies
    truncate_replies: int = 0  #: send only the first half of the next N replies (no LF)
    corrupt_replies: int = 0  #: flip one byte in the next N replies
    only_kinds: tuple[str, ...] = ()  #: if set, the counters above apply only to these request kinds
    #: before the next request is read, N reads end without a line (a read timeout), as
    #: after N quiet spells, for controllers that model it (``read_timeout()``); not
    #: limited by only_kinds
    read_timeouts: int = 0
    #: serve the next N requests, then close the connection instead of replying: the
    #: controller drops the link mid-request (a move is made, its reply never sent)
    close_before_reply: int = 0


class ControllerServer:
    """Runs a :class:`SimulatedController` in a thread behind a transport.

    ``url`` is the robot's port (``socket://127.0.0.1:PORT``, or a pty's device path).
    Use as a context manager or call :meth:`stop`; stopping closes every socket and file
    descriptor and joins the thread. A simulated device of another protocol is served by
    :class:`~spherecal.sim.device_server.SimulatedDeviceServer`; this one keeps a stream
    loop of its own because it also serves a pseudo-terminal and injects the line
    protocol's faults between a request's bytes and its reply."""

    def __init__(self, controller: SimulatedController, transport: Literal["tcp", "pty", "socket"] = "tcp"):
        if transport not in ("tcp", "pty", "socket"):
            raise ValueError(f"transport must be 'tcp', 'pty' or 'socket', got {transport!r}")
        self.controller = controller
        self.transport = transport
        self.faults = Faults()
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._disconnect = threading.Event()
        self._disconnected = threading.Event()
        self._thread: threading.Thread | None = None
        self._listener: socket.socket | None = None
        self._conn: socket.socket | None = None
        self._master: int | None = None
        self._slave: int | None = None
        self.url = ""
        self.error: BaseException | None = None
        self.connections = 0  #: connections accepted (tcp and socket)

    # lifecycle -----------------------------------------------------------------------
    def start(self) -> "ControllerServer":
        if self.transport in ("tcp", "socket"):
            self._listener = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
            self._listener.bind(("127.0.0.1", 0))
            self._listener.listen(1)
            self.url = f"socket://127.0.0.1:{self._listener.getsockname()[1]}"
            target = self._serve_tcp
        else:
            import tty

            self._master, self._slave = os.openpty()
            tty.setraw(self._slave)
            self.url = os.ttyname(self._slave)
            target = self._serve_pty
        self._thread = threading.Thread(target=self._run, args=(target,), name="spherecal-sim-controller", daemon=True)
        self._thread.start()
        return self

    def stop(self) -> None:
        """Stop serving and release everything. Safe to call twice."""
        self._stop.set()
        if self._thread is not None and self._thread is not threading.current_thread():
            self._thread.join(timeout=5)
            if self._thread.is_alive():  # pragma: no cover
                raise DeviceError("simulated controller thread did not stop within 5 s")
        self._close_all()

    def disconnect(self, timeout_s: float = 2.0) -> None:
        """Drop the connection now (the driver sees the link go away); returns once the
        link is closed. A TCP server then accepts a new connection (on the socket server, a
        new session); a pty is gone."""
        self._disconnected.clear()
        self._disconnect.set()
        if self.running and not self._disconnected.wait(timeout_s):  # pragma: no cover
            raise DeviceError(f"simulated controller did not drop its link within {timeout_s} s")

    @property
    def running(self) -> bool:
        return self._thread is not None and self._thread.is_alive()

    def __enter__(self) -> "ControllerServer":
        return self.start() if self._thread is None else self

    def __exit__(self, *exc) -> None:
        self.stop()

    def _close_all(self) -> None:
        for attr in ("_conn", "_listener"):
            sock = getattr(self, attr)
            if sock is not None:
                sock.close()
                setattr(self, attr, None)
        for attr in ("_master", "_slave"):
            fd = getattr(self, attr)
            if fd is not None:
                try:
                    os.close(fd)
                except OSError:  # pragma: no cover
                    pass
                setattr(self, attr, None)

    def _run(self, target) -> None:
        try:
            target()
        except BaseException as exc:  # pragma: no cover - surfaced through .error
            self.error = exc

    # transports ----------------------------------------------------------------------
    def _serve_tcp(self) -> None:
        while not self._stop.is_set():
            ready, _, _ = select.select([self._listener], [], [], _POLL_S)
            if not ready:
                continue
            conn, _ = self._listener.accept()
            self._conn = conn
            self.connections += 1
            if self.transport == "socket":  # a socket server: a new connection, a new session
                self.controller.new_session()
            self._disconnect.clear()
            self._serve_stream(lambda n: conn.recv(n), conn.sendall, conn.fileno())
            if self._conn is not None:
                self._conn.close()
                self._conn = None
            if self._disconnect.is_set():
                self._disconnect.clear()
                self._disconnected.set()

    def _serve_pty(self) -> None:
        master = self._master

        def send(data: bytes) -> None:
            while data:
                n = os.write(master, data)
                data = data[n:]

        self._serve_stream(lambda n: os.read(master, n), send, master)
        if self._disconnect.is_set() and self._master is not None:
            os.close(self._master)  # the slave side now reads EOF/EIO
            self._master = None
            self._disconnected.set()
            self._stop.wait()

    def _serve_stream(self, recv, send, fileno: int) -> None:
        buffer = bytearray()
        while not self._stop.is_set() and not self._disconnect.is_set():
            ready, _, _ = select.select([fileno], [], [], _POLL_S)
            if not ready or self._disconnect.is_set():
                continue
            try:
                chunk = recv(4096)
            except OSError:
                return
            if not chunk:
                return  # the driver closed the link
            buffer.extend(chunk)
            while b"\n" in buffer:
                idx = buffer.index(b"\n")
                line = bytes(buffer[: idx + 1])
                del buffer[: idx + 1]
                try:
                    self._serve_line(line, send)
                except OSError:  # the robot has gone while the reply was on its way
                    return
                if self._disconnect.is_set() or self._stop.is_set():
                    return
            if len(buffer) > 2 * P.MAX_LINE_CHARS:  # garbage without LF: answer and resync
                buffer.clear()
                send(P.error_reply(None, P.ErrorCode.SYNTAX, "line too long"))

    def _take(self, name: str, kind: str) -> bool:
        with self._lock:
            if self.faults.only_kinds and kind not in self.faults.only_kinds:
                return False
            n = getattr(self.faults, name)
            if n > 0:
                setattr(self.faults, name, n - 1)
                return True
            return False

    def send_unsolicited(self, data: bytes) -> None:
        """Send ``data`` now, unasked (a stale reply left from an earlier session). On a
        pty it waits in the device's input queue even before the driver opens it."""
        if self._master is not None:
            os.write(self._master, data)
        elif self._conn is not None:
            self._conn.sendall(data)
        else:
            raise DeviceError("simulated controller: no link to send on yet")

    def _serve_line(self, line: bytes, send) -> None:
        with self._lock:
            timeouts, self.faults.read_timeouts = self.faults.read_timeouts, 0
        read_timeout = getattr(self.controller, "read_timeout", None)
        for _ in range(timeouts if read_timeout is not None else 0):
            sent = read_timeout()
            if sent is not None:  # only a model of an old server sends anything here
                send(sent)
        kind = line.split(b" ", 1)[0].decode("ascii", "replace")
        if self._take("drop_requests", kind):
            return
        if self._take("corrupt_requests", kind):
            line = _flip_byte(line)
        reply = self.controller.handle(line)
        if self._take("close_before_reply", kind):
            self._disconnect.set()  # the stream loop returns, and the link is closed
            return
        delay = self.faults.reply_delay_s
        if self._take("late_replies", kind):
            delay += self.faults.late_reply_delay_s
        if delay > 0 and self._stop.wait(delay):
            return
        if self._take("drop_replies", kind):
            return
        if self._take("truncate_replies", kind):
            reply = reply[: len(reply) // 2]
        elif self._take("corrupt_replies", kind):
            reply = _flip_byte(reply)
        send(reply)


def _flip_byte(line: bytes) -> bytes:
    """The line with its third byte replaced (inside the body, never the LF)."""
    data = bytearray(line)
    i = min(2, len(data) - 2)
    data[i] = ord("#") if data[i] != ord("#") else ord("%")
    return bytes(data)


def start_controller(
    kinematics,
    settings: SimulatedControllerSettings | None = None,
    cell: "SimulatedCell | None" = None,
    n_joints: int = 6,
) -> ControllerServer:
    """Start a simulated controller on the settings' transport; returns the running
    server (its ``url`` is the robot's port)."""
    settings = settings or SimulatedControllerSettings()
    controller = SimulatedController(kinematics, settings, cell, n_joints)
    return ControllerServer(controller, settings.transport).start()
