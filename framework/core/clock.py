"""The relation between the sensor's clock and the robot's (docs/conventions.md, "Time"):

    t_robot = t_sensor + offset_s + drift * (t_sensor - t_sensor0)

with ``t_sensor0`` the recording's first profile stamp, stamps in seconds and ``drift``
dimensionless (ppm is drift * 1e6). Numpy only: the estimator's time effects use it
without loading the recordings' data model (:mod:`spherecal.core.streams`).

:class:`ClockRelation` is that relation as a scan uses it after the calibration: the
numbers with their standard deviations (so that the time error at a stamp far from
``t_sensor0`` can be stated), and where they come from."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["ClockRelation", "sensor_to_robot_time"]


def sensor_to_robot_time(t_sensor_s, offset_s: float, drift: float, t_sensor0_s: float) -> np.ndarray:
    """Robot-clock time of sensor-clock stamps: ``t + offset + drift (t - t0)`` (drift
    dimensionless; ppm is drift * 1e6)."""
    t = np.asarray(t_sensor_s, dtype=float)
    return t + offset_s + drift * (t - t_sensor0_s)


@dataclass(frozen=True)
class ClockRelation:
    """``t_robot = t_sensor + offset_s + drift (t_sensor - t_sensor0_s)`` with its
    1-sigma uncertainty (``offset_std_s``, ``drift_std``, their ``correlation``; None:
    not known, the relation was given, not estimated) and ``source`` (where it comes
    from, for messages and file headers)."""

    offset_s: float
    drift: float
    t_sensor0_s: float
    offset_std_s: float | None
    drift_std: float | None
    correlation: float = 0.0
    source: str = ""

    @classmethod
    def from_timing(cls, timing, source: str = "") -> "ClockRelation":
        """From a result's ``timing`` (:class:`~spherecal.core.models.TimingEstimate`:
        ms and ppm)."""
        return cls(timing.offset_ms * 1e-3, timing.drift_ppm * 1e-6, timing.t_sensor0_s, timing.offset_std_ms * 1e-3,
                   timing.drift_std_ppm * 1e-6, float(timing.offset_drift_correlation), source)

    @property
    def estimated(self) -> bool:
        return self.offset_std_s is not None

    def robot_time(self, t_sensor_s) -> np.ndarray:
        """Robot-clock times of sensor-clock stamps (s)."""
        return sensor_to_robot_time(t_sensor_s, self.offset_s, self.drift, self.t_sensor0_s)

    def std_s(self, t_sensor_s) -> np.ndarray | None:
        """1-sigma of :meth:`robot_time` at each stamp (s): the offset's, and the drift's
        grown with the time since ``t_sensor0_s``; None when not known."""
        if self.offset_std_s is None:
            return None
        d = np.asarray(t_sensor_s, dtype=float) - self.t_sensor0_s
        sd = float(self.drift_std or 0.0)
        var = self.offset_std_s ** 2 + (sd * d) ** 2 + 2 * self.correlation * self.offset_std_s * sd * d
        return np.sqrt(np.maximum(var, 0.0))
