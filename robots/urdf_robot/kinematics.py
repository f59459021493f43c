"""Kinematics of any revolute arm described by a URDF, through Pinocchio.

The chain from the base link to the flange link is read with
:func:`spherecal.plugins.read_urdf_chain` (Pinocchio's ``buildModelFromXML``; metres in the
file, millimetres here; fixed joints on the way folded in). Its joint limits are the
URDF's.

Joint conventions. The controller reports its joints in its own order and convention
(degrees); the URDF's joints are the serial model's (radians). The configuration names,
for each controller joint ``i`` in controller order, the URDF joint ``joints[i]`` it
drives, and the map between the two conventions (the hook for coupled axes)::

    q_model_deg[i] = sum_j A[i][j] q_controller_deg[j] + b_deg[i]

where ``q_model_deg[i]`` is the URDF joint ``joints[i]``'s value in degrees. The identity
(``A = I``, ``b = 0``) is the default. The ABB IRB 2400's parallel linkage is the worked
example: its controller reports axis 3 relative to the horizontal, so
``q3_model = q3_controller - q2_controller``: ``A`` is the identity with row 3 set to
``[0, -1, 1, 0, 0, 0]``. Inverse kinematics solves in the model's angles and maps back
through ``A^-1``.

Inverse kinematics is numerical (:func:`spherecal.plugins.chain_inverse_kinematics`, Newton
steps with damped least squares), seeded from the current joints (given none, from the
configured home): the solution nearest them, as a controller's linear move keeps its
configuration. When a direct solve from
the seed fails, the pose is approached along the straight line from the seed's own pose
(continuation), in more and smaller steps. Revolute joints take the turn (multiple of
360 deg) nearest the seed that fits their limits.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from spherecal.plugins import (
    IkNotConverged,
    InputError,
    Pose,
    SerialChain,
    UrdfChain,
    chain_inverse_kinematics,
    chain_reach_mm,
    matrix_from_rotvec,
    rotvec_from_matrix,
)

#: Convergence of the numerical inverse kinematics.
IK_TOLERANCE_MM = 1e-9
IK_TOLERANCE_RAD = 1e-9
#: Steps of the continuation tried when a direct solve from the seed fails.
CONTINUATION_STEPS = (4, 16, 64)


class JointLimitError(InputError):
    """A joint value lies outside its range. The message names joint, value and limit."""


class UnreachableError(InputError):
    """No joint solution within the limits reaches the requested flange pose."""


@dataclass(frozen=True)
class JointMap:
    """``q_model_deg = matrix @ q_controller_deg + offset_deg`` (controller order on
    both sides; see the module docstring)."""

    matrix: np.ndarray
    offset_deg: np.ndarray

    def __post_init__(self):
        A = np.asarray(self.matrix, dtype=float)
        b = np.asarray(self.offset_deg, dtype=float).reshape(-1)
        n = len(b)
        if A.shape != (n, n) or not np.all(np.isfinite(A)) or not np.all(np.isfinite(b)):
            raise InputError(f"joint_map: matrix must be {n} x {n} and finite, offset_deg {n} finite values")
        if np.linalg.cond(A) > 1e8:
            raise InputError(f"joint_map: matrix {A.tolist()} is singular: controller joints could not be "
                             "recovered from model joints")
        object.__setattr__(self, "matrix", A)
        object.__setattr__(self, "offset_deg", b)
        object.__setattr__(self, "_inverse", np.linalg.inv(A))

    def model_deg(self, q_controller_deg: np.ndarray) -> np.ndarray:
        return self.matrix @ q_controller_deg + self.offset_deg

    def controller_deg(self, q_model_deg: np.ndarray) -> np.ndarray:
        return self._inverse @ (q_model_deg - self.offset_deg)


class UrdfKinematics:
    """Forward and inverse kinematics of the chain of a URDF (implements
    :class:`spherecal.plugins.ArmKinematics`).

    Joints in and out are degrees in the controller's order and convention; poses are
    ``base_from_flange``, mm, quaternion (w, x, y, z). ``controller_limits_deg`` ((n, 2),
    controller convention) narrows the URDF's limits where the controller's own are
    tighter (a coupled axis). ``home_joints_deg`` (controller convention) seeds inverse
    kinematics given no seed (None: zero joints)."""

    def __init__(
        self,
        urdf: UrdfChain,
        joint_names: tuple[str, ...] | None = None,
        joint_map: JointMap | None = None,
        controller_limits_deg=None,
        base_link: str = "base_link",
        flange_link: str = "tool0",
        home_joints_deg=None,
    ):
        names = tuple(urdf.joint_names)
        n = len(names)
        order = tuple(joint_names) if joint_names is not None else names
        if sorted(order) != sorted(names) or len(set(order)) != n:
            raise InputError(
                f"{urdf.source}: joints must name each revolute joint from {base_link!r} to {flange_link!r} once, "
                f"in controller order; the chain's joints are {list(names)}, the configuration gives {list(order)}"
            )
        self.urdf = urdf
        self.source = urdf.source
        self.base_link = base_link
        self.flange_link = flange_link
        #: The URDF's joints from base to flange (the chain's order).
        self.joint_names = names
        #: The URDF joint each controller joint drives, in controller order.
        self.controller_joint_names = order
        self.n_joints = n
        #: chain index of controller joint i
        self._chain_index = np.array([names.index(j) for j in order])
        #: The arm's home (controller convention, deg; None: not declared): where inverse
        #: kinematics starts when given no seed.
        self.home_joints_deg = None if home_joints_deg is None else tuple(float(v) for v in home_joints_deg)
        self.joint_map = joint_map or JointMap(np.eye(n), np.zeros(n))
        if self.joint_map.offset_deg.shape != (n,):
            raise InputError(f"joint_map: expected {n} joints (the chain's), got {len(self.joint_map.offset_deg)}")
        self._chain = urdf.chain
        self.model_lower_rad = np.asarray(urdf.lower_rad, dtype=float)
        self.model_upper_rad = np.asarray(urdf.upper_rad, dtype=float)
        if controller_limits_deg is None:
            self.controller_limits_deg = None
        else:
            lim = np.asarray(controller_limits_deg, dtype=float)
            if lim.shape != (n, 2) or np.any(lim[:, 0] >= lim[:, 1]):
                raise InputError(f"joint_limits_deg: expected {n} pairs [lower, upper] with lower < upper")
            self.controller_limits_deg = lim

    # conventions -----------------------------------------------------------------------
    @property
    def chain(self) -> SerialChain:
        """The URDF's geometry from base link to flange link (mm, model convention, rad)."""
        return self._chain

    def model_joints_rad(self, joints_deg) -> np.ndarray:
        """The chain's angles (rad, chain order) from controller joints (deg, controller order)."""
        q = self._vector(joints_deg)
        out = np.empty(self.n_joints)
        out[self._chain_index] = np.radians(self.joint_map.model_deg(q))
        return out

    def controller_joints_deg(self, q_rad) -> np.ndarray:
        """Controller joints (deg, controller order) from the chain's angles (rad)."""
        q = np.asarray(q_rad, dtype=float).reshape(self.n_joints)
        return self.joint_map.controller_deg(np.degrees(q[self._chain_index]))

    def model_joint_limits_rad(self) -> np.ndarray:
        """(n, 2) lower and upper limits of the chain's joints (chain order, rad), the URDF's;
        a continuous joint's (none) is written as one turn either way."""
        lo = np.where(np.isfinite(self.model_lower_rad), self.model_lower_rad, -2 * math.pi)
        hi = np.where(np.isfinite(self.model_upper_rad), self.model_upper_rad, 2 * math.pi)
        return np.column_stack([lo, hi])

    def check_joint_limits(self, joints_deg, what: str = "joints_deg") -> np.ndarray:
        """The joints as an array, or :class:`JointLimitError` naming the first joint out of
        range (the URDF's limit on its model value, or the controller's own)."""
        q = self._vector(joints_deg, what)
        problem = self._limit_problem(q, what)
        if problem:
            raise JointLimitError(problem)
        return q

    def within_limits(self, joints_deg) -> bool:
        return self._limit_problem(self._vector(joints_deg), "joints_deg") is None

    def _limit_problem(self, q: np.ndarray, what: str, tol: float = 1e-9) -> str | None:
        m = self.model_joints_rad(q)
        for k in range(self.n_joints):
            c = int(self._chain_index[k])
            name = self.controller_joint_names[k]
            lo, hi = self.model_lower_rad[c], self.model_upper_rad[c]
            if not (lo - tol <= m[c] <= hi + tol):
                return (f"{what}: joint {k + 1} ({name}) model value {math.degrees(m[c]):.4f} deg is outside its "
                        f"URDF range {math.degrees(lo):.2f} .. {math.degrees(hi):.2f} deg ({self.source})")
        if self.controller_limits_deg is not None:
            for k in range(self.n_joints):
                lo, hi = self.controller_limits_deg[k]
                if not (lo - 1e-9 <= q[k] <= hi + 1e-9):
                    return (f"{what}: joint {k + 1} ({self.controller_joint_names[k]}) = {q[k]:.4f} deg is outside "
                            f"its range {lo:g} .. {hi:g} deg (robot.joint_limits_deg)")
        return None

    # forward ---------------------------------------------------------------------------
    def flange_matrix_from_joints(self, joints_deg, check_limits: bool = True) -> np.ndarray:
        """4x4 ``base_from_flange`` (mm) from controller joints (deg)."""
        q = self.check_joint_limits(joints_deg) if check_limits else joints_deg
        return self._chain.flange_matrices(self.model_joints_rad(q))

    def flange_pose_from_joints(self, joints_deg, check_limits: bool = True) -> Pose:
        """``base_from_flange`` (mm, quaternion w-first) from controller joints (deg)."""
        return Pose.from_matrix(self.flange_matrix_from_joints(joints_deg, check_limits))

    # inverse ---------------------------------------------------------------------------
    def joints_from_flange_pose(self, base_from_flange: Pose, seed_joints_deg=None) -> np.ndarray:
        """Controller joints (deg) within the limits that put the flange at
        ``base_from_flange``, nearest the seed (default: the home, else zero joints).
        Raises :class:`UnreachableError` when the flange lies beyond the arm's reach, and
        :class:`~spherecal.plugins.IkNotConverged` when it lies within it but the solver
        found no solution within the limits from this seed (another seed may: the
        message names this one)."""
        if seed_joints_deg is None:
            seed_joints_deg = np.zeros(self.n_joints) if self.home_joints_deg is None else self.home_joints_deg
        seed = self._vector(seed_joints_deg, "seed_joints_deg")
        target = base_from_flange.as_matrix()
        seed_model = self.model_joints_rad(seed)
        q = self._solve(target, seed_model)
        if q is None:
            start = self._chain.flange_matrices(seed_model)
            for steps in CONTINUATION_STEPS:
                q = self._continue(start, target, seed_model, steps)
                if q is not None:
                    break
        if q is not None:
            joints = self._nearest_turn_within_limits(q, seed_model)
            if joints is not None:
                return joints
        raise self._not_reached(base_from_flange, seed, q is not None)

    def _not_reached(self, base_from_flange: Pose, seed: np.ndarray, beyond_limit: bool) -> InputError:
        """The error for a pose the solver did not reach from ``seed``: out of reach when
        the flange lies further from the shoulder than the arm reaches, else not
        converged from this seed (the pose may be reachable from another)."""
        t = np.round(base_from_flange.translation, 3).tolist()
        quat = np.round(base_from_flange.quaternion_wxyz, 6).tolist()
        pose = f"flange pose translation_mm={t} quaternion_wxyz={quat}"
        distance = self._shoulder_distance_mm(base_from_flange.translation)
        if distance > self.reach_mm:
            return UnreachableError(
                f"{pose} is out of reach of the arm of {self.source} ({distance:.1f} mm from the shoulder, which "
                f"reaches {self.reach_mm:.1f} mm); choose a pose closer to the robot")
        found = ("found only a solution beyond a joint limit" if beyond_limit else
                 "did not converge to a solution")
        return IkNotConverged(
            f"{pose}: inverse kinematics from joints {np.round(seed, 1).tolist()} deg {found} (the flange lies "
            f"{distance:.1f} mm from the shoulder, within the arm's reach of {self.reach_mm:.1f} mm): the pose may "
            "be reachable from other joints (a seed at a singularity, such as a stretched elbow, converges badly: "
            "give the arm a home away from singularities, robot.home_joints_deg), or not at this flange orientation "
            "within the joint limits")

    def _shoulder_distance_mm(self, point_mm: np.ndarray) -> float:
        """The least distance from ``point_mm`` (base) to the shoulder (the second joint's
        origin, as :attr:`reach_mm` measures from it) as the first joint turns."""
        P = self._chain.placements
        if self.n_joints == 1:
            return float(np.linalg.norm(point_mm - P[0][:3, 3]))
        q = np.zeros((361, self.n_joints))
        q[:, 0] = np.linspace(-math.pi, math.pi, 361)
        first = SerialChain(P[:1], self._chain.axes[:1], P[1])  # the base to the shoulder
        shoulders = first.flange_matrices(q[:, :1])[:, :3, 3]
        return float(np.linalg.norm(shoulders - point_mm, axis=1).min())

    def _solve(self, target: np.ndarray, seed_model: np.ndarray) -> np.ndarray | None:
        try:
            return chain_inverse_kinematics(self._chain, target, seed_model, tol_mm=IK_TOLERANCE_MM,
                                            tol_rad=IK_TOLERANCE_RAD)
        except IkNotConverged:
            return None

    def _continue(self, start: np.ndarray, target: np.ndarray, seed_model: np.ndarray, steps: int):
        """Follow the straight line (position and rotation) from ``start`` to ``target``."""
        rv = rotvec_from_matrix(start[:3, :3].T @ target[:3, :3])
        q = seed_model
        for s in np.arange(1, steps + 1) / steps:
            T = np.eye(4)
            T[:3, :3] = start[:3, :3] @ matrix_from_rotvec(s * rv)
            T[:3, 3] = (1 - s) * start[:3, 3] + s * target[:3, 3]
            q = self._solve(T, q)
            if q is None:
                return None
        return q

    def _nearest_turn_within_limits(self, q_model: np.ndarray, seed_model: np.ndarray) -> np.ndarray | None:
        """Controller joints of ``q_model`` with each joint turned by whole turns to lie
        nearest the seed within its limits; None when a joint fits no turn."""
        q = q_model.copy()
        two_pi = 2 * math.pi
        for c in range(self.n_joints):
            lo, hi = self.model_lower_rad[c], self.model_upper_rad[c]
            best = None
            k0 = round((seed_model[c] - q[c]) / two_pi)
            for k in sorted(range(k0 - 2, k0 + 3), key=lambda k: abs(q[c] + k * two_pi - seed_model[c])):
                v = q[c] + k * two_pi
                if lo - 1e-9 <= v <= hi + 1e-9:
                    best = v
                    break
            if best is None:
                return None
            q[c] = min(max(best, lo), hi)
        joints = self.controller_joints_deg(q)
        return joints if self.within_limits(joints) else None

    # the arm's size --------------------------------------------------------------------
    @property
    def reach_mm(self) -> float:
        """The arm's reach (:func:`spherecal.plugins.chain_reach_mm` within the URDF's
        limits): the largest distance from the shoulder to the flange."""
        if not hasattr(self, "_reach_mm"):
            self._reach_mm = chain_reach_mm(self._chain, self.model_joint_limits_rad())
        return self._reach_mm

    def _vector(self, joints_deg, what: str = "joints_deg") -> np.ndarray:
        q = np.array(joints_deg, dtype=float).reshape(-1)
        if q.shape != (self.n_joints,):
            raise InputError(f"{what}: expected {self.n_joints} joint values in degrees, got {q.size}")
        if not np.all(np.isfinite(q)):
            raise InputError(f"{what}: contains NaN or infinite values: {q.tolist()}")
        return q
