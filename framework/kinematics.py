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

from .models import Pose


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
        :class:`~spherecal.errors.InputError` when out of reach."""
