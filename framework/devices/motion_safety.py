"""The checks a robot makes before and during motion, whatever protocol it speaks.

:class:`MotionSafety` is a base class for a robot plugin's robot: given the robot's
limits (a configuration with the fields of :class:`MotionLimits`), its arm's kinematics
and the point its flange carries (the sensor, or the sphere), it checks

- the speed: a positive number within ``max_speed_mm_s``;
- the workspace box (:class:`~spherecal.core.workspace.WorkspaceBox`, base frame): the
  target, and the start, where the arm stands, so that the whole straight path is in it
  (a box is convex);
- the reach: the target and ``path_check_samples`` points along the straight line to it,
  through the kinematics' inverse, within the joint limits, each solved from the joints
  of the point before, the first from the joints read now;
- the speed at the tool point: :meth:`MotionSafety.move_speeds` gives the flange and
  reorientation speeds, and the duration, that keep the tool point within the move's speed;
- the controller's frame: :meth:`MotionSafety.controller_frame_offset` compares the pose
  the controller reports with the kinematics' pose of the joints it reports, so that a
  controller working in another frame than the robot base is refused before anything moves.

:meth:`MotionSafety.check_target` (one planned target), :meth:`MotionSafety.check_move`
(the move from where the arm stands, the first move of a run) are the optional methods of
the :class:`~spherecal.devices.contract.Robot` protocol that join a run's plan check; a
robot's ``move_linear`` calls :meth:`MotionSafety.check_move_from_here` before it sends
anything. A subclass provides :meth:`MotionSafety.read_joints_deg` and, for the frame
check, :meth:`MotionSafety.read_controller_pose`; the line-protocol robot
(:class:`spherecal.devices.line_robot.LineRobot`) is one such subclass.

The kinematics must have ``flange_pose_from_joints(joints_deg, check_limits)`` and
``joints_from_flange_pose(pose, seed_joints_deg)``, raising an
:class:`~spherecal.core.errors.InputError` when a pose is out of reach (an
:class:`~spherecal.core.kinematics.ArmKinematics` has both).

What the checks raise: a move refused by a limit (the speed, the workspace box, the
reach) is an :class:`~spherecal.core.errors.InputError` (the command line's exit 3, "data
error"), raised before anything is sent. The request is at fault, not the device: the
robot works, and the plan, the configured limits or the target must change. It is the
class the run's plan check raises for a plan outside the limits, so a move refused
mid-run and a plan refused before the first motion read alike. A
:class:`~spherecal.core.errors.DeviceError` (exit 4) is for the device itself: a closed
connection (:meth:`MotionSafety.check_open`), a controller working in another frame
(:meth:`MotionSafety.check_controller_frame`), and a subclass's timeouts, disconnects and
protocol errors.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Callable

import numpy as np
from pydantic import BaseModel, ConfigDict, Field

from spherecal.core.errors import DeviceError, InputError
from spherecal.core.geometry import matrix_from_rotvec as _matrix_from_rotvec
from spherecal.core.geometry import rotvec_from_matrix as _rotvec
from spherecal.core.models import Pose
from spherecal.core.workspace import WorkspaceBox

__all__ = ["MIN_SPEED_MM_S", "FrameOffset", "MotionLimits", "MotionSafety"]

#: Slowest speed a move names (mm/s for the flange, deg/s for the reorientation): a move
#: that does not translate (or turn) still names one.
MIN_SPEED_MM_S = 0.1


class MotionLimits(BaseModel):
    """The limits :class:`MotionSafety` reads from a robot's configuration. A robot
    plugin's configuration model may derive from it (and give ``workspace`` a default, or
    a way to derive one). Lengths in mm, angles in degrees."""

    model_config = ConfigDict(defer_build=True, frozen=True, extra="forbid")

    max_speed_mm_s: float = Field(250.0, gt=0, le=7000, description="largest TCP speed a move may ask for, mm/s")
    orientation_speed_deg_s: float = Field(
        100.0, gt=0, le=10_000,
        description="largest reorientation speed a move asks for, deg/s; each move asks for less when its sensor "
        "(the tool point) would otherwise exceed the move's speed"
    )
    path_check_samples: int = Field(
        10, ge=0, le=10_000, description="points checked for reachability along a linear move, besides its end"
    )
    workspace: WorkspaceBox | None = Field(None, description="allowed flange positions, base, mm")


@dataclass(frozen=True)
class FrameOffset:
    """The controller's pose against a model's pose of the same joints
    (:meth:`MotionSafety.controller_frame_offset`): their distance (mm) and angle (deg),
    the joints (deg, controller convention) and ``controller_from_model`` (the
    controller's pose times the inverse of the model's: a frame on the base's side);
    ``model_from_controller`` the same difference on the flange's side (the inverse of
    the model's pose times the controller's: the controller's flange frame in the model's,
    ``tool0_from_controller_flange`` when that is what differs; None: not known)."""

    offset_mm: float
    angle_deg: float
    joints_deg: np.ndarray
    controller_from_model: Pose
    model_from_controller: Pose | None = None

    def flange_turn_deg(self, tolerance_mm: float) -> float | None:
        """The angle (deg) by which the controller's flange frame is turned from the
        model's when the difference is that alone (the flange-side difference moves the
        origin by at most ``tolerance_mm``); else None."""
        d = self.model_from_controller
        if d is None or float(np.linalg.norm(d.translation)) > tolerance_mm:
            return None
        return float(np.degrees(np.linalg.norm(_rotvec(d.rotation_matrix))))

    def within(self, tolerance_mm: float, tolerance_deg: float) -> bool:
        return self.offset_mm <= tolerance_mm and self.angle_deg <= tolerance_deg

    def joints_text(self) -> str:
        return ", ".join(f"{v:.2f}" for v in self.joints_deg)

    def frame_text(self) -> str:
        """``translation [x, y, z] mm, quaternion (w, x, y, z) [...]`` (no "-0.0")."""
        t = ", ".join(f"{round(v, 1) + 0.0:.1f}" for v in self.controller_from_model.translation_mm)
        q = ", ".join(f"{round(v, 4) + 0.0:.4f}" for v in self.controller_from_model.quaternion_wxyz)
        return f"translation [{t}] mm, quaternion (w, x, y, z) [{q}]"


class MotionSafety:
    """Base of a robot whose every move is checked before anything moves (see the module).

    :param config: the robot's limits: ``max_speed_mm_s``, ``orientation_speed_deg_s``,
        ``path_check_samples`` and ``workspace`` (a :class:`MotionLimits`, or a model
        derived from it).
    :param kinematics: the arm's forward and inverse kinematics (see the module).
    :param workspace: the box the flange must stay in (base frame, mm); default
        ``config.workspace``. :class:`~spherecal.core.errors.InputError` when neither is set.
    :param tool_point_mm: the point the flange carries whose speed every move limits
        (flange frame, mm): the sensor (eye-in-hand) or the sphere (eye-to-hand), the
        :attr:`~spherecal.devices.contract.DeviceContext.tool_point_mm` of the factory's
        context; None: the flange itself.

    A subclass reads its joints in :meth:`read_joints_deg` (and may keep the reading in
    :attr:`last_joints_deg`, the seed of the first :meth:`check_target`), and may
    override :meth:`check_open` (refuse a closed connection) and
    :meth:`read_controller_pose` (for :meth:`controller_frame_offset`)."""

    #: The robot in messages ("IRB 2400", "urdf robot 'ur5'").
    name = "robot"
    #: The resolution of the speeds :meth:`move_speeds` gives (they are rounded down to a
    #: multiple of it, as the protocol carries them), or None: not rounded.
    speed_step: float | None = None

    def __init__(self, config, kinematics, *, workspace: WorkspaceBox | None = None, tool_point_mm=None):
        self.config = config
        self.kin = kinematics
        #: the box the flange must stay in (base frame, mm)
        self.workspace = workspace if workspace is not None else config.workspace
        if self.workspace is None:
            raise InputError(f"{self.name}: no workspace box configured (robot.workspace.min_mm / max_mm)")
        #: the point carried by the flange whose speed every move limits (flange frame, mm):
        #: the sensor (eye-in-hand) or the sphere (eye-to-hand); None: the flange itself
        self.tool_point_mm = None if tool_point_mm is None else np.asarray(tool_point_mm, dtype=float).reshape(3)
        #: the joints last read (deg, controller convention), if the subclass keeps them
        self.last_joints_deg: np.ndarray | None = None
        self._check_seed: np.ndarray | None = None  # joints of the last target checked

    # what a subclass provides -----------------------------------------------------------
    def read_joints_deg(self) -> np.ndarray:
        """Joints now, degrees, controller convention (moves nothing)."""
        raise NotImplementedError(f"{type(self).__name__} must read its joints")

    def read_controller_pose(self) -> Pose:
        """The flange pose as the controller reports it (its own model, its own frame),
        ``base_from_flange``; for :meth:`controller_frame_offset`."""
        raise NotImplementedError(f"{type(self).__name__} does not read the controller's own pose")

    def check_open(self) -> None:
        """Raise :class:`~spherecal.core.errors.DeviceError` when the robot can no longer
        move (its connection is closed). Nothing by default."""

    # the checks -------------------------------------------------------------------------
    def check_target(self, base_from_flange: Pose, speed_mm_s: float) -> None:
        """Check a planned target against every limit without moving: speed,
        workspace box, and reachability within the joint limits. The inverse kinematics
        is seeded as the moves will be: the first check from the arm's joints now (read
        with :meth:`read_joints_deg`, which moves nothing), each next one from the joints
        the previous check found. Raises what ``move_linear`` would."""
        self.check_speed(speed_mm_s)
        self.check_workspace(base_from_flange, "target")
        seed = self._check_seed
        if seed is None:
            seed = self.last_joints_deg if self.last_joints_deg is not None else self.read_joints_deg()
        try:
            self._check_seed = self.kin.joints_from_flange_pose(base_from_flange, seed_joints_deg=seed)
        except InputError as exc:
            raise type(exc)(f"target: {exc}") from None

    def check_move(self, base_from_flange: Pose, speed_mm_s: float) -> None:
        """Check the straight move from where the arm stands now to ``base_from_flange``
        without moving, exactly as ``move_linear`` checks it before sending it: the
        speed, both ends in the workspace box (so the whole straight path: a box is
        convex), and the target and ``path_check_samples`` points along the path
        reachable within the joint limits, from the joints read now (which moves
        nothing). Raises what ``move_linear`` would."""
        self.check_move_from_here(base_from_flange, speed_mm_s)

    def check_move_from_here(self, target: Pose, speed_mm_s: float) -> tuple[Pose, np.ndarray]:
        """The checks of a move from the arm's current joints (:meth:`check_move`);
        returns two values, ``(start, target_joints)``: the start pose (where the arm
        stands) and the target's joints (deg, the solution nearest the start), for
        ``move_linear`` to send."""
        self.check_open()
        self.check_speed(speed_mm_s)
        self.check_workspace(target, "target")
        start_joints = self.read_joints_deg()
        start = self.kin.flange_pose_from_joints(start_joints, check_limits=False)
        self.check_workspace(start, "start", "; the straight path to the target would leave it: jog the arm into "
                                             "the box first")
        return start, self.check_path(start, target, start_joints)

    def check_speed(self, speed_mm_s: float) -> None:
        """A positive number within ``max_speed_mm_s``; InputError otherwise."""
        limit = self.config.max_speed_mm_s
        try:
            speed = float(speed_mm_s)
        except (TypeError, ValueError):
            speed = math.nan
        if not (math.isfinite(speed) and speed > 0):
            raise InputError(f"move_linear: speed_mm_s must be a positive number, got {speed_mm_s!r}")
        if speed_mm_s > limit:
            raise InputError(
                f"move_linear: speed_mm_s = {speed_mm_s} exceeds the configured max_speed_mm_s = {limit}; "
                f"ask for a slower move or raise robot.max_speed_mm_s"
            )

    def check_workspace(self, pose: Pose, what: str, hint: str = "") -> None:
        """The flange position of ``pose`` in the workspace box; InputError naming
        ``what`` (``target``, ``start``) and the box otherwise, followed by ``hint``."""
        box = self.workspace
        if not box.contains(pose.translation_mm):
            t = [round(v, 3) for v in pose.translation_mm]
            raise InputError(
                f"move_linear: {what} flange position {t} mm is outside the configured workspace box "
                f"min_mm={list(box.min_mm)} max_mm={list(box.max_mm)} (base frame){hint}"
            )

    def check_path(self, start: Pose, target: Pose, start_joints: np.ndarray) -> np.ndarray:
        """Check the target and ``path_check_samples`` points along the straight path
        (position linear, orientation along the shortest rotation) for reachability,
        each solved from the joints of the point before (the target from the start's);
        returns the target's joints (the solution nearest the start)."""
        n = self.config.path_check_samples
        seed = start_joints
        target_joints = None
        R0, R1 = start.rotation_matrix, target.rotation_matrix
        rv = _rotvec(R0.T @ R1)
        for s in [1.0, *(np.arange(1, n + 1) / (n + 1))]:  # the target first
            R = R0 @ _matrix_from_rotvec(s * rv)
            t = (1 - s) * start.translation + s * target.translation
            pose = Pose.from_rt(R, t)
            try:
                seed = self.kin.joints_from_flange_pose(pose, seed_joints_deg=seed)
            except InputError as exc:
                where = "target" if s == 1.0 else f"point {s:.0%} along the linear path"
                raise type(exc)(f"move_linear: {where}: {exc}") from None
            if target_joints is None:
                target_joints = seed
        return target_joints

    # speeds -----------------------------------------------------------------------------
    def move_speeds(self, start: Pose, target: Pose, speed_mm_s: float) -> tuple[float, float, float]:
        """(flange speed mm/s, reorientation speed deg/s, duration s) of a linear move that
        keeps the tool point (:attr:`tool_point_mm`; the flange without one) within
        ``speed_mm_s`` and the reorientation within ``orientation_speed_deg_s``.

        A controller interpolates position and orientation together: over a move of
        duration T the flange moves d at d/T and turns by theta at theta/T, so a point r
        off the flange moves at most (d + theta r)/T. T is the least that keeps that
        within ``speed_mm_s``; v_tcp = d/T and v_ori = theta/T make the controller take
        exactly T. The speeds are rounded down to :attr:`speed_step` (the controller then
        takes at least T) and are at least :data:`MIN_SPEED_MM_S`."""
        distance = float(np.linalg.norm(target.translation - start.translation))
        angle_deg = float(np.degrees(np.linalg.norm(_rotvec(start.rotation_matrix.T @ target.rotation_matrix))))
        r = float(np.linalg.norm(self.tool_point_mm)) if self.tool_point_mm is not None else 0.0
        max_ori = self.config.orientation_speed_deg_s
        duration = max((distance + np.radians(angle_deg) * r) / speed_mm_s, angle_deg / max_ori, 1e-6)
        v_tcp = self._named_speed(min(distance / duration, speed_mm_s))
        v_ori = self._named_speed(min(angle_deg / duration, max_ori))
        duration = max(distance / v_tcp, angle_deg / v_ori)  # what the controller will take
        peak = (distance + np.radians(angle_deg) * r) / duration
        if peak > speed_mm_s * (1 + 1e-9) + MIN_SPEED_MM_S:  # pragma: no cover - by construction
            raise InputError(f"move_linear: the tool point would move at {peak:.1f} mm/s, above {speed_mm_s} mm/s")
        return v_tcp, v_ori, duration

    def _named_speed(self, value: float) -> float:
        step = self.speed_step
        if step is not None:
            value = math.floor(value / step + 1e-9) * step
        return max(value, MIN_SPEED_MM_S)

    # the controller's frame -------------------------------------------------------------
    def controller_frame_offset(self, kinematics) -> FrameOffset:
        """How far the controller's pose (:meth:`read_controller_pose`) lies from
        ``kinematics``' pose of the joints it reports (:meth:`read_joints_deg`), read now.
        A controller that reports poses in another frame than the robot base (a base
        frame: a riser, an inverted mount, a multi-robot cell; a user frame) shows it
        here, as does a model whose geometry or joint convention is not the arm's;
        nothing moves. A plugin refuses the connection beyond its tolerance
        (:meth:`check_controller_frame`, or its own words for its controller): the
        workspace and path checks work in the base frame."""
        joints = self.read_joints_deg()
        reported = self.read_controller_pose()
        model = kinematics.flange_pose_from_joints(joints, check_limits=False)
        return FrameOffset(
            float(np.linalg.norm(reported.translation - model.translation)),
            float(np.degrees(np.linalg.norm(_rotvec(model.rotation_matrix.T @ reported.rotation_matrix)))),
            joints, reported @ model.inverse(), model.inverse() @ reported)

    def check_controller_frame(self, kinematics, tolerance_mm: float, tolerance_deg: float,
                               advice: str | Callable[[FrameOffset], str] = "") -> FrameOffset:
        """Refuse a controller whose pose lies beyond ``tolerance_mm`` / ``tolerance_deg``
        from ``kinematics``' pose of the joints it reports (:meth:`controller_frame_offset`):
        a :class:`~spherecal.core.errors.DeviceError` saying by how much, followed by
        ``advice`` (what to check on this controller; a function of the offset, or text).
        Returns the offset when within."""
        off = self.controller_frame_offset(kinematics)
        if off.within(tolerance_mm, tolerance_deg):
            return off
        more = advice(off) if callable(advice) else advice
        turn = off.flange_turn_deg(tolerance_mm)
        if turn is not None:  # the origin agrees: the controller's flange frame is turned from the model's
            d = off.model_from_controller
            q = ", ".join(f"{round(v, 4) + 0.0:.4f}" for v in d.quaternion_wxyz)
            more = (f"The flange's origin agrees: the controller's flange frame is the model's turned by {turn:.1f} "
                    f"deg, model_from_controller = quaternion (w, x, y, z) [{q}] (a KUKA's $FLANGE has x out of the "
                    "mounting face, spherecal's flange z): convert the controller's poses in the driver, "
                    "docs/writing-a-robot-plugin.md \"A controller's own flange frame\". " + more).strip()
        raise DeviceError(
            f"{self.name}: the controller reports the flange {off.offset_mm:.1f} mm and {off.angle_deg:.2f} deg away "
            f"from where the model puts it at the joints it reports ({off.joints_text()} deg), beyond the tolerance "
            f"{tolerance_mm:g} mm / {tolerance_deg:g} deg: about controller_from_model = {off.frame_text()}. "
            "spherecal plans, checks the workspace and the paths, and moves in the model's base frame, so its checks "
            "would not hold. Nothing was moved." + (f" {more}" if more else "")
        )
