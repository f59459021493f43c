"""The programmed-line pose stream: poses computed along each move's programmed line,
for a controller that cannot stream its measured pose (an S4C+).

The controller stamps, with its own clock (``SpherecalLine.mod``), when each move's path
passed ``stamp_distance_mm`` from its start point and when the arm was in position at
its end. The flange is taken to follow the straight line from the start pose to the
target as a ``MoveL`` interpolates it: the translation along the line and the rotation
about one fixed axis, both at one path fraction ``u``, with a trapezoidal speed profile
(cruise at the move's speed, ``acceleration_mm_s2`` at both ends), placed in time so
that it passes the stamp's distance at the stamp. ``u`` runs over the longer of the
move's travel and its turn at the move's speeds (``v_tcp`` and ``v_ori``), as speeddata
limits a ``MoveL``. Before a move's start and after its end the arm stands.

Why a stamp past the start: on the constant-speed part the flange is where the stamp
puts it plus speed x time, whatever the acceleration was; timed from the path's start
instead, an acceleration off by da would shift the whole constant-speed part by
``v / 2 (1 / a_true - 1 / a_assumed)``, a lag that grows with the speed (6 ms, 0.6 mm, at
100 mm/s with 2,000 mm/s^2 assumed and 1,600 true), which a clock offset cannot absorb
across two speeds. A move whose assumed ramp reaches the stamp's distance (with a third
of margin) is not timed that way: all its samples are marked ``on_ramp``.

:func:`programmed_line_stream` samples that on the controller's clock every
``sample_period_ms`` (stamps in seconds since the clock's reset) and marks ``on_ramp``
the samples within ``ramp_margin_s`` of a speed ramp (where an acceleration assumed
wrong moves the computed pose most; a solve leaves the profiles there out). The
stream's ``assumption`` says that the poses are not measured.

Poses are ``base_from_flange`` in mm; rotations as matrices; quaternions nowhere here.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from typing import TYPE_CHECKING

from spherecal.plugins import Pose, PoseStreamClockError, matrix_from_rotvec, rotvec_from_matrix

from .config import ProgrammedLineSettings

if TYPE_CHECKING:  # pragma: no cover - the streams' model is loaded when a stream is computed
    from spherecal.plugins import PoseStream

__all__ = ["ProgrammedMove", "check_move_stamps", "line_fraction", "motion_duration_s", "programmed_line_stream",
           "time_at_distance_s"]


@dataclass(frozen=True)
class ProgrammedMove:
    """One stamped move: from ``start`` to ``end`` (base_from_flange, mm) at
    ``speed_mm_s`` (v_tcp) and ``orientation_speed_deg_s`` (v_ori); the controller's
    clock (s since its reset) when the path passed ``stamp_distance_mm`` from its start
    (``t_stamp_s``), the same distance before its end (``t_cruise_end_s``), and when the
    arm was in position at its end (``t_end_s``)."""

    start: Pose
    end: Pose
    speed_mm_s: float
    orientation_speed_deg_s: float
    t_stamp_s: float
    t_cruise_end_s: float
    t_end_s: float
    stamp_distance_mm: float = 0.0

    @property
    def length_mm(self) -> float:
        """The path's length in mm of travel: the longer of the travel and the turn at
        the move's speeds (speeddata limits a MoveL by both)."""
        travel = float(np.linalg.norm(self.end.translation - self.start.translation))
        turn_deg = float(np.degrees(np.linalg.norm(rotvec_from_matrix(
            self.start.rotation_matrix.T @ self.end.rotation_matrix))))
        return max(travel, turn_deg * self.speed_mm_s / self.orientation_speed_deg_s if turn_deg > 1e-9 else 0.0)


def motion_duration_s(length_mm: float, speed_mm_s: float, acceleration_mm_s2: float) -> float:
    """Time of a rest-to-rest trapezoidal move: ``length / speed + speed / accel`` when it
    reaches the cruise speed, else ``2 sqrt(length / accel)``."""
    if length_mm <= 0:
        return 0.0
    if length_mm >= speed_mm_s**2 / acceleration_mm_s2:
        return length_mm / speed_mm_s + speed_mm_s / acceleration_mm_s2
    return 2.0 * float(np.sqrt(length_mm / acceleration_mm_s2))


def line_fraction(tau_s, length_mm: float, speed_mm_s: float, acceleration_mm_s2: float) -> np.ndarray:
    """Path fraction u in [0, 1] at ``tau_s`` after the start of a trapezoidal move."""
    tau = np.asarray(tau_s, dtype=float)
    if length_mm <= 0:
        return np.ones_like(tau)
    total = motion_duration_s(length_mm, speed_mm_s, acceleration_mm_s2)
    tau = np.clip(tau, 0.0, total)
    peak = min(speed_mm_s, float(np.sqrt(length_mm * acceleration_mm_s2)))
    ramp = peak / acceleration_mm_s2
    up = 0.5 * acceleration_mm_s2 * tau**2
    cruise = 0.5 * peak * ramp + peak * (tau - ramp)
    down = length_mm - 0.5 * acceleration_mm_s2 * (total - tau) ** 2
    s = np.where(tau <= ramp, up, np.where(total - tau <= ramp, down, cruise))
    return np.clip(s / length_mm, 0.0, 1.0)


def time_at_distance_s(distance_mm: float, length_mm: float, speed_mm_s: float, acceleration_mm_s2: float) -> float:
    """When a trapezoidal move of ``length_mm`` passes ``distance_mm`` from its start, s
    (the end, for a distance beyond it)."""
    total = motion_duration_s(length_mm, speed_mm_s, acceleration_mm_s2)
    d = min(max(distance_mm, 0.0), length_mm)
    if length_mm <= 0:
        return 0.0
    peak = min(speed_mm_s, float(np.sqrt(length_mm * acceleration_mm_s2)))
    ramp_mm = 0.5 * peak**2 / acceleration_mm_s2
    if d <= ramp_mm:
        return float(np.sqrt(2.0 * d / acceleration_mm_s2))
    if d <= length_mm - ramp_mm:
        return peak / acceleration_mm_s2 + (d - ramp_mm) / peak
    return total - float(np.sqrt(2.0 * (length_mm - d) / acceleration_mm_s2))


@dataclass(frozen=True)
class _Timing:
    """A move as assumed, s after its path's start: the motion's duration, the end of the
    acceleration ramp, the start of the deceleration ramp, when it passes the stamp's
    distance and the same distance before its end, and whether both lie on the
    constant-speed part (with half a ramp's length of margin)."""

    total: float
    up_end: float
    down_start: float
    stamp: float
    cruise_end: float
    stamp_on_cruise: bool


def _timing(move: ProgrammedMove, settings: ProgrammedLineSettings) -> _Timing:
    a = settings.acceleration_mm_s2
    length = move.length_mm
    total = motion_duration_s(length, move.speed_mm_s, a)
    peak = min(move.speed_mm_s, float(np.sqrt(length * a))) if length > 0 else 0.0
    ramp_mm = 0.5 * peak**2 / a
    d = move.stamp_distance_mm
    on_cruise = peak >= move.speed_mm_s and 1.5 * ramp_mm <= d <= length - 1.5 * ramp_mm
    return _Timing(total, peak / a, total - peak / a, time_at_distance_s(d, length, move.speed_mm_s, a),
                   time_at_distance_s(length - d, length, move.speed_mm_s, a), on_cruise)


def check_move_stamps(move: ProgrammedMove, settings: ProgrammedLineSettings, name: str) -> None:
    """The move's stamps against the profile assumed: PoseStreamClockError naming the
    move when the time between its two stamps along the path differs from the profile's
    by more than ``duration_tolerance_s`` (on the constant-speed part: the speed was not
    the programmed one), or when the time from the second to in position is less than
    the profile's (minus the tolerance) or more than it plus ``settle_max_s``: the arm did
    not follow the programmed line at the programmed speed (a speed override, a stop),
    or the clock did not run."""
    tm = _timing(move, settings)
    tol = settings.duration_tolerance_s
    where = (f"{name}: the controller's stamps of the move to {np.round(move.end.translation, 1).tolist()} mm "
             f"({move.length_mm:.1f} mm at {move.speed_mm_s:g} mm/s; stamps {move.stamp_distance_mm:g} mm after its "
             f"start and before its end at {move.t_stamp_s:.3f} and {move.t_cruise_end_s:.3f} s, in position at "
             f"{move.t_end_s:.3f} s, controller clock)")
    cruise = move.t_cruise_end_s - move.t_stamp_s
    expect = tm.cruise_end - tm.stamp
    if tm.stamp_on_cruise and abs(cruise - expect) > tol:
        raise PoseStreamClockError(
            f"{where} are {cruise:.3f} s apart, but the programmed speed takes {expect:.3f} s "
            f"(robot.pose_stream.duration_tolerance_s = {tol:g}): the arm did not move at the programmed speed "
            f"(the speed override must be 100 %), or the controller's clock did not run. Its poses cannot be "
            "computed; nothing after it is used")
    took = move.t_end_s - move.t_cruise_end_s
    expect = tm.total - tm.cruise_end
    if expect - tol <= took <= expect + settings.settle_max_s + tol:
        return
    raise PoseStreamClockError(
        f"{where} put {took:.3f} s from the second stamp to in position, but with the acceleration assumed "
        f"(robot.pose_stream.acceleration_mm_s2 = {settings.acceleration_mm_s2:g}) the motion takes {expect:.3f} s "
        f"and at most robot.pose_stream.settle_max_s = {settings.settle_max_s:g} s more to settle "
        f"(robot.pose_stream.duration_tolerance_s = {tol:g}): the arm did not follow the programmed line (a stop, "
        "a speed override), or the acceleration assumed is far off. Its poses cannot be computed; nothing after it "
        "is used")


def programmed_line_stream(moves: list[ProgrammedMove], settings: ProgrammedLineSettings) -> PoseStream:
    """The pose stream of stamped ``moves`` (in order, on one clock; see the module
    docstring): samples every ``sample_period_ms`` of the controller's clock from the
    first move's start to the last one's end, stamps in s since the clock's reset,
    ``on_ramp`` marked, ``assumption`` set."""
    if not moves:
        raise ValueError("programmed_line_stream: no move")
    timings = [_timing(m, settings) for m in moves]
    starts = np.array([m.t_stamp_s - tm.stamp for m, tm in zip(moves, timings)])  # each path's start, as assumed
    period = settings.sample_period_ms * 1e-3
    k0 = int(np.ceil(starts[0] / period - 1e-9))
    k1 = int(np.floor(moves[-1].t_end_s / period + 1e-9))
    stamps = np.arange(k0, k1 + 1) * period
    if len(stamps) < 2:  # a move shorter than a period: its ends themselves
        stamps = np.array([starts[0], moves[-1].t_end_s])
    which = np.clip(np.searchsorted(starts, stamps, side="right") - 1, 0, len(moves) - 1)
    R = np.empty((len(stamps), 3, 3))
    t = np.empty((len(stamps), 3))
    ramp = np.zeros(len(stamps), dtype=bool)
    margin = settings.ramp_margin_s
    for i, (move, tm) in enumerate(zip(moves, timings)):
        sel = np.flatnonzero(which == i)
        tau = stamps[sel] - starts[i]
        u = line_fraction(tau, move.length_mm, move.speed_mm_s, settings.acceleration_mm_s2)
        R0, R1 = move.start.rotation_matrix, move.end.rotation_matrix
        phi = rotvec_from_matrix(R0.T @ R1)
        R[sel] = R0 @ matrix_from_rotvec(u[:, None] * phi)
        t[sel] = move.start.translation + u[:, None] * (move.end.translation - move.start.translation)
        # (over every sample: the margin before a start lies in the stand after the move before)
        every = stamps - starts[i]
        if not tm.stamp_on_cruise:  # the constant-speed part is timed through the ramp: all of it unsure
            ramp |= (every >= -margin) & (every <= tm.total + margin)
        ramp |= ((every >= -margin) & (every <= tm.up_end + margin)) | ((every >= tm.down_start - margin)
                                                                        & (every <= tm.total + margin))
    from spherecal.plugins import PoseStream

    return PoseStream(stamps, R, t, on_ramp=ramp, assumption=settings.assumption())
