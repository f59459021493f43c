"""Time-stamped recordings: a pose stream on the robot's clock, a profile stream on the sensor's.

A recording is what an on-the-fly acquisition (or a ROS 2 bag) holds: the flange pose
sampled by the controller (``t_robot_s``, the controller's own stamps) and profiles
exposed by the sensor (``t_sensor_s``, the sensor's own stamps). The two clocks differ
by an offset and a rate (docs/conventions.md, "Time"): the pose of profile j is the pose
stream's at

    t_robot = t_sensor + offset_s + drift * (t_sensor - t_sensor0)

with ``t_sensor0`` the recording's first profile stamp. :meth:`PoseStream.at` gives the
pose at any robot time with its velocity, by interpolation between the two samples
around it (SLERP and linear: the model's derivative is exactly the segment's velocity),
and refuses to interpolate across a gap in the stream.

Frames and units: ``base_from_flange`` in mm, quaternions (w, x, y, z) where they are
stored (:class:`PoseStream` keeps rotation matrices), joints in degrees, stamps in
seconds (float64: 0.2 us resolution at 1.7e9 s since 1970), profile points (y, z) in mm
in the laser plane of the sensor frame. Profiles are stored flat (``points_yz_mm``
(N, 2) and ``start`` (m + 1,)), so ten thousand profiles of a thousand points are two
arrays, not ten thousand objects.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from spherecal.core import geometry as geo
from spherecal.core.clock import sensor_to_robot_time

__all__ = ["POSES_ASSUMED_KEY", "PROGRAMMED_LINE_ASSUMPTION", "PoseAtTimes", "PoseStream", "ProfileStream",
           "Recording", "SweepInfo", "sensor_to_robot_time"]

#: A gap between two pose samples longer than this many median sample periods is a gap
#: in the stream: a profile inside it has no measured pose (it is left out, never
#: interpolated across).
GAP_PERIODS = 3.5
#: What a pose stream whose poses come from the programmed line (not measured) says in
#: its ``assumption``, before the details of the profile assumed.
#: The recording provenance's key that keeps a computed pose stream's ``assumption``
#: (the stream form writes it there; :attr:`Recording.poses_assumption` reads it).
POSES_ASSUMED_KEY = "poses_assumed"
PROGRAMMED_LINE_ASSUMPTION = ("poses from the programmed line, not measured: the arm's path error at speed is in "
                              "the result's error")


@dataclass(frozen=True)
class PoseAtTimes:
    """Poses of the stream at given robot times (n of them).

    ``R``, ``t``: base_from_flange (n, 3, 3) and (n, 3) mm; ``omega_rad_s``: the spatial
    angular velocity (base axes, rad/s) and ``v_mm_s`` the velocity of the flange origin
    (base, mm/s), such that ``dR/dt = [omega] R`` and ``dt/dt = v``; ``q_deg`` the joints
    (n, J) if the stream has them, with their rate ``qdot_deg_s``; ``ok`` (n,) False where
    the time is outside the stream or inside a gap (the other arrays hold the nearest
    sample there, never to be used)."""

    R: np.ndarray
    t: np.ndarray
    omega_rad_s: np.ndarray
    v_mm_s: np.ndarray
    q_deg: np.ndarray | None
    qdot_deg_s: np.ndarray | None
    ok: np.ndarray


@dataclass(frozen=True)
class PoseStream:
    """Flange poses stamped by the robot's clock (seconds), strictly increasing.

    ``R`` (n, 3, 3) and ``t_mm`` (n, 3): base_from_flange; ``joints_deg`` (n, J) or None;
    ``seq`` (n,) the controller's sequence numbers if it sends them (lost samples are
    the gaps in them), else None; ``sweep`` (n,) the sweep each sample was taken in (an
    index into :attr:`Recording.sweeps`), -1 outside a sweep, or None when the recording
    does not say.

    A stream whose poses were not measured but computed (a controller that cannot stream:
    the pose along the programmed line at the controller's time) says so in
    ``assumption`` (what the poses assume, starting with
    :data:`PROGRAMMED_LINE_ASSUMPTION`; None: measured), and marks in ``on_ramp`` (n,)
    the samples where the computed pose is least sure (the speed ramps at the ends of a
    move, where the arm's acceleration is assumed): :meth:`at` treats a time next to such
    a sample like a time in a gap, so nothing is mapped there."""

    t_robot_s: np.ndarray
    R: np.ndarray
    t_mm: np.ndarray
    joints_deg: np.ndarray | None = None
    seq: np.ndarray | None = None
    sweep: np.ndarray | None = None
    on_ramp: np.ndarray | None = None
    assumption: str | None = None

    def __post_init__(self):
        n = len(self.t_robot_s)
        if n < 2:
            raise ValueError(f"a pose stream needs at least 2 samples, got {n}")
        if self.R.shape != (n, 3, 3) or self.t_mm.shape != (n, 3):
            raise ValueError(f"pose stream: {n} stamps but rotations {self.R.shape} and translations {self.t_mm.shape}")
        if self.joints_deg is not None and len(self.joints_deg) != n:
            raise ValueError(f"pose stream: {n} stamps but {len(self.joints_deg)} joint samples")
        for name in ("seq", "sweep", "on_ramp"):
            a = getattr(self, name)
            if a is not None and len(a) != n:
                raise ValueError(f"pose stream: {n} stamps but {len(a)} {name} entries")
        dt = np.diff(self.t_robot_s)
        if not np.all(np.isfinite(self.t_robot_s)):
            raise ValueError("pose stream: a stamp is not finite")
        if np.any(dt <= 0):
            k = int(np.flatnonzero(dt <= 0)[0])
            raise ValueError(f"pose stream: stamps do not increase at sample {k + 1} "
                             f"({self.t_robot_s[k]:.6f} s then {self.t_robot_s[k + 1]:.6f} s, robot clock)")

    @classmethod
    def from_quaternions(cls, t_robot_s, translation_mm, quaternion_wxyz, joints_deg=None, seq=None,
                         sweep=None) -> "PoseStream":
        """From stamps, translations (n, 3) mm and quaternions (n, 4) in (w, x, y, z) order."""
        return cls(np.asarray(t_robot_s, dtype=float), geo.matrix_from_quat_wxyz(np.asarray(quaternion_wxyz, float)),
                   np.asarray(translation_mm, dtype=float),
                   None if joints_deg is None else np.asarray(joints_deg, dtype=float),
                   None if seq is None else np.asarray(seq, dtype=np.int64),
                   None if sweep is None else np.asarray(sweep, dtype=np.int64))

    @property
    def n(self) -> int:
        return len(self.t_robot_s)

    @property
    def period_s(self) -> float:
        """The median sample period (s)."""
        return float(np.median(np.diff(self.t_robot_s)))

    @property
    def quaternion_wxyz(self) -> np.ndarray:
        return geo.quat_wxyz_from_matrix(self.R)

    def gaps(self, periods: float = GAP_PERIODS) -> list[tuple[float, float]]:
        """The stream's gaps: (last stamp before, first after), robot clock, s."""
        dt = np.diff(self.t_robot_s)
        k = np.flatnonzero(dt > periods * self.period_s)
        return [(float(self.t_robot_s[i]), float(self.t_robot_s[i + 1])) for i in k]

    def ramp_at(self, t_robot_s) -> np.ndarray:
        """Whether each robot time lies next to a sample marked ``on_ramp`` (all False
        when the stream marks none)."""
        tq = np.atleast_1d(np.asarray(t_robot_s, dtype=float))
        if self.on_ramp is None:
            return np.zeros(len(tq), dtype=bool)
        k = np.clip(np.searchsorted(self.t_robot_s, tq, side="right") - 1, 0, self.n - 2)
        ramp = np.asarray(self.on_ramp, dtype=bool)
        return ramp[k] | ramp[k + 1]

    def at(self, t_robot_s, periods: float = GAP_PERIODS) -> PoseAtTimes:
        """Poses at robot times ``t_robot_s`` (n,), interpolated between the samples around
        each (see :class:`PoseAtTimes`); not ``ok`` next to a sample marked ``on_ramp``."""
        tq = np.atleast_1d(np.asarray(t_robot_s, dtype=float))
        ts = self.t_robot_s
        k = np.clip(np.searchsorted(ts, tq, side="right") - 1, 0, self.n - 2)
        h = ts[k + 1] - ts[k]
        s = (tq - ts[k]) / h
        ok = (tq >= ts[0]) & (tq <= ts[-1]) & (h <= periods * self.period_s)
        if self.on_ramp is not None:
            ok &= ~self.ramp_at(tq)
        Rk, Rk1 = self.R[k], self.R[k + 1]
        phi = geo.rotvec_from_matrix(np.swapaxes(Rk, 1, 2) @ Rk1)  # body-frame rotation over the segment
        R = Rk @ geo.matrix_from_rotvec(s[:, None] * phi)
        omega = np.einsum("nij,nj->ni", R, phi) / h[:, None]
        dt = self.t_mm[k + 1] - self.t_mm[k]
        t = self.t_mm[k] + s[:, None] * dt
        v = dt / h[:, None]
        q = qdot = None
        if self.joints_deg is not None:
            dq = self.joints_deg[k + 1] - self.joints_deg[k]
            q = self.joints_deg[k] + s[:, None] * dq
            qdot = dq / h[:, None]
        return PoseAtTimes(R, t, omega, v, q, qdot, ok)


@dataclass(frozen=True)
class ProfileStream:
    """Profiles stamped by the sensor's clock (seconds, the exposure's middle), in order.

    ``points_yz_mm`` (N, 2): every profile's points, one after the other; profile j is
    ``points_yz_mm[start[j]:start[j + 1]]``. ``frame`` (m,) the sensor's frame counters
    (lost frames are their gaps) or None. ``sweep`` (m,) the sweep each profile was
    taken in (an index into :attr:`Recording.sweeps`), -1 outside a sweep, or None when
    the recording does not say (a ROS 2 bag)."""

    t_sensor_s: np.ndarray
    points_yz_mm: np.ndarray
    start: np.ndarray
    frame: np.ndarray | None = None
    sweep: np.ndarray | None = None

    def __post_init__(self):
        m = len(self.t_sensor_s)
        if len(self.start) != m + 1 or (m and (self.start[0] != 0 or self.start[-1] != len(self.points_yz_mm))):
            raise ValueError(f"profile stream: {m} profiles need {m + 1} starts from 0 to {len(self.points_yz_mm)}")
        if np.any(np.diff(self.start) < 0):
            raise ValueError("profile stream: profile starts go backwards")
        if self.points_yz_mm.ndim != 2 or self.points_yz_mm.shape[1] != 2:
            raise ValueError(f"profile stream: points must be (N, 2) (y, z), got {self.points_yz_mm.shape}")
        for name in ("frame", "sweep"):
            a = getattr(self, name)
            if a is not None and len(a) != m:
                raise ValueError(f"profile stream: {m} profiles but {len(a)} {name} entries")

    @classmethod
    def from_profiles(cls, t_sensor_s, profiles, frame=None, sweep=None) -> "ProfileStream":
        """From a list of (k, 2) arrays of (y, z) mm."""
        counts = np.array([len(p) for p in profiles], dtype=np.int64)
        start = np.concatenate([[0], np.cumsum(counts)]).astype(np.int64)
        pts = np.concatenate([np.asarray(p, dtype=float).reshape(-1, 2) for p in profiles]) if len(profiles) else \
            np.zeros((0, 2))
        return cls(np.asarray(t_sensor_s, dtype=float), pts, start,
                   None if frame is None else np.asarray(frame, dtype=np.int64),
                   None if sweep is None else np.asarray(sweep, dtype=np.int64))

    @property
    def n(self) -> int:
        return len(self.t_sensor_s)

    @property
    def counts(self) -> np.ndarray:
        return np.diff(self.start)

    def profile(self, j: int) -> np.ndarray:
        return self.points_yz_mm[self.start[j]:self.start[j + 1]]


@dataclass(frozen=True)
class SweepInfo:
    """One commanded sweep: the station it belongs to, its nominal speed (mm/s at the
    tool point) and direction (unit vector, base frame, the way the flange moves)."""

    station: str
    speed_mm_s: float
    direction: tuple[float, float, float]


@dataclass(frozen=True)
class Recording:
    """A pose stream and a profile stream of one calibration (see module docstring).

    ``clocks`` names the clock of each stream: ``robot`` the pose stream's, ``sensor``
    the profile stream's (e.g. ``"abb-egm"``, ``"nxsensor-i"``). Equal names say that one
    clock stamped both streams, so no drift between them can be seen."""

    mounting: str
    sphere_radius_mm: float
    poses: PoseStream
    profiles: ProfileStream
    sweeps: list[SweepInfo] = field(default_factory=list)
    provenance: dict[str, Any] = field(default_factory=dict)
    clocks: dict[str, str] = field(default_factory=lambda: {"robot": "robot", "sensor": "sensor"})

    @property
    def t_sensor0_s(self) -> float:
        """The first profile's sensor stamp, the drift's reference time."""
        return float(self.profiles.t_sensor_s[0])

    @property
    def poses_assumption(self) -> str | None:
        """What the pose stream's poses assume when they were not measured (the stream's
        own ``assumption``, else the provenance's ``poses_assumed``, as the stream form
        keeps it), or None: measured."""
        found = self.poses.assumption or self.provenance.get(POSES_ASSUMED_KEY)
        return str(found) if found else None
