"""Data model: poses, profiles, observations, datasets, calibration results.

Pydantic v2 models validated at the boundary. Arrays are NumPy inside and plain lists
in files. Conventions in ``docs/conventions.md``: lengths in mm, ``A_from_B`` maps
points from frame B to frame A, quaternions (w, x, y, z) as ABB writes them.
"""

from __future__ import annotations

import math
import warnings
from datetime import datetime, timezone
from functools import cached_property
from typing import Annotated, Any, Literal

import numpy as np
from pydantic import (
    BaseModel,
    ConfigDict,
    Field,
    PlainSerializer,
    PlainValidator,
    field_validator,
    model_serializer,
    model_validator,
)

from spherecal.core import geometry as geo

MountingMode = Literal["eye_in_hand", "eye_to_hand"]
#: Three numbers (x, y, z); the unit and frame are in the field's name and description.
Vec3 = tuple[float, float, float]

#: Name of the unknown transform in each mounting mode (see docs/conventions.md).
TRANSFORM_NAME: dict[str, str] = {
    "eye_in_hand": "flange_from_sensor",
    "eye_to_hand": "base_from_sensor",
}
#: Frame in which the sphere centre is fixed in each mounting mode.
SPHERE_FRAME: dict[str, str] = {"eye_in_hand": "base", "eye_to_hand": "flange"}


def _float_vector(value: Any) -> np.ndarray:
    arr = np.asarray(value, dtype=float)
    if arr.ndim != 1:
        raise ValueError(f"expected a flat list of numbers, got shape {arr.shape}")
    if not np.all(np.isfinite(arr)):
        bad = int(np.flatnonzero(~np.isfinite(arr))[0])
        raise ValueError(f"contains NaN or infinite values (first at index {bad}: {arr[bad]})")
    return arr


FloatVector = Annotated[
    np.ndarray,
    PlainValidator(_float_vector),
    PlainSerializer(lambda a: a.tolist(), return_type=list),
]


def _finite(values, what: str):
    if not all(math.isfinite(v) for v in values):
        raise ValueError(f"{what} contains NaN or infinite values: {list(values)}")
    return values


#: Largest plausible reference sphere radius, mm (a check on units and typing errors).
MAX_SPHERE_RADIUS_MM = 10_000.0
#: Longest station label (it is shown in messages, tables and figures).
MAX_STATION_LABEL = 200
#: Longest shot id a sensor may give a profile (see :attr:`Profile.shot_id`).
MAX_SHOT_ID = 64


def _warn_renamed(old: str, new: str) -> None:
    warnings.warn(f"{old} is renamed {new}; the old name goes in the next release", DeprecationWarning, stacklevel=3)


class Pose(BaseModel):
    """A rigid transform ``A_from_B``: rotation as a unit quaternion (w, x, y, z) and a
    translation in mm. Which frames it links is said by the field or variable holding it
    (``base_from_flange``, ``flange_from_sensor``...)."""

    model_config = ConfigDict(defer_build=True, frozen=True, extra="forbid")

    translation_mm: tuple[float, float, float] = Field(description="origin of B expressed in A, mm")
    quaternion_wxyz: tuple[float, float, float, float] = Field(
        description="rotation A_from_B as a unit quaternion, scalar first (ABB order)"
    )

    @field_validator("translation_mm")
    @classmethod
    def _check_translation(cls, v):
        return _finite(v, "translation_mm")

    @field_validator("quaternion_wxyz")
    @classmethod
    def _check_quaternion(cls, v):
        _finite(v, "quaternion_wxyz")
        n = math.sqrt(sum(c * c for c in v))
        if abs(n - 1.0) > 1e-3:
            raise ValueError(f"quaternion_wxyz {list(v)} has norm {n:.6f}; expected a unit quaternion")
        q = list(v) if abs(n - 1.0) < 4e-16 else [c / n for c in v]
        if q[0] < 0:
            q = [-c for c in q]
        return tuple(q)

    # construction -------------------------------------------------------------------
    @classmethod
    def from_rt(cls, R, t_mm) -> "Pose":
        """From a rotation matrix (checked: orthonormal, det +1) and a translation in mm."""
        R = geo.check_rotation_matrix(R)
        t = np.asarray(t_mm, dtype=float).reshape(3)
        return cls(translation_mm=tuple(t.tolist()), quaternion_wxyz=tuple(geo.quat_wxyz_from_matrix(R).tolist()))

    @classmethod
    def from_matrix(cls, T) -> "Pose":
        """From a 4x4 homogeneous matrix in mm."""
        T = np.asarray(T, dtype=float)
        if T.shape != (4, 4):
            raise ValueError(f"expected a 4x4 matrix, got shape {T.shape}")
        if not np.allclose(T[3], [0, 0, 0, 1]):
            raise ValueError(f"last row of a homogeneous matrix must be [0, 0, 0, 1], got {T[3].tolist()}")
        return cls.from_rt(T[:3, :3], T[:3, 3])

    @classmethod
    def from_xyz_quat_wxyz(cls, xyz_mm, quat_wxyz) -> "Pose":
        """From a translation (x, y, z) in mm and a unit quaternion (w, x, y, z), scalar
        first: the order of an ABB robtarget's ``trans`` and ``rot`` [q1..q4]."""
        return cls(translation_mm=tuple(float(c) for c in xyz_mm), quaternion_wxyz=tuple(float(c) for c in quat_wxyz))

    @classmethod
    def from_abb(cls, xyz_mm, quat_wxyz) -> "Pose":
        """Deprecated alias of :meth:`from_xyz_quat_wxyz` (removed in the next release)."""
        _warn_renamed("Pose.from_abb", "Pose.from_xyz_quat_wxyz")
        return cls.from_xyz_quat_wxyz(xyz_mm, quat_wxyz)

    @classmethod
    def identity(cls) -> "Pose":
        return cls(translation_mm=(0.0, 0.0, 0.0), quaternion_wxyz=(1.0, 0.0, 0.0, 0.0))

    # views -----------------------------------------------------------------------------
    @cached_property
    def rotation_matrix(self) -> np.ndarray:
        return geo.matrix_from_quat_wxyz(self.quaternion_wxyz)

    @cached_property
    def translation(self) -> np.ndarray:
        return np.asarray(self.translation_mm, dtype=float)

    def as_matrix(self) -> np.ndarray:
        """4x4 homogeneous matrix, mm."""
        return geo.matrix_from_rt(self.rotation_matrix, self.translation)

    def as_xyz_quat_wxyz(self) -> tuple[tuple[float, float, float], tuple[float, float, float, float]]:
        """(xyz in mm, unit quaternion (w, x, y, z), scalar first): the inverse of
        :meth:`from_xyz_quat_wxyz`, in the order an ABB robtarget takes them."""
        return self.translation_mm, self.quaternion_wxyz

    def as_abb(self) -> tuple[tuple[float, float, float], tuple[float, float, float, float]]:
        """Deprecated alias of :meth:`as_xyz_quat_wxyz` (removed in the next release)."""
        _warn_renamed("Pose.as_abb", "Pose.as_xyz_quat_wxyz")
        return self.as_xyz_quat_wxyz()

    # algebra ---------------------------------------------------------------------------
    def inverse(self) -> "Pose":
        R, t = geo.invert_rt(self.rotation_matrix, self.translation)
        return Pose.from_rt(R, t)

    def __matmul__(self, other: "Pose") -> "Pose":
        """Composition: ``a_from_b @ b_from_c`` is ``a_from_c``."""
        R = self.rotation_matrix @ other.rotation_matrix
        return Pose.from_rt(R, self.rotation_matrix @ other.translation + self.translation)

    def apply(self, points_mm) -> np.ndarray:
        """Map points (..., 3) expressed in B into A."""
        return np.asarray(points_mm, dtype=float) @ self.rotation_matrix.T + self.translation


class Profile(BaseModel):
    """One laser line: points (0, y, z) in the sensor frame's x = 0 plane, mm.

    ``shot_id`` is the sensor's own name for the shot the line came from (a sensor
    plugin documents what it holds, e.g. a frame counter); the core never interprets it,
    only keeps it with the profile in the journal, so that the pairing of a profile
    with its robot pose can be audited afterwards."""

    model_config = ConfigDict(defer_build=True, frozen=True, extra="forbid", arbitrary_types_allowed=True)

    y_mm: FloatVector = Field(description="in-plane coordinate along the line, mm")
    z_mm: FloatVector = Field(description="in-plane range coordinate, mm (positive towards the sensor)")
    shot_id: str | None = Field(
        None, min_length=1, max_length=MAX_SHOT_ID, pattern=r"^[\x21-\x7e]+$",
        description="the sensor's identity of the shot (opaque, printable ASCII without spaces); None: not given",
    )

    @model_validator(mode="after")
    def _check(self):
        if self.y_mm.shape != self.z_mm.shape:
            raise ValueError(f"y_mm has {self.y_mm.size} values but z_mm has {self.z_mm.size}")
        if self.y_mm.size == 0:
            raise ValueError("profile is empty (no points)")
        return self

    @classmethod
    def from_points(cls, points_mm, shot_id: str | None = None) -> "Profile":
        """From an (N, 2) array of (y, z) in mm, with the sensor's shot id if it gives one."""
        p = np.asarray(points_mm, dtype=float)
        if p.ndim != 2 or p.shape[1] != 2:
            raise ValueError(f"profile points: expected shape (N, 2) of (y, z) in mm, got {p.shape}")
        return cls(y_mm=p[:, 0], z_mm=p[:, 1], shot_id=shot_id)

    @property
    def points_mm(self) -> np.ndarray:
        """(N, 2) array of (y, z) in mm."""
        return np.column_stack([self.y_mm, self.z_mm])

    def __len__(self) -> int:
        return int(self.y_mm.size)


class Circle(BaseModel):
    """What a sensor that fits on board reports of one line: the circle the laser plane
    cuts from the sphere, in the sensor's x = 0 plane, mm. It gives the sphere centre up
    to the side of the plane: (+-sqrt(r^2 - radius^2), y, z)."""

    model_config = ConfigDict(defer_build=True, frozen=True, extra="forbid")

    centre_yz_mm: tuple[float, float] = Field(description="circle centre (y, z) in the laser plane, sensor frame, mm")
    radius_mm: float = Field(gt=0, description="circle radius, mm")
    centre_std_mm: float | None = Field(
        None, gt=0, description="standard deviation of each of the centre's y and z, mm (None: estimated from the data)")
    radius_std_mm: float | None = Field(
        None, gt=0, description="standard deviation of the radius, mm (None: estimated from the data)")

    @model_validator(mode="after")
    def _check(self):
        _finite((*self.centre_yz_mm, self.radius_mm), "circle")
        for name in ("centre_std_mm", "radius_std_mm"):
            v = getattr(self, name)
            if v is not None and not math.isfinite(v):
                raise ValueError(f"{name} must be finite, got {v}")
        if self.radius_mm > MAX_SPHERE_RADIUS_MM:
            raise ValueError(f"radius_mm = {self.radius_mm:g} is implausibly large (at most {MAX_SPHERE_RADIUS_MM:g} mm)")
        return self


#: Relative tolerance on the symmetry of a given covariance, and on a negative eigenvalue
#: (of the largest) taken as rounding.
_COV_RTOL = 1e-9


def check_covariance_3x3(value, what: str) -> tuple[tuple[float, float, float], ...]:
    """A 3x3 covariance (mm^2): finite, symmetric and positive definite, else ValueError
    saying which."""
    C = np.asarray(value, dtype=float)
    if C.shape != (3, 3):
        raise ValueError(f"{what}: expected a 3x3 matrix (3 rows of 3 numbers), got shape {C.shape}")
    if not np.all(np.isfinite(C)):
        raise ValueError(f"{what}: contains NaN or infinite values")
    scale = float(np.abs(C).max())
    if scale == 0.0:
        raise ValueError(f"{what}: is all zeros; a measurement has some noise (leave it out to have it estimated)")
    if np.abs(C - C.T).max() > _COV_RTOL * scale:
        i, j = np.unravel_index(int(np.argmax(np.abs(C - C.T))), C.shape)
        raise ValueError(f"{what}: not symmetric (row {i} column {j} is {float(C[i, j])!r}, row {j} column {i} is {float(C[j, i])!r})")
    w = np.linalg.eigvalsh((C + C.T) / 2)
    if w[0] < -_COV_RTOL * scale:
        raise ValueError(f"{what}: not positive semi-definite (eigenvalue {w[0]:.4g} mm^2): not a covariance")
    if w[0] <= _COV_RTOL * scale:
        raise ValueError(f"{what}: singular (smallest eigenvalue {w[0]:.4g} mm^2): a measurement has some noise in "
                         "every direction")
    return tuple(tuple(float(x) for x in row) for row in C)


#: The three kinds of observation (what the sensor reported of the sphere).
OBSERVATION_KINDS = ("profile", "circle", "sphere_centre")


class Observation(BaseModel):
    """One shot: where the robot was and what the sensor saw.

    ``base_from_flange`` is the flange pose as the controller reported it (or as forward
    kinematics gave it); ``joints_deg`` the joint reading (controller convention). At
    least one of the two must be present. Observations of one ``station`` share one
    flange orientation (pure translations between them).

    What the sensor saw is exactly one of: ``profile`` (the raw laser line), ``circle``
    (the circle fitted to it, on board) or ``sphere_centre_mm`` (the sphere centre
    already resolved, sensor frame, with an optional covariance
    ``sphere_centre_covariance_mm2``); :attr:`kind` says which."""

    model_config = ConfigDict(defer_build=True, frozen=True, extra="forbid")

    index: int = Field(ge=0, le=2**53, description="position in the acquisition, 0-based")
    station: str = Field(min_length=1, max_length=MAX_STATION_LABEL,
                         description="station label; one flange orientation per station")
    timestamp: datetime = Field(default_factory=lambda: datetime.now(timezone.utc))
    base_from_flange: Pose | None = None
    joints_deg: tuple[float, float, float, float, float, float] | None = None
    profile: Profile | None = None
    circle: Circle | None = None
    sphere_centre_mm: tuple[float, float, float] | None = Field(
        None, description="sphere centre (x, y, z) in the sensor frame, mm")
    sphere_centre_covariance_mm2: tuple[tuple[float, float, float], tuple[float, float, float],
                                        tuple[float, float, float]] | None = Field(
        None, description="covariance of sphere_centre_mm, sensor frame, mm^2 (None: estimated from the data)")
    target: int | None = Field(None, ge=0, description="index of the planned target it was taken at, if any")

    @model_validator(mode="after")
    def _check(self):
        if self.base_from_flange is None and self.joints_deg is None:
            raise ValueError("needs base_from_flange or joints_deg (neither given)")
        if self.joints_deg is not None:
            _finite(self.joints_deg, "joints_deg")
        given = [k for k, v in (("profile", self.profile), ("circle", self.circle),
                                ("sphere_centre_mm", self.sphere_centre_mm)) if v is not None]
        if len(given) != 1:
            raise ValueError(
                "needs exactly one of profile, circle and sphere_centre_mm "
                + (f"(got {' and '.join(given)})" if given else "(none given)"))
        if self.sphere_centre_mm is not None:
            _finite(self.sphere_centre_mm, "sphere_centre_mm")
        if self.sphere_centre_covariance_mm2 is not None:
            if self.sphere_centre_mm is None:
                raise ValueError("sphere_centre_covariance_mm2 is given without sphere_centre_mm")
            check_covariance_3x3(self.sphere_centre_covariance_mm2, "sphere_centre_covariance_mm2")
        return self

    @property
    def kind(self) -> str:
        """'profile', 'circle' or 'sphere_centre' (:data:`OBSERVATION_KINDS`)."""
        return "profile" if self.profile is not None else "circle" if self.circle is not None else "sphere_centre"


class Dataset(BaseModel):
    """Observations of one reference sphere in one mounting mode."""

    model_config = ConfigDict(defer_build=True, extra="forbid")

    mounting: MountingMode
    sphere_radius_mm: float = Field(gt=0, description="certified radius of the reference sphere, mm")
    observations: list[Observation] = Field(default=[])
    provenance: dict[str, Any] = Field(default={}, description="where the data came from")

    @field_validator("sphere_radius_mm")
    @classmethod
    def _radius_in_mm(cls, v):
        if not math.isfinite(v):
            raise ValueError(f"sphere_radius_mm must be finite, got {v}")
        if v < 0.5:
            raise ValueError(
                f"sphere_radius_mm = {v} looks like metres; give the certified radius in millimetres"
            )
        if v > MAX_SPHERE_RADIUS_MM:
            raise ValueError(f"sphere_radius_mm = {v:g} is implausibly large (at most {MAX_SPHERE_RADIUS_MM:g} mm)")
        return v

    @property
    def transform_name(self) -> str:
        return TRANSFORM_NAME[self.mounting]


class ObservationFlag(BaseModel):
    """An observation left out of (or down-weighted in) the solution, and why."""

    index: int
    station: str
    reason: str


class ResidualStats(BaseModel):
    """Residuals of the final fit, mm: the in-plane distance of each profile point to the
    predicted circle (the sphere cut by the laser plane) and, for centre observations,
    each component of the centre residual (sphere centre: x, y, z; circle: y, z and the
    radius; docs/estimation.md). ``rms_mm``, ``max_abs_mm``, ``p95_abs_mm`` and
    ``per_station_rms_mm`` are over all of these scalars."""

    rms_mm: float
    max_abs_mm: float
    p95_abs_mm: float
    n_points_used: int
    n_points_rejected: int
    n_profiles_used: int
    per_station_rms_mm: dict[str, float]
    n_centres_used: int = Field(0, description="centre observations (circles, sphere centres) used")
    centre_rms_mm: float | None = Field(None, description="RMS length of the centre residuals (3-D), mm")
    centre_max_mm: float | None = Field(None, description="largest length of a centre residual, mm")


class KinematicParameter(BaseModel):
    """One geometric error parameter of the arm (docs/estimation.md, "Kinematic model"),
    in the robot model's joint frames: angles in deg, lengths in mm."""

    model_config = ConfigDict(defer_build=True, extra="forbid")

    name: str = Field(description="joint_<i>.<zero_offset | x | y | z | tilt_u | tilt_v>")
    unit: Literal["deg", "mm"]
    value: float = Field(description="estimate (identified) or posterior mean (marginalised)")
    std: float = Field(description="its standard deviation, 1 sigma")
    identifiable: bool = Field(description="the data tell it apart from the transform, the sphere and the "
                               "parameters before it")
    identified: bool = Field(description="estimated without prior (kinematic calibration)")


class StationPrediction(BaseModel):
    """A kinematic calibration's error at poses it did not see, measured: each station
    left out in turn, the sphere placed through the calibrated arm and the transform fitted
    to the other stations, against where the station's own profiles put it
    (docs/estimation.md, "Kinematic calibration"). Invariant to how the transform and the
    arm's parameters trade against each other: this is the figure a user relies on."""

    model_config = ConfigDict(defer_build=True, extra="forbid")

    rms_mm: float = Field(description="RMS over the stations of the 3-D distance, mm")
    expected_rms_mm: float = Field(description="what it should be if the model holds: the station's own noise and "
                                   "the prediction's uncertainty, RMS 3-D, mm")
    per_station_mm: dict[str, float] = Field(description="the distance at each station, mm")
    worst_station: str
    unpredictable_stations: list[str] = Field(
        default=[], description="stations the others cannot predict (without one of them the data do not determine "
        "the arm's geometry); left out of the figures above")
    in_sample_rms_mm: float = Field(description="the same against the fit of every station (the station included), "
                                    "mm: much smaller than rms_mm means the fit follows its own data (overfitting)")


class RobotErrorSummary(BaseModel):
    """The robot's systematic error as the fit saw it, and what it means for a point.

    With joint readings and the robot's kinematics the error is the arm's geometric error
    (zero offsets, joint origins, axis tilts), marginalised or, with identify_kinematics,
    estimated; without them, a pose offset shared by the shots of a station
    (docs/estimation.md): its station-to-station part, per axis and 1 sigma, is
    estimated from how the stations disagree; the part common to every station cannot
    be seen from one sphere location and is the robot's stated (or assumed) accuracy."""

    model_config = ConfigDict(defer_build=True, extra="forbid")

    model: Literal["kinematic", "station", "kinematic+station", "none"]
    kinematic_parameters: list[KinematicParameter] | None = Field(
        None, description="the arm's geometric error parameters (kinematic model only)")
    kinematic_prior_scale: float | None = Field(
        None, description="factor on the stated prior spread the data showed (1: the stated spread holds)")
    model_choice: str | None = Field(
        None, description="how robot_error_model 'auto' chose between the kinematic model and pose noise only: "
        "the evidence for the arm's geometric error in the data (docs/estimation.md)")
    station_rotation_deg: float = Field(description="station-to-station orientation error, per axis, 1 sigma, deg")
    station_translation_mm: float = Field(description="station-to-station position error, per axis, 1 sigma, mm")
    estimated: bool = Field(description="True when the two figures above were estimated from the data")
    common_rotation_deg: float = Field(description="assumed error shared by every station, per axis, 1 sigma, deg")
    common_translation_mm: float = Field(description="assumed error shared by every station, per axis, 1 sigma, mm")
    std_rotation_deg_robot_frame: tuple[float, float, float] = Field(
        description="1-sigma of the rotation relative to the robot's own frame (common error left out), deg"
    )
    std_translation_mm_robot_frame: tuple[float, float, float] = Field(
        description="1-sigma of the translation relative to the robot's own frame, mm"
    )
    point_error_k2_mm: float = Field(
        description="expected error (k = 2, 3-D) of a point measured at a new pose like the calibration's, "
        "relative to where the calibration puts it, mm"
    )
    point_error_parts_rms_mm: dict[str, float] = Field(description="its parts, RMS 3-D, k = 1, mm")
    point_error_nominal_arm_k2_mm: float | None = Field(
        None, description="kinematic calibration (result version 3): the expected error (k = 2, 3-D) of a point "
        "measured at a new pose like the calibration's with this transform on the controller's nominal arm model, "
        "the arm's identified geometric error not applied; None otherwise (point_error_k2_mm holds only through the "
        "calibrated model), mm")
    dominant: str = Field(description="the part that dominates the point error")
    station_prediction: StationPrediction | None = Field(
        None, description="kinematic calibration: each station predicted by the fit of the others (what the verdict "
        "judges there: the transform's own uncertainty trades with the arm's parameters)")


class ParameterCorrelation(BaseModel):
    """The correlation matrix of a result's parameters, derived from its covariance:
    ``matrix[i][j] = cov[i][j] / (sd_i sd_j)``, rows and columns named by ``parameters``
    in the covariance's order (rotation about the target axes, translation, sphere
    centre[, radius])."""

    model_config = ConfigDict(defer_build=True, extra="forbid")

    parameters: list[str]
    matrix: list[list[float]]


def parameter_labels(transform_name: str, sphere_centre_frame: str, radius_fitted: bool) -> list[str]:
    """Names of the covariance's rows, e.g. ``rotation about flange x``."""
    a = transform_name.split("_from_")[0]
    labels = [f"rotation about {a} {ax}" for ax in "xyz"] + [f"translation along {a} {ax}" for ax in "xyz"]
    labels += [f"sphere centre {ax} ({sphere_centre_frame})" for ax in "xyz"]
    return labels + (["sphere radius"] if radius_fitted else [])


def correlation_matrix(covariance) -> np.ndarray:
    """``cov[i][j] / (sd_i sd_j)``; a parameter with zero variance correlates 0 with the
    others (1 with itself)."""
    cov = np.asarray(covariance, dtype=float)
    sd = np.sqrt(np.maximum(np.diag(cov), 0.0))
    safe = np.where(sd > 0, sd, 1.0)
    corr = cov / np.outer(safe, safe)
    corr[sd == 0, :] = 0.0
    corr[:, sd == 0] = 0.0
    np.fill_diagonal(corr, 1.0)
    return np.clip(corr, -1.0, 1.0)


class ResultDiagnostics(BaseModel):
    """How the estimate was obtained, in ``result.json``'s ``diagnostics``: figures from
    the solve (``estimation.pipeline``) and the verdict (``app.solving``). Every field is
    optional; those never set are left out of the file, so that a result writes the same
    document as when this was a free dict. Keys this version does not know (a result of
    another version, a plugin's figures) are kept (``extra="allow"``). Nested objects whose
    shape varies (keyed by station, by solve) stay plain dicts; their keys are described
    here."""

    model_config = ConfigDict(defer_build=True, extra="allow")

    orientations: int | None = Field(
        None, description="number of orientations (stations) in the fit, after splitting turned stations; count")
    two_step: dict[str, Any] | None = Field(
        None, description="the two-step start's figures: rotation_step (displacement_singular_values_mm, "
        "rms_mm), translation_step (condition_number, singular_values), point_rms_mm (mm), station_move_rank "
        "(per station), sign_combinations_tried, equally_good_alternatives (counts); the keys vary with the data")
    two_step_vs_refined: dict[str, Any] | None = Field(
        None, description="how far the two-step start lies from the refined transform: rotation_deg (deg), "
        "translation_mm (mm)")
    start: dict[str, Any] | None = Field(
        None, description="the start of the joint fit: method ('two-step': the published method, on stations of "
        "pure translations; 'linear': closed-form from the sphere centres at any orientations, for rows that are "
        "not such stations). A linear start gives its figures: rows, centre_spread_mm and rotation_spread_deg "
        "(RMS along the principal axes, largest first), translation_condition (1), linear_condition_number (1), "
        "rms_mm, sides_decided (count), vs_refined (rotation_deg, translation_mm). A two-step start on data where "
        "the linear start applies too gives linear: linear_vs_two_step and linear_vs_refined (rotation_deg, "
        "translation_mm, chi2_6dof against the result's covariance), agree (bool), and when they do not agree "
        "refined_from_linear and chosen ('two-step' or 'linear', by the fit)")
    station_consistency: dict[str, Any] | None = Field(
        None, description="per station label: n_profiles (count), rms_mm and max_mm (mm), the deviation of the "
        "station's measured sphere centres from the predicted ones after removing their means")
    refinement: dict[str, Any] | None = Field(
        None, description="the joint fit: iterations (count), converged (bool), information_condition_number "
        "(1), profile_variance_factor (chi^2/dof of the profiles, 1)")
    noise: dict[str, Any] | None = Field(
        None, description="the noise the fit used: point_noise_mm (mm), pose_translation_noise_mm (mm), "
        "pose_rotation_noise_deg (deg), pose_noise_estimated (bool); with centre observations also "
        "centre_noise_mm and centre_noise_within_stations_mm (mm)")
    station_orientation: dict[str, Any] | None = Field(
        None, description="the screening of each station's orientations: tolerance_deg (deg), tolerance_derived "
        "(bool), rotation_noise_seen_deg (deg), max_angle_to_station_mean_deg (deg per station), split_stations "
        "(station to its parts), turned_observations (indices), notes (text); the keys vary with the data")
    mirror_twin: dict[str, Any] | None = Field(
        None, description="set when the data (circles only, no nominal transform) cannot tell the result from "
        "its mirror twin: excluded (bool, false), text (what to do)")
    joints_vs_poses: dict[str, Any] | None = Field(
        None, description="set when the joints were recorded but not used: used (bool, false), reason (text)")
    nominal_transform: dict[str, Any] | None = Field(
        None, description="set when a nominal transform was given: how far the result lies from it, "
        "rotation_deg (deg), translation_mm (mm), half_turn_about_sensor_z and half_turn_about_sensor_yz (bool)")
    verdict: dict[str, Any] | None = Field(
        None, description="the verdict written with the result: level (green, amber, red), headline (text), "
        "written_with_force (bool: a RED result written only because of --force)")

    @model_serializer(mode="wrap")
    def _given_only(self, handler):
        """Only the fields that were set and the extra keys, as the free dict had them."""
        data = handler(self)
        given = self.model_fields_set | set(self.__pydantic_extra__ or ())
        return {k: v for k, v in data.items() if k in given}

    def __getitem__(self, key: str) -> Any:
        """``diagnostics["noise"]``, as when this was a dict: kept for one release for
        plugins that read it so; use the attribute (``diagnostics.noise``)."""
        warnings.warn("result.diagnostics is typed: read diagnostics.<name> instead of diagnostics['<name>']",
                      DeprecationWarning, stacklevel=2)
        value = getattr(self, key, None) if key in type(self).model_fields else (self.__pydantic_extra__ or {}).get(key)
        if value is None:
            raise KeyError(key)
        return value

    def get(self, key: str, default: Any = None) -> Any:
        """``diagnostics.get("noise")``, as when this was a dict (deprecated, as ``[]``)."""
        try:
            return self[key]
        except KeyError:
            return default


class TimingEstimate(BaseModel):
    """The clock relation of a recording (docs/conventions.md, "Time"): a profile stamped
    ``t_sensor`` on the sensor's clock was exposed at robot-clock time
    ``t_sensor + offset + drift (t_sensor - t_sensor0)``, ``t_sensor0`` the first
    profile's stamp. Standard deviations are 1 sigma, from the joint fit."""

    model_config = ConfigDict(extra="forbid")

    offset_ms: float = Field(description="robot clock minus sensor clock at t_sensor0, ms (epochs and latency included)")
    offset_std_ms: float
    drift_ppm: float = Field(description="rate of the robot clock relative to the sensor clock, minus 1, in 1e-6")
    drift_std_ppm: float
    drift_estimated: bool = Field(description="False: held at drift_ppm (the recording cannot show it)")
    t_sensor0_s: float = Field(description="the first profile's sensor stamp, s (sensor clock)")
    offset_drift_correlation: float = 0.0
    identifiable: bool = Field(description="the data separate the offset from the sphere's position and the transform")
    identifiability: str = Field(description="what the data show of the timing, in words; what to add if not enough")
    start_offset_ms: float | None = Field(None, description="where the fit started (the robust search's offset), ms")
    poses_assumed: str | None = Field(
        None, description="what the pose stream's poses assume when they were not measured (computed along the "
        "programmed line of a controller that cannot stream): the arm's path error at speed is then in the "
        "result's error, beyond its stated uncertainty; None: measured")


class DataFrames(BaseModel):
    """The frames of the data a result was calibrated from, as the data name them (a ROS 2
    bag's frame ids; docs/conventions.md, "A ROS 2 bag's frames"): the robot's base and
    flange frames (None: the data do not name it), the frame the profiles came in (a
    cloud's ``header.frame_id``), and how the calibrated ``sensor`` frame (the laser plane
    its x = 0 plane) lies in that cloud frame. The ROS exports name their frames after
    them and, for the clouds' frame, publish ``<mount>_from_sensor @ sensor_from_cloud``."""

    model_config = ConfigDict(defer_build=True, frozen=True, extra="forbid")

    source: str = Field(description="what named the frames (\"rosbag2\": a ROS 2 bag)")
    base_frame_id: str | None = Field(None, description="the frame the flange poses are in")
    flange_frame_id: str | None = Field(None, description="the flange's frame")
    cloud_frame_id: str | None = Field(None, description="the frame the profiles came in (the clouds' frame_id)")
    sensor_from_cloud: Pose = Field(
        default_factory=Pose.identity, description="maps points in the clouds' frame to the calibrated sensor "
        "frame: the identity, or Rz(+90 deg) for clouds with the laser line along their x")
    sensor_from_cloud_text: str | None = Field(None, description="sensor_from_cloud in words, when not the identity")

    @property
    def cloud_is_sensor(self) -> bool:
        """Whether the calibrated sensor frame is the clouds' frame itself."""
        return self.sensor_from_cloud == Pose.identity()


class CalibrationResult(BaseModel):
    """The calibrated transform, its uncertainty and how it was obtained.

    ``transform`` is ``flange_from_sensor`` (eye-in-hand) or ``base_from_sensor``
    (eye-to-hand), as ``transform_name`` says. Standard deviations of the rotation are
    small rotations about the axes of the transform's target frame (flange or base),
    in degrees; of the translation, mm in that frame."""

    model_config = ConfigDict(defer_build=True, extra="forbid")

    format: Literal["spherecal-result"] = "spherecal-result"
    version: Literal[1, 2, 3] = 3
    mounting: MountingMode
    transform_name: str
    transform: Pose
    std_rotation_deg: tuple[float, float, float]
    std_translation_mm: tuple[float, float, float]
    sphere_centre_frame: str
    sphere_centre_mm: tuple[float, float, float]
    std_sphere_centre_mm: tuple[float, float, float]
    sphere_radius_mm: float
    radius_fitted: bool
    std_sphere_radius_mm: float | None = None
    covariance: list[list[float]] = Field(
        description="covariance of (rotation about target axes rad x3, translation mm x3, "
        "sphere centre mm x3[, radius mm]), including the robot's systematic error (robot_error)"
    )
    covariance_robot_frame: list[list[float]] | None = Field(
        None, description="the same covariance relative to the robot's own frame: without the robot's error shared "
        "by every station (its accuracy), which cancels between calibrations on one robot; None when the robot "
        "error model adds no such error (covariance is then relative to the robot's frame already)"
    )
    correlation: ParameterCorrelation | None = Field(
        None, description="correlations of the parameters, derived from covariance (filled in when absent)"
    )
    variance_factor: float = Field(description="chi^2 / dof of the whitened residuals")
    residuals: ResidualStats
    flagged: list[ObservationFlag] = Field(default=[])
    method: str
    two_step_transform: Pose | None = None
    robot_error: RobotErrorSummary | None = None
    timing: TimingEstimate | None = Field(None, description="a recording's clock relation (TimingEstimate)")
    diagnostics: ResultDiagnostics = Field(
        default_factory=ResultDiagnostics, description="how the estimate was obtained (ResultDiagnostics)")
    data_frames: DataFrames | None = Field(
        None, description="the frames as the data named them (a ROS 2 bag's) and how the calibrated sensor frame "
        "lies in the clouds' frame (DataFrames); None: the data named none")
    provenance: dict[str, Any] = Field(default={})

    @model_validator(mode="after")
    def _check_names(self):
        if self.transform_name != TRANSFORM_NAME[self.mounting]:
            raise ValueError(
                f"transform_name {self.transform_name!r} does not match mounting {self.mounting!r} "
                f"(expected {TRANSFORM_NAME[self.mounting]!r})"
            )
        if self.sphere_centre_frame != SPHERE_FRAME[self.mounting]:
            raise ValueError(
                f"sphere_centre_frame {self.sphere_centre_frame!r} does not match mounting {self.mounting!r}"
            )
        return self

    @model_validator(mode="after")
    def _derive_correlation(self):
        """The correlation is derived from the covariance: filled in when absent, checked
        when given (a hand-edited file whose two disagree is refused)."""
        n = len(self.covariance)
        if n == 0 or any(len(row) != n for row in self.covariance):
            return self
        labels = parameter_labels(self.transform_name, self.sphere_centre_frame, self.radius_fitted)
        if len(labels) != n:
            return self
        derived = correlation_matrix(self.covariance)
        if self.correlation is None:
            self.correlation = ParameterCorrelation(parameters=labels, matrix=np.round(derived, 6).tolist())
            return self
        given = np.asarray(self.correlation.matrix, dtype=float)
        if self.correlation.parameters != labels:
            raise ValueError(f"correlation.parameters {self.correlation.parameters} do not name the covariance's "
                             f"rows {labels}")
        if given.shape != derived.shape or not np.allclose(given, derived, atol=1e-5):
            raise ValueError("correlation does not match the covariance it is derived from (leave it out to have it "
                             "derived)")
        return self
