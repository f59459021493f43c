"""Configuration of the built-in ``urdf`` robot type (the ``robot`` section when ``type =
"urdf"``). Lengths in mm, angles in degrees, times in seconds; the URDF file itself is in
metres and radians, as every URDF."""

from __future__ import annotations

import math
from functools import lru_cache
from pathlib import Path
from typing import Literal

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, ValidationInfo, field_validator, model_validator

from spherecal.plugins import (
    BASE_DIR_CONTEXT_KEY,
    InputError,
    LineLinkSettings,
    SimulatedControllerSettings,
    WorkspaceBox,
    line_protocol,
    read_urdf_chain,
)

from .kinematics import JointMap, UrdfKinematics

#: Most joints the line protocol carries (a ``J`` reply fits one line).
MAX_JOINTS = line_protocol.MAX_JOINTS
#: Largest magnitude of a joint-map entry or a joint angle written in the configuration.
MAX_MAP_ENTRY = 1000.0
MAX_ANGLE_DEG = 100_000.0


class JointMapConfig(BaseModel):
    """The controller's joint convention: ``q_model_deg = matrix @ q_controller_deg +
    offset_deg``, controller order on both sides (row i is the URDF joint ``joints[i]``).
    Example, the IRB 2400's parallel linkage (``q3_model = q3_controller - q2_controller``)::

        matrix = [[1, 0, 0, 0, 0, 0], [0, 1, 0, 0, 0, 0], [0, -1, 1, 0, 0, 0],
                  [0, 0, 0, 1, 0, 0], [0, 0, 0, 0, 1, 0], [0, 0, 0, 0, 0, 1]]
    """

    model_config = ConfigDict(defer_build=True, frozen=True, extra="forbid")

    matrix: tuple[tuple[float, ...], ...] | None = Field(
        None, description="n x n matrix A of q_model_deg = A q_controller_deg + offset_deg, rows in controller "
        "order (row i: the URDF joint joints[i]); absent: the identity"
    )
    offset_deg: tuple[float, ...] | None = Field(
        None, description="n offsets b of q_model_deg = A q_controller_deg + b, deg; absent: zeros"
    )

    @field_validator("matrix", "offset_deg")
    @classmethod
    def _bounded(cls, v, info: ValidationInfo):
        if v is None:
            return v
        flat = [x for row in v for x in row] if info.field_name == "matrix" else list(v)
        limit = MAX_MAP_ENTRY if info.field_name == "matrix" else MAX_ANGLE_DEG
        if not all(math.isfinite(x) and abs(x) <= limit for x in flat):
            raise ValueError(f"entries must be finite and at most {limit:g} in magnitude")
        return v


class UrdfRobotConfig(LineLinkSettings):
    """Any revolute arm described by a URDF, whose controller runs a small server speaking
    the spherecal line protocol over a serial line or TCP (docs/robot-urdf.md,
    docs/line-protocol.md). The link and motion settings are the core's
    (:class:`spherecal.plugins.LineLinkSettings`)."""

    urdf: Path = Field(
        description="the robot's URDF file (metres, radians). A relative path resolves against the configuration "
        "file's folder when the host is given it, else the working directory"
    )
    base_link: str = Field("base_link", min_length=1, max_length=200,
                           description="the URDF link poses are given in (the controller's base frame)")
    flange_link: str = Field("tool0", min_length=1, max_length=200,
                             description="the URDF link of the flange (the mounting face, the controller's tool0)")
    joints: tuple[str, ...] | None = Field(
        None, description="the URDF joint each controller joint drives, in the order the controller reports its "
        f"joints (1 to {MAX_JOINTS} revolute joints from base_link to flange_link); absent: the URDF's order"
    )
    joint_map: JointMapConfig = Field(
        default_factory=JointMapConfig, description="the controller's joint convention (coupled axes): "
        "q_model_deg = matrix @ q_controller_deg + offset_deg"
    )
    joint_limits_deg: tuple[tuple[float, float], ...] | None = Field(
        None, description="the controller's own joint ranges [lower, upper], controller order and convention, deg, "
        "where tighter than the URDF's (checked as well as the URDF's)"
    )
    pose_source: Literal["controller", "joints"] = Field(
        "joints",
        description="flange pose from the joint readings (GETJ) through the URDF ('joints', the default) or from "
        "the controller (GETP: its own model's pose)",
    )
    workspace: WorkspaceBox | None = Field(
        None, description="allowed flange positions, base, mm; absent: a box around the arm's whole reach "
        "(reachability is checked anyway: set a box for your cell)"
    )
    base_frame_tolerance_mm: float = Field(
        5.0, gt=0, le=100, description="on connect, the controller's pose of the flange (GETP) may differ from the "
        "URDF's forward kinematics of the joints it reports (GETJ, base_link) by this much, mm; more means the "
        "controller works in another frame (a base frame, a user frame) or the URDF is not the arm, and the "
        "connection is refused (a controller with its own accuracy compensation differs by up to about 2 mm)",
    )
    base_frame_tolerance_deg: float = Field(
        0.5, gt=0, le=10, description="the same check's limit on the orientation difference, deg",
    )
    home_joints_deg: tuple[float, ...] | None = Field(
        None, description="the arm's home, controller order and convention, deg: where inverse kinematics starts "
        "when the arm's joints are not known (planning before the robot is connected, simulated data) and where "
        "the simulated controller starts unless simulated.home_joints_deg says otherwise. Choose joints away from "
        "singularities (elbow and wrist bent); absent: simulated.home_joints_deg, else zero joints and a few "
        "spread seeds (an arm whose zero joints stretch its elbow should set it)"
    )
    simulated: SimulatedControllerSettings = Field(
        default_factory=SimulatedControllerSettings, description="the simulated controller of simulated runs "
        "(home_joints_deg in controller convention)"
    )

    @field_validator("urdf", mode="after")
    @classmethod
    def _resolve(cls, v: Path, info: ValidationInfo) -> Path:
        v = Path(v).expanduser()
        base = (info.context or {}).get(BASE_DIR_CONTEXT_KEY)
        if not v.is_absolute():
            v = Path(base) / v if base is not None else v
        return v.resolve()

    @model_validator(mode="after")
    def _load(self):
        try:
            kin = self.kinematics()
        except InputError as exc:
            raise ValueError(str(exc)) from None
        n = kin.n_joints
        if n > MAX_JOINTS:
            raise ValueError(f"{self.urdf}: {n} joints from {self.base_link!r} to {self.flange_link!r}; the line "
                             f"protocol carries at most {MAX_JOINTS}")
        for key, home in (("home_joints_deg", self.home_joints_deg),
                          ("simulated.home_joints_deg", self.simulated.home_joints_deg)):
            if home is not None:
                if len(home) != n:
                    raise ValueError(f"{key}: expected {n} joint values, got {len(home)}")
                try:
                    kin.check_joint_limits(home, key)
                except InputError as exc:
                    raise ValueError(str(exc)) from None
        return self

    def arm_home_joints_deg(self) -> tuple[float, ...] | None:
        """The arm's home (controller convention, deg): ``home_joints_deg``, else
        ``simulated.home_joints_deg``, else None (not declared)."""
        return self.home_joints_deg if self.home_joints_deg is not None else self.simulated.home_joints_deg

    def kinematics(self) -> UrdfKinematics:
        """The arm's kinematics as configured (cached per file, its modification time and
        the settings that shape them). Raises :class:`~spherecal.plugins.InputError` naming
        the file and the link, joint or setting at fault."""
        p = Path(self.urdf)
        try:
            st = p.stat()
        except OSError as exc:
            raise InputError(f"{p}: cannot read the URDF file ({exc.strerror or exc})") from None
        return _kinematics(str(p), (st.st_mtime_ns, st.st_size), self.base_link, self.flange_link, self.joints,
                           self.joint_map.matrix, self.joint_map.offset_deg, self.joint_limits_deg,
                           self.arm_home_joints_deg())

    def workspace_box(self, kin: UrdfKinematics | None = None) -> WorkspaceBox:
        """The configured workspace, or a box around the arm's whole reach: the base
        origin +- (reach + the shoulder's distance from it) on every axis."""
        if self.workspace is not None:
            return self.workspace
        kin = kin or self.kinematics()
        r = kin.reach_mm + float(np.linalg.norm(kin.chain.placements[: min(2, kin.n_joints), :3, 3].sum(axis=0)))
        return WorkspaceBox(min_mm=(-r, -r, -r), max_mm=(r, r, r))


@lru_cache(maxsize=16)
def _kinematics(path: str, stamp, base_link, flange_link, joints, matrix, offset, limits, home) -> UrdfKinematics:
    urdf = read_urdf_chain(path, base_link, flange_link)
    n = len(urdf.joint_names)
    A = np.eye(n) if matrix is None else np.array(matrix, dtype=float)
    b = np.zeros(n) if offset is None else np.array(offset, dtype=float)
    if A.shape != (n, n):
        raise InputError(f"joint_map.matrix: expected {n} rows of {n} values (the chain from {base_link!r} to "
                         f"{flange_link!r} has {n} joints), got shape {list(A.shape) if A.ndim == 2 else len(A)}")
    if b.shape != (n,):
        raise InputError(f"joint_map.offset_deg: expected {n} values, got {b.size}")
    if joints is not None and len(joints) != n:
        raise InputError(f"joints: expected the {n} joints from {base_link!r} to {flange_link!r} "
                         f"({list(urdf.joint_names)}), got {len(joints)}")
    if limits is not None and len(limits) != n:
        raise InputError(f"joint_limits_deg: expected {n} pairs [lower, upper], got {len(limits)}")
    return UrdfKinematics(urdf, joints, JointMap(A, b), limits, base_link, flange_link, home)
