"""The spherecal line protocol as the IRB 2400's RAPID server (SpherecalServer.mod) speaks
it. The protocol is brand-free and part of the plugin API (``spherecal.plugins.line_protocol``;
the built-in ``urdf`` robot type speaks it too); this module re-exports its names for the
IRB 2400 plugin and its tests. See docs/line-protocol.md and
docs/robot-abb-irb2400.md.
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
