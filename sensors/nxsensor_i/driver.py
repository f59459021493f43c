"""pyusb driver of the NextWare nxSensor-I laser line sensor.

Talks the wire format of :mod:`spherecal.sensors.nxsensor_i.wire` (an ASSUMPTION of the
unpublished protocol, all of it configuration) through ordinary pyusb calls, so the same
code runs against libusb and real hardware or against
:class:`~spherecal.sensors.nxsensor_i.simbackend.SimulatedNxSensorBackend`.

Profiles are (y, z) in mm in the sensor frame's x = 0 plane, z positive towards the
sensor (``docs/conventions.md``). Implements the :class:`spherecal.plugins.Sensor`
protocol (``read_profile``, ``close``) and the optional
:class:`spherecal.plugins.ProfileStreamingSensor` (``start_profile_stream``,
``stop_profile_stream``: a stream at a set rate, drained by a reader thread, each frame
on the sensor's clock, :mod:`.streaming` and :mod:`.stamps`).

Failures become :class:`spherecal.plugins.DeviceError` naming the device (USB
vendor:product id, serial number) and the operation. Recovery, up to
``config.retries`` times per operation: after a timeout or a corrupt frame the request
is repeated (with the IN endpoint's halt cleared); a stalled endpoint is cleared; a
device that vanished (ENODEV, as after a reset or a brief unplug) is looked for again
by its ids and reopened, with the settings sent again.

Shot identity: a profile is returned only if its frame counter is one that a trigger of
the same ``read_frame`` call got (:mod:`.shots`); frames of earlier shots, however late,
are discarded, and a frame no trigger can have measured is an error. The input is
flushed on open, reopen and after a stream, and the next shot learns the counter.
"""

from __future__ import annotations

import errno
import math
import time
from collections.abc import Callable

import usb.core
import usb.util

from spherecal.plugins import DeviceError, Profile, ProfileStream, ProfileStreamCounts, ProfileStreamError

from .config import NxSensorConfig
from .shots import CounterMismatch, FrameCounter, Shot
from .stamps import StreamStamps
from .streaming import StreamReader
from .wire import Command, Frame, FrameFormatError, encode_bulk_command, encode_control_command, decode_frame

_LIBUSB_ERROR_NO_DEVICE = -4
_LIBUSB_ERROR_PIPE = -9
_LIBUSB_ERROR_ACCESS = -3
_LIBUSB_ERROR_BUSY = -6
#: Wait of each read while flushing the input, ms: the flush ends at the first read
#: that gets nothing within it.
FLUSH_WAIT_MS = 20
#: Most frames a flush discards before it concludes that the sensor is streaming.
MAX_FLUSH_FRAMES = 64
#: Most frames the flush of a stream given up on discards (stop_stream sent: what is left
#: is the frames measured before it, which a simulated device delivers only when read).
MAX_ABANDONED_FRAMES = 4096
#: Most frames of earlier shots one read discards in a row before it gives up.
MAX_EARLIER_FRAMES = 256


def _is_no_device(exc: usb.core.USBError) -> bool:
    return exc.errno == errno.ENODEV or exc.backend_error_code == _LIBUSB_ERROR_NO_DEVICE


def _is_pipe(exc: usb.core.USBError) -> bool:
    return exc.errno == errno.EPIPE or exc.backend_error_code == _LIBUSB_ERROR_PIPE


def _is_access(exc: usb.core.USBError) -> bool:
    return exc.errno == errno.EACCES or exc.backend_error_code == _LIBUSB_ERROR_ACCESS


def _is_busy(exc: usb.core.USBError) -> bool:
    return exc.errno == errno.EBUSY or exc.backend_error_code == _LIBUSB_ERROR_BUSY


#: Longest wait of one read of the stream's reader, ms: how long a stop may wait for it.
STREAM_POLL_MS = 50
#: Slack on the time that can have passed between two streams, seconds (latency of the
#: last frame's delivery, the clocks' rate difference).
STREAM_GAP_SLACK_S = 1.0


class _Gone(Exception):
    """Internal: the device vanished and could not be found again."""


class NxSensorDriver:
    """A connected nxSensor-I.

    ``backend`` is a pyusb backend (None: pyusb's default, libusb-1.0 first). The device
    is found by ``config.wire.vendor_id``/``product_id`` (and ``config.serial_number``
    when set), configured, its interface claimed and the exposure and rate sent.
    ``log`` receives one line per recovery (retry, halt cleared, reopened) and per lost or
    late streamed frame. ``host_clock_s()`` is the host's clock for a stream's stall limit
    (seconds, default ``time.monotonic``; a simulated run gives its simulated clock)."""

    def __init__(self, config: NxSensorConfig, backend=None, log: Callable[[str], None] | None = None,
                 host_clock_s: Callable[[], float] | None = None):
        self.config = config
        self.wire = config.wire
        self._log = log or (lambda msg: None)
        self._backend = backend
        self._host_clock_s = host_clock_s or time.monotonic
        self._dev: usb.core.Device | None = None
        self._streaming = False
        self._closed = False
        self._reader: StreamReader | None = None
        self._stamps: StreamStamps | None = None  # the sensor clock's time line of this device session
        self._last_frame_host_s: float | None = None
        #: the counts of the last profile stream stopped
        self.profile_stream_counts = ProfileStreamCounts()
        #: which time line of the sensor's clock streams are on: +1 each time it cannot be
        #: followed from the previous stream (the device reopened, or too long between)
        self.sensor_clock_session = 0
        #: the counter the next measured profile will carry (see :mod:`.shots`)
        self.counter = FrameCounter(self.wire.frame_counter_modulus)
        self._flushed = False  # the input was flushed and nothing triggered since
        #: frames of earlier shots discarded by their counter (late frames), for tests and logs
        self.frames_discarded = 0
        self._open()

    # --- naming ------------------------------------------------------------------------
    @property
    def device_name(self) -> str:
        serial = f", serial {self.config.serial_number}" if self.config.serial_number else ""
        return f"nxSensor-I (USB {self.wire.usb_id}{serial})"

    def identity(self) -> dict[str, str]:
        """What this unit says it is (spherecal.plugins.device_identity): its USB
        manufacturer, product and serial number strings; a string it cannot give is left
        out."""
        found: dict[str, str] = {}
        dev = self._dev
        for key, index in (("manufacturer", "iManufacturer"), ("model", "iProduct"), ("serial_number", "iSerialNumber")):
            try:
                value = usb.util.get_string(dev, getattr(dev, index))
            except (usb.core.USBError, ValueError, AttributeError, NotImplementedError):
                continue
            if value:
                found[key] = value
        return found

    def _error(self, operation: str, what: str, hint: str) -> DeviceError:
        return DeviceError(f"{self.device_name}: {what} while {operation}. {hint}")

    # --- discovery and opening ---------------------------------------------------------
    def _find(self) -> usb.core.Device | None:
        wire = self.wire
        wanted = self.config.serial_number
        seen_serials: list[str] = []

        def match(dev) -> bool:
            if wanted is None:
                return True
            try:
                serial = usb.util.get_string(dev, dev.iSerialNumber)
            except (usb.core.USBError, ValueError):
                serial = None
            seen_serials.append(str(serial))
            return serial == wanted

        try:
            dev = usb.core.find(idVendor=wire.vendor_id, idProduct=wire.product_id, backend=self._backend, custom_match=match)
        except usb.core.NoBackendError:
            raise DeviceError(
                f"{self.device_name}: no USB backend available (pyusb found neither libusb-1.0, OpenUSB nor "
                "libusb-0.1). Install libusb-1.0 (Debian/Ubuntu: apt install libusb-1.0-0; Windows: put "
                "libusb-1.0.dll next to python.exe or on PATH), or run the simulated cell."
            ) from None
        if dev is None and wanted is not None and seen_serials:
            raise DeviceError(
                f"{self.device_name}: a device with USB id {wire.usb_id} is connected but none has serial number "
                f"{wanted!r} (found: {', '.join(repr(s) for s in seen_serials)}). Fix sensor.serial_number in the "
                "configuration, or leave it out to use the first unit."
            )
        if dev is not None and self._backend is None:
            self._backend = dev.backend
        return dev

    def _open(self) -> None:
        dev = self._find()
        if dev is None:
            raise DeviceError(
                f"{self.device_name}: not found on USB (looked for vendor:product {self.wire.usb_id}). Check that "
                "the sensor is powered and its cable plugged in (`lsusb` on Linux should list it); that your user "
                "may open it (Linux: a udev rule such as SUBSYSTEM==\"usb\", "
                f"ATTR{{idVendor}}==\"{self.wire.vendor_id:04x}\", ATTR{{idProduct}}==\"{self.wire.product_id:04x}\", "
                "MODE=\"0660\", GROUP=\"plugdev\"; Windows: the WinUSB driver bound, e.g. with Zadig); and that "
                "sensor.wire.vendor_id / product_id match the unit: the defaults are assumptions, as the "
                "nxSensor-I's USB protocol is not public."
            )
        self._dev = dev
        self._setup_device()

    def _setup_device(self) -> None:
        self._stamps = None  # a device opened afresh: its clock's count cannot be followed
        dev, wire = self._dev, self.wire
        step = "opening the device"
        try:
            try:
                if dev.is_kernel_driver_active(wire.interface):
                    step = "detaching the kernel driver"
                    dev.detach_kernel_driver(wire.interface)
            except NotImplementedError:  # not every backend/OS has kernel drivers to detach
                pass
            step = f"selecting configuration {wire.configuration_value}"
            active = None
            try:
                active = dev.get_active_configuration().bConfigurationValue
            except usb.core.USBError:
                pass
            if active != wire.configuration_value:
                dev.set_configuration(wire.configuration_value)
            step = f"claiming interface {wire.interface}"
            usb.util.claim_interface(dev, wire.interface)
        except usb.core.USBError as exc:
            if _is_access(exc):
                hint = ("Your user may not open it: add a udev rule (see docs/sensor-nxsensor-i.md) or, on Windows, "
                        "bind the WinUSB driver.")
            elif _is_busy(exc):
                hint = "Another program holds the interface: close other sensor software and try again."
            elif _is_no_device(exc):
                hint = "The device vanished: check the cable and power."
            else:
                hint = "Check sensor.wire.configuration_value and sensor.wire.interface against the unit."
            raise self._error(step, f"USB error ({exc})", hint) from exc
        except ValueError as exc:  # pyusb: no such configuration / interface in the descriptors
            raise self._error(step, f"{exc}", "Check sensor.wire.configuration_value and sensor.wire.interface.") from exc
        self._send_settings()
        self._flush_input("opening the device")

    def _send_settings(self) -> None:
        self._command_raw(Command("set_period", self.config.period_us))
        self._command_raw(Command("set_exposure", self.config.exposure_us))

    def _refind(self, operation: str) -> None:
        """After ENODEV: look for the device again (it re-enumerates after a reset)."""
        old = self._dev
        if old is not None:
            try:
                usb.util.dispose_resources(old)
            except usb.core.USBError:
                pass
        self._dev = None
        dev = self._find()
        if dev is None:
            raise _Gone()
        self._log(f"{self.device_name}: device reappeared while {operation}; reopened it")
        self._dev = dev
        self._setup_device()

    # --- raw transfers -----------------------------------------------------------------
    def _command_raw(self, command: Command) -> None:
        timeout = self.config.timeout_ms
        if self.wire.command_transport == "control":
            s = encode_control_command(command, self.wire)
            self._dev.ctrl_transfer(s.bmRequestType, s.bRequest, s.wValue, s.wIndex, None, timeout)
        else:
            self._dev.write(self.wire.bulk_out_endpoint, encode_bulk_command(command, self.wire), timeout)

    @property
    def _read_size(self) -> int:
        """Bytes asked of one bulk read: the largest frame rounded up to whole packets, so
        that a device filling its last packet never overflows the buffer."""
        size = self.wire.max_frame_bytes
        return size + (-size % self.wire.max_packet_size)

    def _read_frame_raw(self, timeout_ms: int | None = None) -> Frame:
        data = self._dev.read(self.wire.bulk_in_endpoint, self._read_size, timeout_ms or self.config.timeout_ms)
        return decode_frame(data, self.wire)

    def _flush_input(self, operation: str, quiet: bool = False, max_frames: int = MAX_FLUSH_FRAMES) -> int:
        """Read and discard whatever waits on the IN endpoint (frames of an earlier
        session, of a stream, of a device that restarted) until a read gets nothing
        within FLUSH_WAIT_MS; the frame counter is then unknown until the next shot
        learns it. Returns how many frames were discarded; each is logged unless
        ``quiet`` (the caller sums them up). More than ``max_frames`` in a row: the sensor
        streams unasked (DeviceError)."""
        discarded = 0
        for _ in range(max_frames):
            try:
                self._dev.read(self.wire.bulk_in_endpoint, self._read_size, FLUSH_WAIT_MS)
            except usb.core.USBTimeoutError:
                break
            except usb.core.USBError as exc:
                if _is_pipe(exc):
                    self._clear_halt_quietly()
                    continue
                raise
            discarded += 1
            if not quiet:
                self._log(f"{self.device_name}: discarded a waiting frame while {operation}")
        else:
            raise self._error(
                f"flushing the input ({operation})", f"frames kept arriving unasked ({max_frames} in a row)",
                "The sensor is streaming or triggered by something else: close other sensor software, or "
                "power-cycle the sensor.",
            )
        self.counter.forget()
        self._flushed = True
        return discarded

    def _clear_halt_quietly(self) -> None:
        try:
            self._dev.clear_halt(self.wire.bulk_in_endpoint)
        except usb.core.USBError:
            pass

    # --- recovery ----------------------------------------------------------------------
    def _attempt(self, operation: str, action: Callable[[], object], *, after_reopen: Callable[[], None] | None = None):
        """Run ``action`` with up to ``config.retries`` recoveries; raise DeviceError."""
        self._check_open(operation)
        retries = self.config.retries
        for attempt in range(retries + 1):
            last = attempt == retries
            try:
                return action()
            except usb.core.USBTimeoutError as exc:
                if last:
                    raise self._error(
                        operation, f"no answer within timeout_ms = {self.config.timeout_ms} ms "
                        f"({attempt + 1} attempt{'s' if attempt else ''})",
                        "Check the cable, that the sensor is not triggered by another program, and that "
                        "timeout_ms exceeds the frame period and exposure.",
                    ) from exc
                self._log(f"{self.device_name}: timeout while {operation}; retrying")
                self._clear_halt_quietly()
            except FrameFormatError as exc:
                if last:
                    raise self._error(
                        operation, f"malformed frame: {exc}",
                        "If this persists, sensor.wire does not match the device's real wire format.",
                    ) from exc
                self._log(f"{self.device_name}: malformed frame while {operation} ({exc}); retrying")
            except usb.core.USBError as exc:
                if _is_no_device(exc):
                    try:
                        if last:
                            raise _Gone()
                        self._refind(operation)
                    except _Gone:
                        self._dev = None
                        raise self._error(
                            operation, "the device is gone (disconnected)",
                            "Check the USB cable and the sensor's power, then reconnect; "
                            f"`lsusb` should list {self.wire.usb_id}.",
                        ) from exc
                    if after_reopen is not None:
                        after_reopen()
                elif _is_pipe(exc):
                    if last:
                        raise self._error(
                            operation, f"the device stalled the request ({exc})",
                            "The sensor rejected it: check exposure_us, rate_hz and the command codes in sensor.wire.",
                        ) from exc
                    self._log(f"{self.device_name}: endpoint stalled while {operation}; clearing the halt")
                    self._clear_halt_quietly()
                else:
                    raise self._error(operation, f"USB error ({exc})", "Check the cable and reconnect.") from exc

    def _check_open(self, operation: str) -> None:
        if self._closed:
            raise DeviceError(f"{self.device_name}: closed; cannot proceed with {operation}. Open a new driver.")
        if self._dev is None:
            raise DeviceError(f"{self.device_name}: the device was lost earlier; cannot proceed with {operation}. "
                              "Reconnect it and open a new driver.")

    # --- public API --------------------------------------------------------------------
    def configure(self, exposure_us: int | None = None, rate_hz: float | None = None) -> None:
        """Change exposure (microseconds) and/or streaming rate (Hz); checked like the
        configuration (exposure must fit the frame period)."""
        updates = {}
        if exposure_us is not None:
            updates["exposure_us"] = exposure_us
        if rate_hz is not None:
            updates["rate_hz"] = rate_hz
        try:
            new = NxSensorConfig.model_validate({**self.config.model_dump(), **updates})
        except ValueError as exc:
            raise DeviceError(f"{self.device_name}: invalid settings {updates}: {exc}") from exc
        old, self.config = self.config, new

        def send():
            # shorten the period first when it shrinks, so the exposure always fits it
            if new.period_us >= old.period_us:
                self._command_raw(Command("set_period", new.period_us))
                self._command_raw(Command("set_exposure", new.exposure_us))
            else:
                self._command_raw(Command("set_exposure", new.exposure_us))
                self._command_raw(Command("set_period", new.period_us))

        try:
            self._attempt(f"configuring exposure {new.exposure_us} us, rate {new.rate_hz} Hz", send)
        except DeviceError:
            self.config = old
            raise

    def read_frame(self) -> Frame:
        """Trigger one profile and return its decoded frame (counter, timestamp, points).

        The frame returned is one that a trigger of this call measured, told by its frame
        counter (:mod:`.shots`): a frame of an earlier call, however late it comes, is
        discarded, and a frame numbered beyond every trigger sent is a DeviceError. After
        a timeout the trigger is sent again; the first frame of any trigger of this call
        is taken (the sensor has not moved in between: the caller holds it still)."""
        if self._streaming:
            raise DeviceError(f"{self.device_name}: cannot read a single profile while streaming; stop the stream first")
        if not self.counter.known and not self._flushed:
            self._attempt("reading a profile", lambda: self._flush_input("synchronising the frame counter"))
        shot = [self.counter.begin_shot()]

        def once():
            self._trigger()
            return self._receive(shot[0])

        def reopened():  # a new device state: its counter is learnt again
            shot[0] = self.counter.begin_shot()

        return self._attempt("reading a profile", once, after_reopen=reopened)

    def _trigger(self) -> None:
        self._flushed = False
        self.counter.sending_trigger()
        try:
            self._command_raw(Command("trigger"))
        except usb.core.USBError as exc:
            if _is_pipe(exc):  # refused: nothing measured (a timeout leaves it open)
                self.counter.trigger_refused()
            raise
        self.counter.trigger_sent()

    def _receive(self, shot: Shot) -> Frame:
        """Read until a frame of ``shot`` arrives, discarding earlier shots' frames."""
        for _ in range(MAX_EARLIER_FRAMES):
            frame = self._read_frame_raw()
            expected = self.counter.expected(shot)
            try:
                mine = self.counter.place(shot, frame.frame_counter)
            except CounterMismatch as exc:
                self.counter.forget()  # the next read flushes the input and learns the counter again
                self._flushed = False
                raise CounterMismatch(f"{self.device_name}: {exc}") from None
            if mine:
                return frame
            self.frames_discarded += 1
            self._log(f"{self.device_name}: discarded frame {frame.frame_counter}, measured for an earlier shot "
                      f"(this shot's trigger: frame {expected})")
        raise self._error(
            "reading a profile", f"{MAX_EARLIER_FRAMES} frames of earlier shots arrived in a row",
            "The sensor sends frames nobody asked for: close other sensor software, or power-cycle the sensor.",
        )

    def read_profile(self) -> Profile | None:
        """One profile on request: (y, z) mm in the sensor frame; None when the line saw
        nothing valid. The profile's ``shot_id`` is its frame counter, in decimal."""
        frame = self.read_frame()
        if not len(frame.points_mm):
            return None
        return Profile.from_points(frame.points_mm, shot_id=str(frame.frame_counter))

    # --- profile streaming (spherecal.plugins.ProfileStreamingSensor) -------------------
    def start_profile_stream(self, rate_hz: float | None = None) -> None:
        """Stream profiles at ``rate_hz`` (default: the configured rate): the sensor
        measures one every period on its own clock, and a reader thread keeps the input
        drained until :meth:`stop_profile_stream`. Single reads are refused meanwhile."""
        operation = "starting the profile stream"
        self._check_open(operation)
        if self._streaming:
            raise DeviceError(f"{self.device_name}: a profile stream is already running; stop it first")
        if self.wire.timestamp_modulus is None:
            raise DeviceError(f"{self.device_name}: sensor.wire.header_layout has no timestamp_us field, so streamed "
                              "frames carry no sensor time; a stream needs the sensor's stamps")
        if rate_hz is not None:
            self.configure(rate_hz=rate_hz)
        cfg = self.config
        self._attempt(operation, lambda: self._flush_input(operation))  # frames of earlier use are no stream's
        if self._stamps is None:
            self._stamps = StreamStamps(self.wire.frame_counter_modulus, self.wire.timestamp_modulus,
                                        self.wire.timestamp_us_per_count * 1e-6)
        if not self._stamps.continues:
            self.sensor_clock_session += 1
        period_s = cfg.period_us * 1e-6
        self._stamps.begin_stream(period_s, self.wire.exposure_middle_shift_s(cfg.exposure_us),
                                  cfg.late_after_periods * period_s, cfg.clock_jump_periods * period_s)
        started_s = self._host_clock_s()
        self._attempt(operation, lambda: self._command_raw(Command("start_stream")))
        self._streaming = True
        self._flushed = False
        last = self._last_frame_host_s
        dev = self._dev
        self._reader = StreamReader(
            read=lambda timeout_ms: dev.read(self.wire.bulk_in_endpoint, self._read_size, timeout_ms),
            recover=self._recover_in_stream, wire=self.wire, stamps=self._stamps, clock_s=self._host_clock_s,
            stall_s=cfg.stall_timeout_ms / 1000, poll_ms=max(5, min(STREAM_POLL_MS, math.ceil(2 * cfg.period_us / 1000))),
            retries=cfg.retries, log=lambda msg: self._log(f"{self.device_name}: {msg}"),
            max_elapsed_s=lambda: math.inf if last is None else
            (self._host_clock_s() - last) * 1.001 + cfg.stall_timeout_ms / 1000 + STREAM_GAP_SLACK_S,
            on_fault=self._stop_device_quietly, started_s=started_s, period_s=period_s,
        )
        self._reader.start()

    def _recover_in_stream(self, exc: BaseException) -> str | None:
        """A USB error of the reader: None after clearing a halted endpoint (go on), else
        the fault that ends the stream (the stream is not restarted on a reopened device:
        its clock and counter would start again)."""
        if isinstance(exc, usb.core.USBError) and _is_pipe(exc):
            self._log(f"{self.device_name}: endpoint stalled while streaming; clearing the halt")
            self._clear_halt_quietly()
            return None
        if isinstance(exc, usb.core.USBError) and _is_no_device(exc):
            return f"the device is gone (disconnected) ({exc}); check the USB cable and the sensor's power"
        return f"USB error ({exc})"

    def _stop_device_quietly(self) -> None:
        try:
            if self._dev is not None:
                self._command_raw(Command("stop_stream"))
        except usb.core.USBError:
            pass

    @property
    def profile_stream_progress(self) -> ProfileStreamCounts | None:
        """The running stream's counts so far (None when none runs)."""
        reader = self._reader
        return None if reader is None else reader.counts

    @property
    def profile_stream_error(self) -> ProfileStreamError | None:
        """The fault that has ended the running stream (its frames come with
        :meth:`stop_profile_stream`), or None while it runs well."""
        reader = self._reader
        if reader is None or reader.fault is None:
            return None
        return ProfileStreamError(self._stream_fault_message(reader), None, reader.counts)

    def _stream_fault_message(self, reader: StreamReader) -> str:
        return (f"{self.device_name}: {reader.fault} while streaming profiles; the stream ended there, keeping "
                f"{reader.counts.received} frame(s) ({reader.counts.lost} lost, {reader.counts.late} late)")

    def stop_profile_stream(self) -> ProfileStream:
        """Stop the stream, take the frames still in flight and return every frame kept as
        a :class:`~spherecal.core.streams.ProfileStream` (``t_sensor_s``: the middle of
        each exposure on the sensor's clock, unwrapped; ``frame``: the frame counters,
        unwrapped). :attr:`profile_stream_counts` then holds received, lost and late. A
        stream that ended with a fault (stall, device error, clock or counter) raises
        :class:`~spherecal.plugins.ProfileStreamError` naming it, with what was taken."""
        reader = self._reader
        if reader is None:
            raise DeviceError(f"{self.device_name}: no profile stream is running; start one first")
        if reader.fault is None:
            self._stop_device_quietly()
        reader.request_stop()
        try:
            _join_while_draining(reader, self.config.stall_timeout_ms / 1000 + 2 * STREAM_POLL_MS / 1000 + 1.0)
        except BaseException:  # interrupted (Ctrl-C) while the frames in flight were taken
            self._abandon_stream("interrupted while stopping it")
            raise
        self._stream_ended(reader)
        taken = reader.taken()
        if reader.fault is not None:
            raise ProfileStreamError(self._stream_fault_message(reader), taken, reader.counts)
        if taken is None:
            return ProfileStream.from_profiles([], [], frame=[])
        return taken

    def _stream_ended(self, reader: StreamReader) -> None:
        """The driver's state once ``reader``'s stream has ended (joined, or given up on)."""
        self._reader = None
        self._streaming = False
        if reader.is_alive():  # the reader cannot be joined: leave it reading nothing of ours
            reader.fault = reader.fault or "the stream's reader did not end after stop_stream"
        self.counter.forget()  # single shots learn the counter again
        if reader.last_frame_s is not None:
            self._last_frame_host_s = reader.last_frame_s
        self.profile_stream_counts = reader.counts
        if reader.fault is not None and self._stamps is not None and \
                reader.fault_kind in ("clock_backwards", "clock_jump"):
            self._stamps.new_session()  # the clock broke the time line: follow it no further

    def _abandon_stream(self, why: str) -> None:
        """Stop a stream whose frames nobody will take (the run stopped while it ran):
        the reader stops at once, the frames still in flight are discarded, and one line
        says how many frames were dropped in all, instead of one line per frame."""
        reader = self._reader
        if reader is None:
            return
        reader.abandon()
        self._stop_device_quietly()
        reader.join(timeout=2 * STREAM_POLL_MS / 1000 + 1.0)
        self._stream_ended(reader)
        in_flight = "?"
        if self._dev is not None and not self._closed:
            try:
                in_flight = str(self._flush_input("stopping the stream", quiet=True, max_frames=MAX_ABANDONED_FRAMES))
            except DeviceError:
                in_flight = f"{MAX_ABANDONED_FRAMES} or more"
            except usb.core.USBError:
                in_flight = "an unknown number"
        counts = reader.counts
        self._log(f"{self.device_name}: profile stream stopped ({why}): its {counts.received} frame(s) read and "
                  f"{in_flight} still in flight discarded")

    def _stop_stream_quietly(self) -> None:
        if self._dev is None or self._closed:
            return
        try:
            self._command_raw(Command("stop_stream"))
            self._flush_input("stopping the stream")  # frames already in flight
        except (usb.core.USBError, DeviceError):
            pass

    def reset(self) -> None:
        """USB port reset, then find the device again and resend the settings."""
        self._check_open("resetting")
        try:
            self._dev.reset()
        except usb.core.USBError as exc:
            if not _is_no_device(exc):
                raise self._error("resetting", f"USB error ({exc})", "Unplug and replug the sensor.") from exc
        try:
            self._refind("resetting")
        except _Gone:
            self._dev = None
            raise self._error("resetting", "the device did not come back after the reset",
                              "Unplug and replug the sensor; check its power.") from None

    def close(self) -> None:
        """Release the interface and the device. Safe to call twice."""
        if self._closed:
            return
        if self._reader is not None:  # a stream nobody stopped: the run ended while it ran
            self._abandon_stream("closed while streaming")
        if self._streaming:
            self._stop_stream_quietly()
            self._streaming = False
        self._closed = True
        dev, self._dev = self._dev, None
        if dev is None:
            return
        try:
            usb.util.release_interface(dev, self.wire.interface)
        except usb.core.USBError:
            pass
        try:
            usb.util.dispose_resources(dev)
        except usb.core.USBError:
            pass

    def __enter__(self) -> "NxSensorDriver":
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def _join_while_draining(reader, quiet_s: float) -> None:
    """Wait for the reader to end, for as long as it still takes frames: a reader that has
    taken none for ``quiet_s`` of wall time is given up (a stream of many frames in
    flight, or a machine busy with other work, is not a stuck reader)."""
    taken, quiet_since = len(reader.frames), time.monotonic()
    while True:
        reader.join(timeout=min(0.25, quiet_s))
        if not reader.is_alive():
            return
        now = time.monotonic()
        if len(reader.frames) != taken:
            taken, quiet_since = len(reader.frames), now
        elif now - quiet_since > quiet_s:
            return

