"""A revolute serial chain, brand-free: how a robot plugin describes its arm's geometry.

A robot plugin that knows its kinematics describes them as an :class:`ArmKinematics`:
a :class:`SerialChain` in the model's joint convention (radians), the conversion from
the controller's joint readings (degrees, controller convention) to model angles, and
its inverse kinematics. The core uses it where only geometry matters (the simulated
robot's geometric error in :mod:`spherecal.sim`, flange poses from joint readings); it
never needs to know which robot it is.

Chain convention (docs/conventions.md): joint ``i`` sits at ``placements[i]``
(``parent_from_joint_i`` at zero angle, 4x4, mm; the parent of joint 1 is the base)
and turns about ``axes[i]`` (a unit vector in its own frame); the flange (ABB: tool0)
is ``flange_placement`` (``joint_n_from_flange``) on the last joint. So::

    base_from_flange(q) = P_1 Rot(a_1, q_1) P_2 Rot(a_2, q_2) ... P_n Rot(a_n, q_n) F
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Protocol, runtime_checkable

import numpy as np

from spherecal.core.errors import InputError
from spherecal.core.models import Pose


def _axis_angle_matrices(axis: np.ndarray, angles: np.ndarray) -> np.ndarray:
    """(N, 3, 3) rotations about the unit ``axis`` by ``angles`` (rad), Rodrigues."""
    K = np.array([[0.0, -axis[2], axis[1]], [axis[2], 0.0, -axis[0]], [-axis[1], axis[0], 0.0]])
    s = np.sin(angles)[:, None, None]
    c = np.cos(angles)[:, None, None]
    return np.eye(3) + s * K + (1.0 - c) * (K @ K)


@dataclass(frozen=True)
class SerialChain:
    """Geometry of a revolute serial arm (see the module docstring). Lengths in mm,
    angles in radians, model joint convention."""

    placements: np.ndarray  # (n, 4, 4) parent_from_joint at zero angle
    axes: np.ndarray  # (n, 3) unit rotation axes, each in its joint's frame
    flange_placement: np.ndarray  # (4, 4) last_joint_from_flange

    def __post_init__(self):
        P = np.asarray(self.placements, dtype=float)
        a = np.asarray(self.axes, dtype=float)
        F = np.asarray(self.flange_placement, dtype=float)
        if P.ndim != 3 or P.shape[1:] != (4, 4) or a.shape != (len(P), 3) or F.shape != (4, 4):
            raise ValueError(
                f"SerialChain: placements (n, 4, 4), axes (n, 3), flange_placement (4, 4) expected; got "
                f"{P.shape}, {a.shape}, {F.shape}"
            )
        if not (np.all(np.isfinite(P)) and np.all(np.isfinite(a)) and np.all(np.isfinite(F))):
            raise ValueError("SerialChain: placements, axes and flange placement must be finite")
        norms = np.linalg.norm(a, axis=1)
        if np.any(np.abs(norms - 1.0) > 1e-9):
            raise ValueError(f"SerialChain: axes must be unit vectors, norms {norms.tolist()}")
        object.__setattr__(self, "placements", P)
        object.__setattr__(self, "axes", a)
        object.__setattr__(self, "flange_placement", F)

    @property
    def n_joints(self) -> int:
        return len(self.placements)

    def flange_matrices(self, q_rad) -> np.ndarray:
        """``base_from_flange`` 4x4 (mm) for joint vectors ``q_rad``: (n,) -> (4, 4),
        (N, n) -> (N, 4, 4)."""
        q = np.asarray(q_rad, dtype=float)
        single = q.ndim == 1
        Q = np.atleast_2d(q)
        if Q.shape[1] != self.n_joints:
            raise ValueError(f"SerialChain: expected {self.n_joints} joint angles, got {Q.shape[1]}")
        T = np.broadcast_to(np.eye(4), (len(Q), 4, 4)).copy()
        for i in range(self.n_joints):
            T = T @ self.placements[i]
            R = _axis_angle_matrices(self.axes[i], Q[:, i])
            T[:, :3, :3] = T[:, :3, :3] @ R
        T = T @ self.flange_placement
        return T[0] if single else T

    def flange_pose(self, q_rad) -> Pose:
        """``base_from_flange`` as a :class:`Pose` (quaternion w-first) for one joint vector."""
        return Pose.from_matrix(self.flange_matrices(np.asarray(q_rad, dtype=float).reshape(self.n_joints)))


def chain_reach_mm(chain: SerialChain, joint_limits_rad=None, samples: int = 4000) -> float:
    """The arm's reach: the largest distance from the second joint's origin (the
    shoulder; the first joint's for a one-joint chain) to the flange over ``samples``
    joint sets drawn uniformly within ``joint_limits_rad`` ((n, 2), model convention;
    default and at most one turn, -pi .. pi). Seeded: the same value every time."""
    n = chain.n_joints
    lo, hi = np.full(n, -np.pi), np.full(n, np.pi)
    if joint_limits_rad is not None:
        lim = np.asarray(joint_limits_rad, dtype=float).reshape(n, 2)
        lo, hi = np.maximum(lo, lim[:, 0]), np.minimum(hi, lim[:, 1])
    Q = np.random.default_rng(0).uniform(lo, hi, (samples, n))
    k = 1 if n > 1 else 0
    shoulder = np.broadcast_to(chain.placements[0], (samples, 4, 4)).copy()
    if k:
        shoulder[:, :3, :3] = shoulder[:, :3, :3] @ _axis_angle_matrices(chain.axes[0], Q[:, 0])
        shoulder = shoulder @ chain.placements[1]
    flange = chain.flange_matrices(Q)
    return float(np.linalg.norm(flange[:, :3, 3] - shoulder[:, :3, 3], axis=1).max())


@runtime_checkable
class ArmKinematics(Protocol):
    """What a robot plugin exposes about its arm's kinematics (joints in degrees,
    controller convention, at this boundary; poses ``base_from_flange`` in mm)."""

    @property
    def chain(self) -> SerialChain:
        """The nominal geometry, model joint convention (radians)."""

    def model_joints_rad(self, joints_deg) -> np.ndarray:
        """Model angles (rad) of the chain from controller joints (deg)."""

    def flange_pose_from_joints(self, joints_deg, check_limits: bool = True) -> Pose:
        """Nominal ``base_from_flange`` of controller joints (deg)."""

    def joints_from_flange_pose(self, base_from_flange: Pose, seed_joints_deg=None) -> np.ndarray:
        """Controller joints (deg) that reach the pose, nearest the seed; raises an
        :class:`~spherecal.core.errors.InputError` when out of reach."""


# --- where inverse kinematics starts when the arm's joints are not known -------------------
#
# Before a robot is connected (the kinematic planner, its check of a plan) and for a
# simulated arm's first target there are no current joints to seed inverse kinematics
# with. Zero joints are a poor seed on many arms: a KUKA's, a UR's, are the stretched
# elbow there, a singularity from which a numerical solver converges to the wrong branch
# or not at all. So the solve starts from the arm's home when its robot type declares one
# (:attr:`spherecal.devices.contract.RobotType.home_joints_deg`, carried by the arm as
# ``home_joints_deg``: an optional attribute of an ArmKinematics, controller convention,
# deg), and from a few spread seeds after it.

#: The spread seeds tried after the home (or after zero joints, for an arm that declares
#: no home): this many joint sets drawn uniformly within +-:data:`FALLBACK_SEED_SPREAD_DEG`
#: on every joint, controller convention (seeded: the same seeds every time).
FALLBACK_SEED_DRAWS = 4
FALLBACK_SEED_SPREAD_DEG = 120.0


def declared_home_joints_deg(arm) -> np.ndarray | None:
    """The home an arm's kinematics carry (``arm.home_joints_deg``, controller
    convention, deg), or None when it declares none. Raises :class:`InputError` for a
    home of the wrong length or with non-finite values."""
    home = getattr(arm, "home_joints_deg", None)
    if home is None:
        return None
    q = np.asarray(home, dtype=float).reshape(-1)
    n = arm.chain.n_joints
    if q.shape != (n,) or not np.all(np.isfinite(q)):
        raise InputError(f"home_joints_deg: expected {n} finite joint values in degrees (the arm's joints), got "
                         f"{np.asarray(home).tolist()}")
    return q


def arm_joint_names(arm) -> tuple[str, ...] | None:
    """The names of the joints an arm's kinematics takes, in the order it takes them (the
    controller's), or None when it names none: ``controller_joint_names`` when the arm
    has them (a URDF arm whose controller orders its joints otherwise than the chain),
    else ``joint_names`` (optional attributes of an ArmKinematics: the names a ROS
    description and its ``/joint_states`` give the joints). Raises :class:`InputError`
    when they do not name each of the arm's joints once."""
    names = getattr(arm, "controller_joint_names", None) or getattr(arm, "joint_names", None)
    if names is None:
        return None
    names = tuple(str(n) for n in names)
    n = arm.chain.n_joints
    if len(names) != n or len(set(names)) != n:
        raise InputError(f"joint_names: expected {n} distinct names (the arm's joints), got {list(names)}")
    return names


def ik_seeds_deg(arm) -> list[np.ndarray]:
    """The joints (controller convention, deg) inverse kinematics is seeded at, in turn,
    when the arm's own joints are not known: the declared home
    (:func:`declared_home_joints_deg`), or zero joints for an arm that declares none, then
    :data:`FALLBACK_SEED_DRAWS` spread seeds."""
    n = arm.chain.n_joints
    home = declared_home_joints_deg(arm)
    first = np.zeros(n) if home is None else home
    spread = np.random.default_rng(0).uniform(-FALLBACK_SEED_SPREAD_DEG, FALLBACK_SEED_SPREAD_DEG,
                                              (FALLBACK_SEED_DRAWS, n))
    return [first, *spread]


def joints_from_home(arm, base_from_flange: Pose) -> np.ndarray:
    """Controller joints (deg) that reach ``base_from_flange`` when the arm's joints are
    not known: the arm's inverse kinematics from each of :func:`ik_seeds_deg` in turn, the
    first that reaches it. When none does, the error of the first seed (the home),
    saying how many other seeds were tried."""
    seeds = ik_seeds_deg(arm)
    first: InputError | None = None
    for seed in seeds:
        try:
            return arm.joints_from_flange_pose(base_from_flange, seed)
        except InputError as exc:
            first = first or exc
    raise type(first)(f"{first} (nor from {len(seeds) - 1} other seeds spread over the joints)") from None


class ArmWithHome:
    """An arm's kinematics with the home its robot type declares
    (:attr:`~spherecal.devices.contract.RobotType.home_joints_deg`): every attribute is the
    arm's own, and ``home_joints_deg`` the declared home (controller convention, deg)."""

    def __init__(self, arm, home_joints_deg):
        self._arm = arm
        self.home_joints_deg = tuple(float(v) for v in np.asarray(home_joints_deg, dtype=float).reshape(-1))
        declared_home_joints_deg(self)  # the length and the values, checked once

    def __getattr__(self, name: str):
        if name == "_arm":  # not set yet (a copy being built): never recurse
            raise AttributeError(name)
        return getattr(self._arm, name)

    def __repr__(self) -> str:
        return f"ArmWithHome({self._arm!r}, home_joints_deg={list(self.home_joints_deg)})"


# --- geometric error parameters ------------------------------------------------------------
#
# A real arm differs from its nominal chain by small changes to each joint's placement.
# Joint i gets six error parameters, in this order:
#
#   zero_offset  rotation about the joint's own axis (rad): the joint's zero is off;
#   x, y, z      translation of the joint's origin (mm), in its parent's frame;
#   tilt_u/v     rotation of the joint's frame (rad) about two directions perpendicular to
#                its axis (``error_tilt_basis``): the axis is tilted.
#
# The true placement is ``Trans(d) P_i Exp(phi)``, ``phi = tilt_u u + tilt_v v + zero a``.
# The joint axis stays ``axes[i]`` in the (rotated) joint frame, so a chain with errors is
# again a :class:`SerialChain`, with only its placements changed and the joint zero
# offsets folded into them. The flange placement has no error parameters: its error is
# the same at every pose, and the hand-eye transform (or the sphere on the flange)
# absorbs it.

ERROR_PARAMETERS_PER_JOINT = ("zero_offset", "x", "y", "z", "tilt_u", "tilt_v")
#: Which of the six are angles (rad); the others are lengths (mm).
ERROR_PARAMETER_IS_ANGLE = (True, False, False, False, True, True)


def error_tilt_basis(axis) -> tuple[np.ndarray, np.ndarray]:
    """Two unit directions ``u, v`` perpendicular to ``axis`` and to each other, chosen
    deterministically: ``u = normalise(axis x e_k)``, ``e_k`` the coordinate axis least
    aligned with ``axis``; ``v = axis x u``."""
    a = np.asarray(axis, dtype=float)
    e = np.zeros(3)
    e[int(np.argmin(np.abs(a)))] = 1.0
    u = np.cross(a, e)
    u /= np.linalg.norm(u)
    return u, np.cross(a, u)


def error_parameter_names(chain: SerialChain, joint_names: list[str] | None = None) -> list[str]:
    """``joint_<i>.<parameter>`` for every error parameter of ``chain``, in order."""
    names = joint_names or [f"joint_{i + 1}" for i in range(chain.n_joints)]
    return [f"{j}.{p}" for j in names for p in ERROR_PARAMETERS_PER_JOINT]


def _joint_error_rotation(axis: np.ndarray, params: np.ndarray) -> np.ndarray:
    u, v = error_tilt_basis(axis)
    phi = params[0] * axis + params[4] * u + params[5] * v
    return _axis_angle_matrices(phi / max(np.linalg.norm(phi), 1e-300), np.array([np.linalg.norm(phi)]))[0]


def chain_with_errors(chain: SerialChain, errors) -> SerialChain:
    """``chain`` with the geometric errors ``errors`` ((6 n,), see above; rad and mm)
    applied exactly: ``P_i <- Trans(d_i) P_i Exp(phi_i)``."""
    e = np.asarray(errors, dtype=float).reshape(chain.n_joints, len(ERROR_PARAMETERS_PER_JOINT))
    P = chain.placements.copy()
    for i in range(chain.n_joints):
        P[i, :3, 3] += e[i, 1:4]
        P[i, :3, :3] = P[i, :3, :3] @ _joint_error_rotation(chain.axes[i], e[i])
    return SerialChain(P, chain.axes.copy(), chain.flange_placement.copy())


def flange_error_jacobian(chain: SerialChain, q_rad) -> np.ndarray:
    """d(flange pose error)/d(error parameters) at joint vectors ``q_rad`` (N, n): (N, 6,
    6 n). The pose error is ``(omega, tau)``: a rotation ``omega`` (rad, base axes) of the
    flange about its own origin and a translation ``tau`` (mm, base frame), i.e.
    ``R <- exp(omega) R``, ``t <- t + tau``. First order, at ``chain`` as it is."""
    Q = np.atleast_2d(np.asarray(q_rad, dtype=float))
    N, n = len(Q), chain.n_joints
    T_flange = chain.flange_matrices(Q)
    p_f = T_flange[:, :3, 3]
    out = np.zeros((N, 6, 6 * n))
    T = np.broadcast_to(np.eye(4), (N, 4, 4)).copy()
    for i in range(n):
        parent_R = T[:, :3, :3].copy()
        T = T @ chain.placements[i]  # the joint's frame at zero angle (before it turns)
        Rj, o = T[:, :3, :3], T[:, :3, 3]
        lever = p_f - o
        u, v = error_tilt_basis(chain.axes[i])
        base = 6 * i
        for col, direction in ((0, chain.axes[i]), (4, u), (5, v)):
            w = Rj @ direction  # (N, 3) the rotation axis in base
            out[:, :3, base + col] = w
            out[:, 3:, base + col] = np.cross(w, lever)
        out[:, 3:, base + 1:base + 4] = parent_R  # translation of the joint origin, parent frame
        T[:, :3, :3] = T[:, :3, :3] @ _axis_angle_matrices(chain.axes[i], Q[:, i])
    return out


def flange_corrections(nominal: SerialChain, actual: SerialChain, q_rad) -> tuple[np.ndarray, np.ndarray]:
    """What moves a pose the ``nominal`` chain reports at joints ``q_rad`` (N, n) to where
    the ``actual`` chain puts the flange: ``R <- dR R``, ``t <- t + dt`` with
    ``dR = R_a R_n^T`` (N, 3, 3) and ``dt = t_a - t_n`` (N, 3, mm)."""
    Q = np.atleast_2d(np.asarray(q_rad, dtype=float))
    Tn, Ta = nominal.flange_matrices(Q), actual.flange_matrices(Q)
    return Ta[:, :3, :3] @ np.swapaxes(Tn[:, :3, :3], 1, 2), Ta[:, :3, 3] - Tn[:, :3, 3]


def corrected_flange_poses(nominal: SerialChain, actual: SerialChain, q_rad, reported) -> list[Pose]:
    """Reported flange poses (the controller's nominal model at joints ``q_rad``, (N, n))
    moved to where the ``actual`` chain (a calibrated model) puts the flange
    (:func:`flange_corrections`). Exact when the reported pose is the nominal model's."""
    dR, dt = flange_corrections(nominal, actual, q_rad)
    return [Pose.from_rt(r @ p.rotation_matrix, p.translation + d) for p, r, d in zip(reported, dR, dt)]
