"""Driver for the IRB 2400 running ``SpherecalServer.mod`` (spherecal line protocol).

Two links, one driver: a serial line (``SpherecalSerial.mod`` on the controller), opened
with ``serial.serial_for_url`` (a device such as ``/dev/ttyS0``, ``COM1`` or a
pseudo-terminal, or another pyserial URL), or a TCP connection to the IRC5 socket server
(``SpherecalSocket.mod``) when the port is ``socket://host:port``
(:class:`~.tcp_link.TcpLink`). Framing, timeouts, resends and the stale-reply rules below
are the same code for both.

Every exchange is one request and one reply carrying the same sequence number.
Replies whose seq does not match the request (late replies of an earlier attempt) are
discarded; a corrupted line (checksum or syntax) or a timeout makes the driver resend
the request with a fresh seq, up to ``retries`` times, then raise
:class:`~spherecal.errors.DeviceError` saying what went wrong. A lost link raises
DeviceError at once (over TCP: the controller closed the connection, or it broke), and
the driver never reconnects by itself: the robot must be created again, which starts a
new connection (and, for the socket server, a new session that has no staged target).
Requests are idempotent (a MOVL names its staged target, and the
controller moves to a target once), so a resend never makes the robot move twice.

Replies of an earlier session: on open the driver discards whatever waits on the link,
and it starts its sequence numbers at a random value, so that a reply of an earlier
session still on its way is discarded as stale by its seq (unless it carries, by a
1-in-1000 chance, the very seq this session waits for, with the expected kind).

Speed, workspace and joint limits (the latter through inverse kinematics) are checked
before anything is sent.

With a calibrated model (``config.calibrated_model``) the driver applies it on the PC
side, as the controller keeps its nominal model: a target pose P becomes the joints q
that reach P on the calibrated model, and the controller is sent the nominal model's
pose of q (it turns that back into q); the flange pose is read as joints (GETJ) through
the calibrated model. The line protocol carries poses to 0.001 mm and quaternions to
1e-6, joints to 1e-4 deg: that resolution, not the model, limits how closely a target
is reached and a pose read (a few micrometres).
"""

from __future__ import annotations

import math
import secrets
import time
from typing import Callable

import numpy as np
import serial

from spherecal.errors import DeviceError, InputError
from spherecal.geometry import matrix_from_rotvec as _matrix_from_rotvec
from spherecal.geometry import rotvec_from_matrix as _rotvec
from spherecal.models import Pose

from . import protocol as P
from .config import SOCKET_SCHEME, AbbIrb2400Config
from .kinematics import CalibratedIrb2400Kinematics, Irb2400Kinematics, UnreachableError
from .tcp_link import TcpLink

#: Longest single blocking read, s (the overall deadline is checked between reads).
_POLL_S = 0.05
#: Bytes kept while waiting for an LF before the buffer is treated as garbage.
_MAX_PENDING = 4 * P.MAX_LINE_CHARS


def _initial_seq() -> int:
    """A random sequence number to start a session from (the first request carries the
    next one)."""
    return secrets.randbelow(P.SEQ_MODULUS)


#: Slowest speed sent (mm/s for the flange, deg/s for the reorientation): the line
#: carries one decimal, and a move that does not translate (or turn) still names one.
MIN_SPEED_MM_S = 0.1


class AbbIrb2400Robot:
    """A connected IRB 2400 (implements :class:`spherecal.devices.Robot`).

    Poses are ``base_from_flange`` (tool0 in wobj0), mm, quaternion (w, x, y, z).
    Joints are degrees in the controller convention (``CJointT()``)."""

    def __init__(
        self,
        config: AbbIrb2400Config,
        *,
        url: str | None = None,
        kinematics: Irb2400Kinematics | None = None,
        on_close: Callable[[], None] | None = None,
        tool_point_mm=None,
    ):
        self.config = config
        #: the point carried by the flange whose speed every move limits (flange frame, mm):
        #: the sensor (eye-in-hand) or the sphere (eye-to-hand); None: the flange itself
        self.tool_point_mm = None if tool_point_mm is None else np.asarray(tool_point_mm, dtype=float).reshape(3)
        self.url = url or config.port
        if kinematics is None:
            kinematics = config.kinematics()
        self.kin = kinematics
        #: The calibrated model applied on the PC side, or None (nominal model only).
        self.calibrated = kinematics if isinstance(kinematics, CalibratedIrb2400Kinematics) else None
        #: The controller's own model: the nominal one.
        self.nominal_kin = self.calibrated.nominal if self.calibrated is not None else kinematics
        self._on_close = on_close
        self._seq = _initial_seq()
        self._buffer = bytearray()
        self._closed = False
        self.stale_replies = 0  #: replies discarded because their seq did not match
        self.resends = 0  #: requests sent again after a timeout or a corrupted line
        self.last_joints_deg: np.ndarray | None = None
        #: "socket" (TCP to SpherecalSocket.mod) or "serial" (SpherecalSerial.mod)
        self.transport = "socket" if self.url.lower().startswith(SOCKET_SCHEME) else "serial"
        try:
            if self.transport == "socket":
                self._serial = TcpLink(self.url, timeout=min(config.timeout_s, _POLL_S),
                                       write_timeout=config.timeout_s, connect_timeout=config.timeout_s)
            else:
                self._serial = serial.serial_for_url(
                    self.url,
                    baudrate=config.baudrate,
                    bytesize=serial.EIGHTBITS,
                    parity=config.parity,
                    stopbits=config.stopbits,
                    timeout=min(config.timeout_s, _POLL_S),
                    write_timeout=config.timeout_s,
                )
        except (serial.SerialException, OSError, ValueError) as exc:
            self._closed = True
            if on_close is not None:
                on_close()
            what = ("that SpherecalSocket runs on the controller and listens on this address"
                    if self.transport == "socket" else "that the device exists")
            raise DeviceError(f"IRB 2400: cannot open {self.url!r} ({exc}); check robot.port and {what}") from exc
        # a reply of an earlier session may wait on the link: never take it for ours
        # (pyserial's own backends flush on open too; do not depend on it)
        try:
            self._serial.reset_input_buffer()
        except (serial.SerialException, OSError) as exc:
            self._lost(exc)

    # Robot protocol ----------------------------------------------------------------
    def read_joints_deg(self) -> np.ndarray:
        """Joints in degrees, controller convention (as ``CJointT()`` reports them)."""
        msg = self._exchange("GETJ", P.getj_request, "J")
        joints = P.parse_joints_reply(msg)
        self.last_joints_deg = joints
        return joints

    def read_flange_pose(self) -> Pose:
        """``base_from_flange`` now: from the controller (GETP) or from the joints by
        forward kinematics, as ``pose_source`` says; always from the joints through the
        calibrated model when there is one (the controller's pose is its nominal model's)."""
        if self.config.pose_source == "joints" or self.calibrated is not None:
            return self.kin.flange_pose_from_joints(self.read_joints_deg(), check_limits=False)
        return P.parse_pose_reply(self._exchange("GETP", P.getp_request, "P"))

    def move_linear(self, base_from_flange: Pose, speed_mm_s: float) -> None:
        """Move tool0 in a straight line to ``base_from_flange`` at ``speed_mm_s`` and return
        once in position. Limits are checked first; nothing is sent if one fails.

        With a calibrated model the controller is sent :meth:`controller_pose` of the
        target, so that the true flange reaches ``base_from_flange`` (the path between is
        the controller's straight line in its nominal model, within a few mm of a true
        straight line)."""
        self._check_open()
        self._check_speed(speed_mm_s)
        self._check_workspace(base_from_flange, "target")
        start_joints = self.read_joints_deg()
        start = self.kin.flange_pose_from_joints(start_joints, check_limits=False)
        target_joints = self._check_path(start, base_from_flange, start_joints)
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
        exactly T (speeddata limits both). Checked here, before anything is sent."""
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
        # pyserial's socket:// close() skips closing its socket when shutdown() fails on a
        # link the peer already dropped; close it ourselves (closing twice is harmless)
        sock = getattr(self._serial, "_socket", None)
        try:
            self._serial.close()
        finally:
            if sock is not None:
                sock.close()
            if self._on_close is not None:
                self._on_close()

    def __enter__(self) -> "AbbIrb2400Robot":
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    # extras ------------------------------------------------------------------------
    def controller_pose(self, base_from_flange: Pose, target_joints_deg=None) -> Pose:
        """The pose to send the controller for the flange to reach ``base_from_flange``:
        the pose itself with the nominal model; with a calibrated model, the nominal
        model's pose of the joints that reach it on the calibrated model
        (``target_joints_deg`` when already solved, else solved from the last joints)."""
        if self.calibrated is None:
            return base_from_flange
        if target_joints_deg is None:
            seed = self.last_joints_deg if self.last_joints_deg is not None else np.zeros(6)
            target_joints_deg = self.calibrated.joints_from_flange_pose(base_from_flange, seed_joints_deg=seed)
        return self.nominal_kin.flange_pose_from_joints(target_joints_deg, check_limits=False)

    def ping(self) -> int:
        """Check the RAPID server answers; returns its protocol version."""
        msg = self._exchange("PING", P.ping_request, "PONG")
        try:
            version = int(msg.args[0])
        except ValueError:
            raise P.ProtocolError(f"{self.url}: PONG carries a non-integer version {msg.args[0]!r}") from None
        if version != P.PROTOCOL_VERSION:
            raise DeviceError(
                f"{self.url}: SpherecalServer speaks protocol version {version}, this driver "
                f"version {P.PROTOCOL_VERSION}; load the SpherecalServer.mod shipped with this package"
            )
        return version

    # limits ------------------------------------------------------------------------
    def check_target(self, base_from_flange: Pose, speed_mm_s: float) -> None:
        """Check a planned target against every limit without sending anything: speed,
        workspace box, and reachability within the joint limits (inverse kinematics
        seeded with the last joints read, or zero). Raises what :meth:`move_linear` would."""
        self._check_speed(speed_mm_s)
        self._check_workspace(base_from_flange, "target")
        seed = self.last_joints_deg if self.last_joints_deg is not None else np.zeros(6)
        try:
            self.kin.joints_from_flange_pose(base_from_flange, seed_joints_deg=seed)
        except UnreachableError as exc:
            raise UnreachableError(f"target: {exc}") from None

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

    def _check_workspace(self, pose: Pose, what: str) -> None:
        box = self.config.workspace
        if not box.contains(pose.translation_mm):
            t = [round(v, 3) for v in pose.translation_mm]
            raise InputError(
                f"move_linear: {what} flange position {t} mm is outside the configured workspace box "
                f"min_mm={list(box.min_mm)} max_mm={list(box.max_mm)} (base frame)"
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
            except UnreachableError as exc:
                where = "target" if s == 1.0 else f"point {s:.0%} along the linear path"
                raise UnreachableError(f"move_linear: {where}: {exc}") from None
            if target_joints is None:
                target_joints = seed
        return target_joints

    # transport ---------------------------------------------------------------------
    def _check_open(self) -> None:
        if self._closed:
            raise DeviceError(f"IRB 2400 on {self.url}: the connection is closed; create the robot again")

    def _next_seq(self) -> int:
        self._seq = (self._seq + 1) % P.SEQ_MODULUS
        return self._seq

    def _exchange(
        self, kind: str, build: Callable[[int], bytes], expect: str, timeout_s: float | None = None
    ) -> P.Message:
        """Send a request built for a fresh seq and return its reply, resending after a
        timeout or a corrupted line; raises DeviceError when every attempt fails."""
        self._check_open()
        timeout_s = self.config.timeout_s if timeout_s is None else timeout_s
        attempts = self.config.retries + 1
        problem = ""
        for attempt in range(attempts):
            if attempt:
                self.resends += 1
            seq = self._next_seq()
            self._write(build(seq))
            deadline = time.monotonic() + timeout_s
            while True:
                raw = self._read_line(deadline)
                if raw is None:
                    problem = f"no reply within {timeout_s:.3g} s"
                    if self._buffer:  # the start of a reply that never ended: stale now
                        problem += f" (discarded a partial line {bytes(self._buffer)[:40]!r})"
                        self._buffer.clear()
                    break
                try:
                    msg = P.decode_reply(raw)
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
                        f"IRB 2400 on {self.url}: controller refused {kind} (seq {seq}): "
                        f"ERR {code} {_error_name(code)}: {text}"
                    )
                if msg.seq != seq:
                    self.stale_replies += 1
                    continue
                if msg.kind != expect:
                    raise P.ProtocolError(
                        f"IRB 2400 on {self.url}: reply {msg.kind} to {kind} (seq {seq}); expected {expect}"
                    )
                return msg
        if self.transport == "socket":
            check = ("Check that SpherecalServer is running on the controller and serves no other "
                     "connection (it serves one at a time)")
        else:
            check = (f"Check the cable, the serial settings (baudrate {self.config.baudrate}, "
                     f"parity {self.config.parity}) and that SpherecalServer is running on the controller")
        raise DeviceError(
            f"IRB 2400 on {self.url}: no valid reply to {kind} after {attempts} attempt(s); last problem: "
            f"{problem}. {check}"
        )

    def _write(self, data: bytes) -> None:
        try:
            self._serial.write(data)
            self._serial.flush()
        except (serial.SerialException, OSError) as exc:
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
            except (serial.SerialException, OSError) as exc:
                self._lost(exc)
            self._buffer.extend(chunk)

    def _lost(self, exc: BaseException):
        self.close()
        where = "the network" if self.transport == "socket" else "the cable"
        raise DeviceError(
            f"IRB 2400 on {self.url}: connection lost ({exc}); nothing is sent again: check {where} and the "
            f"controller, then create the robot again"
        ) from exc


def _error_name(code: int) -> str:
    try:
        return P.ErrorCode(code).name.lower()
    except ValueError:
        return "unknown code"


