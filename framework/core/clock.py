"""The relation between the sensor's clock and the robot's (docs/conventions.md, "Time"):

    t_robot = t_sensor + offset_s + drift * (t_sensor - t_sensor0)

with ``t_sensor0`` the recording's first profile stamp, stamps in seconds and ``drift``
dimensionless (ppm is drift * 1e6). Numpy only: the estimator's time effects use it
without loading the recordings' data model (:mod:`spherecal.core.streams`)."""

from __future__ import annotations

import numpy as np

__all__ = ["sensor_to_robot_time"]


def sensor_to_robot_time(t_sensor_s, offset_s: float, drift: float, t_sensor0_s: float) -> np.ndarray:
    """Robot-clock time of sensor-clock stamps: ``t + offset + drift (t - t0)`` (drift
    dimensionless; ppm is drift * 1e6)."""
    t = np.asarray(t_sensor_s, dtype=float)
    return t + offset_s + drift * (t - t_sensor0_s)
