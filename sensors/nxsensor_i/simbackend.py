"""A simulated nxSensor-I behind a real pyusb backend.

:class:`SimulatedNxSensorBackend` implements ``usb.backend.IBackend``, so
``usb.core.find(idVendor=..., idProduct=..., backend=SimulatedNxSensorBackend(cell))``
returns an ordinary ``usb.core.Device`` and the real driver talks to it through
unchanged pyusb calls (descriptors, configuration, interface claiming, bulk and control
transfers, clear halt, reset). The device speaks the wire format of
:mod:`spherecal.sensors.nxsensor_i.wire` (the project's assumption, not NextWare's
documentation) and measures with a :class:`spherecal.plugins.SimulatedCell`: each profile is
``cell.measure_profile()`` at the simulated robot's current pose, quantised to counts,
with invalid records for the columns that saw nothing.

Streaming runs on simulated time (:mod:`.simstream`): after ``start_stream`` the device
measures a frame every set period on its own clock (``clock``), each from
``source(T_true_s)`` at the true time of its exposure, and a bulk read returns the next
frame due by the simulated time now (``now_s()``), so that after a simulated move the
driver drains every frame of the move. Triggered shots measure ``cell.measure_profile()``
at once, as before.

Faults can be injected to test a driver: :meth:`inject_timeouts`, :meth:`inject_stalls`,
:meth:`inject_corrupt_frames`, :meth:`drop_frames`, :meth:`delay_exposures`,
:meth:`step_clock`, :meth:`hang_stream`, :meth:`wrap_soon`, :meth:`stream_unasked`, :meth:`disconnect` and
:meth:`reconnect`. Errors are raised as libusb-1.0 would: ``usb.core.USBTimeoutError``
(code -7, ETIMEDOUT), ``usb.core.USBError`` with ENODEV (-4) for a device that is gone,
EPIPE (-9) for a stalled endpoint, EOVERFLOW (-8) for a frame larger than the read.
"""

from __future__ import annotations

import array
import errno
import itertools
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Literal

import numpy as np
import usb.backend
import usb.core

from .simstream import FrameSchedule, SensorClock, SimTime, StreamedFrameTruth, cell_source
from .wire import Command, ControlSetup, FrameFormatError, WireConfig, decode_bulk_command, decode_control_command, encode_frame

# libusb-1.0 error codes, as pyusb's libusb1 backend reports them in backend_error_code.
LIBUSB_ERROR_IO = -1
LIBUSB_ERROR_NO_DEVICE = -4
LIBUSB_ERROR_TIMEOUT = -7
LIBUSB_ERROR_OVERFLOW = -8
LIBUSB_ERROR_PIPE = -9

_GET_DESCRIPTOR = 0x06
_DESC_TYPE_STRING = 0x03
_LANGID_EN_US = 0x0409

CorruptionKind = Literal["magic", "truncate", "count", "checksum"]

#: Real time an empty bulk read waits while a stream runs, ms at most (a real read blocks
#: until its timeout; this keeps a reader thread from spinning while simulated time
#: stands still, and tests fast).
STREAM_IDLE_WAIT_MS = 2


def _no_device() -> usb.core.USBError:
    return usb.core.USBError("No such device (it may have been disconnected)", LIBUSB_ERROR_NO_DEVICE, errno.ENODEV)


def _timeout() -> usb.core.USBTimeoutError:
    return usb.core.USBTimeoutError("Operation timed out", LIBUSB_ERROR_TIMEOUT, errno.ETIMEDOUT)


def _pipe() -> usb.core.USBError:
    return usb.core.USBError("Pipe error", LIBUSB_ERROR_PIPE, errno.EPIPE)


class _Descriptor:
    """A descriptor: attributes named as in the USB specification (what pyusb reads)."""

    def __init__(self, **fields):
        self.__dict__.update(fields)


@dataclass(eq=False)
class _SimDevice:
    """Identification object of one enumeration of the device (a new one after a
    reconnect, as the bus assigns a new address)."""

    bus: int
    address: int
    alive: bool = True


@dataclass(eq=False)
class _Handle:
    device: _SimDevice
    claimed: set[int] = field(default_factory=set)


class SimulatedNxSensorBackend(usb.backend.IBackend):
    """A pyusb backend with one simulated nxSensor-I on it, measuring ``cell``.

    ``wire`` is the wire format the simulated firmware speaks (default: the project's
    assumed one). ``pad_to_columns`` sends one record per column of the cell's field of
    view (invalid where the line saw nothing), as a profiler does; set it False to send
    only valid points. ``simulate_waits`` makes timeouts and triggered reads take real
    time (off by default so that tests stay fast).

    Streaming (:mod:`.simstream`): ``now_s()`` gives the simulated true time (default: the
    backend's own :class:`SimTime`, moved by :meth:`advance_s`), ``clock`` the sensor's
    clock against it (default :class:`SensorClock`: no offset, no drift), ``source(T)``
    the profile at true time T (default :func:`cell_source` at the cell's current pose,
    seeded by ``seed``). ``streamed`` records every streamed frame's truth."""

    def __init__(
        self,
        cell,
        wire: WireConfig | None = None,
        serial_number: str = "NXS-SIM-0001",
        pad_to_columns: bool = True,
        simulate_waits: bool = False,
        now_s: Callable[[], float] | None = None,
        clock=None,
        source: Callable[[float], np.ndarray] | None = None,
        seed: int | None = 0,
    ):
        super().__init__()
        self.cell = cell
        self.wire = wire or WireConfig()
        self.serial_number = serial_number
        self.pad_to_columns = pad_to_columns
        self.simulate_waits = simulate_waits
        self._own_time = SimTime() if now_s is None else None
        self.now_s: Callable[[], float] = now_s or self._own_time.now_s
        self.clock = clock or SensorClock()
        self.source = source or cell_source(cell, seed=seed)
        self._lock = threading.RLock()  # a driver's reader thread and its caller share the device
        self._addresses = itertools.count(5)
        self._device = _SimDevice(bus=1, address=next(self._addresses))
        self._configuration = 1  # the OS configures a device on enumeration
        self._power_on_state()
        # faults
        self._timeouts_pending = 0
        self._late_pending = 0
        self._stalls_pending = 0
        self._corruptions: list[CorruptionKind] = []
        # streamed-frame faults, by the frame's index in ``streamed`` (every frame measured)
        self._drops: set[int] = set()
        self._late_s: dict[int, float] = {}
        self._clock_steps: list[tuple[int, float]] = []
        # what was measured, for tests: list of (frame_counter, (N, 2) mm points), and
        # where: the cell's true base_from_flange at each measurement (same order)
        self.measured: list[tuple[int, np.ndarray]] = []
        self.measured_poses: list = []
        self.commands: list[Command] = []
        #: every frame a stream measured, sent or not, in order (:class:`StreamedFrameTruth`)
        self.streamed: list[StreamedFrameTruth] = []

    def _power_on_state(self) -> None:
        self.exposure_us = 0
        self.period_us = 10_000
        self.streaming = False
        self.frame_counter = 0
        self._queue: list[bytes] = []
        self._halted: set[int] = set()
        self._schedule: FrameSchedule | None = None
        self._hang_at: int | None = None  # the stream's index at which the firmware hangs

    # --- fault injection --------------------------------------------------------------
    def inject_timeouts(self, n: int = 1) -> None:
        """The next ``n`` bulk reads time out; a profile waiting to be read is lost."""
        self._timeouts_pending += n

    def inject_late_frames(self, n: int = 1) -> None:
        """The next ``n`` bulk reads time out although a profile is on its way: the
        profile stays queued and is delivered to a later read (a slow device)."""
        self._late_pending += n

    def inject_stalls(self, n: int = 1) -> None:
        """The bulk IN endpoint halts on the next ``n`` reads (EPIPE until cleared)."""
        self._stalls_pending += n

    def inject_corrupt_frames(self, n: int = 1, kind: CorruptionKind = "magic") -> None:
        """The next ``n`` frames arrive corrupted: a wrong magic, cut short, with bytes
        beyond the header's point count, or (with a CRC-32 trailer) a flipped bit."""
        self._corruptions.extend([kind] * n)

    def drop_frames(self, n: int = 1, after: int = 0) -> None:
        """While streaming, ``n`` frames, ``after`` frames from the next one measured, are
        measured (their counters used) but never sent, as when the device's buffer
        overflows."""
        with self._lock:
            first = len(self.streamed) + after
            self._drops.update(range(first, first + n))

    def delay_exposures(self, late_s: float, n: int = 1, after: int = 0) -> None:
        """While streaming, ``n`` frames, ``after`` frames from the next one measured, are
        exposed (and stamped) ``late_s`` seconds after their slot, as when the sensor's
        trigger slips; the frames after them keep their slots."""
        with self._lock:
            first = len(self.streamed) + after
            self._late_s.update({k: float(late_s) for k in range(first, first + n)})

    def step_clock(self, dt_s: float, after: int = 0) -> None:
        """The sensor's clock steps by ``dt_s`` seconds (forward, or back when negative)
        before the frame ``after`` frames from the next one measured: that frame and every
        later one are stamped ``dt_s`` off, though exposed on schedule."""
        with self._lock:
            self._clock_steps.append((len(self.streamed) + after, float(dt_s)))

    def hang_stream(self, after_frames: int = 0) -> None:
        """The stream stalls: after ``after_frames`` more frames the firmware measures and
        sends nothing, though it says it streams, until it is powered up afresh."""
        with self._lock:
            self._hang_at = len(self.streamed) + after_frames

    def wrap_soon(self, frames: int) -> None:
        """Put the frame counter and the sensor clock's timestamp ``frames`` frame periods
        before their wraps at the next stream's start (set the period first, start the
        stream at the simulated time now), so that both wrap within the stream. The
        sensor's clock becomes a :class:`SensorClock` with its offset moved."""
        with self._lock:
            self.frame_counter = (self.wire.frame_counter_modulus - frames) % self.wire.frame_counter_modulus
            wrap_s = self.wire.timestamp_modulus * self.wire.timestamp_us_per_count * 1e-6
            shift = self.wire.exposure_middle_shift_s(self.exposure_us)
            now = self.clock.to_sensor_s(self.now_s())
            # the first frame's stamp lands (frames - 1/2) periods before the wrap
            target = wrap_s - (frames - 0.5) * self.period_us * 1e-6 - self.period_us * 1e-6 + shift
            self.clock = SensorClock(self.clock.offset_s + (target - now) % wrap_s, getattr(self.clock, "drift_ppm", 0.0))

    def stream_unasked(self) -> None:
        """Another program starts the sensor streaming (this host sent nothing)."""
        with self._lock:
            self._execute(Command("start_stream"))

    def advance_s(self, dt_s: float) -> None:
        """Move the backend's own simulated time on by ``dt_s`` seconds (when it was given
        no ``now_s``)."""
        if self._own_time is None:
            raise RuntimeError("this backend follows the simulated time it was given (now_s); advance that clock")
        self._own_time.advance_s(dt_s)

    def disconnect(self) -> None:
        """Unplug: the device disappears from the bus; open handles fail with ENODEV."""
        self._device.alive = False

    def reconnect(self) -> None:
        """Plug back in: the device enumerates again at a new address, powered up afresh."""
        self._device.alive = False
        self._device = _SimDevice(bus=1, address=next(self._addresses))
        self._configuration = 1
        self._power_on_state()

    # --- the device -------------------------------------------------------------------
    def _alive(self, handle: _Handle) -> None:
        if not handle.device.alive:
            raise _no_device()

    def _execute(self, command: Command) -> None:
        with self._lock:
            self._execute_now(command)

    def _execute_now(self, command: Command) -> None:
        self.commands.append(command)
        if command.name == "set_exposure":
            if not 1 <= command.argument < self.period_us:
                raise _pipe()  # the firmware rejects it: the control request stalls
            self.exposure_us = command.argument
        elif command.name == "set_period":
            if command.argument <= self.exposure_us:
                raise _pipe()
            self.period_us = command.argument
        elif command.name == "trigger":
            if self.streaming:
                raise _pipe()
            self._queue.append(self._measure())
        elif command.name == "start_stream":
            if not self.streaming:
                self.streaming = True
                self._schedule = FrameSchedule(self.clock, self.now_s(), self.period_us * 1e-6)
        elif command.name == "stop_stream":
            self.streaming = False
            self._queue.clear()
            if self._schedule is not None:
                self._schedule.end_s = self.now_s()  # frames measured before it are still to be read

    def _streamed_frame(self) -> bytes | None:
        """The next frame of the stream due by the simulated time now, or None: frames
        dropped by a fault are measured (their counters used) and skipped."""
        sched = self._schedule
        while sched is not None:
            index = len(self.streamed)
            late = self._late_s.get(index, 0.0)
            if index == self._hang_at or not sched.due(self.now_s(), late):
                if sched.end_s is not None:
                    self._schedule = None  # stopped and drained: nothing more will come
                return None
            T, t_sensor = sched.slot(sched.k, late)
            t_sensor += sum(dt for at, dt in self._clock_steps if at <= index)
            sched.k += 1
            counter = self.frame_counter
            self.frame_counter = (counter + 1) % self.wire.frame_counter_modulus
            sent = index not in self._drops
            self.streamed.append(StreamedFrameTruth(counter, T, t_sensor, late, sent))
            if not sent:
                continue
            pts = np.asarray(self.source(T), dtype=float).reshape(-1, 2)
            stamp = round((t_sensor - self.wire.exposure_middle_shift_s(self.exposure_us))
                          / (self.wire.timestamp_us_per_count * 1e-6))
            return self._encode(pts, counter, stamp)
        return None

    def _measure(self) -> bytes:
        counter = self.frame_counter
        self.frame_counter = (self.frame_counter + 1) % self.wire.frame_counter_modulus
        pts = np.asarray(self.cell.measure_profile(), dtype=float).reshape(-1, 2)
        self.measured.append((counter, pts))
        self.measured_poses.append(self.cell.current_base_from_flange)
        return self._encode(pts, counter, counter * self.period_us)

    def _encode(self, pts: np.ndarray, counter: int, stamp: int) -> bytes:
        pad = self.cell.fov.n_columns if self.pad_to_columns else None
        modulus = self.wire.timestamp_modulus or 1
        frame = encode_frame(
            pts[: self.wire.max_points], self.wire, frame_counter=counter,
            timestamp_us=stamp % modulus, pad_to=pad, out_of_range="invalid",
        )
        if self._corruptions:
            frame = self._corrupt(frame, self._corruptions.pop(0))
        return frame

    def _corrupt(self, frame: bytes, kind: CorruptionKind) -> bytes:
        b = bytearray(frame)
        if kind == "magic":
            b[0] ^= 0xFF
        elif kind == "truncate":
            del b[len(b) // 2:]
        elif kind == "count":
            b += bytes(self.wire.record_dtype.itemsize)
        elif kind == "checksum":
            b[self.wire.header_struct.size] ^= 0x01
        return bytes(b)

    # --- IBackend: enumeration and descriptors ----------------------------------------
    def enumerate_devices(self):
        if self._device.alive:
            yield self._device

    def get_parent(self, dev):
        return None

    def get_device_descriptor(self, dev):
        return _Descriptor(
            bLength=18, bDescriptorType=0x01, bcdUSB=0x0200, bDeviceClass=0x00, bDeviceSubClass=0x00,
            bDeviceProtocol=0x00, bMaxPacketSize0=64, idVendor=self.wire.vendor_id, idProduct=self.wire.product_id,
            bcdDevice=0x0100, iManufacturer=1, iProduct=2, iSerialNumber=3, bNumConfigurations=1,
            address=dev.address, bus=dev.bus, port_number=1, port_numbers=(1,), speed=3,  # 3: high speed
        )

    def get_configuration_descriptor(self, dev, config):
        if config != 0:
            raise IndexError(f"configuration index {config} out of range")
        return _Descriptor(
            bLength=9, bDescriptorType=0x02, wTotalLength=9 + 9 + 7 + 7, bNumInterfaces=1,
            bConfigurationValue=self.wire.configuration_value, iConfiguration=0, bmAttributes=0x80,
            bMaxPower=250, extra_descriptors=[],  # 250 x 2 mA = 500 mA, bus powered
        )

    def get_interface_descriptor(self, dev, intf, alt, config):
        if config != 0 or intf != 0 or alt != 0:
            raise IndexError(f"interface ({intf}, {alt}) of configuration {config} out of range")
        return _Descriptor(
            bLength=9, bDescriptorType=0x04, bInterfaceNumber=self.wire.interface, bAlternateSetting=0,
            bNumEndpoints=2, bInterfaceClass=0xFF, bInterfaceSubClass=0x00, bInterfaceProtocol=0x00,
            iInterface=0, extra_descriptors=[],
        )

    def get_endpoint_descriptor(self, dev, ep, intf, alt, config):
        if config != 0 or intf != 0 or alt != 0 or ep not in (0, 1):
            raise IndexError(f"endpoint {ep} of interface ({intf}, {alt}) out of range")
        address = self.wire.bulk_out_endpoint if ep == 0 else self.wire.bulk_in_endpoint
        return _Descriptor(
            bLength=7, bDescriptorType=0x05, bEndpointAddress=address, bmAttributes=0x02,  # bulk
            wMaxPacketSize=self.wire.max_packet_size, bInterval=0, bRefresh=0, bSynchAddress=0, extra_descriptors=[],
        )

    # --- IBackend: handles, configuration, interfaces ---------------------------------
    def open_device(self, dev):
        if not dev.alive:
            raise _no_device()
        return _Handle(dev)

    def close_device(self, dev_handle):
        dev_handle.claimed.clear()

    def set_configuration(self, dev_handle, config_value):
        self._alive(dev_handle)
        if config_value not in (0, self.wire.configuration_value):
            raise usb.core.USBError("Invalid parameter", -2, errno.EINVAL)
        self._configuration = config_value

    def get_configuration(self, dev_handle):
        self._alive(dev_handle)
        return self._configuration

    def set_interface_altsetting(self, dev_handle, intf, altsetting):
        self._alive(dev_handle)
        if intf != self.wire.interface or altsetting != 0:
            raise usb.core.USBError("Invalid parameter", -2, errno.EINVAL)

    def claim_interface(self, dev_handle, intf):
        self._alive(dev_handle)
        if intf != self.wire.interface:
            raise usb.core.USBError("Entity not found", -5, errno.ENOENT)
        dev_handle.claimed.add(intf)

    def release_interface(self, dev_handle, intf):
        self._alive(dev_handle)
        dev_handle.claimed.discard(intf)

    def is_kernel_driver_active(self, dev_handle, intf):
        self._alive(dev_handle)
        return False

    def detach_kernel_driver(self, dev_handle, intf):
        self._alive(dev_handle)

    def attach_kernel_driver(self, dev_handle, intf):
        self._alive(dev_handle)

    # --- IBackend: transfers ----------------------------------------------------------
    def _check_claimed(self, dev_handle, intf):
        if intf not in dev_handle.claimed:
            raise usb.core.USBError("Access denied (interface not claimed)", -3, errno.EACCES)

    def bulk_write(self, dev_handle, ep, intf, data, timeout):
        self._alive(dev_handle)
        self._check_claimed(dev_handle, intf)
        if ep != self.wire.bulk_out_endpoint:
            raise _pipe()
        if self.wire.command_transport != "bulk":
            raise _pipe()  # this firmware takes commands on endpoint 0 only
        try:
            command = decode_bulk_command(bytes(data), self.wire)
        except FrameFormatError:
            raise _pipe() from None
        self._execute(command)
        return len(data)

    def bulk_read(self, dev_handle, ep, intf, buff, timeout):
        with self._lock:
            frame = self._bulk_read_frame(dev_handle, ep, intf)
            waiting_stream = self._schedule is not None
        if frame is None:
            if waiting_stream:  # a real read would block until its timeout; simulated time may move meanwhile
                time.sleep(min(timeout or STREAM_IDLE_WAIT_MS, STREAM_IDLE_WAIT_MS) / 1000.0)
            else:
                self._wait(timeout)
            raise _timeout()
        if len(frame) > len(buff) * buff.itemsize:
            raise usb.core.USBError("Overflow", LIBUSB_ERROR_OVERFLOW, errno.EOVERFLOW)
        buff[: len(frame)] = array.array("B", frame)
        return len(frame)

    def _bulk_read_frame(self, dev_handle, ep, intf) -> bytes | None:
        """The frame one bulk read returns, None for a timeout; raises for the others."""
        self._alive(dev_handle)
        self._check_claimed(dev_handle, intf)
        if ep != self.wire.bulk_in_endpoint or ep in self._halted:
            raise _pipe()
        if self._stalls_pending:
            self._stalls_pending -= 1
            self._halted.add(ep)
            raise _pipe()
        if self._late_pending and self._queue:
            self._late_pending -= 1
            return None
        if self._timeouts_pending:
            self._timeouts_pending -= 1
            if self._queue:
                self._queue.pop(0)
            else:
                self._streamed_frame()  # measured, never delivered
            return None
        if self._queue:
            return self._queue.pop(0)
        return self._streamed_frame()

    def _wait(self, timeout_ms) -> None:
        if self.simulate_waits and timeout_ms:
            time.sleep(timeout_ms / 1000.0)

    def ctrl_transfer(self, dev_handle, bmRequestType, bRequest, wValue, wIndex, data, timeout):
        self._alive(dev_handle)
        if bmRequestType == 0x80 and bRequest == _GET_DESCRIPTOR and (wValue >> 8) == _DESC_TYPE_STRING:
            return self._string_descriptor(wValue & 0xFF, data)
        if bmRequestType == self.wire.command_request_type and self.wire.command_transport == "control":
            try:
                command = decode_control_command(ControlSetup(bmRequestType, bRequest, wValue, wIndex), self.wire)
            except FrameFormatError:
                raise _pipe() from None
            self._execute(command)
            return len(data)
        raise _pipe()  # any other request: the device stalls EP0

    def _string_descriptor(self, index, data):
        if index == 0:
            payload = _LANGID_EN_US.to_bytes(2, "little")
        else:
            strings = {1: "NextWare (simulated)", 2: "nxSensor-I", 3: self.serial_number}
            if index not in strings:
                raise _pipe()
            payload = strings[index].encode("utf-16-le")
        desc = bytes([2 + len(payload), _DESC_TYPE_STRING]) + payload
        n = min(len(desc), len(data))
        data[:n] = array.array("B", desc[:n])
        return n

    def clear_halt(self, dev_handle, ep):
        self._alive(dev_handle)
        self._halted.discard(ep)

    def reset_device(self, dev_handle):
        """A port reset: the firmware restarts (settings and queue lost) and, as many
        devices do, re-enumerates, so the old handle is gone (ENODEV) afterwards."""
        self._alive(dev_handle)
        self.reconnect()
