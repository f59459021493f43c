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

``ERR <seq> 7`` (:data:`ERR_STREAM`) says the stream could not start or stop (the EGM
module not loaded, an EGM error); a server without these requests answers ``ERR - 2``
or ``ERR <seq> 2 unknown request``.
"""

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

__all__ += ["ERR_STREAM", "MAX_STREAM_PERIOD_MS", "STREAM_REQUEST_ARGS", "decode_stream_request",
            "parse_stream_start", "stream_start_request", "stream_stop_request"]

#: Requests of the IRB 2400's server beyond the core protocol -> number of arguments.
STREAM_REQUEST_ARGS = {"SSTART": 1, "SSTOP": 0}
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
