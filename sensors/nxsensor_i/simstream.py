"""Simulated time for the simulated nxSensor-I's stream: its clock, its schedule, its source.

In simulation, time is simulated: a stream's frames exist for the simulated interval
between the stream's start and the simulated time now (which a simulated move advances),
whatever the wall clock does. The simulated device (:mod:`.simbackend`) is given three
things, each replaceable so that a simulated world with a motion timeline can drive it:

* ``now_s()``: the true (simulated) time now, seconds. Default: a :class:`SimTime` of the
  backend's own, which stands still until :meth:`SimTime.advance_s` moves it;
* ``clock``: the sensor's own clock against true time, :class:`SensorClock` (an offset
  and a rate error); any object with ``to_sensor_s(T)`` and ``to_true_s(t)`` will do;
* ``source(T_true_s) -> (N, 2)``: the profile (y, z) mm the sensor sees at true time T.
  Default: :func:`cell_source` at the cell's current (static) pose.

:class:`FrameSchedule` is the device's internal trigger: frame k's exposure is centred on
the sensor-clock time ``t0 + (k + 1) * period`` (``t0`` the sensor's clock when the stream
started), so frames come at the sensor's rate on the sensor's clock.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np


class SimTime:
    """A simulated clock that moves only when told (true time, seconds)."""

    def __init__(self, start_s: float = 0.0):
        self._now_s = float(start_s)

    def now_s(self) -> float:
        return self._now_s

    def advance_s(self, dt_s: float) -> None:
        if not dt_s >= 0:
            raise ValueError(f"simulated time cannot go back: dt_s = {dt_s}")
        self._now_s += float(dt_s)


@dataclass(frozen=True)
class SensorClock:
    """The sensor's clock: ``t_sensor = offset_s + (1 + drift_ppm * 1e-6) * T_true``
    (seconds). ``offset_s`` puts its count anywhere (near its wrap, to exercise it)."""

    offset_s: float = 0.0
    drift_ppm: float = 0.0

    @property
    def rate(self) -> float:
        return 1.0 + self.drift_ppm * 1e-6

    def to_sensor_s(self, T_true_s: float) -> float:
        return self.offset_s + self.rate * T_true_s

    def to_true_s(self, t_sensor_s: float) -> float:
        return (t_sensor_s - self.offset_s) / self.rate


def cell_source(cell, pose_at: Callable[[float], object] | None = None, seed: int | None = 0,
                point_noise_mm: float | None = None) -> Callable[[float], np.ndarray]:
    """``source(T_true_s) -> (N, 2)``: the cell's ray caster at the flange pose
    ``pose_at(T)`` (default: the cell's current pose, a robot standing still), with the
    cell's point noise (or ``point_noise_mm``) drawn from a generator of its own seeded by
    ``seed``, so that a stream read by another thread draws nothing from the cell's."""
    rng = np.random.default_rng(seed)
    sigma = cell.noise.point_noise_mm if point_noise_mm is None else point_noise_mm

    def source(T_true_s: float) -> np.ndarray:
        pose = cell.current_base_from_flange if pose_at is None else pose_at(T_true_s)
        pts = cell.ideal_profile(pose)
        if len(pts) and sigma > 0:
            pts = pts + rng.normal(0.0, sigma, pts.shape)
        return pts

    return source


@dataclass(frozen=True)
class StreamedFrameTruth:
    """What the simulated device did for one streamed frame: its ``counter`` (as sent),
    the true time of its exposure's middle ``T_true_s``, the same on the sensor's clock
    ``t_sensor_s`` (not wrapped), how late it was exposed ``late_s``, and whether it was
    ``sent``."""

    counter: int
    T_true_s: float
    t_sensor_s: float
    late_s: float
    sent: bool


class FrameSchedule:
    """The internal trigger of one stream: started at true time ``T0_s`` with frame period
    ``period_s`` (sensor clock); stopped at ``end_s`` (true time), after which only the
    frames due before it remain to be read."""

    def __init__(self, clock, T0_s: float, period_s: float):
        self.clock = clock
        self.t0_sensor_s = clock.to_sensor_s(T0_s)
        self.period_s = period_s
        self.k = 0
        self.end_s: float | None = None

    def slot(self, k: int, late_s: float = 0.0) -> tuple[float, float]:
        """(T_true_s, t_sensor_s) of frame k's exposure middle, ``late_s`` after its slot."""
        t = self.t0_sensor_s + (k + 1) * self.period_s + late_s
        return self.clock.to_true_s(t), t

    def due(self, now_s: float, late_s: float = 0.0) -> bool:
        """Whether the next frame has been measured by true time ``now_s``."""
        horizon = now_s if self.end_s is None else min(now_s, self.end_s)
        return self.slot(self.k, late_s)[0] <= horizon
