"""A stream's frames on the sensor's clock: unwrapping its timestamp and frame counter.

While streaming, the nxSensor-I (as assumed in :mod:`.wire`) measures one frame every set
period on its own clock and sends each with two wrapping counters: the frame counter (+1
per measured frame, sent or not) and the timestamp (counts of ``timestamp_us_per_count``
us). :class:`StreamStamps` turns them into what a recording needs:

* ``frame``: the counter unwrapped into a growing integer (a stream's first frame keeps
  the number the sensor sent), so that its gaps are the lost frames (measured by the
  sensor, never received: dropped in the device, on the bus, or corrupt);
* ``t_sensor_s``: the timestamp unwrapped into seconds of the sensor's clock, monotonic
  across the timestamp's wrap (every 71.6 min with the default u32 microseconds), moved
  to the middle of the exposure (``timestamp_marks``).

A wrap is told from a step backwards by the counter: each step of the timestamp, taken
modulo its wrap, must be close to the counter's step times the frame period. So:

* a step within ``late_after_s`` of that is on time;
* a step longer by more than ``late_after_s`` (and at most ``clock_jump_s``) is a **late**
  frame: the sensor exposed it late (its trigger slipped). Its stamp says when, so it is
  kept, and counted;
* a step longer by more than ``clock_jump_s`` is a **clock jump**, and a step that goes
  backwards or does not advance (taken modulo the wrap, more than half the wrap forward)
  is a **clock going backwards**: the stamps can no longer be trusted, and
  :class:`StampFault` is raised;
* a counter that repeats or goes backwards (more than half its wrap forward) is a
  :class:`StampFault` too: the sensor does not number its frames as assumed.

The first frame of a stream has no schedule to be late against. Stamps continue across
the streams of one device session (the first frame of a later stream is placed by the
timestamp's step modulo its wrap, which must not exceed the time that can have passed:
``max_elapsed_s``); counters do not (a gap between two streams is not a loss). Pure
logic, no I/O.
"""

from __future__ import annotations

from dataclasses import dataclass

from spherecal.plugins import DeviceError


class StampFault(DeviceError):
    """A frame's counter or timestamp breaks the stream's time line; ``kind`` is
    ``"clock_backwards"``, ``"clock_jump"`` or ``"counter"``."""

    def __init__(self, message: str, kind: str):
        super().__init__(message)
        self.kind = kind


@dataclass(frozen=True)
class StampedFrame:
    """One frame placed on the sensor's time line: ``frame`` the unwrapped counter,
    ``t_sensor_s`` the middle of its exposure (sensor clock, s), ``lost_before`` frames
    the sensor numbered between the previous frame of the stream and this one,
    ``late_s`` how much later than its slot it was exposed (0 when on time)."""

    frame: int
    t_sensor_s: float
    lost_before: int
    late_s: float


class StreamStamps:
    """Unwraps one device session's frame counters and timestamps (see the module).

    ``counter_modulus``, ``stamp_modulus``: where the two counters wrap; ``tick_s``: seconds
    per timestamp count. Each stream then says its frame period, the shift from a stamp to
    its exposure's middle and the limits above (:meth:`begin_stream`)."""

    def __init__(self, counter_modulus: int, stamp_modulus: int, tick_s: float):
        if counter_modulus < 4 or stamp_modulus < 4:
            raise ValueError(f"counter and stamp moduli must be at least 4, got {counter_modulus} and {stamp_modulus}")
        if not tick_s > 0:
            raise ValueError(f"tick_s must be positive, got {tick_s}")
        self.counter_modulus = counter_modulus
        self.stamp_modulus = stamp_modulus
        self.tick_s = tick_s
        self.period_s = 1.0
        self.middle_shift_s = 0.0
        self.late_after_s, self.clock_jump_s = 0.5, 4.0
        self._stamp: int | None = None  # last raw stamp
        self._ticks = 0  # last stamp unwrapped, in counts
        self._counter: int | None = None  # last raw counter of this stream
        self._frame = 0  # last counter unwrapped (from the stream's first)

    @property
    def wrap_s(self) -> float:
        """The timestamp's wrap, seconds of the sensor's clock."""
        return self.stamp_modulus * self.tick_s

    @property
    def continues(self) -> bool:
        """Whether the next stream's stamps continue this session's count."""
        return self._stamp is not None

    def begin_stream(self, period_s: float, middle_shift_s: float = 0.0, late_after_s: float | None = None,
                     clock_jump_s: float | None = None) -> None:
        """A new stream starts at frame period ``period_s`` (sensor clock, s); every stamp
        is moved by ``middle_shift_s`` to its exposure's middle; a frame more than
        ``late_after_s`` after its slot is late (default half a period), more than
        ``clock_jump_s`` is a clock jump (default four periods)."""
        late_after_s = 0.5 * period_s if late_after_s is None else late_after_s
        clock_jump_s = 4.0 * period_s if clock_jump_s is None else clock_jump_s
        if not period_s > 0 or not 0 < late_after_s < clock_jump_s:
            raise ValueError(f"need period_s > 0 and 0 < late_after_s < clock_jump_s, got {period_s}, "
                             f"{late_after_s} and {clock_jump_s}")
        if period_s + clock_jump_s >= 0.5 * self.wrap_s:
            raise ValueError(f"a frame period of {period_s} s (with clock_jump_s {clock_jump_s} s) is not well below "
                             f"half the timestamp's wrap ({self.wrap_s} s): its wraps cannot be told apart")
        self.period_s, self.middle_shift_s = period_s, middle_shift_s
        self.late_after_s, self.clock_jump_s = late_after_s, clock_jump_s
        self._counter = None

    def new_session(self) -> None:
        """The sensor's clock cannot be followed from the last frame (the device was
        reopened, or too long has passed): the next frame's count starts the time line."""
        self._stamp = None
        self._counter = None

    def _t(self, ticks: int) -> float:
        return ticks * self.tick_s + self.middle_shift_s

    def add(self, counter: int, stamp: int, max_elapsed_s: float = float("inf")) -> StampedFrame:
        """Place the next frame received; raises :class:`StampFault` (see the module).
        ``max_elapsed_s``: for a stream's first frame continuing the session, the most
        sensor-clock time that can have passed since the session's last frame (beyond
        half the wrap the count cannot be followed: the session starts afresh)."""
        counter, stamp = int(counter) % self.counter_modulus, int(stamp) % self.stamp_modulus
        if self._stamp is None:  # the session's first frame: its count is where the clock stands
            self._stamp, self._ticks, self._counter, self._frame = stamp, stamp, counter, counter
            return StampedFrame(counter, self._t(stamp), 0, 0.0)
        if self._counter is None and max_elapsed_s >= 0.5 * self.wrap_s:
            self._stamp = None
            return self.add(counter, stamp)
        step_counts = (stamp - self._stamp) % self.stamp_modulus
        if self._counter is None:  # a stream's first frame, continuing the session's clock
            step_s = step_counts * self.tick_s
            if step_counts == 0 or step_s > max_elapsed_s:
                raise StampFault(
                    f"the sensor's clock did not continue between two streams: frame {counter} is stamped {stamp} "
                    f"(counts of {self.tick_s * 1e6:g} us), {step_s:.6f} s after the previous stream's last frame "
                    f"modulo the wrap, but at most {max_elapsed_s:.3f} s can have passed: it went back or "
                    "was reset", "clock_backwards")
            self._stamp, self._counter, self._frame = stamp, counter, counter
            self._ticks += step_counts
            return StampedFrame(counter, self._t(self._ticks), 0, 0.0)
        steps = (counter - self._counter) % self.counter_modulus
        if steps == 0 or steps >= self.counter_modulus // 2:
            behind = (self._counter - counter) % self.counter_modulus
            raise StampFault(
                f"frame counter {'repeated' if steps == 0 else f'went back by {behind}'}: frame {counter} after "
                f"frame {self._counter}; the sensor does not number its frames +1 per frame as sensor.wire assumes "
                f"(header field frame_counter, wrapping at {self.counter_modulus})", "counter")
        if step_counts == 0 or step_counts >= self.stamp_modulus // 2:
            back_s = ((self._stamp - stamp) % self.stamp_modulus) * self.tick_s
            what = "did not advance" if step_counts == 0 else f"went back by {back_s * 1e3:.3f} ms"
            raise StampFault(
                f"the sensor's timestamp {what} at frame {counter} (stamp {stamp} after "
                f"{self._stamp}, counts of {self.tick_s * 1e6:g} us, wrapping at {self.stamp_modulus}); not a wrap: "
                f"{steps} frame period(s) of {self.period_s * 1e3:.3f} ms had to pass", "clock_backwards")
        late_s = step_counts * self.tick_s - steps * self.period_s
        if late_s > self.clock_jump_s:
            raise StampFault(
                f"the sensor's clock jumped {late_s * 1e3:.3f} ms ahead at frame {counter}: its stamp is "
                f"{step_counts * self.tick_s * 1e3:.3f} ms after the previous frame's, {steps} frame period(s) "
                f"({steps * self.period_s * 1e3:.3f} ms) by the counter (more than clock_jump_periods)", "clock_jump")
        self._stamp, self._counter = stamp, counter
        self._ticks += step_counts
        self._frame += steps
        return StampedFrame(self._frame, self._t(self._ticks), steps - 1, late_s if late_s > self.late_after_s else 0.0)
