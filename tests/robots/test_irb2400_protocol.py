"""The spherecal line protocol: framing, round trips, line length, garbage."""

import numpy as np
import pytest

from spherecal.core.models import Pose
from spherecal.robots.abb_irb2400 import protocol as P


def test_checksum_is_the_xor_of_the_body():
    # "GETJ 7": G^E^T^J^' '^'7' computed by hand
    x = 0
    for c in b"GETJ 7":
        x ^= c
    assert P.getj_request(7) == f"GETJ 7*{x:02X}\n".encode()
    assert P.checksum("") == "00"


def test_request_round_trips():
    msg = P.decode_request(P.getp_request(42))
    assert (msg.kind, msg.seq, msg.args) == ("GETP", 42, ())
    msg = P.decode_request(P.ping_request(0, "0a1b2c3d4e5f"))
    assert (msg.kind, P.ping_token(msg)) == ("PING", "0a1b2c3d4e5f")
    version, token = P.parse_pong_reply(P.decode_reply(P.pong_reply(7, "0a1b2c3d4e5f")))
    assert (version, token) == (P.PROTOCOL_VERSION, "0a1b2c3d4e5f")


@pytest.mark.parametrize("token", ["", "0a1b2c3d4e5f0", "ABC", "12 4", "xyz", None, 12])
def test_a_bad_session_token_is_refused(token):
    with pytest.raises(P.ProtocolError, match="session token must be 1..12 lower-case hex digits"):
        P.ping_request(1, token)


def test_session_tokens_are_fresh_hex():
    tokens = {P.new_session_token() for _ in range(100)}
    assert len(tokens) == 100 and all(P.check_token(t) == t and len(t) == P.TOKEN_CHARS for t in tokens)


def test_target_and_move_requests_round_trip():
    pose = Pose.from_xyz_quat_wxyz([1234.5678, -12.0, 0.25], [0.5, -0.5, 0.5, -0.5])
    msg = P.decode_request(P.target_request(999, pose))
    back = P.parse_target_request(msg)
    np.testing.assert_allclose(back.translation_mm, [1234.568, -12.0, 0.25], atol=1e-9)
    np.testing.assert_allclose(back.quaternion_wxyz, [0.5, -0.5, 0.5, -0.5], atol=1e-9)
    speed, target = P.parse_movl_request(P.decode_request(P.movl_request(3, 150.04, 999)))
    assert (speed, target) == (150.0, 999)


def test_replies_round_trip_with_the_stated_precision():
    joints = np.array([-179.99994, 12.34567, 0.0, 399.5, -0.00004, 1.0])
    got = P.parse_joints_reply(P.decode_reply(P.joints_reply(5, joints)))
    np.testing.assert_allclose(got, np.round(joints, 4), atol=1e-12)
    rng = np.random.default_rng(1)
    for _ in range(50):
        q = rng.normal(size=4)
        q /= np.linalg.norm(q)
        pose = Pose.from_xyz_quat_wxyz(rng.uniform(-1800, 1800, 3), q)
        line = P.pose_reply(17, pose)
        assert len(line) - 1 <= P.MAX_LINE_CHARS
        back = P.parse_pose_reply(P.decode_reply(line))
        assert np.abs(back.translation - pose.translation).max() <= 0.0005 + 1e-9
        # quaternion (w, x, y, z) to 6 decimals: rotation within 2e-4 deg
        angle = np.degrees(np.linalg.norm(_rotvec(back.rotation_matrix.T @ pose.rotation_matrix)))
        assert angle < 2e-4


def _rotvec(R):
    from spherecal.core.geometry import rotvec_from_matrix

    return rotvec_from_matrix(R)


def test_the_longest_pose_fits_one_rapid_string():
    pose = Pose.from_xyz_quat_wxyz([-1999.999, -1999.999, -1999.999], [0.000001, -0.577350, -0.577350, -0.577351])
    for line in (P.pose_reply(999, pose), P.target_request(999, pose)):
        assert len(line.rstrip(b"\n")) <= 80


def test_error_reply_is_cleaned_and_shortened():
    line = P.error_reply(12, P.ErrorCode.UNREACHABLE, "target * out of reach\n" + "x" * 200)
    assert len(line) - 1 == P.MAX_LINE_CHARS
    msg = P.decode_reply(line)
    code, text = P.parse_error_reply(msg)
    assert (msg.seq, code) == (12, 5)
    assert text.startswith("target ? out of reach x")
    assert P.decode_reply(P.error_reply(None, P.ErrorCode.CHECKSUM, "bad checksum")).seq is None


def test_crlf_and_lower_case_hex_are_accepted():
    body = "OK 3"
    assert P.decode_reply(f"{body}*{P.checksum(body).lower()}\r\n".encode()).kind == "OK"


@pytest.mark.parametrize(
    "line, error, message",
    [
        (b"J 1 0 0 0 0 0 0*00\n", P.ChecksumError, "checksum mismatch"),
        (b"OK 1\n", P.ProtocolError, "without a '\\*XX' checksum"),
        (b"OK 1*Z1\n", P.ProtocolError, "not two hex digits"),
        (b"\xff\xfe*00\n", P.ProtocolError, "non-ASCII"),
        (b"A" * 90 + b"*00\n", P.ProtocolError, "93 characters"),
    ],
)
def test_garbage_lines_raise_clear_errors(line, error, message):
    with pytest.raises(error, match=message):
        P.decode_reply(line)


def _framed(body: str) -> bytes:
    return f"{body}*{P.checksum(body)}\n".encode()


@pytest.mark.parametrize(
    "body, message",
    [
        ("HELLO 1", "unknown reply kind 'HELLO'"),
        ("OK", "has no sequence number"),
        ("OK 1000", "not an integer 0..999"),
        ("OK x", "not an integer"),
        ("J 1 0 0 0", "J takes 6 arguments, got 3"),
        ("OK  1", "single spaces"),
        ("ERR 4 3", "needs a code and a text"),
    ],
)
def test_well_framed_but_wrong_replies_raise(body, message):
    with pytest.raises(P.ProtocolError, match=message):
        P.decode_reply(_framed(body))


def test_bad_numbers_name_the_field():
    with pytest.raises(P.ProtocolError, match="J joint 3: 'abc' is not a number"):
        P.parse_joints_reply(P.decode_reply(_framed("J 1 0 0 abc 0 0 0")))
    with pytest.raises(P.ProtocolError, match="not a finite number"):
        P.parse_joints_reply(P.decode_reply(_framed("J 1 0 0 nan 0 0 0")))
    with pytest.raises(P.ProtocolError, match=r"quaternion \(q1..q4 = w, x, y, z\).*has norm 0.5"):
        P.parse_pose_reply(P.decode_reply(_framed("P 1 0 0 0 0.5 0 0 0")))


def test_encoding_refuses_what_the_controller_could_not_read():
    with pytest.raises(P.ProtocolError, match="sequence number must be an integer 0..999"):
        P.getj_request(1000)
    with pytest.raises(P.ProtocolError, match="speed_mm_s must be finite"):
        P.movl_request(1, float("nan"), 2)
    with pytest.raises(P.ProtocolError, match="exceeds the 80-character line limit"):
        P.frame("x" * 78)
    with pytest.raises(P.ProtocolError, match="without '\\*'"):
        P.frame("OK 1*")


def test_rapid_server_uses_the_same_version_and_error_codes():
    import re
    from importlib import resources

    text = (resources.files("spherecal.robots.abb_irb2400") / "rapid" / "SpherecalServer.mod").read_text()
    consts = {m[0]: int(m[1]) for m in re.findall(r"CONST num (\w+) := (\d+);", text)}
    assert consts["PROTOCOL_VERSION"] == P.PROTOCOL_VERSION
    for code in P.ErrorCode:
        assert consts[f"E_{code.name}"] == code.value, code
    # it reads the flange as tool0 in wobj0, waits in position, and prints enough decimals
    # (WaitTime \InPos, 0 rather than WaitRob \InPos, which the S4C+ lacks)
    assert "CRobT(\\Tool:=tool0 \\WObj:=wobj0)" in text and "WaitTime \\InPos, 0;" in text
    assert not re.search(r"^\s*WaitRob\b", text, re.M)
    assert "NumToStr(p.rot.q1, 6)" in text and "NumToStr(j.robax.rax_1, 4)" in text


def test_rapid_server_stream_requests_match_the_driver():
    """SSTART and SSTOP: the server's error code, period limit and field counts are the
    driver's (a field count off by one would answer every SSTART with ERR 2)."""
    import re
    from importlib import resources

    from spherecal.robots.abb_irb2400 import protocol as SP

    text = (resources.files("spherecal.robots.abb_irb2400") / "rapid" / "SpherecalServer.mod").read_text()
    consts = {m[0]: int(m[1]) for m in re.findall(r"CONST num (\w+) := (\d+);", text)}
    assert consts["E_STREAM"] == SP.ERR_STREAM and SP.ERR_STREAM not in {c.value for c in P.ErrorCode}
    assert consts["MAX_SAMPLE_MS"] == SP.MAX_STREAM_PERIOD_MS
    for kind, n_args in SP.STREAM_REQUEST_ARGS.items():
        assert re.search(rf'CASE "{kind}":\s*want := {n_args + 2};', text), kind


def test_stream_requests_round_trip_and_refuse_bad_periods():
    from spherecal.robots.abb_irb2400 import protocol as SP

    msg = SP.decode_stream_request(SP.stream_start_request(41, 8))
    assert (msg.kind, msg.seq, SP.parse_stream_start(msg)) == ("SSTART", 41, 8)
    assert SP.decode_stream_request(SP.stream_stop_request(999)) == P.Message("SSTOP", 999, ())
    assert SP.decode_stream_request(P.getj_request(3)) is None  # the core protocol's request
    for bad in (0, 6, 3.5, 104, True):
        with pytest.raises(P.ProtocolError, match="multiple of 4 ms in 4..100"):
            SP.stream_start_request(1, bad)
    with pytest.raises(P.ProtocolError, match="SSTART takes 1 arguments, got 0"):
        SP.decode_stream_request(P.frame("SSTART 5"))

