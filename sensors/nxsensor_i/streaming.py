"""The reader thread of a profile stream: keeps the bulk IN endpoint drained.

While the sensor streams, the robot moves; nobody else reads the sensor. A
:class:`StreamReader` thread reads frame after frame (each read waits at most
``poll_ms``), decodes each, places it on the sensor's time line (:mod:`.stamps`) and
keeps it. It ends:

* when asked to stop (:meth:`StreamReader.request_stop`, after ``stop_stream`` was sent):
  it takes the frames still in flight, until a read begun after the request gets nothing;
* when abandoned (:meth:`StreamReader.abandon`: the run stopped while the stream ran, its
  frames are of no use): at once, reading and saying nothing more;
* with a named fault, keeping every frame taken before it: a stall, a USB error the driver cannot recover from (the
  device gone, an endpoint halted again and again), more malformed frames in a row than
  ``retries``, a counter or clock that breaks the time line, or a sensor that keeps
  sending after it was told to stop.

A stall is judged on the sensor's own time line, not by when frames happen to be read:
the frames kept cover the host clock from the stream's start (``started_s``) until
``started_s + (t_last - t_first) + period`` (the sensor's clock from the first frame
kept to the last, one period for the first to come); when the host clock is more than
``stall_s`` past that, while running or when stopped, the stream stalled. So frames read
in a burst after a simulated move count for the time they were exposed, and a sensor
whose rate lags by a drift of d covers d x duration less (100 ppm: 0.36 s an hour).

USB specifics stay with the driver: the reader gets ``read(timeout_ms) -> bytes`` and
``recover(exc) -> str | None`` (None: recovered, go on; a text: the fault).
"""

from __future__ import annotations

import threading
from collections.abc import Callable

import numpy as np
import usb.core

from spherecal.plugins import ProfileStream, ProfileStreamCounts

from .stamps import StampFault, StreamStamps
from .wire import FrameFormatError, WireConfig, decode_frame


class StreamReader(threading.Thread):
    """Drains one stream (see the module). ``clock_s()``: the host's clock, seconds, for
    the stall limit ``stall_s``; ``max_elapsed_s()``: for the stream's first frame, the
    most sensor time that can have passed since the session's last frame; ``log``
    receives one line per lost, late or malformed frame; ``on_fault`` is called once, from
    this thread, when a fault ends the stream (the driver stops the device there)."""

    def __init__(self, read: Callable[[int], bytes], recover: Callable[[BaseException], str | None],
                 wire: WireConfig, stamps: StreamStamps, clock_s: Callable[[], float], stall_s: float, poll_ms: int,
                 retries: int, max_elapsed_s: Callable[[], float], log: Callable[[str], None],
                 on_fault: Callable[[], None], started_s: float, period_s: float):
        super().__init__(name="nxsensor-stream-reader", daemon=True)
        self._read, self._recover, self._wire, self._stamps = read, recover, wire, stamps
        self._clock_s, self._stall_s, self._poll_ms, self._retries = clock_s, stall_s, poll_ms, retries
        self._max_elapsed_s, self._log, self._on_fault = max_elapsed_s, log, on_fault
        self._started_s, self._period_s = started_s, period_s
        self._stop_asked = threading.Event()
        self._abandoned = threading.Event()
        self._lock = threading.Lock()
        self.t_sensor_s: list[float] = []
        self.frames: list[int] = []
        self.profiles: list[np.ndarray] = []
        self.lost = 0
        self.late = 0
        #: the fault that ended the stream (a sentence), None while it runs or after a clean stop
        self.fault: str | None = None
        #: its kind: "stall", "usb", "malformed", "drain", "reader", or a StampFault's kind
        #: ("clock_backwards", "clock_jump", "counter")
        self.fault_kind: str | None = None
        #: host clock at the last frame kept
        self.last_frame_s: float | None = None

    def request_stop(self) -> None:
        self._stop_asked.set()

    def abandon(self) -> None:
        """Stop at the next read, logging nothing more (see the module)."""
        self._abandoned.set()
        self._stop_asked.set()

    def _say(self, message: str) -> None:
        if not self._abandoned.is_set():
            self._log(message)

    def run(self) -> None:
        try:
            self._drain()
        except Exception as exc:  # noqa: BLE001 - a reader that dies must end the stream with a name, not vanish
            self._fail(f"the stream reader failed ({type(exc).__name__}: {exc})", "reader")

    def _fail(self, fault: str, kind: str) -> None:
        with self._lock:
            if self.fault is None:
                self.fault, self.fault_kind = fault, kind
        self._on_fault()

    def covered_until_s(self) -> float:
        """Host time up to which the frames kept account for the stream (module docstring)."""
        if not self.frames:
            return self._started_s
        return self._started_s + (self.t_sensor_s[-1] - self.t_sensor_s[0]) + self._period_s

    def _stalled(self, now_s: float) -> bool:
        behind = now_s - self.covered_until_s()
        if behind <= self._stall_s:
            return False
        self._fail(f"no frame for {1e3 * behind:.0f} ms of the stream (stall_timeout_ms = {1e3 * self._stall_s:.0f}): "
                   f"the stream stalled after {len(self.frames)} frame(s)", "stall")
        return True

    def _drain(self) -> None:
        draining_since: float | None = None
        misses = 0
        while not self._abandoned.is_set():
            draining = self._stop_asked.is_set()
            now = self._clock_s()
            if draining and draining_since is None:
                draining_since = now
            if draining_since is not None and now - draining_since > self._stall_s:
                return self._fail(f"the sensor kept sending for {now - draining_since:.3f} s after stop_stream", "drain")
            try:
                data = self._read(self._poll_ms)
            except usb.core.USBTimeoutError:
                if draining:  # a read begun after the stop got nothing: drained
                    self._stalled(draining_since)
                    return
                if self._stalled(now):  # the clock as the read began: nothing was due then either
                    return
                continue
            except usb.core.USBError as exc:
                fault = self._recover(exc)
                misses += 1
                if fault is not None or misses > self._retries:
                    return self._fail(fault or f"USB error again and again ({exc})", "usb")
                continue
            try:
                frame = decode_frame(data, self._wire)
            except FrameFormatError as exc:
                misses += 1
                self._say(f"malformed frame skipped while streaming ({exc})")
                if misses > self._retries:
                    return self._fail(f"{misses} malformed frames in a row (last: {exc}); does sensor.wire match "
                                      "the device?", "malformed")
                continue
            misses = 0
            if not self._keep(frame):
                return

    def _keep(self, frame) -> bool:
        elapsed = self._max_elapsed_s() if not self.frames else float("inf")
        try:
            placed = self._stamps.add(frame.frame_counter, frame.timestamp_us, elapsed)
        except StampFault as exc:
            self._fail(str(exc), exc.kind)
            return False
        if placed.lost_before:
            self.lost += placed.lost_before
            self._say(f"{placed.lost_before} frame(s) lost before frame {frame.frame_counter}")
        if placed.late_s:
            self.late += 1
            self._say(f"frame {frame.frame_counter} was exposed {1e3 * placed.late_s:.3f} ms late (kept: its stamp "
                      "says when)")
        self.t_sensor_s.append(placed.t_sensor_s)
        self.frames.append(placed.frame)
        self.profiles.append(frame.points_mm)
        self.last_frame_s = self._clock_s()
        return True

    # --- results (read after the thread ended) ---------------------------------------
    @property
    def counts(self) -> ProfileStreamCounts:
        return ProfileStreamCounts(received=len(self.frames), lost=self.lost, late=self.late)

    def taken(self) -> ProfileStream | None:
        """The frames kept, as a ProfileStream (None when none were)."""
        if not self.frames:
            return None
        return ProfileStream.from_profiles(self.t_sensor_s, self.profiles, frame=self.frames)
