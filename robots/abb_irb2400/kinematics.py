"""Kinematic model of the ABB IRB 2400, built in Pinocchio from published geometry.

Frames and units follow ``docs/conventions.md``: lengths in mm, joint readings in
degrees at the edges, radians inside, poses ``base_from_flange`` with quaternions
(w, x, y, z) as ABB writes them.

The chain (all joint frames parallel to ``base`` at zero joints): joint i sits at
``offset_mm`` from joint i-1 and turns about its own ``axis``. The flange frame
``tool0`` sits on joint 6's origin, rotated by ``tool0_rotvec_deg`` (default a +90 deg
turn about y) so that its z axis points out of the flange: at zero joints tool0's z is
the base's x and the flange is at (940, 0, 1455) mm.

Axis 2/3 parallel linkage. The IRB 2400 drives its upper arm through a parallel rod,
and the controller reports axis 3 relative to the horizontal rather than to the lower
arm. With ``j23_coupled=True`` (the IRB 2400 default) the serial model's third angle is
``q3_model = q3_controller - q2_controller``; every public function here takes and
returns joints in the **controller** convention (as ``CJointT()`` reports them) and
converts internally. Joint limits are the datasheet ranges and are checked on the
controller-convention values, as the controller itself checks them.

Inverse kinematics is analytic (the wrist axes 4, 5, 6 meet in one point): the wrist
centre fixes axes 1-3 (up to a shoulder flip and an elbow flip), the wrist rotation
fixes axes 4-6 (up to a wrist flip), and axes 4 and 6, whose ranges exceed one turn,
take the turn nearest the seed. Every solution is checked against Pinocchio's forward
kinematics before it is returned.
"""

from __future__ import annotations

import itertools
import math
from functools import lru_cache
from typing import Literal

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, model_validator

from spherecal.plugins import (
    ConfigError,
    IkNotConverged,
    InputError,
    Pose,
    SerialChain,
    chain_from_urdf,
    chain_inverse_kinematics,
    matrix_from_rotvec,
    rotation_angle_deg,
)

JOINT_COUNT = 6
#: Largest position error (mm) an IK solution may show under forward kinematics.
IK_TOLERANCE_MM = 1e-4
#: Largest element-wise rotation-matrix error an IK solution may show.
IK_TOLERANCE_ROTATION = 1e-8


class JointLimitError(InputError):
    """A joint value lies outside its range. The message names joint, value and limit."""


class UnreachableError(InputError):
    """No joint solution within the limits reaches the requested flange pose."""


class JointSpec(BaseModel):
    """One revolute joint: where it sits on the previous joint, its axis, its range."""

    model_config = ConfigDict(defer_build=True, frozen=True, extra="forbid")

    offset_mm: tuple[float, float, float] = Field(
        description="origin of this joint in the previous joint's frame (all joints at zero), mm"
    )
    axis: Literal["x", "y", "z"] = Field(description="rotation axis in the joint's own frame")
    lower_deg: float = Field(description="lower limit, controller convention, deg")
    upper_deg: float = Field(description="upper limit, controller convention, deg")
    max_speed_deg_s: float = Field(gt=0, description="maximum joint speed, deg/s")

    @model_validator(mode="after")
    def _check_range(self):
        if not self.lower_deg < self.upper_deg:
            raise ValueError(f"lower_deg ({self.lower_deg}) must be below upper_deg ({self.upper_deg})")
        return self


def _j(offset, axis, lo, hi, speed) -> JointSpec:
    return JointSpec(offset_mm=offset, axis=axis, lower_deg=lo, upper_deg=hi, max_speed_deg_s=speed)


#: IRB 2400/10 and /16 (one geometry), from /work/shared/reference/hardware.md.
IRB2400_JOINTS: tuple[JointSpec, ...] = (
    _j((0.0, 0.0, 0.0), "z", -180.0, 180.0, 150.0),
    _j((100.0, 0.0, 615.0), "y", -100.0, 110.0, 150.0),
    _j((0.0, 0.0, 705.0), "y", -60.0, 65.0, 150.0),
    _j((0.0, 0.0, 135.0), "x", -200.0, 200.0, 360.0),
    _j((755.0, 0.0, 0.0), "y", -120.0, 120.0, 360.0),
    _j((85.0, 0.0, 0.0), "x", -400.0, 400.0, 450.0),
)

#: Axes the analytic inverse kinematics is written for.
_EXPECTED_AXES = ("z", "y", "y", "x", "y", "x")


class Irb2400Geometry(BaseModel):
    """Nominal geometry of the arm. Defaults: the published IRB 2400 values.

    The analytic inverse kinematics needs the IRB 2400's structure: axes z, y, y, x, y,
    x; no y offsets; joints 5 and 6 offset along x only (a spherical wrist)."""

    model_config = ConfigDict(defer_build=True, frozen=True, extra="forbid")

    joints: tuple[JointSpec, JointSpec, JointSpec, JointSpec, JointSpec, JointSpec] = Field(
        IRB2400_JOINTS, description="joints 1..6, base to flange"
    )
    tool0_rotvec_deg: tuple[float, float, float] = Field(
        (0.0, 90.0, 0.0),
        description="rotation of tool0 relative to joint 6's frame, rotation vector in deg "
        "(default: +90 deg about y, so tool0's z points out of the flange)",
    )

    @model_validator(mode="after")
    def _check_structure(self):
        axes = tuple(j.axis for j in self.joints)
        if axes != _EXPECTED_AXES:
            raise ValueError(f"joint axes must be {_EXPECTED_AXES} for this model, got {axes}")
        for i, j in enumerate(self.joints, start=1):
            if j.offset_mm[1] != 0.0:
                raise ValueError(f"joint {i}: offset_mm y must be 0 for this model, got {j.offset_mm}")
        for i in (5, 6):
            off = self.joints[i - 1].offset_mm
            if off[2] != 0.0:
                raise ValueError(f"joint {i}: offset_mm must lie along x (spherical wrist), got {off}")
        if self.joints[0].offset_mm != (0.0, 0.0, 0.0):
            raise ValueError(f"joint 1 must sit at the base origin, got {self.joints[0].offset_mm}")
        return self


class _Pinocchio:
    """The ``pinocchio`` module, imported on first use: loading the plugin (``spherecal
    plugins``, ``--help``) does not pay its import (about 0.1 s)."""

    def __getattr__(self, name: str):
        import pinocchio

        return getattr(pinocchio, name)


pin = _Pinocchio()
_JOINT_AXES = {"x": "JointModelRX", "y": "JointModelRY", "z": "JointModelRZ"}


def _rot(axis: str, angle: float) -> np.ndarray:
    c, s = math.cos(angle), math.sin(angle)
    if axis == "x":
        return np.array([[1, 0, 0], [0, c, -s], [0, s, c]])
    if axis == "y":
        return np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]])
    return np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])


def _wrap_pi(a: float) -> float:
    return (a + math.pi) % (2 * math.pi) - math.pi


class Irb2400Kinematics:
    """Forward and inverse kinematics of one IRB 2400 geometry.

    Joints in and out are degrees in the controller convention (see the module
    docstring for ``j23_coupled``). Poses are ``base_from_flange`` (tool0 in wobj0), mm,
    quaternion (w, x, y, z)."""

    #: The joints' names, base to flange: those of the ROS-Industrial description of the
    #: IRB 2400 (and of the model's URDF), by which a ROS ``/joint_states`` is read.
    joint_names = tuple(f"joint_{i}" for i in range(1, JOINT_COUNT + 1))

    def __init__(self, geometry: Irb2400Geometry | None = None, j23_coupled: bool = True):
        self.geometry = geometry or Irb2400Geometry()
        self.j23_coupled = bool(j23_coupled)
        self.lower_deg = np.array([j.lower_deg for j in self.geometry.joints])
        self.upper_deg = np.array([j.upper_deg for j in self.geometry.joints])
        self.max_speed_deg_s = np.array([j.max_speed_deg_s for j in self.geometry.joints])
        self.model = self._build_model()
        self.data = self.model.createData()
        self.tool0_id = self.model.getFrameId("tool0")
        self._R_j6_from_tool0 = matrix_from_rotvec(np.radians(self.geometry.tool0_rotvec_deg))

    @property
    def chain(self) -> SerialChain:
        """The nominal geometry as a brand-free :class:`~spherecal.plugins.SerialChain`
        (model joint convention, rad; see ``model_joints_rad``): each joint placed at its
        ``offset_mm`` with no rotation, turning about its own x, y or z axis; tool0 turned
        by ``tool0_rotvec_deg`` on joint 6."""
        placements = np.repeat(np.eye(4)[None], JOINT_COUNT, axis=0)
        for i, spec in enumerate(self.geometry.joints):
            placements[i, :3, 3] = spec.offset_mm
        axes = np.array([np.eye(3)["xyz".index(spec.axis)] for spec in self.geometry.joints])
        flange = np.eye(4)
        flange[:3, :3] = self._R_j6_from_tool0
        return SerialChain(placements, axes, flange)

    def _build_model(self) -> pin.Model:
        model = pin.Model()
        model.name = "abb_irb2400"
        parent = 0
        for i, spec in enumerate(self.geometry.joints, start=1):
            placement = pin.SE3(np.eye(3), np.asarray(spec.offset_mm, dtype=float))
            parent = model.addJoint(parent, getattr(pin, _JOINT_AXES[spec.axis])(), placement, f"joint_{i}")
            model.appendBodyToJoint(parent, pin.Inertia.Zero(), pin.SE3.Identity())
        R = matrix_from_rotvec(np.radians(self.geometry.tool0_rotvec_deg))
        model.addFrame(pin.Frame("tool0", parent, 0, pin.SE3(R, np.zeros(3)), pin.FrameType.OP_FRAME))
        return model

    # conventions -----------------------------------------------------------------------
    def model_joints_rad(self, joints_deg) -> np.ndarray:
        """Serial-model angles (rad) from controller-convention joints (deg)."""
        q = _joint_vector(joints_deg)
        if self.j23_coupled:
            q[2] = q[2] - q[1]
        return np.radians(q)

    def controller_joints_deg(self, q_rad) -> np.ndarray:
        """Controller-convention joints (deg) from serial-model angles (rad)."""
        q = np.degrees(np.asarray(q_rad, dtype=float).reshape(JOINT_COUNT))
        if self.j23_coupled:
            q[2] = q[2] + q[1]
        return q

    def check_joint_limits(self, joints_deg, what: str = "joints_deg") -> np.ndarray:
        """Return the joints as an array, or raise :class:`JointLimitError` naming the
        first joint out of range, its value and the limit (controller convention)."""
        q = _joint_vector(joints_deg, what)
        for i in range(JOINT_COUNT):
            if q[i] < self.lower_deg[i]:
                raise JointLimitError(
                    f"{what}: joint {i + 1} = {q[i]:.4f} deg is below its lower limit "
                    f"{self.lower_deg[i]:.1f} deg (range {self.lower_deg[i]:.1f} .. {self.upper_deg[i]:.1f})"
                )
            if q[i] > self.upper_deg[i]:
                raise JointLimitError(
                    f"{what}: joint {i + 1} = {q[i]:.4f} deg is above its upper limit "
                    f"{self.upper_deg[i]:.1f} deg (range {self.lower_deg[i]:.1f} .. {self.upper_deg[i]:.1f})"
                )
        return q

    def model_joint_limits_rad(self) -> np.ndarray:
        """(6, 2) lower and upper limits in the serial model's convention (rad), for a URDF
        (``spherecal.plugins.chain_to_urdf(..., joint_limits_rad=)``). With ``j23_coupled`` the
        controller limits axis 3 relative to the horizontal, which no fixed range of the
        model's joint 3 expresses: its range here is the widest the controller can reach,
        ``lower_3 - upper_2 .. upper_3 - lower_2``; the controller still checks its own."""
        lo, hi = self.lower_deg.copy(), self.upper_deg.copy()
        if self.j23_coupled:
            lo[2], hi[2] = self.lower_deg[2] - self.upper_deg[1], self.upper_deg[2] - self.lower_deg[1]
        return np.radians(np.column_stack([lo, hi]))

    def within_limits(self, joints_deg) -> bool:
        q = np.asarray(joints_deg, dtype=float)
        return bool(np.all(q >= self.lower_deg - 1e-9) and np.all(q <= self.upper_deg + 1e-9))

    # forward ---------------------------------------------------------------------------
    def flange_matrix_from_joints(self, joints_deg, check_limits: bool = True) -> np.ndarray:
        """4x4 ``base_from_flange`` (mm) from controller-convention joints (deg)."""
        if check_limits:
            self.check_joint_limits(joints_deg)
        q = self.model_joints_rad(joints_deg)
        pin.framesForwardKinematics(self.model, self.data, q)
        return np.array(self.data.oMf[self.tool0_id].homogeneous)

    def flange_pose_from_joints(self, joints_deg, check_limits: bool = True) -> Pose:
        """``base_from_flange`` (mm, quaternion w-first) from controller joints (deg)."""
        return Pose.from_matrix(self.flange_matrix_from_joints(joints_deg, check_limits))

    # inverse ---------------------------------------------------------------------------
    def joint_solutions(self, base_from_flange: Pose, seed_joints_deg=None) -> list[np.ndarray]:
        """Every analytic solution (controller convention, deg), limits not applied.

        Axes 4 and 6 take the turn (multiple of 360 deg) nearest the seed (or zero)."""
        g = self.geometry.joints
        seed = np.zeros(JOINT_COUNT) if seed_joints_deg is None else _joint_vector(seed_joints_deg, "seed_joints_deg")
        seed_model = self.model_joints_rad(seed)
        R_tool = base_from_flange.rotation_matrix
        R6 = R_tool @ self._R_j6_from_tool0.T  # joint 6 frame in base
        d6 = g[5].offset_mm[0]
        wc = base_from_flange.translation - d6 * R6[:, 0]
        a1, d1 = g[1].offset_mm[0], g[1].offset_mm[2]
        # upper arm: joint 2 -> joint 3; forearm: joint 3 -> wrist centre (in joint-3 frame at q3=0)
        u = np.array([g[2].offset_mm[0], g[2].offset_mm[2]])
        f = np.array([g[3].offset_mm[0] + g[4].offset_mm[0], g[3].offset_mm[2] + g[4].offset_mm[2]])
        Lu, Lf = float(np.hypot(*u)), float(np.hypot(*f))
        solutions: list[np.ndarray] = []
        rho = math.hypot(wc[0], wc[1])
        if rho < 1e-9:
            q1_options = [seed_model[0]]  # on axis 1: any q1 works, keep the seed's
        else:
            base_angle = math.atan2(wc[1], wc[0])
            q1_options = [base_angle, _wrap_pi(base_angle + math.pi)]
        for q1 in q1_options:
            radial = wc[0] * math.cos(q1) + wc[1] * math.sin(q1)
            r, h = radial - a1, wc[2] - d1
            D2 = r * r + h * h
            # |u + Ry(q3) f|^2 = Lu^2 + Lf^2 + 2 u . Ry(q3) f, with Ry acting on (x, z)
            # u . Ry(q3) f = A cos q3 + B sin q3
            A = u[0] * f[0] + u[1] * f[1]
            B = u[0] * f[1] - u[1] * f[0]
            C = (D2 - Lu * Lu - Lf * Lf) / 2.0
            amp = math.hypot(A, B)
            if amp < 1e-12 or abs(C) > amp * (1 + 1e-12):
                continue
            phi = math.atan2(B, A)
            delta = math.acos(max(-1.0, min(1.0, C / amp)))
            for q3 in {_wrap_pi(phi + delta), _wrap_pi(phi - delta)}:
                c3, s3 = math.cos(q3), math.sin(q3)
                fx, fz = c3 * f[0] + s3 * f[1], -s3 * f[0] + c3 * f[1]
                vx, vz = u[0] + fx, u[1] + fz
                q2 = _wrap_pi(math.atan2(r, h) - math.atan2(vx, vz))
                R03 = _rot("z", q1) @ _rot("y", q2 + q3)
                W = R03.T @ R6  # = Rx(q4) Ry(q5) Rx(q6)
                s5_abs = math.hypot(W[1, 0], W[2, 0])
                if s5_abs < 1e-6:  # wrist singular: axes 4 and 6 aligned, keep the seed's q4
                    q4 = seed_model[3]
                    M = _rot("x", -q4) @ W  # = Ry(q5) Rx(q6)
                    wrist = [(q4, math.atan2(-M[2, 0], M[0, 0]), math.atan2(-M[1, 2], M[1, 1]))]
                else:
                    q5a = math.atan2(s5_abs, W[0, 0])
                    wrist = []
                    for q5 in (q5a, -q5a):
                        s5 = math.sin(q5)
                        wrist.append(
                            (math.atan2(W[1, 0] / s5, -W[2, 0] / s5), q5, math.atan2(W[0, 1] / s5, W[0, 2] / s5))
                        )
                for q4, q5, q6 in wrist:
                    q4 = _nearest_turn(q4, seed_model[3])
                    q6 = _nearest_turn(q6, seed_model[5])
                    q = np.array([q1, q2, q3, q4, q5, q6])
                    solutions.append(self.controller_joints_deg(q))
        checked = []
        for sol in solutions:
            T = self.flange_matrix_from_joints(sol, check_limits=False)
            if (
                np.linalg.norm(T[:3, 3] - base_from_flange.translation) < IK_TOLERANCE_MM
                and np.abs(T[:3, :3] - R_tool).max() < IK_TOLERANCE_ROTATION
            ):
                checked.append(sol)
        return checked

    def joints_from_flange_pose(self, base_from_flange: Pose, seed_joints_deg=None) -> np.ndarray:
        """The joint solution (controller convention, deg) within the limits that is
        nearest the seed (default: zero joints), or :class:`UnreachableError`."""
        seed = np.zeros(JOINT_COUNT) if seed_joints_deg is None else _joint_vector(seed_joints_deg, "seed_joints_deg")
        candidates = []
        for sol in self.joint_solutions(base_from_flange, seed):
            # axes 4 and 6 may also be reachable one turn further: try the neighbours
            for k4, k6 in itertools.product((0, -360, 360), repeat=2):
                cand = sol + np.array([0, 0, 0, k4, 0, k6], dtype=float)
                if self.within_limits(cand):
                    candidates.append(cand)
        if not candidates:
            t = np.round(base_from_flange.translation, 3).tolist()
            q = np.round(base_from_flange.quaternion_wxyz, 6).tolist()
            raise UnreachableError(
                f"flange pose translation_mm={t} quaternion_wxyz={q} is out of reach of the "
                f"IRB 2400 within its joint limits; choose a pose closer to the robot or "
                f"another flange orientation"
            )
        weights = 1.0 / self.max_speed_deg_s  # prefer solutions that take less time
        best = min(candidates, key=lambda c: float(np.max(np.abs(c - seed) * weights)))
        return np.clip(best, self.lower_deg, self.upper_deg)


class CalibratedIrb2400Kinematics(Irb2400Kinematics):
    """An IRB 2400 whose geometry is a calibrated chain (read from ``robot_calibrated.urdf``)
    rather than the nominal one: forward kinematics from the calibrated chain, inverse
    kinematics numerical on it, seeded with the nominal analytic solutions. Joints,
    limits and the axis 2/3 coupling stay the nominal model's (``nominal``).

    The controller keeps its nominal model: it cannot take new link lengths. So the
    calibration is applied on the PC side: :meth:`controller_target` gives the pose to
    send the controller for the flange to reach a true pose, and the true pose of the
    arm is the calibrated forward kinematics of its joint readings."""

    def __init__(self, nominal: Irb2400Kinematics, calibrated_chain: SerialChain, source: str = "calibrated model"):
        super().__init__(nominal.geometry, nominal.j23_coupled)
        if calibrated_chain.n_joints != JOINT_COUNT:
            raise InputError(f"{source}: a calibrated IRB 2400 model needs {JOINT_COUNT} joints, "
                             f"got {calibrated_chain.n_joints}")
        self.nominal = nominal
        self.source = source
        self._calibrated = calibrated_chain

    @property
    def chain(self) -> SerialChain:
        """The calibrated geometry (model joint convention, rad)."""
        return self._calibrated

    def flange_matrix_from_joints(self, joints_deg, check_limits: bool = True) -> np.ndarray:
        """4x4 ``base_from_flange`` (mm) of controller joints (deg) through the calibrated chain."""
        if check_limits:
            self.check_joint_limits(joints_deg)
        return self._calibrated.flange_matrices(self.model_joints_rad(joints_deg))

    def _refine(self, base_from_flange: Pose, joints_deg) -> np.ndarray | None:
        """Controller joints (deg) on the calibrated chain reached by Newton steps from a
        nominal solution, or None when they do not converge."""
        try:
            q = chain_inverse_kinematics(self._calibrated, base_from_flange.as_matrix(), self.model_joints_rad(joints_deg),
                                         tol_mm=CALIBRATED_IK_TOLERANCE_MM, tol_rad=CALIBRATED_IK_TOLERANCE_RAD)
        except IkNotConverged:
            return None
        return self.controller_joints_deg(q)

    def joint_solutions(self, base_from_flange: Pose, seed_joints_deg=None) -> list[np.ndarray]:
        """Every solution on the calibrated chain (controller convention, deg), limits not
        applied: each nominal analytic solution refined by Newton steps on the calibrated
        chain to :data:`CALIBRATED_IK_TOLERANCE_MM` and ``_RAD``."""
        refined = (self._refine(base_from_flange, sol) for sol in self.nominal.joint_solutions(base_from_flange, seed_joints_deg))
        return [q for q in refined if q is not None]

    def joints_from_flange_pose(self, base_from_flange: Pose, seed_joints_deg=None) -> np.ndarray:
        """Controller joints (deg) within the limits that put the **true** flange (the
        calibrated model's) at ``base_from_flange``, nearest the seed; or
        :class:`UnreachableError`.

        The nominal analytic solutions (and their neighbours one turn away on axes 4 and
        6) are ranked as the nominal model ranks them; the best one is refined on the
        calibrated chain, the next ones only if it fails or leaves the limits (a
        calibration moves a solution by a fraction of a degree)."""
        seed = np.zeros(JOINT_COUNT) if seed_joints_deg is None else _joint_vector(seed_joints_deg, "seed_joints_deg")
        margin = 1.0  # deg: a nominal solution just outside a limit may be inside once refined
        candidates = []
        for sol in self.nominal.joint_solutions(base_from_flange, seed):
            for k4, k6 in itertools.product((0, -360, 360), repeat=2):
                cand = sol + np.array([0, 0, 0, k4, 0, k6], dtype=float)
                if np.all(cand >= self.lower_deg - margin) and np.all(cand <= self.upper_deg + margin):
                    candidates.append(cand)
        weights = 1.0 / self.max_speed_deg_s
        candidates.sort(key=lambda c: float(np.max(np.abs(c - seed) * weights)))
        for cand in candidates:
            q = self._refine(base_from_flange, cand)
            if q is not None and self.within_limits(q):
                return np.clip(q, self.lower_deg, self.upper_deg)
        t = np.round(base_from_flange.translation, 3).tolist()
        quat = np.round(base_from_flange.quaternion_wxyz, 6).tolist()
        raise UnreachableError(
            f"flange pose translation_mm={t} quaternion_wxyz={quat} is out of reach of the IRB 2400 "
            f"(calibrated model {self.source}) within its joint limits; choose a pose closer to the robot "
            f"or another flange orientation"
        )

    def controller_target(self, base_from_flange: Pose, seed_joints_deg=None) -> tuple[np.ndarray, Pose]:
        """What to send the controller so that the flange really reaches ``base_from_flange``:
        the joints ``q`` that reach it on the calibrated chain, and the nominal model's
        pose at ``q`` (the controller, which knows only the nominal model, turns that pose
        back into ``q``)."""
        q = self.joints_from_flange_pose(base_from_flange, seed_joints_deg)
        return q, self.nominal.flange_pose_from_joints(q, check_limits=False)


#: Convergence of the numerical inverse kinematics on a calibrated chain.
CALIBRATED_IK_TOLERANCE_MM = 1e-9
CALIBRATED_IK_TOLERANCE_RAD = 1e-9
#: A calibrated model further than this from the nominal one at some joints is refused:
#: it is another robot, or a model in the wrong joint convention or unit.
CALIBRATED_MAX_DEVIATION_MM = 20.0
CALIBRATED_MAX_DEVIATION_DEG = 2.0
#: Joint names, base and flange links a calibrated model's URDF must have.
CALIBRATED_JOINT_NAMES = Irb2400Kinematics.joint_names
CALIBRATED_BASE_LINK = "base_link"
CALIBRATED_FLANGE_LINK = "tool0"


@lru_cache(maxsize=8)
def _calibrated_cached(geometry, j23_coupled: bool, path: str, stamp: tuple[int, int]) -> CalibratedIrb2400Kinematics:
    nominal = kinematics_for(geometry, j23_coupled)
    chain = chain_from_urdf(path, CALIBRATED_BASE_LINK, CALIBRATED_FLANGE_LINK, joint_names=CALIBRATED_JOINT_NAMES)
    # the PC-side scheme seeds from the nominal model: the two must be close
    rng = np.random.default_rng(0)
    q = rng.uniform(nominal.lower_deg, nominal.upper_deg, (64, JOINT_COUNT))
    Q = np.array([nominal.model_joints_rad(x) for x in q])
    Tc = chain.flange_matrices(Q)
    Tn = nominal.chain.flange_matrices(Q)
    dist = np.linalg.norm(Tc[:, :3, 3] - Tn[:, :3, 3], axis=1)
    ang = np.array([rotation_angle_deg(a[:3, :3], b[:3, :3]) for a, b in zip(Tc, Tn)])
    worst = int(np.argmax(dist))
    if dist.max() > CALIBRATED_MAX_DEVIATION_MM or ang.max() > CALIBRATED_MAX_DEVIATION_DEG:
        raise InputError(
            f"{path}: this model puts tool0 {dist.max():.1f} mm and {ang.max():.2f} deg away from the nominal "
            f"IRB 2400's (e.g. at controller joints {np.round(q[worst], 1).tolist()} deg); a calibration moves it "
            f"by a few mm at most (limits {CALIBRATED_MAX_DEVIATION_MM:g} mm, {CALIBRATED_MAX_DEVIATION_DEG:g} deg). "
            f"Is it the model of another robot, or in another joint convention (joint_3 must be the serial "
            f"model's, q3_model = q3_controller - q2_controller when j23_coupled)?"
        )
    return CalibratedIrb2400Kinematics(nominal, chain, path)


def calibrated_kinematics_for(
    geometry: Irb2400Geometry | None, j23_coupled: bool, path
) -> CalibratedIrb2400Kinematics:
    """The IRB 2400 kinematics with the calibrated geometry of a URDF file (joints
    ``joint_1`` .. ``joint_6`` in the serial model's convention, links ``base_link`` and
    ``tool0``, metres). Cached per file and modification time. Raises
    :class:`~spherecal.plugins.InputError` naming the file."""
    from pathlib import Path

    p = Path(path)
    try:
        st = p.stat()
    except OSError as exc:
        raise InputError(f"{p}: cannot read the calibrated model ({exc.strerror or exc})") from None
    return _calibrated_cached(geometry or Irb2400Geometry(), bool(j23_coupled), str(p), (st.st_mtime_ns, st.st_size))


def _nearest_turn(angle: float, reference: float) -> float:
    return angle + 2 * math.pi * round((reference - angle) / (2 * math.pi))


def _joint_vector(joints_deg, what: str = "joints_deg") -> np.ndarray:
    q = np.array(joints_deg, dtype=float).reshape(-1)
    if q.shape != (JOINT_COUNT,):
        raise InputError(f"{what}: expected {JOINT_COUNT} joint values in degrees, got {q.size}")
    if not np.all(np.isfinite(q)):
        raise InputError(f"{what}: contains NaN or infinite values: {q.tolist()}")
    return q


@lru_cache(maxsize=8)
def kinematics_for(geometry: Irb2400Geometry | None = None, j23_coupled: bool = True) -> Irb2400Kinematics:
    """A cached :class:`Irb2400Kinematics` (geometry models are frozen, so hashable)."""
    try:
        return Irb2400Kinematics(geometry, j23_coupled)
    except ValueError as exc:  # pragma: no cover - geometry is validated by pydantic first
        raise ConfigError(f"IRB 2400 geometry: {exc}") from exc


def flange_pose_from_joints(
    joints_deg, *, geometry: Irb2400Geometry | None = None, j23_coupled: bool = True
) -> Pose:
    """``base_from_flange`` (mm, quaternion (w, x, y, z)) from joint readings in degrees,
    controller convention. Raises :class:`JointLimitError` for a joint out of range."""
    return kinematics_for(geometry, j23_coupled).flange_pose_from_joints(joints_deg)
