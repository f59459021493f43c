"""Keep-out geometry: how close a sensor's body (a box in its own frame) comes to the
reference sphere and the rod that holds it, at flange poses sampled along straight moves.

Pure geometry, no devices and no protocol, so that a planner, a plan check or any robot
plugin can use it. Both mountings reduce to one computation in the sensor frame:

- eye-in-hand: the sensor rides on the flange (``flange_from_sensor``), the sphere is
  fixed in base on a stand, a vertical rod from its centre down ``rod_length_mm``;
- eye-to-hand: the sensor is fixed (``base_from_sensor``), the sphere rides on the flange
  on a stem, a rod from its centre to the flange's origin.

Distances are signed: positive is the gap between the body and the sphere (or rod),
negative how deep they overlap. A move is the controller's linear move: the flange's
position along the straight line, its orientation along the shortest rotation, as
:meth:`spherecal.devices.motion_safety.MotionSafety.check_path` samples it.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from spherecal.core.field_of_view import SensorBody
from spherecal.core.geometry import rotvec_from_matrix
from spherecal.core.models import MountingMode, Pose

#: Golden-section steps of the rod's closest point to the box: the bracket shrinks to
#: 0.618^45 (4e-10) of the rod's length.
_ROD_STEPS = 45
_GOLDEN = (np.sqrt(5.0) - 1.0) / 2.0


def box_signed_distance_mm(min_mm, max_mm, points_mm) -> np.ndarray:
    """Signed distance (mm) of ``points_mm`` (..., 3) from the axis-aligned box
    ``min_mm``..``max_mm``: the distance outside, minus the depth inside."""
    lo, hi = np.asarray(min_mm, float), np.asarray(max_mm, float)
    q = np.abs(np.asarray(points_mm, float) - (lo + hi) / 2) - (hi - lo) / 2
    outside = np.linalg.norm(np.maximum(q, 0.0), axis=-1)
    return outside + np.minimum(q.max(axis=-1), 0.0)


def rod_box_signed_distance_mm(min_mm, max_mm, a_mm, b_mm) -> np.ndarray:
    """Signed distance (mm) between the box and the segments ``a_mm``-``b_mm`` (..., 3):
    the least signed distance of the segment's points. A box's signed distance is convex,
    so along a segment it has one minimum, found by golden-section search."""
    a, b = np.asarray(a_mm, float), np.asarray(b_mm, float)
    d = b - a
    lo_t, hi_t = np.zeros(a.shape[:-1]), np.ones(a.shape[:-1])

    def at(t):
        return box_signed_distance_mm(min_mm, max_mm, a + t[..., None] * d)

    t1, t2 = hi_t - _GOLDEN, lo_t + _GOLDEN
    f1, f2 = at(t1), at(t2)
    for _ in range(_ROD_STEPS):  # each step keeps one inner point and evaluates one new one
        left = f1 <= f2
        hi_t, lo_t = np.where(left, t2, hi_t), np.where(left, lo_t, t1)
        t_new = np.where(left, hi_t - _GOLDEN * (hi_t - lo_t), lo_t + _GOLDEN * (hi_t - lo_t))
        f_new = at(t_new)
        t2, f2, t1, f1 = (np.where(left, t1, t_new), np.where(left, f1, f_new),
                          np.where(left, t_new, t2), np.where(left, f_new, f2))
    return np.minimum(np.minimum(f1, f2), np.minimum(at(np.zeros_like(lo_t)), at(np.ones_like(lo_t))))


def _rotations(rotvecs: np.ndarray) -> np.ndarray:
    """Rotation matrices (n, 3, 3) of rotation vectors (n, 3) (Rodrigues)."""
    theta = np.linalg.norm(rotvecs, axis=1)
    k = np.divide(rotvecs, theta[:, None], out=np.zeros_like(rotvecs), where=theta[:, None] > 0)
    K = np.zeros((len(k), 3, 3))
    K[:, 0, 1], K[:, 0, 2], K[:, 1, 2] = -k[:, 2], k[:, 1], -k[:, 0]
    K[:, 1, 0], K[:, 2, 0], K[:, 2, 1] = k[:, 2], -k[:, 1], k[:, 0]
    s, c = np.sin(theta)[:, None, None], np.cos(theta)[:, None, None]
    return np.eye(3) + s * K + (1 - c) * (K @ K)


def linear_move(start: Pose, end: Pose, fractions) -> tuple[np.ndarray, np.ndarray]:
    """Flange poses ``base_from_flange`` at ``fractions`` (0..1) of the linear move from
    ``start`` to ``end``: rotations (n, 3, 3) and translations (n, 3), mm."""
    s = np.asarray(fractions, float)
    R0 = start.rotation_matrix
    rv = rotvec_from_matrix(R0.T @ end.rotation_matrix)
    R = R0 @ _rotations(s[:, None] * rv)
    t = (1 - s)[:, None] * start.translation + s[:, None] * end.translation
    return R, t


@dataclass(frozen=True)
class KeepOutGeometry:
    """The sensor's body and the sphere with its rod, in the frames they are fixed in.

    ``transform``: the sensor's pose, ``flange_from_sensor`` (eye-in-hand) or
    ``base_from_sensor`` (eye-to-hand); ``sphere_centre_mm``: in base (eye-in-hand) or the
    flange frame (eye-to-hand); ``rod_radius_mm`` the stand's or stem's radius;
    ``rod_length_mm`` how far the stand reaches down (base -z) from the sphere's centre
    (eye-in-hand; eye-to-hand's stem runs to the flange's origin)."""

    mounting: MountingMode
    transform: Pose
    body: SensorBody
    sphere_centre_mm: tuple[float, float, float]
    sphere_radius_mm: float
    rod_radius_mm: float
    rod_length_mm: float

    @property
    def rod_name(self) -> str:
        """What holds the sphere: ``"stand"`` (eye-in-hand) or ``"stem"`` (eye-to-hand)."""
        return "stand" if self.mounting == "eye_in_hand" else "stem"

    def reach_mm(self) -> float:
        """The farthest point that moves with the flange, from the flange's origin (mm):
        a turn by theta moves no point of it farther than theta times this."""
        if self.mounting == "eye_in_hand":
            corners = np.array([[x, y, z] for x in (self.body.min_mm[0], self.body.max_mm[0])
                                for y in (self.body.min_mm[1], self.body.max_mm[1])
                                for z in (self.body.min_mm[2], self.body.max_mm[2])])
            return float(np.linalg.norm(self.transform.apply(corners), axis=1).max())
        return float(np.linalg.norm(self.sphere_centre_mm)) + self.sphere_radius_mm

    def clearances_mm(self, R_bf: np.ndarray, t_bf: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Signed clearance (mm) of the body from the sphere and from its rod at the flange
        poses ``R_bf`` (n, 3, 3), ``t_bf`` (n, 3) (``base_from_flange``): two arrays (n,)."""
        X = self.transform
        c = np.asarray(self.sphere_centre_mm, float)
        if self.mounting == "eye_in_hand":
            R_bs = R_bf @ X.rotation_matrix  # base_from_sensor at each pose
            t_bs = np.einsum("nij,j->ni", R_bf, X.translation) + t_bf
            foot = c - np.array([0.0, 0.0, self.rod_length_mm])

            def in_sensor(p):
                return np.einsum("nji,nj->ni", R_bs, p - t_bs)

            centre, rod_end = in_sensor(np.broadcast_to(c, t_bf.shape)), in_sensor(np.broadcast_to(foot, t_bf.shape))
        else:
            R_sb, t_sb = X.rotation_matrix.T, -X.rotation_matrix.T @ X.translation  # sensor_from_base
            centre = (R_sb @ (np.einsum("nij,j->ni", R_bf, c) + t_bf).T).T + t_sb
            rod_end = (R_sb @ t_bf.T).T + t_sb  # the flange's origin
        lo, hi = self.body.min_mm, self.body.max_mm
        sphere = box_signed_distance_mm(lo, hi, centre) - self.sphere_radius_mm
        if self.mounting == "eye_in_hand" and self.rod_length_mm <= 0:  # no stand
            return sphere, np.full_like(sphere, np.inf)
        rod = rod_box_signed_distance_mm(lo, hi, centre, rod_end) - self.rod_radius_mm
        return sphere, rod


@dataclass(frozen=True)
class Closest:
    """The least clearance along one move (or at one pose): ``clearance_mm`` (signed),
    what it is to (``"sphere"`` or ``"stand"``/``"stem"``), at which fraction of the move
    and at which flange position (base, mm)."""

    clearance_mm: float
    part: str
    fraction: float
    flange_mm: tuple[float, float, float]


def closest_along_moves(geometry: KeepOutGeometry, poses: list[Pose],
                        step_mm: float = 1.0) -> tuple[list[Closest], int]:
    """The closest approach of the body to the sphere and its rod along each straight move
    between consecutive ``poses`` (``base_from_flange``), both ends included: one
    :class:`Closest` per move, and the number of poses sampled. Each move is sampled so
    that no point of the moving body (eye-in-hand) or sphere (eye-to-hand) travels more
    than ``step_mm`` between samples."""
    if len(poses) < 2:
        return [], 0
    reach = geometry.reach_mm()
    Rs, ts, fracs, bounds = [], [], [], [0]
    for start, end in zip(poses[:-1], poses[1:]):
        angle = float(np.linalg.norm(rotvec_from_matrix(start.rotation_matrix.T @ end.rotation_matrix)))
        travel = float(np.linalg.norm(end.translation - start.translation)) + angle * reach
        s = np.linspace(0.0, 1.0, max(int(np.ceil(travel / step_mm)), 1) + 1)
        R, t = linear_move(start, end, s)
        Rs.append(R), ts.append(t), fracs.append(s)
        bounds.append(bounds[-1] + len(s))
    sphere, rod = geometry.clearances_mm(np.concatenate(Rs), np.concatenate(ts))
    fraction, flange = np.concatenate(fracs), np.concatenate(ts)
    out = []
    for a, b in zip(bounds[:-1], bounds[1:]):
        k_s, k_r = a + int(np.argmin(sphere[a:b])), a + int(np.argmin(rod[a:b]))
        k, part = (k_s, "sphere") if sphere[k_s] <= rod[k_r] else (k_r, geometry.rod_name)
        value = sphere[k] if part == "sphere" else rod[k]
        out.append(Closest(float(value), part, float(fraction[k]), tuple(float(v) for v in flange[k])))
    return out, bounds[-1]


def closest_at_poses(geometry: KeepOutGeometry, poses: list[Pose]) -> list[Closest]:
    """The body's clearance from the sphere and its rod at each of ``poses`` (no motion)."""
    if not poses:
        return []
    R = np.array([p.rotation_matrix for p in poses])
    t = np.array([p.translation for p in poses])
    sphere, rod = geometry.clearances_mm(R, t)
    return [Closest(float(s), "sphere", 1.0, tuple(float(v) for v in tt)) if s <= r else
            Closest(float(r), geometry.rod_name, 1.0, tuple(float(v) for v in tt)) for s, r, tt in zip(sphere, rod, t)]
