"""A robot behind the spherecal line protocol (:mod:`spherecal.devices.line_protocol`), PC side, brand-free.

:class:`LineRobot` implements :class:`spherecal.devices.contract.Robot` over one of two links,
chosen by the port: a serial line, opened with ``serial.serial_for_url`` (a device such as
``/dev/ttyS0`` or ``COM1``, a pseudo-terminal, or another pyserial URL such as
``rfc2217://``), or a TCP connection when the port is ``socket://host:port``
(:class:`TcpLink`: to a controller's socket server, or to a serial device server). A
robot plugin gives it its configuration (the link and limit settings named below) and
its arm's kinematics, and may override :meth:`LineRobot.controller_pose` and
:meth:`LineRobot.pose_from_joints_only` (a calibrated model applied on the PC side does).

The link. Every exchange is one request and one reply carrying the same sequence
number. Replies whose seq does not match the request (late replies of an earlier
attempt) are discarded; a corrupted line (checksum or syntax) or a timeout makes the
robot resend the request with a fresh seq, up to ``retries`` times, then raise
:class:`~spherecal.core.errors.DeviceError` saying what went wrong; this is the same code on
both links. A lost link raises DeviceError at once (over TCP: the controller closed the
connection, or it broke), and the robot never reconnects by itself: it must be created
again, which opens a new connection (on a socket server, a new session in which no
target is staged; docs/line-protocol.md). Requests are idempotent (a MOVL names its
staged target, and the controller moves to a target once), so a resend never makes the
robot move twice. On open the link discards whatever waits on it, and the first exchange
opens the session: ``PING`` carries a token drawn at random for this connection, and
until a ``PONG`` echoes it under the PING's seq every line that comes is discarded as
stale. The server answers one line after another, so a reply of an earlier session still
on its way (a late reply after the PC program was killed, on a serial line) comes before
that PONG and is never taken for a reply of this session, whatever seq it carries. No
request but PING is sent before the session is open.

Safety. Speed, workspace box (the target and the start, where the arm stands: both ends
in a box, the whole straight path is) and reachability (the target, and
``path_check_samples`` points along the straight line to it, through the kinematics'
inverse, within the joint limits, from the joints read now) are checked before anything
is sent (:meth:`LineRobot.check_move` runs the same checks without moving); a move's flange and reorientation speeds
keep the tool point (the sensor or the sphere the flange carries) within the move's
speed.

The configuration is a plugin's model derived from :class:`LineLinkSettings`; its
``workspace`` must be set by the time the robot moves (:class:`LineRobot` takes a
``workspace`` argument when the plugin derives it). The kinematics must have ``flange_pose_from_joints(joints_deg,
check_limits)`` and ``joints_from_flange_pose(pose, seed_joints_deg)``, raising an
:class:`~spherecal.core.errors.InputError` when a pose is out of reach.
"""

from __future__ import annotations

import math
import secrets
import select
import socket
import time
from dataclasses import dataclass
from typing import Callable, Literal

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, field_validator, model_validator

from spherecal.config import Vec3
from spherecal.devices import line_protocol as P
from spherecal.core.errors import DeviceError, InputError
from spherecal.core.geometry import matrix_from_rotvec as _matrix_from_rotvec
from spherecal.core.geometry import rotvec_from_matrix as _rotvec
from spherecal.core.models import Pose

#: Longest single blocking read, s (the overall deadline is checked between reads).
_POLL_S = 0.05
#: Shortest bound on one write, s. A write that did go out is reported as timed out when
#: the process was not scheduled within the bound (pyserial checks the clock after the
#: write), and the link is then closed as lost: under load, a reply timeout of a fraction
#: of a second must not make that happen to a line that was sent.
_MIN_WRITE_TIMEOUT_S = 2.0
#: Bytes kept while waiting for an LF before the buffer is treated as garbage.
_MAX_PENDING = 4 * P.MAX_LINE_CHARS
#: Slowest speed sent (mm/s for the flange, deg/s for the reorientation): the line
#: carries one decimal, and a move that does not translate (or turn) still names one.
MIN_SPEED_MM_S = 0.1


#: The scheme of a TCP port: ``socket://host:port``.
SOCKET_SCHEME = "socket://"


def parse_socket_url(url: str) -> tuple[str, int]:
    """(host, port) of ``socket://host:port``; ValueError saying what is wrong."""
    if not url.lower().startswith(SOCKET_SCHEME):
        raise ValueError(f"{url!r} is not a socket://host:port address")
    rest = url[len(SOCKET_SCHEME):]
    host, sep, port = rest.rpartition(":")
    host = host[1:-1] if host.startswith("[") and host.endswith("]") else host  # [::1]
    if not sep or not host or any(c in rest for c in "/?#@ "):
        raise ValueError(f"{url!r}: write a TCP port as socket://host:port (for example socket://192.168.0.10:5000)")
    if not port.isdigit() or not 1 <= int(port) <= 65535:
        raise ValueError(f"{url!r}: the TCP port {port!r} must be a number 1..65535")
    return host, int(port)


def link_transport(port: str) -> Literal["serial", "socket"]:
    """``socket`` when ``port`` is ``socket://host:port`` (TCP, :class:`TcpLink`), else
    ``serial`` (pyserial)."""
    return "socket" if port.lower().startswith(SOCKET_SCHEME) else "serial"


class ControllerClosedError(ConnectionError):
    """The controller closed the connection (its server program was stopped or reset, it
    restarted, or it dropped the connection after an error)."""


class TcpLink:
    """A connected TCP socket to ``url`` (``socket://host:port``): the robot's link to a
    controller's socket server (or to a serial device server).

    It offers the part of pyserial's ``Serial`` interface :class:`LineRobot` uses
    (``read``, ``in_waiting``, ``write``, ``flush``, ``reset_input_buffer``, ``close``), so
    that framing, timeouts, resends and stale replies are one code for both links. Over
    pyserial's own ``socket://`` handler it adds what a link to a controller needs: the
    connection attempt waits at most ``connect_timeout``, small lines go out at once
    (``TCP_NODELAY``), a connection the controller closed reads as an error saying so
    (never as silence), and closing does not sleep.

    ``timeout`` bounds one :meth:`read` (s); ``write_timeout`` one :meth:`write`;
    ``connect_timeout`` the connection attempt. Errors are OSError (ConnectionError for a
    closed or refused connection, TimeoutError for a write that did not go out)."""

    def __init__(self, url: str, *, timeout: float, write_timeout: float, connect_timeout: float):
        host, port = parse_socket_url(url)
        self.url = url
        self.timeout = timeout
        self._sock: socket.socket | None = socket.create_connection((host, port), timeout=connect_timeout)
        self._sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        self._sock.setsockopt(socket.SOL_SOCKET, socket.SO_KEEPALIVE, 1)
        self._sock.settimeout(write_timeout)

    @property
    def is_open(self) -> bool:
        return self._sock is not None

    def _connected(self) -> socket.socket:
        if self._sock is None:
            raise ConnectionError(f"{self.url}: the connection is closed")
        return self._sock

    def _recv(self, n: int) -> bytes:
        data = self._connected().recv(n)
        if not data:
            raise ControllerClosedError(f"{self.url}: the controller closed the connection")
        return data

    def read(self, size: int = 1) -> bytes:
        """Up to ``size`` bytes: what has arrived, waiting at most :attr:`timeout` for the
        first; b"" when nothing came."""
        ready, _, _ = select.select([self._connected()], [], [], self.timeout)
        return self._recv(size) if ready else b""

    @property
    def in_waiting(self) -> int:
        """A positive number when bytes wait to be read (not their count), else 0."""
        ready, _, _ = select.select([self._connected()], [], [], 0)
        return 4096 if ready else 0

    def write(self, data: bytes) -> int:
        self._connected().sendall(data)
        return len(data)

    def flush(self) -> None:
        """Nothing to do: :meth:`write` returns once the data is handed to the network."""

    def reset_input_buffer(self) -> None:
        """Discard every byte that has arrived and not been read."""
        while self.in_waiting:
            self._recv(4096)

    def close(self) -> None:
        """Close the connection (the controller sees it end). Idempotent."""
        sock, self._sock = self._sock, None
        if sock is None:
            return
        try:
            sock.shutdown(socket.SHUT_RDWR)
        except OSError:  # the controller has gone already
            pass
        sock.close()


class WorkspaceBox(BaseModel):
    """Axis-aligned box in the base frame (mm) the flange origin must stay in. Moves
    whose target lies outside are refused before anything is sent."""

    model_config = ConfigDict(defer_build=True, frozen=True, extra="forbid")

    min_mm: Vec3 = Field(description="lower corner (x, y, z) in base, mm")
    max_mm: Vec3 = Field(description="upper corner (x, y, z) in base, mm")

    @model_validator(mode="after")
    def _check(self):
        for axis, lo, hi in zip("xyz", self.min_mm, self.max_mm):
            if not lo < hi:
                raise ValueError(f"workspace: min_mm {axis} = {lo} must be below max_mm {axis} = {hi}")
        return self

    def contains(self, point_mm) -> bool:
        return all(lo <= p <= hi for p, lo, hi in zip(point_mm, self.min_mm, self.max_mm))


class LineLinkSettings(BaseModel):
    """The settings :class:`LineRobot` reads: the link (serial or TCP), the replies, the pose
    source and the motion limits. A robot plugin's configuration model derives from it
    (and gives ``workspace`` a default or a way to derive one). Lengths in mm, angles in
    degrees, times in seconds."""

    model_config = ConfigDict(defer_build=True, frozen=True, extra="forbid")

    port: str = Field(
        "/dev/ttyS0",
        description="the link to the controller: a serial device (/dev/ttyS0, /dev/ttyUSB0, COM1) or another "
        "pyserial URL (rfc2217://...), or socket://host:port for a TCP connection (the controller's socket "
        "server, or a serial device server); ignored in simulated runs",
    )
    baudrate: int = Field(9600, gt=0, le=10_000_000,
                          description="serial speed, baud; must match the controller's serial port setting "
                          "(not used over TCP)")
    parity: Literal["N", "E", "O"] = Field("N", description="serial parity: none, even, odd")
    stopbits: Literal[1, 2] = Field(1, description="serial stop bits")
    timeout_s: float = Field(2.0, gt=0, le=600, description="time to wait for a reply (besides a move's duration), s")
    retries: int = Field(2, ge=0, le=100, description="resends after a timeout or a corrupted reply (0: none)")
    pose_source: Literal["controller", "joints"] = Field(
        "controller",
        description="flange pose from the controller (GETP) or from the joint readings (GETJ) through the "
        "plugin's forward kinematics",
    )
    max_speed_mm_s: float = Field(250.0, gt=0, le=7000, description="largest TCP speed a move may ask for, mm/s")
    move_timeout_extra_s: float = Field(
        5.0, ge=0, le=600, description="time allowed for a move beyond twice distance / speed (acceleration, settling), s"
    )
    orientation_speed_deg_s: float = Field(
        100.0, gt=0, le=P.MAX_ORIENTATION_SPEED_DEG_S,
        description="largest reorientation speed a move asks for, deg/s; each move asks for less when its sensor "
        "(the tool point) would otherwise exceed the move's speed"
    )
    path_check_samples: int = Field(
        10, ge=0, le=10_000, description="points checked for reachability along a linear move, besides its end"
    )
    workspace: WorkspaceBox | None = Field(None, description="allowed flange positions, base, mm")

    @field_validator("port", mode="after")
    @classmethod
    def _check_port(cls, v: str) -> str:
        if not v.strip():
            raise ValueError("port is empty: give a serial device (/dev/ttyS0, COM1) or socket://host:port")
        if link_transport(v) == "socket":
            parse_socket_url(v)
        return v

    @property
    def transport(self) -> Literal["serial", "socket"]:
        """``socket`` when :attr:`port` is ``socket://host:port`` (TCP), else ``serial``."""
        return link_transport(self.port)


def initial_seq() -> int:
    """A random sequence number to start a session from (the first request carries the
    next one)."""
    return secrets.randbelow(P.SEQ_MODULUS)


@dataclass(frozen=True)
class FrameOffset:
    """The controller's pose against a model's pose of the same joints
    (:meth:`LineRobot.controller_frame_offset`): their distance (mm) and angle (deg), the
    joints (deg, controller convention) and ``controller_from_model`` (the controller's
    pose times the inverse of the model's)."""

    offset_mm: float
    angle_deg: float
    joints_deg: np.ndarray
    controller_from_model: Pose

    def within(self, tolerance_mm: float, tolerance_deg: float) -> bool:
        return self.offset_mm <= tolerance_mm and self.angle_deg <= tolerance_deg

    def joints_text(self) -> str:
        return ", ".join(f"{v:.2f}" for v in self.joints_deg)

    def frame_text(self) -> str:
        """``translation [x, y, z] mm, quaternion (w, x, y, z) [...]`` (no "-0.0")."""
        t = ", ".join(f"{round(v, 1) + 0.0:.1f}" for v in self.controller_from_model.translation_mm)
        q = ", ".join(f"{round(v, 4) + 0.0:.4f}" for v in self.controller_from_model.quaternion_wxyz)
        return f"translation [{t}] mm, quaternion (w, x, y, z) [{q}]"


class LineRobot:
    """A connected robot speaking the spherecal line protocol (implements
    :class:`spherecal.devices.contract.Robot`).

    Poses are ``base_from_flange``, mm, quaternion (w, x, y, z). Joints are degrees in
    the controller convention. ``name`` names the robot in every message;
    ``server_hint`` says what to check when the controller does not answer, and
    ``socket_hint`` what to check when a ``socket://`` port cannot be opened."""

    #: The robot in messages ("IRB 2400", "urdf robot 'ur5'").
    name = "robot"
    #: What to check when no valid reply comes.
    server_hint = "that the controller's spherecal line server is running"
    #: What to check when a socket:// port cannot be opened.
    socket_hint = "that the controller's socket server listens on this address"

    def __init__(
        self,
        config,
        kinematics,
        *,
        url: str | None = None,
        on_close: Callable[[], None] | None = None,
        tool_point_mm=None,
        n_joints: int = 6,
        seq_start: int | None = None,
        workspace: WorkspaceBox | None = None,
    ):
        import serial

        self._serial_errors = (serial.SerialException, OSError)
        self.config = config
        self.kin = kinematics
        #: the box the flange must stay in (base frame, mm)
        self.workspace = workspace if workspace is not None else config.workspace
        if self.workspace is None:
            raise InputError(f"{self.name}: no workspace box configured (robot.workspace.min_mm / max_mm)")
        self.n_joints = int(n_joints)
        #: the point carried by the flange whose speed every move limits (flange frame, mm):
        #: the sensor (eye-in-hand) or the sphere (eye-to-hand); None: the flange itself
        self.tool_point_mm = None if tool_point_mm is None else np.asarray(tool_point_mm, dtype=float).reshape(3)
        self.url = url or config.port
        self._on_close = on_close
        self._seq = initial_seq() if seq_start is None else int(seq_start)
        #: this connection's session token (PING carries it, PONG echoes it)
        self.session_token = P.new_session_token()
        self._session_open = False  # no PONG with our token seen yet: every reply is stale
        self._buffer = bytearray()
        self._closed = False
        self.stale_replies = 0  #: replies discarded because their seq did not match
        self.resends = 0  #: requests sent again after a timeout or a corrupted line
        self.last_joints_deg: np.ndarray | None = None
        self._check_seed: np.ndarray | None = None  # joints of the last target checked
        #: "socket" (TCP, :class:`TcpLink`) or "serial" (pyserial), from the port
        self.transport = link_transport(self.url)
        try:
            if self.transport == "socket":
                self._serial = TcpLink(self.url, timeout=min(config.timeout_s, _POLL_S),
                                       write_timeout=max(config.timeout_s, _MIN_WRITE_TIMEOUT_S),
                                       connect_timeout=config.timeout_s)
            else:
                self._serial = serial.serial_for_url(
                    self.url,
                    baudrate=config.baudrate,
                    bytesize=serial.EIGHTBITS,
                    parity=config.parity,
                    stopbits=config.stopbits,
                    timeout=min(config.timeout_s, _POLL_S),
                    write_timeout=max(config.timeout_s, _MIN_WRITE_TIMEOUT_S),
                )
        except (serial.SerialException, OSError, ValueError) as exc:
            self._closed = True
            if on_close is not None:
                on_close()
            what = self.socket_hint if self.transport == "socket" else "that the device exists"
            raise DeviceError(f"{self.name}: cannot open {self.url!r} ({exc}); check robot.port and {what}") from exc
        # a reply of an earlier session may wait on the link: never take it for ours
        # (pyserial's own backends flush on open too; do not depend on it)
        try:
            self._serial.reset_input_buffer()
        except self._serial_errors as exc:
            self._lost(exc)

    # hooks ----------------------------------------------------------------------------
    def controller_pose(self, base_from_flange: Pose, target_joints_deg=None) -> Pose:
        """The pose to send the controller for the flange to reach ``base_from_flange``
        (``target_joints_deg``: the joints the path check solved for it). The pose itself
        here; a plugin that applies a calibrated model on the PC side overrides this."""
        return base_from_flange

    def pose_from_joints_only(self) -> bool:
        """Whether :meth:`read_flange_pose` must come from the joints, whatever
        ``pose_source`` says (a calibrated model applied on the PC side)."""
        return False

    def controller_frame_offset(self, kinematics) -> "FrameOffset":
        """How far the controller's pose (``GETP``) lies from ``kinematics``' pose of the
        joints it reports (``GETJ``), read now (:class:`FrameOffset`). A controller that
        reports poses in another frame than the robot base (a base frame: a riser, an
        inverted mount, a multi-robot cell; a user frame) shows it here, as does a model
        whose geometry or joint convention is not the arm's; nothing moves. A plugin
        refuses the connection beyond its tolerance (spherecal's workspace and path
        checks work in the base frame), each in its controller's words."""
        joints = self.read_joints_deg()
        reported = P.parse_pose_reply(self._exchange("GETP", P.getp_request, "P"))
        model = kinematics.flange_pose_from_joints(joints, check_limits=False)
        return FrameOffset(
            float(np.linalg.norm(reported.translation - model.translation)),
            float(np.degrees(np.linalg.norm(_rotvec(model.rotation_matrix.T @ reported.rotation_matrix)))),
            joints, reported @ model.inverse())

    # Robot protocol ----------------------------------------------------------------
    def read_joints_deg(self) -> np.ndarray:
        """Joints in degrees, controller convention."""
        msg = self._exchange("GETJ", P.getj_request, "J")
        joints = P.parse_joints_reply(msg)
        self.last_joints_deg = joints
        return joints

    def read_flange_pose(self) -> Pose:
        """``base_from_flange`` now: from the controller (GETP) or from the joints (GETJ)
        through the kinematics, as ``pose_source`` says."""
        if self.config.pose_source == "joints" or self.pose_from_joints_only():
            return self.kin.flange_pose_from_joints(self.read_joints_deg(), check_limits=False)
        return P.parse_pose_reply(self._exchange("GETP", P.getp_request, "P"))

    def move_linear(self, base_from_flange: Pose, speed_mm_s: float) -> None:
        """Move the flange in a straight line to ``base_from_flange`` at ``speed_mm_s`` and
        return once in position. Limits are checked first; nothing is sent if one fails."""
        start, target_joints = self._check_move_from_here(base_from_flange, speed_mm_s)
        command = self.controller_pose(base_from_flange, target_joints)
        target_seq_holder: list[int] = []

        def tgt(seq: int) -> bytes:
            target_seq_holder.append(seq)
            return P.target_request(seq, command)

        self._exchange("TGT", tgt, "OK")
        target_seq = target_seq_holder[-1]
        v_tcp, v_ori, duration = self.move_speeds(start, base_from_flange, speed_mm_s)
        timeout = self.config.timeout_s + 2.0 * duration + self.config.move_timeout_extra_s
        self._exchange("MOVL", lambda seq: P.movl_request(seq, v_tcp, target_seq, v_ori), "OK", timeout)

    def move_speeds(self, start: Pose, target: Pose, speed_mm_s: float) -> tuple[float, float, float]:
        """(flange speed mm/s, reorientation speed deg/s, duration s) of a linear move that
        keeps the tool point (:attr:`tool_point_mm`; the flange without one) within
        ``speed_mm_s`` and the reorientation within ``orientation_speed_deg_s``.

        The controller interpolates position and orientation together: over a move of
        duration T the flange moves d at d/T and turns by theta at theta/T, so a point r
        off the flange moves at most (d + theta r)/T. T is the least that keeps that
        within ``speed_mm_s``; v_tcp = d/T and v_ori = theta/T make the controller take
        exactly T. Checked here, before anything is sent."""
        distance = float(np.linalg.norm(target.translation - start.translation))
        angle_deg = float(np.degrees(np.linalg.norm(_rotvec(start.rotation_matrix.T @ target.rotation_matrix))))
        r = float(np.linalg.norm(self.tool_point_mm)) if self.tool_point_mm is not None else 0.0
        duration = max((distance + np.radians(angle_deg) * r) / speed_mm_s,
                       angle_deg / self.config.orientation_speed_deg_s, 1e-6)
        # rounded down to the decimal the line carries: the controller then takes at least T
        step = 10.0**-P.SPEED_DECIMALS
        v_tcp = max(math.floor(min(distance / duration, speed_mm_s) / step + 1e-9) * step, MIN_SPEED_MM_S)
        v_ori = max(math.floor(min(angle_deg / duration, self.config.orientation_speed_deg_s) / step + 1e-9) * step,
                    MIN_SPEED_MM_S)
        duration = max(distance / v_tcp, angle_deg / v_ori)  # what the controller will take
        peak = (distance + np.radians(angle_deg) * r) / duration
        if peak > speed_mm_s * (1 + 1e-9) + MIN_SPEED_MM_S:  # pragma: no cover - by construction
            raise InputError(f"move_linear: the tool point would move at {peak:.1f} mm/s, above {speed_mm_s} mm/s")
        return v_tcp, v_ori, duration

    def close(self) -> None:
        """Close the link (and stop the simulated controller, if any). Idempotent."""
        if self._closed:
            return
        self._closed = True
        # pyserial's network URLs (rfc2217://) skip closing their socket when shutdown()
        # fails on a link the peer already dropped; close it ourselves (closing twice is
        # harmless; a TcpLink has no _socket and closes its own)
        sock = getattr(self._serial, "_socket", None)
        try:
            self._serial.close()
        finally:
            if sock is not None:
                sock.close()
            if self._on_close is not None:
                self._on_close()

    def __enter__(self):
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def ping(self) -> int:
        """Open the session (or check it): ``PING`` with this connection's token; returns
        the server's protocol version. Every reply before the PONG that echoes the token
        under the PING's seq is discarded as stale (:attr:`stale_replies`)."""
        token = self.session_token
        msg = self._exchange("PING", lambda seq: P.ping_request(seq, token), "PONG", session=token)
        version, _ = P.parse_pong_reply(msg)
        self._session_open = True
        if version != P.PROTOCOL_VERSION:
            raise DeviceError(
                f"{self.url}: the controller's server speaks protocol version {version}, this driver "
                f"version {P.PROTOCOL_VERSION}; {self.version_hint}"
            )
        return version

    #: What to do when the server speaks another protocol version.
    version_hint = "update the controller's server to this version (docs/line-protocol.md)"

    # limits ------------------------------------------------------------------------
    def check_target(self, base_from_flange: Pose, speed_mm_s: float) -> None:
        """Check a planned target against every limit without sending anything: speed,
        workspace box, and reachability within the joint limits. The inverse kinematics
        is seeded as the moves will be: the first check from the arm's joints now (read
        with GETJ, which moves nothing), each next one from the joints the previous check
        found. Raises what :meth:`move_linear` would."""
        self._check_speed(speed_mm_s)
        self._check_workspace(base_from_flange, "target")
        seed = self._check_seed
        if seed is None:
            seed = self.last_joints_deg if self.last_joints_deg is not None else self.read_joints_deg()
        try:
            self._check_seed = self.kin.joints_from_flange_pose(base_from_flange, seed_joints_deg=seed)
        except InputError as exc:
            raise type(exc)(f"target: {exc}") from None

    def check_move(self, base_from_flange: Pose, speed_mm_s: float) -> None:
        """Check the straight move from where the arm stands now to ``base_from_flange``
        without moving, exactly as :meth:`move_linear` checks it before sending it: the
        speed, both ends in the workspace box (so the whole straight path: a box is
        convex), and the target and ``path_check_samples`` points along the path
        reachable within the joint limits, from the joints read now (GETJ, which moves
        nothing). Raises what :meth:`move_linear` would."""
        self._check_move_from_here(base_from_flange, speed_mm_s)

    def _check_move_from_here(self, target: Pose, speed_mm_s: float) -> tuple[Pose, np.ndarray]:
        """The checks of a move from the arm's current joints; returns (start pose,
        target joints)."""
        self._check_open()
        self._check_speed(speed_mm_s)
        self._check_workspace(target, "target")
        start_joints = self.read_joints_deg()
        start = self.kin.flange_pose_from_joints(start_joints, check_limits=False)
        self._check_workspace(start, "start", "; the straight path to the target would leave it: jog the arm into "
                                              "the box first")
        return start, self._check_path(start, target, start_joints)

    def _check_speed(self, speed_mm_s: float) -> None:
        limit = self.config.max_speed_mm_s
        try:
            speed = float(speed_mm_s)
        except (TypeError, ValueError):
            speed = math.nan
        if not (math.isfinite(speed) and speed > 0):
            raise InputError(f"move_linear: speed_mm_s must be a positive number, got {speed_mm_s!r}")
        if speed_mm_s > limit:
            raise InputError(
                f"move_linear: speed_mm_s = {speed_mm_s} exceeds the configured max_speed_mm_s = {limit}; "
                f"ask for a slower move or raise robot.max_speed_mm_s"
            )

    def _check_workspace(self, pose: Pose, what: str, hint: str = "") -> None:
        box = self.workspace
        if not box.contains(pose.translation_mm):
            t = [round(v, 3) for v in pose.translation_mm]
            raise InputError(
                f"move_linear: {what} flange position {t} mm is outside the configured workspace box "
                f"min_mm={list(box.min_mm)} max_mm={list(box.max_mm)} (base frame){hint}"
            )

    def _check_path(self, start: Pose, target: Pose, start_joints: np.ndarray) -> np.ndarray:
        """Check the target and points along the path for reachability; returns the
        target's joints (the solution nearest the start)."""
        n = self.config.path_check_samples
        seed = start_joints
        target_joints = None
        R0, R1 = start.rotation_matrix, target.rotation_matrix
        rv = _rotvec(R0.T @ R1)
        for s in [1.0, *(np.arange(1, n + 1) / (n + 1))]:  # the target first
            R = R0 @ _matrix_from_rotvec(s * rv)
            t = (1 - s) * start.translation + s * target.translation
            pose = Pose.from_rt(R, t)
            try:
                seed = self.kin.joints_from_flange_pose(pose, seed_joints_deg=seed)
            except InputError as exc:
                where = "target" if s == 1.0 else f"point {s:.0%} along the linear path"
                raise type(exc)(f"move_linear: {where}: {exc}") from None
            if target_joints is None:
                target_joints = seed
        return target_joints

    # transport ---------------------------------------------------------------------
    def _check_open(self) -> None:
        if self._closed:
            raise DeviceError(f"{self.name} on {self.url}: the connection is closed; create the robot again")

    def _next_seq(self) -> int:
        self._seq = (self._seq + 1) % P.SEQ_MODULUS
        return self._seq

    def _exchange(
        self, kind: str, build: Callable[[int], bytes], expect: str, timeout_s: float | None = None,
        session: str | None = None,
    ) -> P.Message:
        """Send a request built for a fresh seq and return its reply, resending after a
        timeout or a corrupted line; raises DeviceError when every attempt fails.

        ``session``: the token a PING carries; only a PONG echoing it under the seq is
        taken, any other reply is stale. Any other request opens the session first."""
        self._check_open()
        if session is None and not self._session_open:
            self.ping()
        timeout_s = self.config.timeout_s if timeout_s is None else timeout_s
        attempts = self.config.retries + 1
        problem = ""
        for attempt in range(attempts):
            if attempt:
                self.resends += 1
            seq = self._next_seq()
            self._write(build(seq))
            deadline = time.monotonic() + timeout_s
            if session is not None:
                msg, problem = self._await_pong(seq, session, deadline, timeout_s)
                if msg is not None:
                    return msg
                continue
            while True:
                raw = self._read_line(deadline)
                if raw is None:
                    problem = f"no reply within {timeout_s:.3g} s"
                    if self._buffer:  # the start of a reply that never ended: stale now
                        problem += f" (discarded a partial line {bytes(self._buffer)[:40]!r})"
                        self._buffer.clear()
                    break
                try:
                    msg = P.decode_reply(raw, self.n_joints)
                except P.ProtocolError as exc:  # corrupted, partial or garbage: resend
                    problem = str(exc)
                    break
                if msg.kind == "ERR":
                    code, text = P.parse_error_reply(msg)
                    if msg.seq is None or code == P.ErrorCode.CHECKSUM:
                        if msg.seq in (None, seq):  # the controller got a garbled request
                            problem = f"controller could not read the request: ERR {code} {text}"
                            break
                    if msg.seq != seq:
                        self.stale_replies += 1
                        continue
                    raise DeviceError(
                        f"{self.name} on {self.url}: controller refused {kind} (seq {seq}): "
                        f"ERR {code} {_error_name(code)}: {text}"
                    )
                if msg.seq != seq:
                    self.stale_replies += 1  # a late reply to an earlier attempt
                    continue
                if msg.kind != expect:
                    raise P.ProtocolError(
                        f"{self.name} on {self.url}: reply {msg.kind} to {kind} (seq {seq}); expected {expect}"
                    )
                return msg
        if self.transport == "socket":
            check = f"Check {self.server_hint} and serves no other connection (it serves one at a time)"
        else:
            check = (f"Check the cable, the serial settings (baudrate {self.config.baudrate}, "
                     f"parity {self.config.parity}) and {self.server_hint}")
        raise DeviceError(
            f"{self.name} on {self.url}: no valid reply to {kind} after {attempts} attempt(s); last problem: "
            f"{problem}. {check}"
        )

    def _await_pong(self, seq: int, token: str, deadline: float, timeout_s: float) -> tuple[P.Message | None, str]:
        """Read until the PONG that echoes ``token`` under ``seq`` (returned with ""), or
        the deadline (None and the problem). Before that PONG every line may be an
        earlier session's, whatever it says: an ERR (even under this seq), a garbled
        line, a PONG with another token are held, never acted on at once; only if no
        PONG comes by the deadline do they say what went wrong. An ERR under this seq is
        then the server's refusal of the PING, raised as such."""
        refusal = noted = ""
        held = 0  # lines held before the PONG: stale, if it comes
        while True:
            raw = self._read_line(deadline)
            if raw is None:
                break
            held += 1
            try:
                msg = P.decode_reply(raw, self.n_joints)
            except P.ProtocolError as exc:
                text = raw.decode("ascii", "replace")
                noted = str(exc) + (self._old_server_hint() if text.startswith("PONG ") else "")
                continue
            if msg.kind == "ERR":
                code, text = P.parse_error_reply(msg)
                hint = self._old_server_hint() if code == P.ErrorCode.SYNTAX else ""
                if msg.seq == seq and code != P.ErrorCode.CHECKSUM:
                    refusal = f"ERR {code} {_error_name(code)}: {text}{hint}"
                elif msg.seq in (None, seq):
                    noted = f"controller could not read the request: ERR {code} {text}{hint}"
                continue
            if msg.seq == seq and msg.kind == "PONG":
                if msg.args[1] == token:
                    self.stale_replies += held - 1
                    return msg, ""
                noted = (f"the server answered PING {seq} with the token {msg.args[1]!r}, not this session's "
                         f"{token!r}: its PING handling is wrong (it must echo the token as it came; "
                         "docs/line-protocol.md, 'Sessions and stale replies')")
        self.stale_replies += held
        if refusal:
            raise DeviceError(f"{self.name} on {self.url}: controller refused PING (seq {seq}): {refusal}")
        problem = noted or f"no reply within {timeout_s:.3g} s"
        if self._buffer:  # the start of a reply that never ended: stale now
            problem += f" (discarded a partial line {bytes(self._buffer)[:40]!r})"
            self._buffer.clear()
        return None, problem

    def _old_server_hint(self) -> str:
        return (f" (a server of protocol version 2 or older refuses the session token, or answers PING without "
                f"it; this driver speaks version {P.PROTOCOL_VERSION}: {self.version_hint})")

    def _write(self, data: bytes) -> None:
        try:
            self._serial.write(data)
            self._serial.flush()
        except self._serial_errors as exc:
            self._lost(exc)

    def _read_line(self, deadline: float) -> bytes | None:
        """One line (LF stripped), garbage flushed as a line, or None at the deadline."""
        while True:
            idx = self._buffer.find(b"\n")
            if idx >= 0:
                line = bytes(self._buffer[:idx])
                del self._buffer[: idx + 1]
                return line
            if len(self._buffer) > _MAX_PENDING:
                line = bytes(self._buffer)
                self._buffer.clear()
                return line
            if time.monotonic() >= deadline:
                return None
            try:
                chunk = self._serial.read(1)
                if chunk:
                    waiting = self._serial.in_waiting
                    if waiting:
                        chunk += self._serial.read(waiting)
            except self._serial_errors as exc:
                self._lost(exc)
            self._buffer.extend(chunk)

    def _lost(self, exc: BaseException):
        self.close()
        where = "the network" if self.transport == "socket" else "the cable"
        raise DeviceError(
            f"{self.name} on {self.url}: connection lost ({exc}); nothing is sent again: check {where} and the "
            f"controller, then create the robot again"
        ) from exc


def _error_name(code: int) -> str:
    try:
        return P.ErrorCode(code).name.lower()
    except ValueError:
        return "unknown code"
