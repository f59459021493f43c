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

Safety is protocol-free and :class:`LineRobot` inherits it
(:class:`~spherecal.devices.motion_safety.MotionSafety`): speed, workspace box (the target
and the start, where the arm stands: both ends in a box, the whole straight path is) and
reachability (the target, and ``path_check_samples`` points along the straight line to
it, through the kinematics' inverse, within the joint limits, from the joints read now)
are checked before anything is sent (``check_move`` runs the same checks without
moving); a move's flange and reorientation speeds keep the tool point (the sensor or the
sphere the flange carries) within the move's speed; ``controller_frame_offset`` compares
the controller's pose (GETP) with the kinematics' pose of the joints it reports (GETJ).

The configuration is a plugin's model derived from :class:`LineLinkSettings`; its
``workspace`` must be set by the time the robot moves (:class:`LineRobot` takes a
``workspace`` argument when the plugin derives it). The kinematics must have
``flange_pose_from_joints(joints_deg, check_limits)`` and ``joints_from_flange_pose(pose,
seed_joints_deg)``, raising an :class:`~spherecal.core.errors.InputError` when a pose is
out of reach.
"""

from __future__ import annotations

import secrets
import select
import socket
import time
from typing import Callable, Literal

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, field_validator

from spherecal.core.errors import DeviceError
from spherecal.core.models import Pose
from spherecal.core.workspace import WorkspaceBox
from spherecal.devices import line_protocol as P
from spherecal.devices.motion_safety import MIN_SPEED_MM_S, FrameOffset, MotionLimits, MotionSafety

__all__ = ["MIN_SPEED_MM_S", "SOCKET_SCHEME", "ControllerClosedError", "FrameOffset", "LineLinkSettings", "LineRobot",
           "LinkSettings", "TcpLink", "WorkspaceBox", "initial_seq", "link_transport", "parse_socket_url"]

#: Longest single blocking read, s (the overall deadline is checked between reads).
_POLL_S = 0.05
#: Shortest bound on one write, s. A write that did go out is reported as timed out when
#: the process was not scheduled within the bound (pyserial checks the clock after the
#: write), and the link is then closed as lost: under load, a reply timeout of a fraction
#: of a second must not make that happen to a line that was sent.
_MIN_WRITE_TIMEOUT_S = 2.0
#: Bytes kept while waiting for an LF before the buffer is treated as garbage.
_MAX_PENDING = 4 * P.MAX_LINE_CHARS

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


class LinkSettings(BaseModel):
    """The link part of :class:`LineLinkSettings`: the link (serial or TCP), the replies
    and the pose source. Times in seconds."""

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
    move_timeout_extra_s: float = Field(
        5.0, ge=0, le=600, description="time allowed for a move beyond twice distance / speed (acceleration, settling), s"
    )

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


class LineLinkSettings(MotionLimits, LinkSettings):
    """The settings :class:`LineRobot` reads: the link (:class:`LinkSettings`: serial or
    TCP, the replies, the pose source) and the motion limits
    (:class:`~spherecal.devices.motion_safety.MotionLimits`). A robot plugin's
    configuration model derives from it (and gives ``workspace`` a default or a way to
    derive one). Lengths in mm, angles in degrees, times in seconds."""

    orientation_speed_deg_s: float = Field(
        100.0, gt=0, le=P.MAX_ORIENTATION_SPEED_DEG_S,
        description="largest reorientation speed a move asks for, deg/s; each move asks for less when its sensor "
        "(the tool point) would otherwise exceed the move's speed"
    )


def initial_seq() -> int:
    """A random sequence number to start a session from (the first request carries the
    next one)."""
    return secrets.randbelow(P.SEQ_MODULUS)


class LineRobot(MotionSafety):
    """A connected robot speaking the spherecal line protocol (implements
    :class:`spherecal.devices.contract.Robot`), its moves checked by
    :class:`~spherecal.devices.motion_safety.MotionSafety`.

    Poses are ``base_from_flange``, mm, quaternion (w, x, y, z). Joints are degrees in
    the controller convention. ``name`` names the robot in every message;
    ``server_hint`` says what to check when the controller does not answer, and
    ``socket_hint`` what to check when a ``socket://`` port cannot be opened."""

    #: The speeds a MOVL carries have one decimal.
    speed_step = 10.0**-P.SPEED_DECIMALS
    #: Reply kinds of the plugin's own requests -> their number of arguments (beside the
    #: protocol's, which they may not redefine): :func:`~spherecal.devices.line_protocol.decode_reply`.
    extra_replies: dict[str, int] = {}
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
        super().__init__(config, kinematics, workspace=workspace, tool_point_mm=tool_point_mm)
        self.n_joints = int(n_joints)
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

    def read_controller_pose(self) -> Pose:
        """The controller's own pose of the flange (GETP), whatever ``pose_source`` says:
        for :meth:`~spherecal.devices.motion_safety.MotionSafety.controller_frame_offset`."""
        return P.parse_pose_reply(self._exchange("GETP", P.getp_request, "P"))

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
        start, target_joints = self.check_move_from_here(base_from_flange, speed_mm_s)
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
        self.moved(start, base_from_flange, v_tcp, v_ori)

    def moved(self, start: Pose, target: Pose, speed_mm_s: float, orientation_speed_deg_s: float) -> None:
        """Called once a move is done (its MOVL answered OK): from ``start`` (the pose of
        the joints read before it, this robot's kinematics) to ``target``
        (base_from_flange), at the flange speed and reorientation speed sent. Nothing
        here; a plugin that times its moves (a pose stream computed along the programmed
        line) overrides it."""

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

    # transport ---------------------------------------------------------------------
    def check_open(self) -> None:
        """DeviceError when the connection is closed."""
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
        self.check_open()
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
                    msg = P.decode_reply(raw, self.n_joints, self.extra_replies)
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
                msg = P.decode_reply(raw, self.n_joints, self.extra_replies)
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
