"""The ASSUMED USB wire format of the NextWare nxSensor-I, in one place.

NextWare never published the sensor's USB protocol. Everything in this module is the
project's documented *assumption* of it: the numbers (vendor and product id, interface,
endpoints, command codes, frame header, point record, count-to-mm scaling, invalid-point
marker) are fields of :class:`WireConfig` with plausible defaults, so that the driver can
be matched to a real unit by changing configuration only (see
``docs/sensor-nxsensor-i.md``, "Matching a real unit"). No other module of the plugin
knows a byte offset or a command code.

Assumed protocol (defaults in brackets):

* Commands go host -> device either as vendor control requests on endpoint 0
  [``command_transport="control"``: bmRequestType 0x40 (OUT | vendor | device),
  bRequest = command code, wValue = low 16 bits of the 32-bit argument, wIndex = high 16
  bits, no data stage] or as an 8-byte packet on the bulk OUT endpoint
  [``"bulk"``: command magic u16, command code u16, argument u32].
  Commands: set exposure (argument: microseconds), set frame period (argument:
  microseconds, i.e. 1e6 / rate in Hz), trigger one profile, start streaming,
  stop streaming.
* Every profile arrives as one bulk IN transfer (a *frame*): a header (by default
  magic u32 = b"NXPF", frame counter u32, timestamp u32 in microseconds, point count
  u16, flags u16; little-endian), then ``point count`` records of two signed integer
  counts (by default int16 y then int16 z), then an optional CRC-32 trailer [none].
* The timestamp counts ``timestamp_us_per_count`` microseconds of the sensor's own clock
  [1 us] and wraps at 2^bits of its header type [u32: every 71.6 min]; it gives the start
  of the exposure [``timestamp_marks="exposure_start"``]. While streaming, the sensor
  measures one frame every set period on its own clock (internally triggered) and numbers
  every frame it measures, sent or not (:mod:`.stamps` unwraps both counters).
* A point is invalid when its y or z count equals ``invalid_count`` [-32768]; invalid
  points are dropped on decoding.
* Counts become millimetres as ``mm = offset_mm + count * scale_mm_per_count`` [scale
  0.005 mm (the sensor's 5 um resolution) for both axes; offset 0 mm for y and -10 mm
  for z, the middle of the -60 .. +40 mm range, so that int16 covers the whole range].

Coordinates are the sensor frame's (y, z) in mm, z positive towards the sensor
(``docs/conventions.md``).
"""

from __future__ import annotations

import struct
import zlib
from dataclasses import dataclass
from typing import Literal

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, field_validator, model_validator

from spherecal.plugins import DeviceError, InputError

HeaderField = Literal["magic", "frame_counter", "timestamp_us", "point_count", "flags", "pad"]
IntType = Literal["u8", "u16", "u32", "i8", "i16", "i32"]

_STRUCT_CODE = {"u8": "B", "u16": "H", "u32": "I", "i8": "b", "i16": "h", "i32": "i"}
_NUMPY_CODE = {"i16": "i2", "i32": "i4"}
_BITS = {"u8": 8, "u16": 16, "u32": 32, "i8": 8, "i16": 16, "i32": 32}


class FrameFormatError(DeviceError):
    """A frame from the sensor does not match the configured (assumed) wire format."""


class CommandCodes(BaseModel):
    """Command codes (vendor bRequest values, or the code field of a bulk command).
    ASSUMED values: check them against the real device."""

    model_config = ConfigDict(defer_build=True, frozen=True, extra="forbid")

    set_exposure: int = Field(0x10, ge=0, le=0xFF, description="set exposure time; argument in microseconds (us)")
    set_period: int = Field(0x11, ge=0, le=0xFF, description="set streaming frame period; argument in microseconds (us)")
    trigger: int = Field(0x20, ge=0, le=0xFF, description="measure and send one profile; argument unused (0)")
    start_stream: int = Field(0x21, ge=0, le=0xFF, description="start sending profiles at the set period; argument unused (0)")
    stop_stream: int = Field(0x22, ge=0, le=0xFF, description="stop streaming; argument unused (0)")

    @model_validator(mode="after")
    def _distinct(self):
        codes = self.model_dump()
        seen: dict[int, str] = {}
        for name, code in codes.items():
            if code in seen:
                raise ValueError(f"command codes {seen[code]} and {name} are both {code:#04x}; codes must differ")
            seen[code] = name
        return self


class WireConfig(BaseModel):
    """The assumed USB wire format of the nxSensor-I. Every default is an ASSUMPTION
    (the protocol is not public); change these fields, not the code, to match a unit."""

    model_config = ConfigDict(defer_build=True, frozen=True, extra="forbid")

    # --- identity and topology ---------------------------------------------------------
    vendor_id: int = Field(
        0x04B4, ge=0, le=0xFFFF,
        description="USB idVendor, unitless 16-bit id (default 0x04B4, write hex in TOML). Assumed: Cypress, maker of the FX2 USB controller",
    )
    product_id: int = Field(0x5A01, ge=0, le=0xFFFF, description="USB idProduct, unitless 16-bit id (default 0x5A01). Assumed placeholder")
    configuration_value: int = Field(1, ge=1, le=255, description="bConfigurationValue to select (unitless)")
    interface: int = Field(0, ge=0, le=255, description="bInterfaceNumber holding the bulk endpoints (unitless)")
    bulk_in_endpoint: int = Field(0x82, ge=0x81, le=0x8F, description="bEndpointAddress of the bulk IN (profile) endpoint")
    bulk_out_endpoint: int = Field(0x01, ge=0x01, le=0x0F, description="bEndpointAddress of the bulk OUT (command) endpoint")
    max_packet_size: int = Field(512, ge=8, le=1024, description="wMaxPacketSize of the bulk endpoints, bytes (512: high speed)")

    # --- commands ----------------------------------------------------------------------
    command_transport: Literal["control", "bulk"] = Field(
        "control", description="how commands travel: vendor control requests on EP0, or packets on the bulk OUT endpoint"
    )
    command_request_type: int = Field(0x40, ge=0, le=0x7F, description="bmRequestType of command control transfers (OUT, vendor, device)")
    command_magic: int = Field(0x434E, ge=0, le=0xFFFF, description="first u16 of a bulk command packet (b'NC' little-endian)")
    commands: CommandCodes = Field(default_factory=CommandCodes, description="command codes")

    # --- frames ------------------------------------------------------------------------
    byte_order: Literal["little", "big"] = Field("little", description="byte order of every multi-byte field")
    frame_magic: int = Field(0x4650584E, ge=0, description="value of the header's magic field (b'NXPF' as little-endian u32)")
    header_layout: tuple[tuple[HeaderField, IntType], ...] = Field(
        (("magic", "u32"), ("frame_counter", "u32"), ("timestamp_us", "u32"), ("point_count", "u16"), ("flags", "u16")),
        description="frame header fields in order, each (name, integer type); magic, frame_counter and point_count "
        "are required, 'pad' may repeat; timestamp in microseconds",
    )
    point_order: Literal["yz", "zy"] = Field("yz", description="order of the two counts in a point record")
    count_type: Literal["i16", "i32"] = Field("i16", description="signed integer type of each count")
    y_scale_mm_per_count: float = Field(0.005, gt=0, description="y: mm per count (5 um resolution)")
    y_offset_mm: float = Field(0.0, description="y: mm at count 0")
    z_scale_mm_per_count: float = Field(0.005, gt=0, description="z: mm per count (5 um resolution)")
    z_offset_mm: float = Field(-10.0, description="z: mm at count 0 (middle of the -60 .. +40 mm range)")
    invalid_count: int = Field(-32768, description="count marking an invalid point (in y or z); must fit count_type")
    max_points: int = Field(2048, ge=1, le=65535, description="most points one frame may carry (points)")
    timestamp_us_per_count: float = Field(
        1.0, gt=0, le=1e6,
        description="microseconds of the sensor's clock per count of the header's timestamp_us field (us per count; "
        "the field wraps at 2^bits counts)",
    )
    timestamp_marks: Literal["exposure_start", "exposure_middle", "exposure_end"] = Field(
        "exposure_start",
        description="which moment of the exposure a frame's timestamp gives; the driver turns it into the "
        "exposure's middle with exposure_us",
    )
    checksum: Literal["none", "crc32"] = Field("none", description="frame trailer: none, or CRC-32 (zlib) of header + records as u32")

    @field_validator("header_layout")
    @classmethod
    def _check_layout(cls, layout):
        names = [name for name, _ in layout]
        for required in ("magic", "frame_counter", "point_count"):
            if names.count(required) != 1:
                raise ValueError(f"header_layout must contain {required!r} exactly once, got fields {names}")
        for name in ("timestamp_us", "flags"):
            if names.count(name) > 1:
                raise ValueError(f"header_layout contains {name!r} more than once: {names}")
        for name, typ in layout:
            if name != "pad" and typ.startswith("i"):
                raise ValueError(f"header field {name!r} must be unsigned (u8/u16/u32), got {typ}")
        return layout

    @model_validator(mode="after")
    def _check(self):
        magic_type = dict(self.header_layout)["magic"]
        if self.frame_magic >= 1 << _BITS[magic_type]:
            raise ValueError(f"frame_magic {self.frame_magic:#x} does not fit the header's magic field ({magic_type})")
        count_type = dict(self.header_layout)["point_count"]
        if self.max_points >= 1 << _BITS[count_type]:
            raise ValueError(f"max_points {self.max_points} does not fit the header's point_count field ({count_type})")
        lo, hi = self.count_range
        if not lo <= self.invalid_count <= hi:
            raise ValueError(f"invalid_count {self.invalid_count} does not fit count_type {self.count_type} ({lo} .. {hi})")
        return self

    # --- derived sizes -----------------------------------------------------------------
    @property
    def struct_byte_order(self) -> str:
        return "<" if self.byte_order == "little" else ">"

    @property
    def header_struct(self) -> struct.Struct:
        codes = "".join(
            f"{_BITS[typ] // 8}x" if name == "pad" else _STRUCT_CODE[typ] for name, typ in self.header_layout
        )
        return struct.Struct(self.struct_byte_order + codes)

    @property
    def header_names(self) -> list[str]:
        return [name for name, _ in self.header_layout if name != "pad"]

    @property
    def record_dtype(self) -> np.dtype:
        code = ("<" if self.byte_order == "little" else ">") + _NUMPY_CODE[self.count_type]
        return np.dtype([(self.point_order[0], code), (self.point_order[1], code)])

    @property
    def trailer_size(self) -> int:
        return 4 if self.checksum == "crc32" else 0

    @property
    def max_frame_bytes(self) -> int:
        """Largest frame, bytes: what the driver asks one bulk read for."""
        return self.header_struct.size + self.max_points * self.record_dtype.itemsize + self.trailer_size

    @property
    def count_range(self) -> tuple[int, int]:
        bits = _BITS[self.count_type]
        return -(1 << (bits - 1)), (1 << (bits - 1)) - 1

    @property
    def frame_counter_modulus(self) -> int:
        """The frame counter wraps to 0 at this value."""
        return 1 << _BITS[dict(self.header_layout)["frame_counter"]]

    @property
    def timestamp_modulus(self) -> int | None:
        """The header's timestamp wraps to 0 at this count; None when the header has no
        timestamp (a stream then cannot be stamped)."""
        typ = dict(self.header_layout).get("timestamp_us")
        return None if typ is None else 1 << _BITS[typ]

    def exposure_middle_shift_s(self, exposure_us: float) -> float:
        """Seconds to add to a frame's timestamp to get the middle of its exposure."""
        half = 0.5e-6 * exposure_us
        return {"exposure_start": half, "exposure_middle": 0.0, "exposure_end": -half}[self.timestamp_marks]

    @property
    def usb_id(self) -> str:
        """'vvvv:pppp' as lsusb prints it."""
        return f"{self.vendor_id:04x}:{self.product_id:04x}"


# --- commands ------------------------------------------------------------------------------

@dataclass(frozen=True)
class Command:
    """One command: its name (a field of :class:`CommandCodes`) and 32-bit argument."""

    name: str
    argument: int = 0


@dataclass(frozen=True)
class ControlSetup:
    """The setup packet of a command sent as a vendor control transfer (no data stage)."""

    bmRequestType: int
    bRequest: int
    wValue: int
    wIndex: int


def _code(cfg: WireConfig, name: str) -> int:
    try:
        return getattr(cfg.commands, name)
    except AttributeError:
        raise InputError(f"unknown nxSensor-I command {name!r}; known: {sorted(CommandCodes.model_fields)}") from None


def _check_argument(command: Command) -> None:
    if not 0 <= command.argument <= 0xFFFFFFFF:
        raise InputError(f"argument of command {command.name!r} must fit an unsigned 32-bit integer, got {command.argument}")


def encode_control_command(command: Command, cfg: WireConfig) -> ControlSetup:
    """Setup packet for a command sent on endpoint 0 (``command_transport="control"``)."""
    _check_argument(command)
    return ControlSetup(cfg.command_request_type, _code(cfg, command.name), command.argument & 0xFFFF, command.argument >> 16)


def decode_control_command(setup: ControlSetup, cfg: WireConfig) -> Command:
    """Inverse of :func:`encode_control_command` (used by the simulated device)."""
    if setup.bmRequestType != cfg.command_request_type:
        raise FrameFormatError(f"bmRequestType {setup.bmRequestType:#04x} is not the command type {cfg.command_request_type:#04x}")
    return Command(_name_of(setup.bRequest, cfg), (setup.wIndex << 16) | setup.wValue)


def encode_bulk_command(command: Command, cfg: WireConfig) -> bytes:
    """8-byte packet for a command sent on the bulk OUT endpoint (``command_transport="bulk"``)."""
    _check_argument(command)
    return struct.pack(cfg.struct_byte_order + "HHI", cfg.command_magic, _code(cfg, command.name), command.argument)


def decode_bulk_command(data: bytes, cfg: WireConfig) -> Command:
    """Inverse of :func:`encode_bulk_command` (used by the simulated device)."""
    data = bytes(data)
    if len(data) != 8:
        raise FrameFormatError(f"bulk command packet has {len(data)} bytes, expected 8")
    magic, code, argument = struct.unpack(cfg.struct_byte_order + "HHI", data)
    if magic != cfg.command_magic:
        raise FrameFormatError(f"bulk command magic {magic:#06x} is not {cfg.command_magic:#06x}")
    return Command(_name_of(code, cfg), argument)


def _name_of(code: int, cfg: WireConfig) -> str:
    for name, value in cfg.commands.model_dump().items():
        if value == code:
            return name
    raise FrameFormatError(f"unknown command code {code:#04x}")


# --- frames --------------------------------------------------------------------------------

@dataclass(frozen=True)
class Frame:
    """A decoded profile frame. ``points_mm`` (N, 2) holds (y, z) in mm of the valid
    points, in the order the sensor sent them; ``n_invalid`` counts the dropped ones."""

    frame_counter: int
    timestamp_us: int
    flags: int
    points_mm: np.ndarray
    n_invalid: int


def counts_from_mm(points_mm, cfg: WireConfig) -> tuple[np.ndarray, np.ndarray]:
    """(y, z) mm -> nearest integer counts. Returns (counts (N, 2) int64, representable
    mask (N,)); a point is not representable when a count falls outside ``count_type`` or
    on ``invalid_count``."""
    p = np.asarray(points_mm, dtype=float).reshape(-1, 2)
    if not np.all(np.isfinite(p)):
        raise InputError("profile points contain NaN or infinite values; cannot encode them")
    y = np.rint((p[:, 0] - cfg.y_offset_mm) / cfg.y_scale_mm_per_count)
    z = np.rint((p[:, 1] - cfg.z_offset_mm) / cfg.z_scale_mm_per_count)
    lo, hi = cfg.count_range
    ok = (y >= lo) & (y <= hi) & (z >= lo) & (z <= hi) & (y != cfg.invalid_count) & (z != cfg.invalid_count)
    counts = np.column_stack([np.where(ok, y, cfg.invalid_count), np.where(ok, z, cfg.invalid_count)]).astype(np.int64)
    return counts, ok


def mm_from_counts(counts, cfg: WireConfig) -> np.ndarray:
    """Integer counts (N, 2) (y, z) -> mm (N, 2)."""
    c = np.asarray(counts, dtype=float).reshape(-1, 2)
    return np.column_stack(
        [cfg.y_offset_mm + c[:, 0] * cfg.y_scale_mm_per_count, cfg.z_offset_mm + c[:, 1] * cfg.z_scale_mm_per_count]
    )


def encode_frame(
    points_mm,
    cfg: WireConfig,
    frame_counter: int,
    timestamp_us: int = 0,
    flags: int = 0,
    pad_to: int | None = None,
    out_of_range: Literal["error", "invalid"] = "error",
) -> bytes:
    """Encode (N, 2) (y, z) mm points as one frame.

    ``pad_to`` appends invalid records up to that many points (a sensor sends one record
    per column, hit or not). ``out_of_range="invalid"`` sends points that counts cannot
    represent as invalid records; ``"error"`` raises :class:`InputError`."""
    counts, ok = counts_from_mm(points_mm, cfg)
    if not np.all(ok) and out_of_range == "error":
        bad = int(np.flatnonzero(~ok)[0])
        raise InputError(
            f"point {bad} (y, z) = {np.asarray(points_mm, dtype=float).reshape(-1, 2)[bad].tolist()} mm cannot be "
            f"represented as {cfg.count_type} counts with the configured scale and offset"
        )
    n_pad = max(0, (pad_to or 0) - len(counts))
    if n_pad:
        counts = np.vstack([counts, np.full((n_pad, 2), cfg.invalid_count, dtype=np.int64)])
    if len(counts) > cfg.max_points:
        raise InputError(f"frame would carry {len(counts)} points; max_points is {cfg.max_points}")
    records = np.zeros(len(counts), dtype=cfg.record_dtype)
    records["y"] = counts[:, 0]
    records["z"] = counts[:, 1]
    values = {
        "magic": cfg.frame_magic,
        "frame_counter": frame_counter % cfg.frame_counter_modulus,
        "timestamp_us": timestamp_us,
        "point_count": len(counts),
        "flags": flags,
    }
    header = cfg.header_struct.pack(*(values[name] for name in cfg.header_names))
    body = header + records.tobytes()
    if cfg.checksum == "crc32":
        body += struct.pack(cfg.struct_byte_order + "I", zlib.crc32(body))
    return body


def decode_frame(data, cfg: WireConfig) -> Frame:
    """Decode one frame; invalid points are dropped, counts converted to mm.

    Raises :class:`FrameFormatError` on a short frame, a wrong magic, a point count above
    ``max_points``, a length that disagrees with the point count, or a bad checksum."""
    data = bytes(data)
    hs = cfg.header_struct
    if len(data) < hs.size:
        raise FrameFormatError(
            f"short frame: {len(data)} bytes, the header alone needs {hs.size} (wire.header_layout)"
        )
    header = dict(zip(cfg.header_names, hs.unpack_from(data)))
    if header["magic"] != cfg.frame_magic:
        raise FrameFormatError(
            f"bad frame magic {header['magic']:#x}, expected {cfg.frame_magic:#x} (wire.frame_magic); "
            "the stream is out of step or the wire format does not match this device"
        )
    n = header["point_count"]
    if n > cfg.max_points:
        raise FrameFormatError(f"frame header says {n} points, more than max_points = {cfg.max_points}")
    expected = hs.size + n * cfg.record_dtype.itemsize + cfg.trailer_size
    if len(data) < expected:
        raise FrameFormatError(
            f"short frame: header says {n} points ({expected} bytes in all) but only {len(data)} bytes arrived"
        )
    if len(data) > expected:
        raise FrameFormatError(
            f"point count mismatch: header says {n} points ({expected} bytes) but the frame has {len(data)} bytes"
        )
    if cfg.checksum == "crc32":
        (crc,) = struct.unpack_from(cfg.struct_byte_order + "I", data, expected - 4)
        actual = zlib.crc32(data[: expected - 4])
        if crc != actual:
            raise FrameFormatError(f"frame checksum mismatch: trailer {crc:#010x}, computed {actual:#010x}")
    records = np.frombuffer(data, dtype=cfg.record_dtype, count=n, offset=hs.size)
    counts = np.column_stack([records["y"].astype(np.int64), records["z"].astype(np.int64)])
    valid = (counts[:, 0] != cfg.invalid_count) & (counts[:, 1] != cfg.invalid_count)
    return Frame(
        frame_counter=header["frame_counter"],
        timestamp_us=header.get("timestamp_us", 0),
        flags=header.get("flags", 0),
        points_mm=mm_from_counts(counts[valid], cfg),
        n_invalid=int(n - valid.sum()),
    )
