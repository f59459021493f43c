"""Time in the simulated world: a clock of true time, the arm's motion over it, and the
devices' own clocks.

- :class:`SimClock`: true time T (s) of the simulated world. Only simulated events move
  it (a move, a settle, an exposure, a wait the acquisition asks for); wall time never
  does, so a test of an hour of robot time runs in milliseconds.
- :class:`MotionTimeline`: the arm's flange over true time, as segments: standstills
  ('hold', 'settle', 'pause') and straight MoveL moves ('move', 'sweep', 'transit'), the
  translation along the line and the rotation about one fixed axis, with a trapezoidal
  speed profile (cruise speed, acceleration). A stop-and-go move
  (:meth:`MotionTimeline.move_linear`) lasts its trapezoid plus a settle and advances the
  clock by both. With an arm (:class:`~spherecal.sim.robot_error.SimulatedArm`) the
  controller's joints follow the path by its nominal inverse kinematics (knots every
  :data:`KNOT_MM` / :data:`KNOT_DEG`, each seeded with the one before, joined by cubic
  splines in the path fraction); the flange goes where the arm's true geometry puts it
  and the controller reports its nominal model's pose.
- :class:`DeviceClock`: a device's clock against true time,
  ``reading = epoch_s + offset_s + (1 + drift_ppm 1e-6) T`` (plus a stamp jitter), and
  back.
- :meth:`MotionTimeline.sample`: what a streaming device sends over an interval of true
  time: ticks every ``period_s`` of its own clock, their stamps, the reported poses and
  joints, with losses.
- :class:`SmoothNoise`: a first-order Gauss-Markov process per base axis (translation
  mm, rotation rad), the same at a time however often and in whatever order it is asked.

Timing assumptions of the simulated IRB 2400-class arm (not ABB figures):
:data:`DEFAULT_ACCELERATION_MM_S2` of path acceleration and deceleration for every
stop-and-go MoveL, and :data:`DEFAULT_SETTLE_S` of settling at each fine point.
"""

from __future__ import annotations

import threading
from dataclasses import dataclass

import numpy as np
from scipy.interpolate import CubicSpline
from scipy.signal import lfilter

from spherecal.core import geometry as geo
from spherecal.core.models import Pose

__all__ = [
    "DEFAULT_ACCELERATION_MM_S2", "DEFAULT_SETTLE_S", "DeviceClock", "MotionTimeline", "MoveTiming", "Samples",
    "Segment", "SimClock", "SmoothNoise", "trapezoid_duration_s", "trapezoid_position_mm",
]

#: Path acceleration and deceleration of a stop-and-go MoveL, mm/s^2: an assumption for
#: an IRB 2400-class arm at the controller's default acceleration settings with a light
#: tool (2 m/s^2, about 0.2 g), not a manufacturer's figure.
DEFAULT_ACCELERATION_MM_S2 = 2000.0
#: Standstill after each stop-and-go move before the controller answers that it is in
#: position (a fine point's settling), s: an assumption, as above.
DEFAULT_SETTLE_S = 0.2
#: Spacing of the inverse-kinematics knots along a move (mm of travel, deg of turn):
#: cubic splines through joints this far apart follow the straight path to well under
#: a micrometre on an arm of a metre's reach.
KNOT_MM = 5.0
KNOT_DEG = 1.0
#: Kinds of segment in which the flange stands still.
STANDSTILLS = ("hold", "settle", "pause")


class SimClock:
    """True time of the simulated world, s (0 at the cell's creation unless given).
    Advanced only by simulated events (:meth:`advance`, :meth:`advance_to`); reading it
    is safe from any thread."""

    simulated = True  #: (a wall clock says False: the acquisition names which it measured in)

    def __init__(self, start_s: float = 0.0):
        start_s = float(start_s)
        if not np.isfinite(start_s):
            raise ValueError(f"SimClock: start_s must be finite, got {start_s!r}")
        self._now = start_s
        self._lock = threading.Lock()

    @property
    def now_s(self) -> float:
        return self._now

    def advance(self, seconds: float) -> float:
        """Let ``seconds`` (>= 0) of simulated time pass; returns the new time."""
        seconds = float(seconds)
        if not (np.isfinite(seconds) and seconds >= 0):
            raise ValueError(f"SimClock.advance: seconds must be finite and >= 0, got {seconds!r}")
        with self._lock:
            self._now += seconds
            return self._now

    def advance_to(self, T_s: float) -> float:
        """Move the clock on to true time ``T_s`` (never back: an earlier time leaves it)."""
        T_s = float(T_s)
        if not np.isfinite(T_s):
            raise ValueError(f"SimClock.advance_to: T_s must be finite, got {T_s!r}")
        with self._lock:
            self._now = max(self._now, T_s)
            return self._now

    def wait(self, seconds: float) -> None:
        """A wait in simulated time (what ``time.sleep`` is to a wall clock)."""
        self.advance(seconds)


@dataclass(frozen=True)
class DeviceClock:
    """A device's clock against true time T (s): it reads
    ``epoch_s + offset_s + (1 + drift_ppm 1e-6) T``; each stamp it puts on a sample is
    off that by a jitter of standard deviation ``jitter_s``. ``epoch_s`` is where its
    count starts (power-on, 1970), ``offset_s`` a further offset (the phase of its ticks,
    a clock set wrong)."""

    offset_s: float = 0.0
    drift_ppm: float = 0.0
    epoch_s: float = 0.0
    jitter_s: float = 0.0

    def __post_init__(self):
        for name in ("offset_s", "drift_ppm", "epoch_s", "jitter_s"):
            if not np.isfinite(getattr(self, name)):
                raise ValueError(f"DeviceClock.{name} must be finite, got {getattr(self, name)!r}")
        if not -1e5 < self.drift_ppm < 1e5:
            raise ValueError(f"DeviceClock.drift_ppm = {self.drift_ppm}: expected within +-1e5 ppm")
        if self.jitter_s < 0:
            raise ValueError(f"DeviceClock.jitter_s = {self.jitter_s}: expected >= 0")

    @property
    def rate(self) -> float:
        """Device seconds per true second."""
        return 1.0 + self.drift_ppm * 1e-6

    def stamp(self, T_true_s) -> np.ndarray:
        """The clock's reading at true times ``T_true_s`` (no jitter)."""
        return self.epoch_s + (self.offset_s + self.rate * np.asarray(T_true_s, dtype=float))

    def true_time(self, stamp_s) -> np.ndarray:
        """The true time at which the clock read ``stamp_s`` (no jitter): :meth:`stamp` inverted."""
        return ((np.asarray(stamp_s, dtype=float) - self.epoch_s) - self.offset_s) / self.rate


def trapezoid_duration_s(length_mm: float, speed: float, accel: float) -> float:
    """Time of a rest-to-rest move of ``length_mm`` at cruise ``speed`` (mm/s) and
    ``accel`` (mm/s^2): ``length / speed + speed / accel`` when it reaches the cruise
    speed (``length >= speed^2 / accel``), else ``2 sqrt(length / accel)`` (triangular)."""
    if length_mm <= 0:
        return 0.0
    if length_mm >= speed * speed / accel:
        return length_mm / speed + speed / accel
    return 2.0 * np.sqrt(length_mm / accel)


def trapezoid_position_mm(tau, length_mm: float, speed: float, accel: float) -> np.ndarray:
    """Distance travelled (mm) after ``tau`` (s) of a rest-to-rest trapezoidal move."""
    tau = np.asarray(tau, dtype=float)
    v = min(speed, np.sqrt(length_mm * accel))  # the peak speed
    t_ramp = v / accel
    d_ramp = 0.5 * v * t_ramp
    total = trapezoid_duration_s(length_mm, speed, accel)
    up = 0.5 * accel * tau**2
    cruise = d_ramp + v * (tau - t_ramp)
    left = total - tau
    down = length_mm - 0.5 * accel * left**2
    return np.where(tau <= t_ramp, up, np.where(left <= t_ramp, down, cruise))


_trapezoid_duration = trapezoid_duration_s
_trapezoid_position = trapezoid_position_mm


@dataclass(frozen=True)
class Segment:
    """One piece of the commanded motion, in true time: from flange pose (R0, t0) to
    (R1, t1) (base_from_flange, mm), the translation along the straight line and the
    rotation about one fixed axis, at path fraction ``s(tau) / length_mm`` with ``s`` a
    trapezoidal profile (cruise ``speed_mm_s``, ``acceleration_mm_s2``). ``kind`` is a
    standstill ('pause', 'hold', 'settle'), a stop-and-go 'move', or on the fly a 'sweep'
    (``sweep`` indexes the recording's sweeps) or a 'transit' (a move between sweeps;
    ``sweep`` -1). ``length_mm`` of a move with reorientation is the longer of its travel
    and its turn at the move's speeds, in mm of travel."""

    kind: str
    sweep: int
    station: str
    T0_s: float
    duration_s: float
    R0: np.ndarray
    t0_mm: np.ndarray
    R1: np.ndarray
    t1_mm: np.ndarray
    length_mm: float
    speed_mm_s: float
    acceleration_mm_s2: float

    @property
    def T1_s(self) -> float:
        return self.T0_s + self.duration_s

    def fraction(self, T_s) -> np.ndarray:
        """Path fraction u in [0, 1] at true times ``T_s`` (clipped to the segment)."""
        tau = np.clip(np.asarray(T_s, dtype=float) - self.T0_s, 0.0, self.duration_s)
        if self.length_mm <= 0:
            return np.zeros_like(tau)
        return np.clip(_trapezoid_position(tau, self.length_mm, self.speed_mm_s, self.acceleration_mm_s2)
                       / self.length_mm, 0.0, 1.0)

    def poses(self, u) -> tuple[np.ndarray, np.ndarray]:
        """Commanded (R (n, 3, 3), t (n, 3) mm) at path fractions ``u`` (n,)."""
        u = np.asarray(u, dtype=float)
        phi = geo.rotvec_from_matrix(self.R0.T @ self.R1)
        R = self.R0 @ geo.matrix_from_rotvec(u[:, None] * phi)
        t = self.t0_mm + u[:, None] * (self.t1_mm - self.t0_mm)
        return R, t


def _gauss_markov(rng: np.random.Generator, T_s: np.ndarray, sd: np.ndarray, tau_s: float) -> np.ndarray:
    """A stationary first-order Gauss-Markov process (per column, standard deviations
    ``sd``) sampled exactly at the increasing times ``T_s`` (n,): (n, len(sd))."""
    n, d = len(T_s), len(sd)
    w = rng.standard_normal((n, d))
    a = np.exp(-np.diff(T_s) / tau_s)
    b = np.sqrt(1.0 - a * a)
    x = np.empty((n, d))
    x[0] = w[0]
    for i in range(1, n):  # exact discretisation of the process over each interval
        x[i] = a[i - 1] * x[i - 1] + b[i - 1] * w[i]
    return x * sd


def _losses(rng: np.random.Generator, n: int, rate: float, bursts_per_s: float, burst_length, duration_s: float) -> \
        np.ndarray:
    """A mask of kept samples: each lost with probability ``rate``, and a Poisson number
    of bursts (``bursts_per_s`` x ``duration_s``) of ``burst_length`` consecutive ones."""
    kept = rng.random(n) >= rate
    if bursts_per_s > 0:
        lo, hi = burst_length
        for start in rng.integers(0, n, rng.poisson(bursts_per_s * duration_s)):
            kept[start:start + rng.integers(lo, hi + 1)] = False
    return kept


def _grid(rng: np.random.Generator, period_s: float, rate_error: float, duration_s: float, jitter_s: float):
    """Ticks of a clock with this period and rate error over ``duration_s`` of true time
    (a random phase): their clock readings since its epoch (n,), their true times, and
    stamp jitters (n,), normal, cut at a quarter period so that the stamps increase."""
    phase = rng.uniform(0.0, period_s)
    n = int(np.floor(((1.0 + rate_error) * duration_s - phase) / period_s)) + 1
    clock = phase + period_s * np.arange(n)
    jitter = np.clip(rng.normal(0.0, jitter_s, n), -period_s / 4, period_s / 4) if jitter_s > 0 else np.zeros(n)
    return clock, clock / (1.0 + rate_error), jitter


def _with_noise(R: np.ndarray, t: np.ndarray, noise: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The true pose of a reported one: (exp(-[eps_r]) R, t - eps_t), ``noise`` (n, 6)
    (eps_t mm, eps_r rad, base frame)."""
    return geo.matrix_from_rotvec(-noise[:, 3:]) @ R, t - noise[:, :3]


class SmoothNoise:
    """A stationary first-order Gauss-Markov process per base axis: 3 of translation
    (SD ``translation_sd_mm``) and 3 of rotation (SD ``rotation_sd_deg``, given in rad),
    correlation time ``correlation_s`` (autocorrelation exp(-dt / correlation)).

    It is drawn from ``rng`` on a grid of true time from ``T0_s`` (``step_s``, default a
    25th of the correlation time), in order and kept, and is linear between grid
    points: its value at a time is the same however often, and in whatever order, it is
    asked for. Times before ``T0_s`` take its first value."""

    def __init__(self, translation_sd_mm: float, rotation_sd_deg: float, correlation_s: float,
                 rng: np.random.Generator, T0_s: float = 0.0, step_s: float | None = None):
        if not (translation_sd_mm >= 0 and rotation_sd_deg >= 0):
            raise ValueError("SmoothNoise: standard deviations must be >= 0")
        if not correlation_s > 0:
            raise ValueError(f"SmoothNoise: correlation_s must be > 0, got {correlation_s!r}")
        self.sd = np.array([translation_sd_mm] * 3 + [np.radians(rotation_sd_deg)] * 3, dtype=float)
        self.correlation_s = float(correlation_s)
        self.step_s = float(step_s) if step_s is not None else self.correlation_s / 25.0
        self.T0_s = float(T0_s)
        self._rng = rng
        self._a = float(np.exp(-self.step_s / self.correlation_s))
        self._b = float(np.sqrt(1.0 - self._a * self._a))
        self._x = rng.standard_normal((1, 6))  # unit variance; scaled on the way out
        self._lock = threading.Lock()

    def _extend(self, n: int) -> np.ndarray:
        with self._lock:
            have = len(self._x)
            if n > have:
                grow = max(n - have, have // 2, 256)
                w = self._rng.standard_normal((grow, 6))
                # x[i] = a x[i-1] + b w[i], from the last value kept
                x, _ = lfilter([self._b], [1.0, -self._a], w, axis=0, zi=self._a * self._x[-1:])
                self._x = np.vstack([self._x, x])
            return self._x

    def at(self, T_s) -> np.ndarray:
        """The process at true times ``T_s`` (n,): (n, 6), eps_t (mm) then eps_r (rad), base frame."""
        T = np.atleast_1d(np.asarray(T_s, dtype=float))
        pos = np.maximum((T - self.T0_s) / self.step_s, 0.0)
        x = self._extend(int(np.ceil(pos.max(initial=0.0))) + 2)
        i = np.floor(pos).astype(np.int64)
        f = (pos - i)[:, None]
        return ((1.0 - f) * x[i] + f * x[i + 1]) * self.sd


@dataclass(frozen=True)
class MoveTiming:
    """A stop-and-go move on the timeline: it starts at ``start_s`` (true time), moves
    for ``motion_s`` (the trapezoid) over ``length_mm`` and settles for ``settle_s``;
    the controller answers at ``end_s``."""

    start_s: float
    motion_s: float
    settle_s: float
    length_mm: float

    @property
    def end_s(self) -> float:
        return self.start_s + self.motion_s + self.settle_s


@dataclass(frozen=True)
class Samples:
    """What a streaming device sent over an interval (:meth:`MotionTimeline.sample`),
    kept samples only: ``T_true_s`` when each was taken, ``stamp_s`` its stamp on the
    device's clock, ``tick`` its tick number on that clock (consecutive; a lost sample's
    is missing), the reported ``R`` (n, 3, 3) and ``t_mm`` (n, 3) (base_from_flange),
    ``joints_deg`` (n, J) or None, and ``lost``: the ticks of the interval not sent."""

    T_true_s: np.ndarray
    stamp_s: np.ndarray
    tick: np.ndarray
    R: np.ndarray
    t_mm: np.ndarray
    joints_deg: np.ndarray | None
    lost: int


class MotionTimeline:
    """The arm's flange over true time (module docstring), on ``clock``.

    Built two ways: stepwise, as a simulated controller moves
    (:meth:`move_linear`, :meth:`jump`), starting at ``start`` (default the identity)
    with ``joints_deg``; or whole, from planned segments (:meth:`of_segments`). ``arm``
    (a :class:`~spherecal.sim.robot_error.SimulatedArm`, or None: no joints, the flange
    is the commanded pose) turns the path into joints. ``repeatability`` (a
    :class:`SmoothNoise`, or None) moves the true flange off the path, as a real arm's
    repeatability does; the controller's report (:meth:`reported_at`) does not see it.
    Safe to read from other threads while a controller appends."""

    def __init__(self, start: Pose | None = None, *, joints_deg=None, arm=None, clock: SimClock | None = None,
                 acceleration_mm_s2: float = DEFAULT_ACCELERATION_MM_S2, settle_s: float = DEFAULT_SETTLE_S,
                 repeatability: SmoothNoise | None = None):
        if not (np.isfinite(acceleration_mm_s2) and acceleration_mm_s2 > 0):
            raise ValueError(f"MotionTimeline: acceleration_mm_s2 must be > 0, got {acceleration_mm_s2!r}")
        if not (np.isfinite(settle_s) and settle_s >= 0):
            raise ValueError(f"MotionTimeline: settle_s must be >= 0, got {settle_s!r}")
        self.clock = clock if clock is not None else SimClock()
        self.arm = arm
        self.acceleration_mm_s2 = float(acceleration_mm_s2)
        self.settle_s = float(settle_s)
        self.repeatability = repeatability
        self._lock = threading.RLock()
        self._segments: list[Segment] = []
        self._T0: list[float] = []
        #: per segment: joints as an array (a standstill), a CubicSpline in the path
        #: fraction, a (q0, q1) pair still to be splined, or None (no joints)
        self._joints: list = []
        start = start or Pose.identity()
        self._add(Segment("hold", -1, "", self.clock.now_s, 0.0, start.rotation_matrix, start.translation,
                          start.rotation_matrix, start.translation, 0.0, 1.0, self.acceleration_mm_s2),
                  None if joints_deg is None else np.asarray(joints_deg, dtype=float).copy())

    @classmethod
    def of_segments(cls, segments: list[Segment], arm=None) -> "MotionTimeline":
        """A timeline of planned segments (contiguous in true time), the joints along
        every one computed now, each segment's first knot seeded with the last one's."""
        self = cls.__new__(cls)
        self.clock = SimClock(segments[-1].T1_s)
        self.arm, self.repeatability = arm, None
        self.acceleration_mm_s2, self.settle_s = segments[0].acceleration_mm_s2, 0.0
        self._lock = threading.RLock()
        self._segments, self._T0, self._joints = list(segments), [s.T0_s for s in segments], []
        q = None
        for seg in segments:
            if arm is None:
                self._joints.append(None)
            elif seg.length_mm <= 0:
                q = arm.joints_for(Pose.from_rt(seg.R0, seg.t0_mm), q)
                self._joints.append(np.asarray(q, dtype=float).copy())
            else:
                spline, q = self._spline(seg, q)
                self._joints.append(spline)
        return self

    # building -------------------------------------------------------------------------
    def _add(self, seg: Segment, joints) -> None:
        with self._lock:
            self._segments.append(seg)
            self._T0.append(seg.T0_s)
            self._joints.append(joints)

    @property
    def segments(self) -> list[Segment]:
        with self._lock:
            return list(self._segments)

    @property
    def end_s(self) -> float:
        """True time at which the last segment ends (the arm stands still after it)."""
        with self._lock:
            return self._segments[-1].T1_s

    def _end_state(self) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
        seg, q = self._segments[-1], self._joints[-1]
        if isinstance(q, tuple):
            q = q[1]
        elif isinstance(q, CubicSpline):
            q = q(1.0)
        return seg.R1, seg.t1_mm, None if q is None else np.asarray(q, dtype=float)

    def _hold_until(self, T_s: float) -> None:
        end = self._segments[-1].T1_s
        if T_s > end:
            R, t, q = self._end_state()
            self._add(Segment("hold", -1, "", end, T_s - end, R, t, R, t, 0.0, 1.0, self.acceleration_mm_s2), q)

    def jump(self, pose: Pose, joints_deg=None) -> None:
        """The arm is at ``pose`` (commanded base_from_flange) with ``joints_deg`` from now
        on, without a move in between (a jog, a controller started where the arm stands)."""
        with self._lock:
            now = self.clock.now_s
            self._hold_until(now)
            R, t = pose.rotation_matrix, pose.translation
            self._add(Segment("hold", -1, "", max(now, self._segments[-1].T1_s), 0.0, R, t, R, t, 0.0, 1.0,
                              self.acceleration_mm_s2),
                      None if joints_deg is None else np.asarray(joints_deg, dtype=float).copy())

    def move_linear(self, target: Pose, speed_mm_s: float, orientation_speed_deg_s: float | None = None, *,
                    joints_deg=None, acceleration_mm_s2: float | None = None, settle_s: float | None = None,
                    kind: str = "move", station: str = "") -> MoveTiming:
        """A stop-and-go MoveL from where the timeline ends (or now, if later) to
        ``target`` (commanded base_from_flange, mm): a trapezoid over the longer of its
        travel and its turn at ``speed_mm_s`` and ``orientation_speed_deg_s`` (as a MoveL's
        speeddata limits it), then a settle; the clock advances to its end. ``joints_deg``:
        the controller's joints at the target (default: the arm's inverse kinematics
        from the joints before)."""
        a = self.acceleration_mm_s2 if acceleration_mm_s2 is None else float(acceleration_mm_s2)
        settle = self.settle_s if settle_s is None else float(settle_s)
        if not (np.isfinite(speed_mm_s) and speed_mm_s > 0):
            raise ValueError(f"move_linear: speed_mm_s must be > 0, got {speed_mm_s!r}")
        if not (np.isfinite(a) and a > 0) or not (np.isfinite(settle) and settle >= 0):
            raise ValueError(f"move_linear: acceleration_mm_s2 ({a!r}) must be > 0 and settle_s ({settle!r}) >= 0")
        with self._lock:
            self._hold_until(self.clock.now_s)
            R0, t0, q0 = self._end_state()
            R1, t1 = target.rotation_matrix, target.translation
            travel = float(np.linalg.norm(t1 - t0))
            turn = geo.rotation_angle_deg(R0, R1)
            if turn > 1e-9 and orientation_speed_deg_s is None:
                raise ValueError("move_linear: the move turns the flange; give orientation_speed_deg_s")
            length = max(travel, turn * speed_mm_s / orientation_speed_deg_s if turn > 1e-9 else 0.0)
            motion = trapezoid_duration_s(length, speed_mm_s, a)
            start = self._segments[-1].T1_s
            q1 = None if joints_deg is None else np.asarray(joints_deg, dtype=float).copy()
            if self.arm is not None and q1 is None:
                q1 = np.asarray(self.arm.joints_for(target, q0), dtype=float)
            joints = None if self.arm is None and q1 is None else (q0, q1)
            self._add(Segment(kind, -1, station, start, motion, R0, t0, R1, t1, length, float(speed_mm_s), a), joints)
            if settle > 0:
                self._add(Segment("settle", -1, station, start + motion, settle, R1, t1, R1, t1, 0.0, 1.0, a), q1)
            timing = MoveTiming(start, motion, settle, length)
            self.clock.advance_to(timing.end_s)
            return timing

    def _spline(self, seg: Segment, q, q_end=None) -> tuple[CubicSpline, np.ndarray]:
        """Joints along ``seg`` from knots of the arm's inverse kinematics, the first
        seeded with ``q``; the last knot is ``q_end`` when given. Returns the spline and
        the last knot."""
        travel = float(np.linalg.norm(seg.t1_mm - seg.t0_mm))
        turn = geo.rotation_angle_deg(seg.R0, seg.R1)
        n = int(max(2, np.ceil(travel / KNOT_MM), np.ceil(turn / KNOT_DEG))) + 1
        u = np.linspace(0.0, 1.0, n)
        R, t = seg.poses(u)
        knots = []
        for Ri, ti in zip(R, t):
            q = self.arm.joints_for(Pose.from_rt(Ri, ti), q)
            knots.append(np.asarray(q, dtype=float).copy())
        if q_end is not None:
            knots[-1] = np.asarray(q_end, dtype=float)
        return CubicSpline(u, np.array(knots), axis=0), knots[-1]

    def _joints_of(self, i: int):
        """Segment ``i``'s joints (an array or a spline), splined now if still pending."""
        with self._lock:
            q = self._joints[i]
            if isinstance(q, tuple):
                q0, q1 = q
                seg = self._segments[i]
                if seg.length_mm <= 0 or q1 is None:
                    q = q1
                elif self.arm is None:  # no arm to follow the path with: straight between the ends, if known
                    q = None if q0 is None else CubicSpline([0.0, 1.0], np.array([q0, q1]), axis=0)
                else:
                    q = self._spline(seg, q0, q1)[0]
                self._joints[i] = q
            return q

    # reading --------------------------------------------------------------------------
    def segment_of(self, T_s: np.ndarray) -> np.ndarray:
        """Index of the segment under each true time (the first before the start, the
        last after the end: the arm stands still there)."""
        with self._lock:
            T0 = np.asarray(self._T0)
        return np.clip(np.searchsorted(T0, T_s, side="right") - 1, 0, len(T0) - 1)

    def at(self, T_s) -> tuple[np.ndarray, np.ndarray, np.ndarray | None, np.ndarray]:
        """At true times ``T_s`` (n,): the commanded (R (n, 3, 3), t (n, 3) mm), the
        controller's joints (n, J) deg (None without an arm, or where they are unknown)
        and each time's sweep index (-1 outside sweeps)."""
        T_s = np.atleast_1d(np.asarray(T_s, dtype=float))
        k = self.segment_of(T_s)
        R = np.empty((len(T_s), 3, 3))
        t = np.empty((len(T_s), 3))
        sweep = np.full(len(T_s), -1, dtype=np.int64)
        q = None
        for i in np.unique(k):
            sel = np.flatnonzero(k == i)
            seg = self._segments[i]
            u = seg.fraction(T_s[sel])
            R[sel], t[sel] = seg.poses(u)
            sweep[sel] = seg.sweep
            joints = self._joints_of(i)
            if joints is None:
                continue
            values = joints(u) if isinstance(joints, CubicSpline) else joints
            if q is None:
                q = np.full((len(T_s), np.shape(values)[-1]), np.nan)
            q[sel] = values
        if q is not None and np.isnan(q).any():
            q = None  # joints unknown somewhere (a part without an arm): none rather than some
        return R, t, q, sweep

    def commanded_at(self, T_true_s) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
        """The commanded path at true times: (R (N, 3, 3), t_mm (N, 3), joints_deg (N, J) or None)."""
        R, t, q, _ = self.at(T_true_s)
        return R, t, q

    def pose_at(self, T_true_s) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
        """Where the flange truly is at true times ``T_true_s`` (N,): (R (N, 3, 3), t_mm
        (N, 3), joints_deg (N, J) or None). With an arm and joints: its true geometry at
        the joints; else the commanded path. Off both by :attr:`repeatability` when set."""
        T = np.atleast_1d(np.asarray(T_true_s, dtype=float))
        R, t, q, _ = self.at(T)
        if self.arm is not None and q is not None:
            A = self.arm.true_flange_matrices(q)
            R, t = np.ascontiguousarray(A[:, :3, :3]), np.ascontiguousarray(A[:, :3, 3])
        if self.repeatability is not None:
            R, t = _with_noise(R, t, self.repeatability.at(T))
        return R, t, q

    def reported_at(self, T_true_s) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
        """What the controller reports at true times, noise-free: its nominal model's pose
        of its joints (with an arm), else the commanded path; and the joints."""
        R, t, q, _ = self.at(T_true_s)
        if self.arm is not None and q is not None:
            M = self.arm.nominal_flange_matrices(q)
            R, t = np.ascontiguousarray(M[:, :3, :3]), np.ascontiguousarray(M[:, :3, 3])
        return R, t, q

    def sample(self, T0_true_s: float, T1_true_s: float, period_s: float, clock: DeviceClock,
               rng: np.random.Generator, smooth_noise: SmoothNoise | None = None, *, drop_rate: float = 0.0,
               burst_rate_per_s: float = 0.0, burst_length: tuple[int, int] = (2, 5)) -> Samples:
        """What a device streaming the reported pose sends for the true-time interval
        [``T0_true_s``, ``T1_true_s``): a tick every ``period_s`` of its own ``clock``
        (tick k at reading ``epoch_s + k period_s``, so that consecutive intervals join
        without a gap or a repeat), each stamped with the clock's jitter (cut at a
        quarter period, so stamps increase); the controller's report
        (:meth:`reported_at`) plus ``smooth_noise`` (the stream's own error, on the report
        only); losses from ``rng``: each sample with probability ``drop_rate``, and
        bursts of ``burst_length`` at ``burst_rate_per_s``. Draws from ``rng`` (the
        device's own generator) only."""
        if not (np.isfinite(period_s) and period_s > 0):
            raise ValueError(f"sample: period_s must be > 0, got {period_s!r}")
        if not T1_true_s >= T0_true_s:
            raise ValueError(f"sample: the interval ends ({T1_true_s!r}) before it starts ({T0_true_s!r})")
        if not 0 <= drop_rate < 1:
            raise ValueError(f"sample: drop_rate must be in [0, 1), got {drop_rate!r}")
        k0, k1 = (int(np.ceil((clock.offset_s + clock.rate * T) / period_s)) for T in (T0_true_s, T1_true_s))
        tick = np.arange(k0, max(k0, k1), dtype=np.int64)
        T = (tick * period_s - clock.offset_s) / clock.rate
        jitter = (np.clip(rng.normal(0.0, clock.jitter_s, len(T)), -period_s / 4, period_s / 4)
                  if clock.jitter_s > 0 else np.zeros(len(T)))
        kept = _losses(rng, len(T), drop_rate, burst_rate_per_s, burst_length, T1_true_s - T0_true_s)
        T, tick, jitter = T[kept], tick[kept], jitter[kept]
        R, t, q = self.reported_at(T) if len(T) else (np.empty((0, 3, 3)), np.empty((0, 3)), None)
        if smooth_noise is not None and len(T):
            eps = smooth_noise.at(T)
            R, t = geo.matrix_from_rotvec(eps[:, 3:]) @ R, t + eps[:, :3]
        stamps = clock.epoch_s + (tick * period_s + jitter)
        return Samples(T, stamps, tick, R, t, q, int((~kept).sum()))
