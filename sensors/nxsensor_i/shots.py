"""Which frame belongs to which trigger: by the sensor's frame counter, never by timing.

The nxSensor-I (as assumed in :mod:`.wire`) numbers every profile it measures, +1 per
profile, wrapping at ``WireConfig.frame_counter_modulus``; one ``trigger`` measures one
profile. So once the driver knows the counter the device will give its next profile,
it knows the counter of every trigger it sends, and a frame that arrives can be told
apart from a late frame of an earlier shot however late that one is.

:class:`FrameCounter` keeps that knowledge as an interval ``[lo, hi]`` of unwrapped
integers holding the counter of the next measured profile:

* exact (``lo == hi``) in the normal case;
* wider when a trigger's transfer failed in a way that leaves open whether the device
  measured (``hi`` grows, ``lo`` does not), or when the shot that synchronised needed
  several triggers (the frame received may be any of theirs); frames received later
  narrow it again (a frame numbered ``u`` proves the next one is at least ``u + 1``);
* unknown (``None``) after the device was opened, reopened or reset, or streamed: the
  driver then flushes the input (reads until nothing comes) and the first frame of the
  next shot gives the counter (a *synchronising* shot).

A frame received during a shot is placed by :meth:`FrameCounter.place`:

* numbered at or above ``hi`` as the shot began, and below ``hi`` now: one of this
  shot's triggers measured it, at this shot's pose: **this shot's**;
* numbered below that: an earlier shot's (certainly, below ``lo`` as the shot began;
  possibly, between ``lo`` and ``hi``): **discarded** (an over-wide interval can cost a
  frame of this shot and a new trigger, never a wrong pairing);
* numbered at or above ``hi`` now: no trigger of this driver can have measured it
  (another program triggers the sensor, or the device counts otherwise than assumed):
  :class:`CounterMismatch`.

"Below" and "above" are taken modulo the counter's wrap: a frame is behind when it is
less than half the modulus behind ``hi`` (2**31 frames with the default u32 counter).
Pure logic, no I/O: the driver calls it around its USB transfers.
"""

from __future__ import annotations

from dataclasses import dataclass

from spherecal.plugins import DeviceError


class CounterMismatch(DeviceError):
    """A frame whose counter no trigger of this shot (or an earlier one) can have given."""


@dataclass
class Shot:
    """One shot (one ``read_frame``): the interval as it began, or ``sync`` when the
    counter was unknown (the first frame after a flush is then this shot's)."""

    sync: bool
    lo0: int = 0
    hi0: int = 0


class FrameCounter:
    """The counter of the device's next measured profile, as an interval (see the module)."""

    def __init__(self, modulus: int):
        if modulus < 4:
            raise ValueError(f"frame counter modulus must be at least 4, got {modulus}")
        self.modulus = modulus
        self.lo: int | None = None
        self.hi: int | None = None
        #: triggers sent since the input was flushed: certainly measured, possibly measured
        self._since_flush = [0, 0]

    # state ----------------------------------------------------------------------------
    @property
    def known(self) -> bool:
        return self.lo is not None

    @property
    def exact(self) -> bool:
        return self.lo is not None and self.lo == self.hi

    def forget(self) -> None:
        """The counter is unknown (device opened, reopened, reset, or streamed) and the
        input has just been flushed: the next shot synchronises."""
        self.lo = self.hi = None
        self._since_flush = [0, 0]

    def begin_shot(self) -> Shot:
        if self.lo is None:
            return Shot(sync=True)
        return Shot(sync=False, lo0=self.lo, hi0=self.hi)

    # triggers -------------------------------------------------------------------------
    def sending_trigger(self) -> None:
        """Before a trigger is sent: it may measure a profile from now on."""
        if self.hi is None:
            self._since_flush[1] += 1
        else:
            self.hi += 1

    def trigger_sent(self) -> None:
        """The trigger's transfer succeeded: the device measured a profile."""
        if self.lo is None:
            self._since_flush[0] += 1
        else:
            self.lo += 1

    def trigger_refused(self) -> None:
        """The device refused the trigger (a stalled request): nothing was measured."""
        if self.hi is None:
            self._since_flush[1] -= 1
        else:
            self.hi -= 1

    # frames ---------------------------------------------------------------------------
    def place(self, shot: Shot, counter: int) -> bool:
        """True if the frame numbered ``counter`` is this shot's, False if it is an
        earlier shot's (discard it); raises :class:`CounterMismatch` otherwise."""
        counter = int(counter) % self.modulus
        if shot.sync:
            # the first frame after the flush: one of the triggers sent since measured it
            self.lo = counter + 1
            self.hi = counter + max(self._since_flush[1], 1)
            shot.sync = False
            shot.lo0, shot.hi0 = counter, counter
            return True
        behind = (self.hi - 1 - counter) % self.modulus
        if behind >= self.modulus // 2:
            raise CounterMismatch(
                f"frame {counter} arrived, but the triggers sent so far can have numbered frames only up to "
                f"{self.name(self.hi - 1)}: this driver did not trigger it (does another program use the sensor?), "
                "or the sensor does not number one frame per trigger as sensor.wire assumes (header field "
                f"frame_counter, wrapping at {self.modulus})"
            )
        u = self.hi - 1 - behind
        self.lo = max(self.lo, u + 1)
        return u >= shot.hi0

    def name(self, u: int) -> int:
        """The counter as the device writes it (wrapped)."""
        return u % self.modulus

    def expected(self, shot: Shot) -> str:
        """This shot's counters in words, for messages."""
        if shot.sync:
            return "any (the counter is being synchronised)"
        first, last = self.name(shot.hi0), self.name(self.hi - 1)
        return str(first) if first == last else f"{first}..{last}"
