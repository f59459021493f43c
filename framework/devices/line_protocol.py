"""The spherecal line protocol between the PC and a robot controller, brand-free.

Pure functions only: no I/O (the link is :mod:`spherecal.devices.line_robot`). Robot plugins speak
it to the small server their controller runs (the built-in ``urdf`` robot type does; a
plugin may use it for its own robot). The full description, with examples, is in
``docs/line-protocol.md``; in short:

* ASCII lines ending in LF; a line holds at most :data:`MAX_LINE_CHARS` (80) characters
  before the LF, so that a controller whose strings hold 80 characters reads a whole line.
* A line is ``<body>*<XX>`` where ``XX`` is the XOR of every byte of ``body``, as two
  upper-case hex digits (as in NMEA 0183). The body is space-separated fields: a kind,
  a sequence number (0..999, chosen by the PC, echoed in the reply) and arguments.
* Requests: ``PING`` (carries the PC's session token), ``GETJ``, ``GETP``, ``TGT`` (stage a target pose), ``MOVL`` (move
  linearly to the staged target at a speed; the reply comes once in position).
* Replies: ``PONG`` (the protocol version and the token echoed), ``J`` (joints, deg, 4 decimals, one per joint: six for a six-axis
  arm, at most :data:`MAX_JOINTS` so that the line fits), ``P`` (flange pose x y z in mm
  with 3 decimals and quaternion q1..q4 = (w, x, y, z) with 6 decimals), ``OK``,
  ``ERR <seq> <code> <text>`` (seq ``-`` when the request's own seq was unreadable).

A move takes two requests because a pose and a speed do not fit one 80-character line:
``TGT <seq> x y z q1 q2 q3 q4`` stages the target under its seq, and
``MOVL <seq> <speed_mm_s> <target_seq> <v_ori_deg_s>`` moves to the target staged under ``target_seq``
(the controller refuses any other), which makes a repeated MOVL harmless.

A session opens with ``PING <seq> <token>``: the token (:func:`new_session_token`, 12
lower-case hex digits drawn at random per connection) comes back in ``PONG <seq> 3
<token>``. The server answers one line after another, so every reply that comes before
that PONG belongs to an earlier session (it is discarded), and every reply after it
belongs to this one: a reply of an earlier session is never taken for one of this
session's, whatever seq it carries.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from enum import IntEnum
from typing import Sequence

import numpy as np

from spherecal.core.errors import DeviceError
from spherecal.core.models import Pose

#: Characters in a line before its LF (many controller languages' strings hold at most 80).
MAX_LINE_CHARS = 80
#: Sequence numbers run 0 .. SEQ_MODULUS - 1 and wrap.
SEQ_MODULUS = 1000
#: Protocol version the PONG reply carries (2: MOVL carries the reorientation speed;
#: 3: PING carries a session token that PONG echoes).
PROTOCOL_VERSION = 3
#: Characters of a session token (lower-case hex digits).
TOKEN_CHARS = 12
_TOKEN_ALPHABET = frozenset("0123456789abcdef")
#: Largest reorientation speed a MOVL may ask for, deg/s (the server refuses more).
MAX_ORIENTATION_SPEED_DEG_S = 500.0

JOINT_DECIMALS = 4
POSITION_DECIMALS = 3
QUATERNION_DECIMALS = 6
SPEED_DECIMALS = 1

#: Most joints a ``J`` reply carries: seven values of up to 9 characters ("-359.9999") fit
#: an 80-character line, eight do not.
MAX_JOINTS = 7

#: Request kind -> number of arguments.
REQUEST_ARGS: dict[str, int] = {"PING": 1, "GETJ": 0, "GETP": 0, "TGT": 7, "MOVL": 3}
#: Reply kind -> number of arguments (ERR: code and at least one word of text; J: the
#: arm's joint count, given to :func:`decode_reply`).
REPLY_ARGS: dict[str, int] = {"PONG": 2, "J": 6, "P": 7, "OK": 0, "ERR": 2}


class ErrorCode(IntEnum):
    """Codes of ``ERR`` replies."""

    CHECKSUM = 1  #: the request's checksum did not match (resend)
    SYNTAX = 2  #: unknown kind, wrong number of fields, unreadable number
    RANGE = 3  #: a value out of range (speed <= 0 or above the controller's maximum)
    NO_TARGET = 4  #: MOVL names a target seq that is not the staged target
    UNREACHABLE = 5  #: the target is out of reach or beyond a joint limit
    MOTION = 6  #: the move failed on the controller


class ProtocolError(DeviceError):
    """A line that does not follow the protocol (garbage, wrong field count, ...)."""


class ChecksumError(ProtocolError):
    """A line whose checksum does not match its body (corrupted in transit)."""


@dataclass(frozen=True)
class Message:
    """One decoded line. ``seq`` is None only for an ``ERR`` whose seq is ``-``."""

    kind: str
    seq: int | None
    args: tuple[str, ...]


# framing ---------------------------------------------------------------------------------
def checksum(body: str) -> str:
    """XOR of the body's bytes as two upper-case hex digits."""
    x = 0
    for b in body.encode("ascii"):
        x ^= b
    return f"{x:02X}"


def frame(body: str) -> bytes:
    """``body*XX\\n`` as bytes; raises ProtocolError if the line would break the rules."""
    if not body.isascii() or any(c in body for c in "*\r\n"):
        raise ProtocolError(f"line body must be ASCII without '*', CR or LF: {body!r}")
    line = f"{body}*{checksum(body)}"
    if len(line) > MAX_LINE_CHARS:
        raise ProtocolError(
            f"line of {len(line)} characters exceeds the {MAX_LINE_CHARS}-character line limit: {line!r}"
        )
    return (line + "\n").encode("ascii")


def unframe(line: bytes | str) -> str:
    """The body of one received line (trailing CR/LF allowed), checksum verified.

    Raises :class:`ChecksumError` on a mismatch, :class:`ProtocolError` on anything
    that is not a framed line."""
    if isinstance(line, bytes):
        try:
            text = line.decode("ascii")
        except UnicodeDecodeError:
            raise ProtocolError(f"received non-ASCII bytes: {line[:100]!r}") from None
    else:
        text = line
    text = text.rstrip("\r\n")
    if len(text) > MAX_LINE_CHARS:
        raise ProtocolError(f"received a line of {len(text)} characters (max {MAX_LINE_CHARS}): {text[:100]!r}")
    star = text.rfind("*")
    if star < 0 or len(text) - star != 3:
        raise ProtocolError(f"received a line without a '*XX' checksum at its end: {text!r}")
    body, given = text[:star], text[star + 1 :]
    if not all(c in "0123456789ABCDEFabcdef" for c in given):
        raise ProtocolError(f"checksum {given!r} is not two hex digits in line {text!r}")
    expected = checksum(body)
    if given.upper() != expected:
        raise ChecksumError(f"checksum mismatch in line {text!r}: computed {expected}, line says {given}")
    if not body.isprintable():
        raise ProtocolError(f"line contains control characters: {text!r}")
    return body


def _decode(line: bytes | str, table: dict[str, int], role: str) -> Message:
    body = unframe(line)
    parts = body.split(" ")
    if any(p == "" for p in parts):
        raise ProtocolError(f"{role} {body!r}: fields must be separated by single spaces")
    kind = parts[0]
    if kind not in table:
        raise ProtocolError(f"unknown {role} kind {kind!r} in {body!r}; expected one of {sorted(table)}")
    if len(parts) < 2:
        raise ProtocolError(f"{role} {body!r} has no sequence number")
    seq = _parse_seq(parts[1], body, allow_dash=(kind == "ERR"))
    args = tuple(parts[2:])
    want = table[kind]
    if kind == "ERR":
        if len(args) < want:
            raise ProtocolError(f"ERR reply {body!r} needs a code and a text")
    elif len(args) != want:
        raise ProtocolError(f"{role} {kind} takes {want} arguments, got {len(args)} in {body!r}")
    return Message(kind, seq, args)


def _parse_seq(text: str, body: str, allow_dash: bool) -> int | None:
    if allow_dash and text == "-":
        return None
    if not text.isdigit() or not 0 <= int(text) < SEQ_MODULUS:
        raise ProtocolError(f"sequence number {text!r} in {body!r} is not an integer 0..{SEQ_MODULUS - 1}")
    return int(text)


def decode_request(line: bytes | str) -> Message:
    """Decode a request line (as the controller does)."""
    return _decode(line, REQUEST_ARGS, "request")


def decode_reply(line: bytes | str, n_joints: int = 6, extra: dict[str, int] | None = None) -> Message:
    """Decode a reply line (as the PC does); a ``J`` reply must carry ``n_joints`` values.
    ``extra``: reply kinds of a plugin's own requests -> their number of arguments (they
    may not redefine the protocol's)."""
    table = REPLY_ARGS if n_joints == REPLY_ARGS["J"] else {**REPLY_ARGS, "J": _joint_count(n_joints)}
    if extra:
        clash = sorted(set(extra) & set(REPLY_ARGS))
        if clash:
            raise ProtocolError(f"a plugin's reply kinds may not redefine the protocol's: {clash}")
        table = {**table, **extra}
    return _decode(line, table, "reply")


def _joint_count(n: int) -> int:
    if not isinstance(n, (int, np.integer)) or not 1 <= int(n) <= MAX_JOINTS:
        raise ProtocolError(f"a J reply carries 1..{MAX_JOINTS} joints, not {n!r}")
    return int(n)


def _check_seq(seq: int | None) -> str:
    if seq is None:
        return "-"
    if not isinstance(seq, (int, np.integer)) or not 0 <= int(seq) < SEQ_MODULUS:
        raise ProtocolError(f"sequence number must be an integer 0..{SEQ_MODULUS - 1}, got {seq!r}")
    return str(int(seq))


def _fmt(value: float, decimals: int, what: str) -> str:
    v = float(value)
    if not math.isfinite(v):
        raise ProtocolError(f"{what} must be finite, got {value!r}")
    text = f"{v:.{decimals}f}"
    if float(text) == 0.0:
        text = f"{0.0:.{decimals}f}"  # no "-0.000"
    return text


def encode(kind: str, seq: int | None, args: Sequence[str] = ()) -> bytes:
    """Frame ``kind seq args...``; arguments are already formatted strings."""
    if kind not in REQUEST_ARGS and kind not in REPLY_ARGS:
        raise ProtocolError(f"unknown message kind {kind!r}")
    return frame(" ".join([kind, _check_seq(seq), *args]))


def parse_number(text: str, what: str) -> float:
    """A finite decimal number, or ProtocolError naming the field."""
    try:
        v = float(text)
    except ValueError:
        raise ProtocolError(f"{what}: {text!r} is not a number") from None
    if not math.isfinite(v):
        raise ProtocolError(f"{what}: {text!r} is not a finite number")
    return v


# requests ----------------------------------------------------------------------------
def new_session_token() -> str:
    """A fresh session token: :data:`TOKEN_CHARS` random lower-case hex digits (48 bits)."""
    import secrets

    return secrets.token_hex(TOKEN_CHARS // 2)


def check_token(token: str, what: str = "session token") -> str:
    """``token`` if it is 1..:data:`TOKEN_CHARS` lower-case hex digits, else ProtocolError."""
    if not isinstance(token, str) or not 1 <= len(token) <= TOKEN_CHARS or not set(token) <= _TOKEN_ALPHABET:
        raise ProtocolError(f"{what} must be 1..{TOKEN_CHARS} lower-case hex digits, got {token!r}")
    return token


def ping_request(seq: int, token: str) -> bytes:
    """``PING seq token``: open (or check) a session; the server echoes the token."""
    return encode("PING", seq, [check_token(token)])


def ping_token(msg: Message) -> str:
    """The session token of a ``PING`` request."""
    _expect(msg, "PING")
    return check_token(msg.args[0], "PING token")


def getj_request(seq: int) -> bytes:
    return encode("GETJ", seq)


def getp_request(seq: int) -> bytes:
    return encode("GETP", seq)


def _pose_fields(pose: Pose) -> list[str]:
    t, q = pose.as_xyz_quat_wxyz()
    return [_fmt(v, POSITION_DECIMALS, "translation_mm") for v in t] + [
        _fmt(v, QUATERNION_DECIMALS, "quaternion_wxyz") for v in q
    ]


def _parse_pose(args: Sequence[str], what: str) -> Pose:
    xyz = [parse_number(a, f"{what} {n}") for a, n in zip(args[:3], ("x_mm", "y_mm", "z_mm"))]
    q = np.array([parse_number(a, f"{what} {n}") for a, n in zip(args[3:7], ("q1", "q2", "q3", "q4"))])
    norm = float(np.linalg.norm(q))
    if abs(norm - 1.0) > 1e-4:
        raise ProtocolError(f"{what}: quaternion (q1..q4 = w, x, y, z) {q.tolist()} has norm {norm:.6f}, not 1")
    return Pose.from_xyz_quat_wxyz(xyz, q / norm)


def target_request(seq: int, base_from_flange: Pose) -> bytes:
    """``TGT seq x y z q1 q2 q3 q4``: stage a flange target (mm, quaternion w-first)."""
    return encode("TGT", seq, _pose_fields(base_from_flange))


def parse_target_request(msg: Message) -> Pose:
    """The staged ``base_from_flange`` of a TGT request."""
    _expect(msg, "TGT")
    return _parse_pose(msg.args, "TGT")


def movl_request(seq: int, speed_mm_s: float, target_seq: int, orientation_speed_deg_s: float = 10.0) -> bytes:
    """``MOVL seq speed_mm_s target_seq v_ori``: move to the target staged by TGT
    target_seq with the flange at ``speed_mm_s`` (speeddata v_tcp) and the reorientation
    at ``orientation_speed_deg_s`` (v_ori); the driver chooses both so that the sensor
    (the tool point) stays within the move's speed."""
    return encode("MOVL", seq, [_fmt(speed_mm_s, SPEED_DECIMALS, "speed_mm_s"), _check_seq(target_seq),
                                _fmt(orientation_speed_deg_s, SPEED_DECIMALS, "orientation_speed_deg_s")])


def parse_movl_request(msg: Message) -> tuple[float, int]:
    """(speed_mm_s, target_seq) of a MOVL request (:func:`movl_orientation_speed`: its v_ori)."""
    _expect(msg, "MOVL")
    speed = parse_number(msg.args[0], "MOVL speed_mm_s")
    target_seq = _parse_seq(msg.args[1], "MOVL", allow_dash=False)
    return speed, target_seq


def movl_orientation_speed(msg: Message) -> float:
    """The reorientation speed (deg/s, speeddata v_ori) of a MOVL request."""
    _expect(msg, "MOVL")
    return parse_number(msg.args[2], "MOVL orientation_speed_deg_s")


# replies -----------------------------------------------------------------------------
def pong_reply(seq: int, token: str) -> bytes:
    """``PONG seq version token``: the reply to ``PING seq token``."""
    return encode("PONG", seq, [str(PROTOCOL_VERSION), check_token(token)])


def parse_pong_reply(msg: Message) -> tuple[int, str]:
    """(protocol version, token) of a ``PONG`` reply."""
    _expect(msg, "PONG")
    version = msg.args[0]
    if not version.isdigit():
        raise ProtocolError(f"PONG carries a non-integer version {version!r}")
    return int(version), msg.args[1]


def ok_reply(seq: int) -> bytes:
    return encode("OK", seq)


def joints_reply(seq: int, joints_deg, n_joints: int = 6) -> bytes:
    """``J seq j1 .. jn`` in degrees, controller convention, 4 decimals."""
    q = np.asarray(joints_deg, dtype=float).reshape(-1)
    if q.size != _joint_count(n_joints):
        raise ProtocolError(f"joints_deg: expected {n_joints} values, got {q.size}")
    return encode("J", seq, [_fmt(v, JOINT_DECIMALS, f"joint {i + 1}") for i, v in enumerate(q)])


def parse_joints_reply(msg: Message) -> np.ndarray:
    """Joints in degrees (controller convention) from a ``J`` reply."""
    _expect(msg, "J")
    return np.array([parse_number(a, f"J joint {i + 1}") for i, a in enumerate(msg.args)])


def pose_reply(seq: int, base_from_flange: Pose) -> bytes:
    """``P seq x y z q1 q2 q3 q4``: flange pose, mm (3 decimals), quaternion w-first (6)."""
    return encode("P", seq, _pose_fields(base_from_flange))


def parse_pose_reply(msg: Message) -> Pose:
    """``base_from_flange`` from a ``P`` reply."""
    _expect(msg, "P")
    return _parse_pose(msg.args, "P reply")


def error_reply(seq: int | None, code: ErrorCode | int, text: str) -> bytes:
    """``ERR seq code text``; the text is cleaned to printable ASCII and shortened to fit."""
    clean = " ".join(text.split())  # line breaks and tabs become single spaces
    clean = "".join(c if (c.isascii() and c.isprintable() and c != "*") else "?" for c in clean) or "error"
    head = f"ERR {_check_seq(seq)} {int(code)} "
    room = MAX_LINE_CHARS - 3 - len(head)
    return frame(head + clean[:room].rstrip())


def parse_error_reply(msg: Message) -> tuple[int, str]:
    """(code, text) of an ``ERR`` reply."""
    _expect(msg, "ERR")
    code = msg.args[0]
    if not code.isdigit():
        raise ProtocolError(f"ERR reply: code {code!r} is not an integer")
    return int(code), " ".join(msg.args[1:])


def _expect(msg: Message, kind: str) -> None:
    if msg.kind != kind:
        raise ProtocolError(f"expected a {kind} message, got {msg.kind} (seq {msg.seq})")
