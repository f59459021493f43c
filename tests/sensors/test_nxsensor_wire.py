"""The assumed nxSensor-I wire format: round trips, known bytes, malformed frames."""

import struct
import zlib

import numpy as np
import pytest
from pydantic import ValidationError

from spherecal.core.errors import DeviceError, InputError
from spherecal.sensors.nxsensor_i.wire import (
    Command,
    ControlSetup,
    FrameFormatError,
    WireConfig,
    decode_bulk_command,
    decode_control_command,
    decode_frame,
    encode_bulk_command,
    encode_control_command,
    encode_frame,
)

DEFAULT = WireConfig()
# A deliberately different layout: big-endian, int32 counts in (z, y) order, a padded
# header without timestamp, a u16 magic, finer scale, CRC-32 trailer.
OTHER = WireConfig(
    byte_order="big",
    count_type="i32",
    point_order="zy",
    header_layout=(("magic", "u16"), ("pad", "u16"), ("frame_counter", "u16"), ("point_count", "u32")),
    frame_magic=0xBEEF,
    y_scale_mm_per_count=0.001,
    y_offset_mm=1.5,
    z_scale_mm_per_count=0.002,
    z_offset_mm=-20.0,
    invalid_count=2**31 - 1,
    checksum="crc32",
)


def _points_in_range(rng, n):
    """(y, z) mm over the nxSensor-I's field of view (z -60..+40, |y| <= 24)."""
    return np.column_stack([rng.uniform(-24.0, 24.0, n), rng.uniform(-60.0, 40.0, n)])


@pytest.mark.parametrize("cfg", [DEFAULT, OTHER], ids=["default", "other-layout"])
def test_round_trip_within_half_a_count(cfg):
    rng = np.random.default_rng(7)
    pts = _points_in_range(rng, 500)
    frame = decode_frame(encode_frame(pts, cfg, frame_counter=41, timestamp_us=123, flags=2), cfg)
    assert frame.frame_counter == 41
    assert frame.n_invalid == 0
    assert frame.points_mm.shape == pts.shape
    err = np.abs(frame.points_mm - pts)
    assert np.all(err[:, 0] <= cfg.y_scale_mm_per_count / 2 + 1e-12)
    assert np.all(err[:, 1] <= cfg.z_scale_mm_per_count / 2 + 1e-12)
    # counts are exact: encoding the decoded points again gives the same bytes
    again = encode_frame(frame.points_mm, cfg, frame_counter=41, timestamp_us=123, flags=2)
    assert again == encode_frame(pts, cfg, frame_counter=41, timestamp_us=123, flags=2)


def test_default_frame_bytes_known_answer():
    # y = 0.005 mm -> count 1; z = -10 mm (the offset) -> count 0; z = +40 mm -> 10000
    data = encode_frame([[0.005, -10.0], [-24.0, 40.0]], DEFAULT, frame_counter=258, timestamp_us=1000, flags=0)
    expected = (
        b"NXPF"
        + struct.pack("<IIHH", 258, 1000, 2, 0)
        + struct.pack("<hhhh", 1, 0, -4800, 10000)
    )
    assert data == expected
    assert DEFAULT.header_struct.size == 16
    assert DEFAULT.usb_id == "04b4:5a01"


def test_invalid_points_are_dropped_in_order():
    pts = np.array([[1.0, 2.0], [3.0, 4.0], [5.0, 6.0]])
    data = bytearray(encode_frame(pts, DEFAULT, frame_counter=0, pad_to=6))
    # mark the middle point invalid in z only: the whole point goes
    struct.pack_into("<h", data, 16 + 4 * 1 + 2, DEFAULT.invalid_count)
    frame = decode_frame(bytes(data), DEFAULT)
    assert frame.n_invalid == 4  # 3 padding records + the marked one
    np.testing.assert_allclose(frame.points_mm, pts[[0, 2]], atol=0.0025)


def test_all_invalid_frame_gives_no_points():
    frame = decode_frame(encode_frame(np.empty((0, 2)), DEFAULT, frame_counter=5, pad_to=640), DEFAULT)
    assert frame.points_mm.shape == (0, 2)
    assert frame.n_invalid == 640


def test_unrepresentable_points():
    far = [[0.0, -300.0]]  # z count -58000 does not fit int16
    with pytest.raises(InputError, match=r"point 0 .* cannot be represented as i16 counts"):
        encode_frame(far, DEFAULT, frame_counter=0)
    frame = decode_frame(encode_frame(far, DEFAULT, frame_counter=0, out_of_range="invalid"), DEFAULT)
    assert frame.n_invalid == 1 and len(frame.points_mm) == 0
    with pytest.raises(InputError, match="NaN"):
        encode_frame([[np.nan, 0.0]], DEFAULT, frame_counter=0)


def test_frame_counter_wraps_at_its_field_width():
    frame = decode_frame(encode_frame([[0.0, 0.0]], OTHER, frame_counter=70000), OTHER)
    assert OTHER.frame_counter_modulus == 65536
    assert frame.frame_counter == 70000 - 65536


# --- malformed frames ---------------------------------------------------------------------

GOOD = encode_frame([[1.0, 2.0], [3.0, 4.0]], DEFAULT, frame_counter=9)


def test_short_header():
    with pytest.raises(FrameFormatError, match=r"short frame: 7 bytes, the header alone needs 16"):
        decode_frame(GOOD[:7], DEFAULT)


def test_bad_magic():
    bad = b"XXPF" + GOOD[4:]
    with pytest.raises(FrameFormatError, match=r"bad frame magic 0x46505858, expected 0x4650584e"):
        decode_frame(bad, DEFAULT)


def test_truncated_records():
    with pytest.raises(FrameFormatError, match=r"short frame: header says 2 points \(24 bytes in all\) but only 22"):
        decode_frame(GOOD[:-2], DEFAULT)


def test_count_mismatch_extra_bytes():
    with pytest.raises(FrameFormatError, match=r"point count mismatch: header says 2 points \(24 bytes\) but the frame has 28"):
        decode_frame(GOOD + bytes(4), DEFAULT)


def test_point_count_above_max_points():
    cfg = WireConfig(max_points=4)
    data = bytearray(encode_frame([[0.0, 0.0]], cfg, frame_counter=0))
    struct.pack_into("<H", data, 12, 5)
    with pytest.raises(FrameFormatError, match="header says 5 points, more than max_points = 4"):
        decode_frame(bytes(data), cfg)
    with pytest.raises(InputError, match="max_points is 4"):
        encode_frame(np.zeros((5, 2)), cfg, frame_counter=0)


def test_checksum_mismatch():
    data = bytearray(encode_frame([[1.0, 2.0]], OTHER, frame_counter=1))
    data[-5] ^= 0x01  # a bit of the last record
    with pytest.raises(FrameFormatError, match="frame checksum mismatch"):
        decode_frame(bytes(data), OTHER)
    # and the trailer is the zlib CRC-32 of everything before it, big-endian here
    good = encode_frame([[1.0, 2.0]], OTHER, frame_counter=1)
    assert struct.unpack(">I", good[-4:])[0] == zlib.crc32(good[:-4])


def test_frame_format_error_is_a_device_error():
    assert issubclass(FrameFormatError, DeviceError)


# --- commands -------------------------------------------------------------------------------

def test_control_command_known_answer_and_round_trip():
    setup = encode_control_command(Command("set_period", 100_000), DEFAULT)
    assert setup == ControlSetup(bmRequestType=0x40, bRequest=0x11, wValue=0x86A0, wIndex=0x0001)
    assert decode_control_command(setup, DEFAULT) == Command("set_period", 100_000)


@pytest.mark.parametrize("name", ["set_exposure", "set_period", "trigger", "start_stream", "stop_stream"])
def test_bulk_command_round_trip(name):
    packet = encode_bulk_command(Command(name, 0xDEADBEEF), DEFAULT)
    assert len(packet) == 8 and packet[:2] == b"NC"
    assert decode_bulk_command(packet, DEFAULT) == Command(name, 0xDEADBEEF)


def test_bad_commands():
    with pytest.raises(InputError, match="unknown nxSensor-I command 'fire'"):
        encode_bulk_command(Command("fire"), DEFAULT)
    with pytest.raises(InputError, match="unsigned 32-bit"):
        encode_control_command(Command("set_exposure", -1), DEFAULT)
    with pytest.raises(FrameFormatError, match="bulk command packet has 3 bytes, expected 8"):
        decode_bulk_command(b"abc", DEFAULT)
    with pytest.raises(FrameFormatError, match="unknown command code 0x7f"):
        decode_bulk_command(struct.pack("<HHI", 0x434E, 0x7F, 0), DEFAULT)


# --- configuration ----------------------------------------------------------------------------

@pytest.mark.parametrize(
    "fields, message",
    [
        ({"commands": {"trigger": 0x10}}, "command codes set_exposure and trigger are both 0x10"),
        ({"invalid_count": 40000}, r"invalid_count 40000 does not fit count_type i16"),
        ({"header_layout": [["frame_counter", "u32"], ["point_count", "u16"]]}, "must contain 'magic' exactly once"),
        ({"frame_magic": 0x1_0000_0000}, "does not fit the header's magic field"),
        ({"bulk_in_endpoint": 0x02}, "bulk_in_endpoint"),
        ({"vendor_id": 0x10000}, "vendor_id"),
        ({"vendor_idd": 1}, "vendor_idd"),
    ],
)
def test_config_rejects(fields, message):
    with pytest.raises(ValidationError, match=message):
        WireConfig.model_validate(fields)


@pytest.mark.parametrize("marks, shift_s", [("exposure_start", 100e-6), ("exposure_middle", 0.0),
                                            ("exposure_end", -100e-6)])
def test_a_stamp_is_moved_to_the_exposure_middle(marks, shift_s):
    assert WireConfig(timestamp_marks=marks).exposure_middle_shift_s(200) == pytest.approx(shift_s)


def test_the_timestamp_wraps_at_its_header_type():
    assert DEFAULT.timestamp_modulus == 1 << 32
    u16 = WireConfig(header_layout=(("magic", "u32"), ("frame_counter", "u32"), ("timestamp_us", "u16"),
                                    ("point_count", "u16")))
    assert u16.timestamp_modulus == 1 << 16
    assert WireConfig(header_layout=(("magic", "u32"), ("frame_counter", "u32"),
                                     ("point_count", "u16"))).timestamp_modulus is None
