"""The EgmRobot message subset against the wire format, encoded by hand here.

The bytes below are built field by field from ABB's published field numbers (egm.proto:
EgmRobot header 1, feedBack 2, planned 3, motorState 4, mciState 5, rapidExecState 8;
EgmHeader seqno 1, tm 2, mtype 3; EgmFeedBack joints 1, cartesian 2, time 4; EgmPose pos
1, orient 2; EgmQuaternion u0..u3 1..4; EgmClock sec 1, usec 2), independently of the
module's descriptor: a wrong field number there decodes these bytes wrongly and fails.
"""

from __future__ import annotations

import struct

import pytest

from spherecal.robots.abb_irb2400.egm_messages import (EgmDecodeError, EgmSample, decode_egm_robot,
                                                       encode_egm_robot)


# --- a hand encoder of the protobuf wire format ---------------------------------------------------
def varint(n: int) -> bytes:
    out = bytearray()
    while True:
        b = n & 0x7F
        n >>= 7
        out.append(b | (0x80 if n else 0))
        if not n:
            return bytes(out)


def uint(field: int, n: int) -> bytes:
    return varint(field << 3 | 0) + varint(n)


def double(field: int, x: float) -> bytes:
    return varint(field << 3 | 1) + struct.pack("<d", x)


def sub(field: int, payload: bytes) -> bytes:
    return varint(field << 3 | 2) + varint(len(payload)) + payload


def pose_bytes(xyz, q):
    return sub(1, b"".join(double(i + 1, v) for i, v in enumerate(xyz))) + \
        sub(2, b"".join(double(i + 1, v) for i, v in enumerate(q)))


def joints_bytes(joints, packed=False):
    if packed:
        return sub(1, b"".join(struct.pack("<d", v) for v in joints))
    return b"".join(double(1, v) for v in joints)


JOINTS = (10.5, -20.25, 30.0, -40.0, 50.0, -60.125)
XYZ = (855.125, -12.5, 1370.0625)
Q = (0.5, -0.5, 0.5, 0.5)  # (w, x, y, z): u0 is the scalar
PLANNED_XYZ = (856.0, -12.0, 1371.0)


def robot_bytes(seqno=4_294_967_290, packed=False, with_time=True):
    header = uint(1, seqno) + uint(2, 123_456_789) + uint(3, 2)
    feedback = sub(1, joints_bytes(JOINTS, packed)) + sub(2, pose_bytes(XYZ, Q))
    if with_time:
        feedback += sub(4, uint(1, 1_700_000_123) + uint(2, 456_789))
    planned = sub(2, pose_bytes(PLANNED_XYZ, (1.0, 0.0, 0.0, 0.0)))
    test_signals = sub(7, double(1, 99.0))  # a field this subset leaves out: skipped
    return (sub(1, header) + sub(2, feedback) + sub(3, planned) + sub(4, uint(1, 1)) + sub(5, uint(1, 3))
            + test_signals + sub(8, uint(1, 2)) + double(10, 0.25))


# --- decoding --------------------------------------------------------------------------------------
@pytest.mark.parametrize("packed", [False, True], ids=["joints unpacked (proto2)", "joints packed"])
def test_hand_encoded_message_decodes_field_by_field(packed):
    s = decode_egm_robot(robot_bytes(packed=packed))
    assert s.seqno == 4_294_967_290 and s.tm_ms == 123_456_789 and s.mtype == 2
    assert s.translation_mm == XYZ and s.quaternion_wxyz == Q and s.joints_deg == JOINTS
    assert (s.time_sec, s.time_usec) == (1_700_000_123, 456_789)
    assert s.time_s == pytest.approx(1_700_000_123.456789, abs=1e-6)
    assert s.planned_translation_mm == PLANNED_XYZ and s.planned_quaternion_wxyz == (1.0, 0.0, 0.0, 0.0)
    assert (s.motor_state, s.mci_state, s.rapid_exec_state) == (1, 3, 2)


def test_a_message_without_the_feedback_clock_has_no_time():
    s = decode_egm_robot(robot_bytes(with_time=False))
    assert s.time_s is None and s.tm_ms == 123_456_789


@pytest.mark.parametrize("data, message", [
    (b"\xff\xff\xff", "is not an EgmRobot message"),
    (sub(2, sub(2, pose_bytes(XYZ, Q))), "without header.seqno"),
    (sub(1, uint(1, 7)), "seqno 7 carries no feedBack.cartesian"),
    (sub(1, uint(1, 7)) + sub(2, sub(2, sub(1, double(1, 1.0)) + sub(2, double(1, 1.0)))), "is not an EgmRobot"),
])
def test_what_is_not_a_measured_pose_is_refused(data, message):
    with pytest.raises(EgmDecodeError, match=message):
        decode_egm_robot(data)


# --- encoding: read back by a hand wire parser ------------------------------------------------------
def parse(data: bytes) -> dict[int, list]:
    """Field number -> values (varint ints, doubles, or raw bytes of a length-delimited field)."""
    out: dict[int, list] = {}
    i = 0

    def read_varint():
        nonlocal i
        n = shift = 0
        while True:
            b = data[i]
            i += 1
            n |= (b & 0x7F) << shift
            shift += 7
            if not b & 0x80:
                return n

    while i < len(data):
        key = read_varint()
        field, wire = key >> 3, key & 7
        if wire == 0:
            value = read_varint()
        elif wire == 1:
            value = struct.unpack("<d", data[i:i + 8])[0]
            i += 8
        elif wire == 2:
            n = read_varint()
            value = data[i:i + n]
            i += n
        else:  # pragma: no cover
            raise AssertionError(f"wire type {wire}")
        out.setdefault(field, []).append(value)
    return out


def test_the_encoder_writes_abbs_field_numbers():
    sample = EgmSample(seqno=2**32 + 5, tm_ms=2**32 + 9, mtype=2, translation_mm=XYZ, quaternion_wxyz=Q,
                       joints_deg=JOINTS, time_sec=1_700_000_000, time_usec=999_999, motor_state=1, mci_state=3,
                       rapid_exec_state=2)
    top = parse(encode_egm_robot(sample))
    header = parse(top[1][0])
    assert header == {1: [5], 2: [9], 3: [2]}  # uint32 fields wrap
    feedback = parse(top[2][0])
    assert tuple(parse(feedback[1][0])[1]) == JOINTS
    cart = parse(feedback[2][0])
    assert tuple(v for f in (1, 2, 3) for v in parse(cart[1][0])[f]) == XYZ
    assert tuple(v for f in (1, 2, 3, 4) for v in parse(cart[2][0])[f]) == Q
    assert parse(feedback[4][0]) == {1: [1_700_000_000], 2: [999_999]}
    assert parse(top[4][0]) == {1: [1]} and parse(top[5][0]) == {1: [3]} and parse(top[8][0]) == {1: [2]}
    assert 3 not in top  # no planned pose given, none sent


def test_encode_decode_round_trip_and_non_finite_pose_refused():
    sample = EgmSample(seqno=1, tm_ms=2, mtype=2, translation_mm=XYZ, quaternion_wxyz=Q, joints_deg=JOINTS,
                       time_sec=3, time_usec=4)
    back = decode_egm_robot(encode_egm_robot(sample))
    assert (back.seqno, back.translation_mm, back.quaternion_wxyz, back.joints_deg, back.time_s) == (
        1, XYZ, Q, JOINTS, 3.000004)
    with pytest.raises(ValueError, match="seqno 1: the pose is not finite"):
        encode_egm_robot(EgmSample(seqno=1, tm_ms=None, mtype=2, translation_mm=(float("nan"), 0, 0),
                                   quaternion_wxyz=Q))
