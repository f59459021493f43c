"""The simulated world as live streaming devices see it: what a simulated run hands the
device factories (``DeviceContext.extras``) so that the simulated controller's pose
stream and the simulated sensor's profile stream follow the arm over the cell's true
time, each stamped by its own clock.

- The pose stream: what the controller reports at true time T
  (:meth:`~spherecal.sim.timeline.MotionTimeline.reported_at`: its nominal model's pose
  of its joints), stamped by the controller's clock (``cell.controller_clock``).
- The profile stream: what the sensor sees where the flange truly is at T
  (:meth:`~spherecal.sim.timeline.MotionTimeline.pose_at`: the arm's true geometry, and
  its repeatability, :func:`add_repeatability`), with the cell's point noise, stamped by
  the sensor's clock read as its hardware counts it (:class:`CounterClock`).
- The simulated time both run on: the cell's :class:`~spherecal.sim.timeline.SimClock`.

The keys are the plugin API's (``spherecal.plugins.POSE_STREAM_SOURCE_KEY`` and the
``SIM_*_KEY`` names, defined in :mod:`spherecal.devices.contract` and re-exported here),
which the built-in plugins read (docs/robot-abb-irb2400.md and docs/sensor-nxsensor-i.md,
"Simulation"); a plugin that knows none of them ignores them.
:func:`clock_truth` and :func:`true_time_relation` give the truth of the two clocks'
relation as docs/conventions.md defines it ("Time: two clocks"), to compare an
on-the-fly calibration's clock offset with.
"""

from __future__ import annotations

from typing import Any, Callable

import numpy as np

from spherecal.core.models import Pose
from spherecal.devices.contract import (POSE_STREAM_SOURCE_KEY, SIM_CLOCK_KEY, SIM_CONTROLLER_CLOCK_KEY, SIM_NOW_KEY,
                                        SIM_PROFILE_SOURCE_KEY, SIM_SENSOR_CLOCK_KEY)
from spherecal.sim.timeline import DeviceClock, SmoothNoise

__all__ = ["POSE_STREAM_SOURCE_KEY", "SIM_CLOCK_KEY", "SIM_CONTROLLER_CLOCK_KEY", "SIM_NOW_KEY",
           "SIM_PROFILE_SOURCE_KEY", "SIM_SENSOR_CLOCK_KEY", "CounterClock", "add_repeatability", "clock_truth",
           "device_extras", "profile_source", "true_time_relation"]

#: Correlation time of the arm's repeatability error along a move, s (as the simulated
#: recordings' default: a real arm's path error is smooth over tens of milliseconds).
REPEATABILITY_CORRELATION_S = 0.05


class CounterClock:
    """A device's clock (:class:`~spherecal.sim.timeline.DeviceClock`) read as its
    hardware counts it: from the device's power-on, without the clock's epoch. A sensor
    stamping frames with a 32-bit microsecond counter cannot count from 1970; its count
    is the clock's ``offset_s + (1 + drift_ppm 1e-6) T``. Gives ``to_sensor_s`` and
    ``to_true_s`` (the simulated sensor's interface)."""

    def __init__(self, clock: DeviceClock):
        self.clock = clock

    @property
    def offset_s(self) -> float:
        return float(self.clock.offset_s)

    @property
    def rate(self) -> float:
        return float(self.clock.rate)

    def to_sensor_s(self, T_true_s):
        return self.clock.offset_s + self.clock.rate * np.asarray(T_true_s, dtype=float)

    def to_true_s(self, t_sensor_s):
        return (np.asarray(t_sensor_s, dtype=float) - self.clock.offset_s) / self.clock.rate


def add_repeatability(cell, correlation_s: float = REPEATABILITY_CORRELATION_S) -> None:
    """Give the cell's arm a repeatability error smooth in time, as a real arm's path
    error along a move is: the true flange (``timeline.pose_at``) leaves the reported path
    by a Gauss-Markov process per base axis with the cell's robot pose noise
    (``noise.pose_translation_noise_mm``, ``pose_rotation_noise_deg``), drawn from the
    device stream "repeatability". The controller's report does not see it. Stop-and-go
    shots are unchanged (they measure where the controller put the flange)."""
    n = cell.noise
    if n.pose_translation_noise_mm <= 0 and n.pose_rotation_noise_deg <= 0:
        return
    cell.timeline.repeatability = SmoothNoise(n.pose_translation_noise_mm, n.pose_rotation_noise_deg, correlation_s,
                                              cell.device_rng("repeatability"), T0_s=cell.clock.now_s)


def profile_source(cell, rng: np.random.Generator | None = None) -> Callable[[float], np.ndarray]:
    """``source(T_true_s) -> (N, 2)``: the cell's ray caster at the flange's true pose at
    T (``cell.timeline.pose_at``), with the cell's point noise drawn from ``rng``
    (default: the device stream "sensor stream")."""
    rng = rng if rng is not None else cell.device_rng("sensor stream")
    sigma = cell.noise.point_noise_mm

    def source(T_true_s: float) -> np.ndarray:
        R, t, _ = cell.timeline.pose_at(np.array([float(T_true_s)]))
        pts = cell.ideal_profile(Pose.from_rt(R[0], t[0]))
        if len(pts) and sigma > 0:
            pts = pts + rng.normal(0.0, sigma, pts.shape)
        return pts

    return source


def device_extras(cell) -> dict[str, Any]:
    """What a simulated run gives the device factories besides the cell (the module's
    docstring): the controller's report and clock, the sensor's view and clock, and the
    simulated time."""
    clock = cell.clock
    return {
        POSE_STREAM_SOURCE_KEY: cell.timeline.reported_at,
        SIM_CLOCK_KEY: lambda: clock.now_s,
        SIM_CONTROLLER_CLOCK_KEY: cell.controller_clock,
        SIM_NOW_KEY: lambda: clock.now_s,
        SIM_SENSOR_CLOCK_KEY: CounterClock(cell.sensor_clock),
        SIM_PROFILE_SOURCE_KEY: profile_source(cell),
    }


def clock_truth(cell) -> dict[str, dict[str, float]]:
    """The two stream clocks of :func:`device_extras` against true time T, for a
    recording's provenance: each reads ``epoch_s + offset_s + rate T`` (the sensor's
    counter has no epoch)."""
    c, s = cell.controller_clock, CounterClock(cell.sensor_clock)
    return {"robot": {"epoch_s": float(c.epoch_s), "offset_s": float(c.offset_s), "rate": float(c.rate)},
            "sensor": {"epoch_s": 0.0, "offset_s": s.offset_s, "rate": s.rate}}


def true_time_relation(truth: dict, t_sensor0_s: float) -> tuple[float, float]:
    """``(offset_s, drift)`` of ``t_robot = t_sensor + offset + drift (t_sensor -
    t_sensor0)`` (docs/conventions.md) for clocks described as :func:`clock_truth`
    describes them: exact for linear clocks. ``t_sensor0_s``: the recording's first
    profile stamp."""
    r, s = truth["robot"], truth["sensor"]
    ratio = float(r["rate"]) / float(s["rate"])
    T0 = (float(t_sensor0_s) - float(s["epoch_s"]) - float(s["offset_s"])) / float(s["rate"])
    t_robot0 = float(r["epoch_s"]) + (float(r["offset_s"]) + float(r["rate"]) * T0)
    return t_robot0 - float(t_sensor0_s), ratio - 1.0
