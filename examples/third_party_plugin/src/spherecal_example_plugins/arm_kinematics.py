"""The example arm's geometry: a six-axis arm with a spherical wrist (axes z, y, y, x, y, x
from base to flange), about 1.55 m of reach, its controller's joints the chain's angles in
degrees. An :class:`spherecal.plugins.ArmKinematics`: forward kinematics through the
chain, inverse kinematics numerically (:func:`spherecal.plugins.chain_inverse_kinematics`)
from a seed, never from zero joints (the stretched elbow, a singularity) but from
:data:`HOME_JOINTS_DEG` when no seed is given.
"""

from __future__ import annotations

import numpy as np

from spherecal.plugins import (InputError, Pose, SerialChain, chain_inverse_kinematics, matrix_from_rotvec,
                               rotation_angle_deg, rotvec_from_matrix)


def _placement(xyz_mm, rotvec_deg=(0.0, 0.0, 0.0)) -> np.ndarray:
    T = np.eye(4)
    T[:3, :3] = matrix_from_rotvec(np.radians(rotvec_deg))
    T[:3, 3] = xyz_mm
    return T


#: parent_from_joint at zero angle (mm) and each joint's axis: base, shoulder 150 mm out
#: and 630 mm up, upper arm 700 mm, elbow 120 mm up, forearm 760 mm to the wrist centre
CHAIN = SerialChain(
    placements=np.array([_placement([0, 0, 0]), _placement([150, 0, 630]), _placement([0, 0, 700]),
                         _placement([0, 0, 120]), _placement([760, 0, 0]), _placement([0, 0, 0])]),
    axes=np.array([[0, 0, 1], [0, 1, 0], [0, 1, 0], [1, 0, 0], [0, 1, 0], [1, 0, 0]], dtype=float),
    flange_placement=_placement([90, 0, 0], [0, 90, 0]),  # tool0: z out of the flange, along the forearm at zero
)
#: the controller's joint limits, deg (lower, upper)
LIMITS_DEG = np.array([[-170, 170], [-90, 150], [-200, 75], [-185, 185], [-125, 125], [-350, 350]], dtype=float)
#: where the arm starts and the inverse kinematics' default seed: flange pointing down
HOME_JOINTS_DEG = np.array([0.0, 0.0, 0.0, 0.0, 90.0, 0.0])


class ExampleArmKinematics:
    """The example arm (module docstring); joints in degrees, poses ``base_from_flange`` in mm."""

    chain = CHAIN

    def model_joints_rad(self, joints_deg) -> np.ndarray:
        return np.radians(np.asarray(joints_deg, dtype=float))

    def model_joint_limits_rad(self) -> np.ndarray:
        """(6, 2) lower and upper limits in rad: the simulated cell lays itself out for this reach."""
        return np.radians(LIMITS_DEG)

    def check_joint_limits(self, joints_deg, what: str = "joints_deg") -> np.ndarray:
        q = np.asarray(joints_deg, dtype=float).reshape(6)
        out = [i + 1 for i in range(6) if not LIMITS_DEG[i, 0] - 1e-9 <= q[i] <= LIMITS_DEG[i, 1] + 1e-9]
        if out:
            raise InputError(f"{what}: joint(s) {out} of {np.round(q, 3).tolist()} deg beyond the limits "
                             f"{LIMITS_DEG[[i - 1 for i in out]].tolist()} deg")
        return q

    def flange_pose_from_joints(self, joints_deg, check_limits: bool = True) -> Pose:
        q = self.check_joint_limits(joints_deg) if check_limits else np.asarray(joints_deg, dtype=float)
        return self.chain.flange_pose(np.radians(q))

    def joints_from_flange_pose(self, base_from_flange: Pose, seed_joints_deg=None) -> np.ndarray:
        """The joints (deg) reaching ``base_from_flange`` nearest the seed (default
        :data:`HOME_JOINTS_DEG`), within the limits; an InputError when out of reach. It
        walks from the seed's pose to the target in steps of at most 100 mm and 15 deg,
        each solved from the one before, so it keeps the seed's configuration."""
        seed = HOME_JOINTS_DEG if seed_joints_deg is None else np.asarray(seed_joints_deg, dtype=float)
        where = f"flange pose {np.round(base_from_flange.translation_mm, 1).tolist()} mm"
        start = self.chain.flange_pose(np.radians(seed))
        steps = int(max(1, np.ceil(np.linalg.norm(base_from_flange.translation - start.translation) / 100.0),
                        np.ceil(rotation_angle_deg(start.rotation_matrix, base_from_flange.rotation_matrix) / 15.0)))
        q = np.radians(seed)
        for s in np.arange(1, steps + 1) / steps:
            try:
                q = chain_inverse_kinematics(self.chain, _between(start, base_from_flange, s).as_matrix(), q)
            except InputError:
                raise InputError(f"{where} is out of the example arm's reach (inverse kinematics did not "
                                 "converge)") from None
        q = np.degrees(q)
        flipped = q + [0.0, 0.0, 0.0, 180.0, -2 * q[4], 180.0]  # the other wrist: Rx(a) Ry(b) Rx(c) = Rx(a+180) Ry(-b) Rx(c+180)
        candidates = [seed + (c - seed + 180.0) % 360.0 - 180.0 for c in (q, flipped)]  # each turn nearest the seed
        best = min(candidates, key=lambda c: np.abs(c - seed).sum())
        return self.check_joint_limits(best, where)


def _between(a: Pose, b: Pose, s: float) -> Pose:
    """The pose a fraction ``s`` of the way from ``a`` to ``b`` (straight, shortest turn)."""
    turn = rotvec_from_matrix(a.rotation_matrix.T @ b.rotation_matrix)
    return Pose.from_rt(a.rotation_matrix @ matrix_from_rotvec(s * turn),
                        (1 - s) * a.translation + s * b.translation)
