"""The relation between the sensor's clock and the robot's, estimated with the transform.

A profile stamped ``t_s`` on the sensor's clock was exposed at robot time
``t_r = t_s + offset + drift (t_s - t_s0)`` (:func:`spherecal.core.streams.sensor_to_robot_time`);
its flange pose is the pose stream's at ``t_r``. The fit carries the two as fixed
effects, the offset in milliseconds and the drift in parts per million (so that their
columns are of the size of the others'): each shot's pose is re-read from the stream
whenever they move, and the derivative of shot i's predicted sphere centre with respect
to them is its derivative with respect to a flange pose error (``Jd``) applied to the
flange's velocity (the twist: spatial angular velocity and the origin's velocity) at
``t_r``, times dt_r/d(offset_ms) = 1e-3 s and dt_r/d(drift_ppm) = 1e-6 (t_s - t_s0) s.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import TYPE_CHECKING

import numpy as np

from spherecal.core.clock import sensor_to_robot_time
from spherecal.estimation.problem import Problem, sphere_from_mount

if TYPE_CHECKING:
    from spherecal.core.streams import PoseStream

#: Seconds per unit of the fit's time parameters: offset in ms, drift in ppm.
OFFSET_UNIT_S = 1e-3
DRIFT_UNIT = 1e-6


@dataclass(frozen=True)
class TimeEffects:
    """The clock relation as unknowns of the fit.

    ``stream``: the pose stream (robot clock); the problem's shots carry their sensor
    stamps (:attr:`Problem.t_sensor_s`); ``t_sensor0_s`` the drift's reference time;
    ``offset_ms`` and ``drift_ppm`` where the fit starts; ``estimate_drift`` False holds
    the drift at its start (a recording too short to see it). ``q_model_rad`` (samples,
    J): the stream's joints as the arm model's angles (rad), for the kinematic robot
    error model (read at a shot's time by linear interpolation, as the poses are)."""

    stream: PoseStream
    t_sensor0_s: float
    offset_ms: float = 0.0
    drift_ppm: float = 0.0
    estimate_drift: bool = True
    q_model_rad: np.ndarray | None = None

    @property
    def n_parameters(self) -> int:
        return 2 if self.estimate_drift else 1

    def robot_times(self, t_sensor_s: np.ndarray, tau: np.ndarray) -> np.ndarray:
        """Robot-clock times of the shots at ``tau`` = (offset_ms, drift_ppm)."""
        return sensor_to_robot_time(t_sensor_s, tau[0] * OFFSET_UNIT_S, tau[1] * DRIFT_UNIT, self.t_sensor0_s)

    def start(self) -> np.ndarray:
        return np.array([self.offset_ms, self.drift_ppm], dtype=float)


@dataclass(frozen=True)
class TimedShots:
    """The shots' poses at a clock relation: the problem re-read from the stream, each
    shot's twist (n, 6: spatial angular velocity rad/s, then velocity mm/s) and whether
    its time falls where the stream has samples around it (``ok``)."""

    problem: Problem
    twist: np.ndarray
    ok: np.ndarray


def shots_at(problem: Problem, te: TimeEffects, tau: np.ndarray) -> TimedShots:
    """``problem`` with every shot's flange pose (and joints) read from the stream at its
    robot time under ``tau`` = (offset_ms, drift_ppm)."""
    at = te.stream.at(te.robot_times(problem.t_sensor_s, tau))
    R_sm, t_sm = sphere_from_mount(problem.mounting, at.R, at.t)
    q_rad = problem.q_rad
    if te.q_model_rad is not None and problem.q_rad is not None:
        t_r = te.robot_times(problem.t_sensor_s, tau)
        q_rad = np.stack([np.interp(t_r, te.stream.t_robot_s, q) for q in te.q_model_rad.T], axis=1)
    moved = replace(problem, R0=at.R, t0=at.t, R_sphere_from_mount=R_sm, t_sphere_from_mount=t_sm, q_rad=q_rad)
    return TimedShots(moved, np.concatenate([at.omega_rad_s, at.v_mm_s], axis=1), at.ok)


def time_design(problem: Problem, te: TimeEffects, twist: np.ndarray) -> np.ndarray:
    """d(flange pose error)/d(offset_ms, drift_ppm) per shot, (n, 6, 1 or 2): the twist
    times each parameter's effect on the shot's robot time."""
    dt_offset = np.full(problem.n_profiles, OFFSET_UNIT_S)
    cols = [dt_offset]
    if te.estimate_drift:
        cols.append(DRIFT_UNIT * (problem.t_sensor_s - te.t_sensor0_s))
    return twist[:, :, None] * np.stack(cols, axis=1)[:, None, :]


def with_start(te: TimeEffects, timing: dict | None) -> TimeEffects:
    """``te`` starting where an earlier fit's clock relation (``RefineResult.timing``) ended."""
    if timing is None:
        return te
    return replace(te, offset_ms=timing["offset_ms"], drift_ppm=timing["drift_ppm"])
