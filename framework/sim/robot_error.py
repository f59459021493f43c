"""A simulated robot with a real robot's systematic error.

A real arm differs from its controller's nominal model: joint zero offsets, link lengths
and offsets, small axis tilts. The controller turns a target into joints with its
nominal model, the arm goes where its *true* geometry puts it, and the controller
reports the pose of its nominal model at the actual joints. So the reported pose is
(nearly) the commanded one, and the flange is off by 0.5-2 mm and 0.05-0.15 deg by an
amount that changes slowly over the joint space (see ``shared/reference/method.md``,
"Robot error"). :class:`SimulatedArm` does exactly that on the geometry a robot plugin
describes (:class:`~spherecal.core.kinematics.ArmKinematics`); it knows no robot brand.

The error of a particular arm is drawn once from :class:`~spherecal.config.RobotErrorModel` (magnitudes
uniform in the given ranges, signs and directions random) and stays fixed: it is the
arm's geometry, not noise.
"""

from __future__ import annotations

import numpy as np

from spherecal.config import RobotErrorModel
from spherecal.core import geometry as geo
from spherecal.core.kinematics import ArmKinematics, SerialChain, joints_from_home
from spherecal.core.models import Pose


def _signed(rng: np.random.Generator, rng_range: tuple[float, float], size) -> np.ndarray:
    lo, hi = rng_range
    return rng.uniform(lo, hi, size) * rng.choice([-1.0, 1.0], size)


def perturbed_chain(chain: SerialChain, model: RobotErrorModel, rng: np.random.Generator) -> tuple[SerialChain, np.ndarray]:
    """The true geometry of one arm: ``chain`` with errors drawn from ``model``, and the
    joint zero offsets (rad) to add to the model angles. Joint placements move along
    the link (the direction to the joint from its parent) by ``link_length_mm`` and across
    it by ``link_offset_mm``; every joint axis tilts by ``axis_tilt_deg`` about a random
    direction perpendicular to it. The flange placement itself is exact (the sensor or
    sphere transform is measured relative to the real flange)."""
    n = chain.n_joints
    P = chain.placements.copy()
    for i in range(n):
        t = P[i, :3, 3]
        along = t / np.linalg.norm(t) if np.linalg.norm(t) > 1e-9 else chain.axes[i]
        across = np.cross(along, rng.normal(size=3))
        across /= max(np.linalg.norm(across), 1e-12)
        P[i, :3, 3] = t + _signed(rng, model.link_length_mm, 1)[0] * along + _signed(rng, model.link_offset_mm, 1)[0] * across
        # tilt the joint's axis: rotate its frame about a direction perpendicular to the axis
        a = chain.axes[i]
        perp = np.cross(a, rng.normal(size=3))
        perp /= max(np.linalg.norm(perp), 1e-12)
        tilt = np.radians(_signed(rng, model.axis_tilt_deg, 1)[0])
        P[i, :3, :3] = P[i, :3, :3] @ geo.matrix_from_rotvec(tilt * perp)
    zero_offsets_rad = np.radians(_signed(rng, model.joint_zero_offset_deg, n))
    return SerialChain(P, chain.axes.copy(), chain.flange_placement.copy()), zero_offsets_rad


class SimulatedArm:
    """A robot arm whose true geometry differs from its controller's nominal model.

    ``kinematics`` is the robot plugin's nominal model; the true chain is drawn from
    ``error`` with ``seed``. Joints in and out are degrees, controller convention."""

    def __init__(self, kinematics: ArmKinematics, error: RobotErrorModel, seed: int | None = 0):
        self.kinematics = kinematics
        self.error = error
        rng = np.random.default_rng(error.seed if error.seed is not None else [seed or 0, 0x5EED])
        self.true_chain, self.zero_offsets_rad = perturbed_chain(kinematics.chain, error, rng)
        self.compliance_rad_per_mm = np.radians(rng.uniform(*error.joint_compliance_deg_per_m,
                                                            self.true_chain.n_joints)) / 1000.0

    def nominal_flange_pose(self, joints_deg) -> Pose:
        """What the controller reports at these joints: its nominal model's pose."""
        return self.kinematics.flange_pose_from_joints(joints_deg, check_limits=False)

    def true_flange_pose(self, joints_deg) -> Pose:
        """Where the flange really is at these joints."""
        q = self.kinematics.model_joints_rad(joints_deg) + self.zero_offsets_rad
        if np.any(self.compliance_rad_per_mm):
            q = q + self._sag_rad(q)
        return self.true_chain.flange_pose(q)

    def _sag_rad(self, q: np.ndarray) -> np.ndarray:
        """Each joint's gravity sag (rad): compliance x the gravity moment of a load at
        the flange about the joint's axis (lever in mm), signed to turn with gravity.
        ``q`` (n,) or (N, n) model angles (rad); the sag has the same shape."""
        chain = self.true_chain
        Q = np.atleast_2d(q)
        p_f = chain.flange_matrices(Q)[:, :3, 3]
        T = np.broadcast_to(np.eye(4), (len(Q), 4, 4)).copy()
        sag = np.zeros(Q.shape)
        down = np.array([0.0, 0.0, -1.0])
        for i in range(chain.n_joints):
            T = T @ chain.placements[i]
            axis = T[:, :3, :3] @ chain.axes[i]
            sag[:, i] = self.compliance_rad_per_mm[i] * np.einsum("nj,nj->n", axis, np.cross(p_f - T[:, :3, 3], down))
            T[:, :3, :3] = T[:, :3, :3] @ geo.matrix_from_rotvec(np.outer(Q[:, i], chain.axes[i]))
        return sag[0] if np.ndim(q) == 1 else sag

    def model_joints_rad(self, joints_deg) -> np.ndarray:
        """Model angles (rad) of controller joints (deg), (J,) or (N, J) row by row
        through the robot plugin's conversion."""
        J = np.asarray(joints_deg, dtype=float)
        convert = self.kinematics.model_joints_rad
        if J.ndim == 1:
            return np.asarray(convert(J), dtype=float)
        if len(J) > 2 * J.shape[1]:  # an affine conversion (most are: radians, a coupled axis) as one product
            b = np.asarray(convert(np.zeros(J.shape[1])), dtype=float)
            A = np.array([np.asarray(convert(e), dtype=float) - b for e in np.eye(J.shape[1])])
            probe = J[[0, len(J) // 2, -1]]
            if np.allclose(probe @ A + b, [convert(row) for row in probe], rtol=0.0, atol=1e-12):
                return J @ A + b
        return np.array([convert(row) for row in J]).reshape(J.shape)

    def nominal_flange_matrices(self, joints_deg) -> np.ndarray:
        """What the controller reports at many joint vectors (N, J), deg: its nominal
        chain's ``base_from_flange`` (N, 4, 4), mm (:meth:`nominal_flange_pose` at each)."""
        return self.kinematics.chain.flange_matrices(np.atleast_2d(self.model_joints_rad(joints_deg)))

    def true_flange_matrices(self, joints_deg) -> np.ndarray:
        """Where the flange really is at many joint vectors (N, J), deg: (N, 4, 4), mm
        (:meth:`true_flange_pose` at each)."""
        q = np.atleast_2d(self.model_joints_rad(joints_deg)) + self.zero_offsets_rad
        if np.any(self.compliance_rad_per_mm):
            q = q + self._sag_rad(q)
        return self.true_chain.flange_matrices(q)

    def joints_for(self, base_from_flange: Pose, seed_joints_deg=None) -> np.ndarray:
        """The joints the controller chooses for a target (nominal inverse kinematics),
        nearest ``seed_joints_deg`` (None: from the arm's home,
        :func:`~spherecal.core.kinematics.joints_from_home`)."""
        if seed_joints_deg is None:
            return joints_from_home(self.kinematics, base_from_flange)
        return self.kinematics.joints_from_flange_pose(base_from_flange, seed_joints_deg)

    def flange_error(self, joints_deg) -> tuple[float, float]:
        """(mm, deg) between the true and the reported flange pose at these joints."""
        a, b = self.true_flange_pose(joints_deg), self.nominal_flange_pose(joints_deg)
        return (float(np.linalg.norm(a.translation - b.translation)),
                geo.rotation_angle_deg(a.rotation_matrix, b.rotation_matrix))
