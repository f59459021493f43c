"""The spherecal line protocol as the IRB 2400's RAPID server (SpherecalServer.mod) speaks
it. The protocol is brand-free and part of the plugin API (``spherecal.plugins.line_protocol``;
the built-in ``urdf`` robot type speaks it too); this module re-exports its names for the
IRB 2400 plugin and its tests. See docs/line-protocol.md and
docs/robot-abb-irb2400.md.

It adds two requests of the IRB 2400's server alone, for pose streaming over Externally
Guided Motion (``SpherecalEgm.mod``); both are answered ``OK`` or ``ERR``:

* ``SSTART <seq> <period_ms>``: start the EGM position stream with this sample period
  (a multiple of 4 ms, at most :data:`MAX_STREAM_PERIOD_MS`); ``OK`` once streaming;
* ``SSTOP <seq>``: stop it (``OK`` also when no stream runs).

And three for the programmed-line pose stream of a controller without EGM
(``SpherecalLine.mod``; an S4C+): the controller sends no poses, it stamps each move's
start and end with its own clock, and the PC computes the poses along the programmed line:

* ``LSTART <seq> <reset> <distance_mm>``: from now on every ``MOVL`` is run as a
  ``TriggL`` stamped when its path passes ``distance_mm`` from its start (past the
  acceleration ramp, so that the constant-speed part is timed without the acceleration);
  ``reset`` 1 restarts the controller's clock from zero (the first stream of a
  connection), 0 keeps it running; ``OK``;
* ``LSTOP <seq>``: ``MOVL`` runs as a plain ``MoveL`` again; ``OK``;
* ``LTIME <seq>``: the stamps of the last stamped move, ``T <seq> <moves> <start_ms>
  <cruise_end_ms> <end_ms>``: the moves stamped since ``LSTART``, the clock (whole ms
  since its reset) when the path passed the stamp's distance from its start, when it
  passed the same distance before its end, and when the arm was in position at its
  end; -1 for a stamp not taken.

``ERR <seq> 7`` (:data:`ERR_STREAM`) says the stream could not start or stop (the EGM
or line module not loaded, an EGM error); a server without these requests answers
``ERR - 2`` or ``ERR <seq> 2 unknown request``.
"""

import re
from dataclasses import dataclass

from spherecal.plugins import line_protocol as _line_protocol

__all__ = [
    "MAX_LINE_CHARS",
    "SEQ_MODULUS",
    "PROTOCOL_VERSION",
    "TOKEN_CHARS",
    "MAX_ORIENTATION_SPEED_DEG_S",
    "JOINT_DECIMALS",
    "POSITION_DECIMALS",
    "QUATERNION_DECIMALS",
    "SPEED_DECIMALS",
    "MAX_JOINTS",
    "REQUEST_ARGS",
    "REPLY_ARGS",
    "ErrorCode",
    "ProtocolError",
    "ChecksumError",
    "Message",
    "checksum",
    "frame",
    "unframe",
    "decode_request",
    "decode_reply",
    "encode",
    "parse_number",
    "new_session_token",
    "check_token",
    "ping_request",
    "ping_token",
    "getj_request",
    "getp_request",
    "target_request",
    "parse_target_request",
    "movl_request",
    "parse_movl_request",
    "movl_orientation_speed",
    "pong_reply",
    "parse_pong_reply",
    "ok_reply",
    "joints_reply",
    "parse_joints_reply",
    "pose_reply",
    "parse_pose_reply",
    "error_reply",
    "parse_error_reply",
]


globals().update({_name: getattr(_line_protocol, _name) for _name in __all__})

__all__ += ["ERR_STREAM", "LINE_REPLY_ARGS", "MAX_CLOCK_MS", "MAX_STAMP_DISTANCE_MM", "MAX_STREAM_PERIOD_MS", "STREAM_REQUEST_ARGS",
            "LineStamps", "decode_stream_request", "line_start_request", "line_stop_request", "line_time_request",
            "line_time_reply", "parse_line_start", "parse_line_time_reply", "parse_stream_start",
            "stream_start_request", "stream_stop_request"]

#: Requests of the IRB 2400's server beyond the core protocol -> number of arguments.
STREAM_REQUEST_ARGS = {"SSTART": 1, "SSTOP": 0, "LSTART": 2, "LSTOP": 0, "LTIME": 0}
#: Largest stamp distance a ``LSTART`` may ask for, mm.
MAX_STAMP_DISTANCE_MM = 500.0
#: Replies of those requests beyond the core protocol's -> number of arguments.
LINE_REPLY_ARGS = {"T": 4}
#: Largest clock stamp, ms, a ``T`` reply carries exactly: RAPID's num holds whole
#: numbers exactly up to 2**23 (2 h 19 min of clock).
MAX_CLOCK_MS = 2**23
#: ``ERR`` code of a stream request that failed on the controller.
ERR_STREAM = 7
#: Longest sample period a ``SSTART`` may ask for, ms.
MAX_STREAM_PERIOD_MS = 100


def stream_start_request(seq: int, sample_period_ms: int) -> bytes:
    """``SSTART seq period_ms``: start the EGM position stream."""
    ms = _check_period(sample_period_ms)
    return _line_protocol.frame(f"SSTART {_line_protocol._check_seq(seq)} {ms}")


def stream_stop_request(seq: int) -> bytes:
    """``SSTOP seq``: stop the EGM position stream."""
    return _line_protocol.frame(f"SSTOP {_line_protocol._check_seq(seq)}")


def _check_period(ms) -> int:
    if isinstance(ms, bool) or not isinstance(ms, (int, float)) or ms != int(ms) or not (
            4 <= int(ms) <= MAX_STREAM_PERIOD_MS and int(ms) % 4 == 0):
        raise _line_protocol.ProtocolError(
            f"stream sample period must be a multiple of 4 ms in 4..{MAX_STREAM_PERIOD_MS}, got {ms!r}")
    return int(ms)


def decode_stream_request(line: bytes | str) -> "_line_protocol.Message | None":
    """The ``SSTART``/``SSTOP`` request of ``line``, or None when the line is another
    request (or not a framed line: the core protocol's decoder answers those). Raises
    ProtocolError for a stream request with the wrong fields."""
    try:
        body = _line_protocol.unframe(line)
    except _line_protocol.ProtocolError:
        return None
    parts = body.split(" ")
    if parts[0] not in STREAM_REQUEST_ARGS:
        return None
    if len(parts) < 2 or not parts[1].isdigit() or not 0 <= int(parts[1]) < _line_protocol.SEQ_MODULUS:
        raise _line_protocol.ProtocolError(f"request {body!r} has no valid sequence number")
    if len(parts) - 2 != STREAM_REQUEST_ARGS[parts[0]]:
        raise _line_protocol.ProtocolError(
            f"request {parts[0]} takes {STREAM_REQUEST_ARGS[parts[0]]} arguments, got {len(parts) - 2} in {body!r}")
    return _line_protocol.Message(parts[0], int(parts[1]), tuple(parts[2:]))


def parse_stream_start(msg) -> int:
    """The sample period (ms) of a ``SSTART`` request."""
    if msg.kind != "SSTART":
        raise _line_protocol.ProtocolError(f"expected a SSTART request, got {msg.kind}")
    try:
        return _check_period(float(msg.args[0]))
    except ValueError:
        raise _line_protocol.ProtocolError(f"SSTART period_ms {msg.args[0]!r} is not a number") from None


def line_start_request(seq: int, reset_clock: bool, distance_mm: float) -> bytes:
    """``LSTART seq reset distance_mm``: stamp every following MOVL where its path passes
    ``distance_mm`` (one decimal) from its start, and in position at its end."""
    d = float(distance_mm)
    if not 0 <= d <= MAX_STAMP_DISTANCE_MM:
        raise _line_protocol.ProtocolError(f"stamp distance must be in 0..{MAX_STAMP_DISTANCE_MM:g} mm, got {d!r}")
    return _line_protocol.frame(f"LSTART {_line_protocol._check_seq(seq)} {1 if reset_clock else 0} {d:.1f}")


def line_stop_request(seq: int) -> bytes:
    """``LSTOP seq``: MOVL runs unstamped again."""
    return _line_protocol.frame(f"LSTOP {_line_protocol._check_seq(seq)}")


def line_time_request(seq: int) -> bytes:
    """``LTIME seq``: the stamps of the last stamped move."""
    return _line_protocol.frame(f"LTIME {_line_protocol._check_seq(seq)}")


def parse_line_start(msg) -> tuple[bool, float]:
    """Whether a ``LSTART`` request restarts the clock, and its stamp distance (mm)."""
    if msg.kind != "LSTART":
        raise _line_protocol.ProtocolError(f"expected a LSTART request, got {msg.kind}")
    if msg.args[0] not in ("0", "1"):
        raise _line_protocol.ProtocolError(f"LSTART reset {msg.args[0]!r} must be 0 or 1")
    d = _line_protocol.parse_number(msg.args[1], "LSTART distance_mm")
    if not 0 <= d <= MAX_STAMP_DISTANCE_MM:
        raise _line_protocol.ProtocolError(f"LSTART distance_mm {d!r} outside 0..{MAX_STAMP_DISTANCE_MM:g}")
    return msg.args[0] == "1", d


@dataclass(frozen=True)
class LineStamps:
    """A ``T`` reply: ``moves`` stamped since ``LSTART``; the controller's clock (whole ms
    since its reset) when the last one's path passed the stamp's distance from its start
    (``start_ms``) and the same distance before its end (``cruise_end_ms``), and when the
    arm was in position at its end (``end_ms``); None for a stamp not taken."""

    moves: int
    start_ms: int | None
    cruise_end_ms: int | None
    end_ms: int | None


def line_time_reply(seq: int, stamps: LineStamps) -> bytes:
    """``T seq moves start_ms cruise_end_ms end_ms`` (-1 for a stamp not taken)."""
    def ms(v):
        return "-1" if v is None else str(int(v))
    return _line_protocol.frame(f"T {_line_protocol._check_seq(seq)} {int(stamps.moves)} {ms(stamps.start_ms)} "
                                f"{ms(stamps.cruise_end_ms)} {ms(stamps.end_ms)}")


def parse_line_time_reply(msg) -> LineStamps:
    """The stamps of a ``T`` reply; ProtocolError naming the field when one is not a whole
    number in its range."""
    if msg.kind != "T":
        raise _line_protocol.ProtocolError(f"expected a T reply, got {msg.kind}")
    values = []
    for name, text in zip(("moves", "start_ms", "cruise_end_ms", "end_ms"), msg.args):
        low = 0 if name == "moves" else -1
        if not re.fullmatch(r"-?[0-9]{1,9}", text) or int(text) < low:
            raise _line_protocol.ProtocolError(
                f"T reply {name} {text!r}: expected a whole number of at most 9 digits, at least {low}")
        values.append(int(text))
    moves, start, cruise_end, end = values
    return LineStamps(moves, *(None if v < 0 else v for v in (start, cruise_end, end)))
