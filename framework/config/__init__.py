"""The run configuration: one TOML file validated by pydantic.

Unknown keys are errors and every error names its dotted path and the file. The robot
and sensor sections belong to their plugins: this module checks only that they name a
``type``; the plugin host validates the rest against the plugin's own model. Relative
paths in the file (``output_dir``, ``replay``) are relative to the file's folder.
See docs/configuration.md.
"""

from __future__ import annotations

import math
import tomllib
from pathlib import Path
from types import UnionType
from typing import Annotated, Any, Literal, Union, get_args, get_origin

import numpy as np
from pydantic import AfterValidator, BaseModel, ConfigDict, Field, ValidationError, field_validator, model_validator

from spherecal.core.errors import ConfigError
from spherecal.estimation import CalibrationOptions
from spherecal.motion.kinematic_plan import KinematicPlanSettings
from spherecal.core.metrology import MaximumPermissibleErrors
from spherecal.core.models import MountingMode, Pose
from spherecal.core.workspace import WorkspaceBox
from spherecal.motion.planning import SweepPlan
from spherecal.report.assess import POINT_DISTANCE_MM
from spherecal.sim import NoiseModel, RobotErrorModel

#: Largest magnitude of any number in a configuration file: beyond it the value is a
#: typing or units error (and would overflow the computations).
MAX_ABS_NUMBER = 1e9
#: Most profiles one scan may ask for.
MAX_SCAN_PROFILES = 10_000_000
#: Largest configuration file read, bytes.
MAX_CONFIG_BYTES = 1 << 20

Vec3 = tuple[float, float, float]
Vec4 = tuple[float, float, float, float]


def _unit_quaternion(v: Vec4) -> Vec4:
    n = float(np.linalg.norm(v))
    if abs(n - 1.0) > 1e-3:
        raise ValueError(f"quaternion {list(v)} has norm {n:.6f}; give a unit quaternion (w, x, y, z)")
    return v


#: A unit quaternion (w, x, y, z), checked where it is read.
UnitQuaternion = Annotated[Vec4, AfterValidator(_unit_quaternion)]


class _Section(BaseModel):
    model_config = ConfigDict(defer_build=True, frozen=True, extra="forbid")


class TransformConfig(_Section):
    """A rigid transform written by hand: translation in mm, quaternion (w, x, y, z)."""

    translation_mm: Vec3 = Field(description="translation, mm")
    quaternion_wxyz: UnitQuaternion = Field(description="rotation, unit quaternion, scalar first (ABB order)")

    def pose(self) -> Pose:
        return Pose.from_abb(self.translation_mm, self.quaternion_wxyz)


class SphereConfig(_Section):
    radius_mm: float = Field(gt=0, le=10_000, description="certified radius of the reference sphere, mm")
    radius_uncertainty_mm: float | None = Field(
        None, ge=0, le=10, description="expanded uncertainty (k = 2) of the certified radius, from the certificate, "
        "mm; shown in the report and recorded in the result (not propagated into the transform's uncertainty)"
    )
    certificate: str | None = Field(None, max_length=200, description="the sphere's certificate (number, issuer)")

    @field_validator("radius_mm")
    @classmethod
    def _mm(cls, v):
        if v < 0.5:
            raise ValueError(f"radius_mm = {v} looks like metres; give the certified radius in millimetres")
        return v


#: The box every planned flange position must lie in (base frame, mm): the one workspace
#: box of spherecal, also a robot plugin's.
WorkspaceConfig = WorkspaceBox


class AcquisitionConfig(_Section):
    """How to acquire: where the sphere roughly is, the sweeps, speeds and limits."""

    mode: Literal["automatic", "manual"] = Field(
        "automatic", description="automatic: the program moves the robot; manual: the operator jogs, the program captures"
    )
    sphere_centre_mm: Vec3 = Field(
        description="rough sphere centre: in base (eye_in_hand) or in the flange frame (eye_to_hand), mm"
    )
    reference_flange_quaternion_wxyz: UnitQuaternion = Field(
        (0.0, 0.0, 1.0, 0.0), description="flange orientation of the first station, base_from_flange, (w, x, y, z)"
    )
    sweep: SweepPlan = Field(default_factory=SweepPlan, description="stations and sweeps")
    kinematic_plan: KinematicPlanSettings | None = Field(
        None, description="plan the stations for kinematic calibration (spread over the arm's joints) instead of "
        "listing them in sweep.tilts_deg; the default with calibration.identify_kinematics when sweep.tilts_deg "
        "is not given")
    speed_mm_s: float = Field(20.0, gt=0, description="speed along a sweep, mm/s")
    approach_speed_mm_s: float = Field(100.0, gt=0, description="speed of the move to a station's first target, mm/s")
    max_speed_mm_s: float = Field(250.0, gt=0, description="no move may be faster, mm/s")
    settle_s: float = Field(0.0, ge=0, le=3600, description="wait after each move before reading, s")
    pose_agreement_mm: float = Field(0.05, gt=0, description="poses read before and after a profile must agree, mm")
    pose_agreement_deg: float = Field(0.02, gt=0, description="... and in orientation, deg")
    retries_per_target: int = Field(2, ge=0, le=100, description="re-takes of a shot whose poses disagree")
    workspace: WorkspaceConfig = Field(description="allowed flange positions, base frame, mm")

    @model_validator(mode="after")
    def _one_station_source(self):
        if self.kinematic_plan is not None and "tilts_deg" in self.sweep.model_fields_set:
            raise ValueError("give either sweep.tilts_deg (the stations listed) or [acquisition.kinematic_plan] (the "
                             "stations planned), not both")
        return self

    @model_validator(mode="after")
    def _speeds(self):
        for name in ("speed_mm_s", "approach_speed_mm_s"):
            if getattr(self, name) > self.max_speed_mm_s:
                raise ValueError(f"{name} = {getattr(self, name)} exceeds max_speed_mm_s = {self.max_speed_mm_s}")
        return self


class SweepSite(_Section):
    """Where and how a validation or scan sweep looks at its target: the sensor tilted by
    ``tilt_deg`` (rotation vector, about the sensor axes in eye-in-hand, base axes in
    eye-to-hand) from the reference orientation, the sweep shifted by ``offset_mm`` (y, z)
    in the sensor's field of view."""

    tilt_deg: Vec3 = Field((0.0, 0.0, 0.0), description="rotation vector from the reference orientation, deg")
    offset_mm: tuple[float, float] | None = Field(
        None, description="(y, z) shift of the sweep in the sensor frame, mm (default: offset_percent of the sensor's "
        "field of view)")
    offset_percent: tuple[float, float] = Field(
        (0.0, 0.0), description="(y, z) shift as shares of the sensor's field of view, percent: y of the line's width "
        "at the sweep's standoff, z of the measuring range; used when offset_mm is not given")


def _default_sphere_sites() -> list[SweepSite]:
    # orientations other than the calibration's (0/30/30/45 deg about x, y, z), places in the field of view
    # sized to it: for a 100 mm range and a line 40 mm wide at the standoff (5, -10), (-8, 10), (0, -20), (8, 0) mm
    return [
        SweepSite(tilt_deg=(15.0, 15.0, 0.0), offset_percent=(12.5, -10.0)),
        SweepSite(tilt_deg=(-20.0, 10.0, 25.0), offset_percent=(-20.0, 10.0)),
        SweepSite(tilt_deg=(10.0, -25.0, -30.0), offset_percent=(0.0, -20.0)),
        SweepSite(tilt_deg=(-15.0, -15.0, 60.0), offset_percent=(20.0, 0.0)),
    ]


class BallBarConfig(_Section):
    """A ball bar: two spheres at a certified centre distance, fixed where the reference
    sphere is fixed (base in eye-in-hand, flange in eye-to-hand)."""

    centre_a_mm: Vec3 = Field(description="rough centre of ball A, mm")
    centre_b_mm: Vec3 = Field(description="rough centre of ball B, mm")
    ball_radius_mm: float = Field(gt=0.5, description="radius of the balls, mm")
    certified_distance_mm: float = Field(gt=0, description="certified centre distance, mm")
    positions: list[SweepSite] = Field(
        default_factory=lambda: [SweepSite(), SweepSite(tilt_deg=(20.0, 0.0, 30.0)), SweepSite(tilt_deg=(0.0, -20.0, -40.0))],
        description="views of the bar; at each, ball A is swept at this site and ball B at the next site's orientation",
    )


class FlatConfig(_Section):
    """A flat (a plate), fixed where the reference sphere is fixed."""

    centre_mm: Vec3 = Field(description="rough centre of the area to sweep, mm")
    quaternion_wxyz: UnitQuaternion = Field((1.0, 0.0, 0.0, 0.0), description="orientation of the plate (its z: the normal)")
    length_mm: float = Field(150.0, gt=0, description="size along the plate's x (simulation), mm")
    width_mm: float = Field(100.0, gt=0, description="size along the plate's y (simulation), mm")
    sweep_length_mm: float = Field(30.0, gt=0, description="length of each sweep across the flat, mm")
    positions: list[SweepSite] = Field(
        default_factory=lambda: [SweepSite(), SweepSite(tilt_deg=(10.0, 0.0, 45.0), offset_percent=(0.0, -15.0))],
        description="views of the flat",
    )


class MpeConfig(_Section):
    """Maximum permissible errors, mm. Each has its own default; a figure is judged
    against its MPE whenever it is measured."""

    probing_form_mm: float = Field(0.25, gt=0, description="MPE of P_F, mm")
    probing_size_mm: float = Field(0.06, gt=0, description="MPE of |P_S|, mm")
    sphere_spacing_mm: float = Field(0.1, gt=0, description="MPE of |SD|, mm")
    flatness_mm: float = Field(0.15, gt=0, description="MPE of F, mm")

    def as_metrology(self) -> MaximumPermissibleErrors:
        return MaximumPermissibleErrors(**self.model_dump())


class ValidationConfig(_Section):
    """`spherecal validate`: scan with the calibrated system at positions other than the
    calibration's and compare the acceptance figures with the MPEs."""

    result: str | None = Field(None, description="calibration result to validate (default: <output_dir>/result.json)")
    profiles_per_sweep: int = Field(24, ge=8, le=10_000, description="profiles per sweep")
    sphere_positions: list[SweepSite] = Field(default_factory=_default_sphere_sites, description="views of the sphere")
    ball_bar: BallBarConfig | None = None
    flat: FlatConfig | None = None
    mpe: MpeConfig = Field(default_factory=MpeConfig, description="maximum permissible errors, mm")
    mpe_centre_spread_mm: float | None = Field(
        0.1, gt=0, description="MPE of the spread of the sphere centres fitted from the different views, mm"
    )


class ScanConfig(_Section):
    """`spherecal scan`: sweep an object with the calibrated system, write a PLY."""

    result: str | None = Field(None, description="calibration result (default: <output_dir>/result.json)")
    object_centre_mm: Vec3 = Field(description="centre of the area to scan, in the frame the object is fixed in, mm")
    site: SweepSite = Field(default_factory=SweepSite, description="orientation and field-of-view offset")
    length_mm: float = Field(100.0, gt=0, le=10_000, description="length of each pass (along the sensor's x), mm")
    step_mm: float = Field(0.5, ge=0.001, le=10_000, description="distance between profiles, mm")
    passes: int = Field(1, ge=1, le=10_000, description="parallel passes")
    pass_spacing_mm: float = Field(20.0, gt=0, description="distance between passes (along the laser line), mm")
    standoff_z_mm: float | None = Field(
        None, description="sensor-frame z of the object's surface at the centre, mm (default: the middle of the "
        "sensor's declared measuring range)")
    speed_mm_s: float = Field(50.0, gt=0, description="speed between profiles, mm/s")
    ply: str = Field("scan.ply", description="output file (relative: in output_dir); a path outside output_dir "
                     "(absolute, or through '..') needs ply_outside_output_dir = true")
    ply_outside_output_dir: bool = Field(
        False, description="allow scan.ply to lie outside output_dir (an absolute path or one through '..')"
    )
    format: Literal["binary_little_endian", "ascii"] = Field("binary_little_endian", description="PLY encoding")

    @model_validator(mode="after")
    def _bounded(self):
        n = (self.length_mm / self.step_mm + 1) * self.passes
        if n > MAX_SCAN_PROFILES:
            raise ValueError(f"length_mm / step_mm x passes asks for {n:.3g} profiles (at most {MAX_SCAN_PROFILES:g}): "
                             "a longer step_mm or fewer passes")
        return self


class FieldOfViewOverride(_Section):
    """``[simulation.fov]``: fields of the simulated sensor's field of view that replace
    its sensor type's declared ones (:class:`spherecal.devices.contract.SensorFieldOfView`); a
    sensor type that declares none needs the four geometric fields here."""

    z_near_mm: float | None = Field(None, description="near end of the measuring range (z, mm)")
    z_far_mm: float | None = Field(None, description="far end of the measuring range (z, mm)")
    width_near_mm: float | None = Field(None, gt=0, description="line width at the near end, mm")
    width_far_mm: float | None = Field(None, gt=0, description="line width at the far end, mm")
    n_columns: int | None = Field(None, ge=16, le=100_000, description="points across the full line")
    standoff_z_mm: float | None = Field(None, description="z of the sphere centre in a calibration sweep, mm")


class SimulationConfig(_Section):
    """Present: the run is simulated (devices speak their real protocols to a simulated cell)."""

    seed: int = Field(0, ge=0, le=2**63 - 1, description="seed of the cell's noise")
    true_transform: TransformConfig | None = Field(
        None, description="the cell's true X (default: the standard cell's), mm and (w, x, y, z)"
    )
    sphere_centre_mm: Vec3 | None = Field(
        None, description="true sphere centre, base (eye_in_hand) or flange (eye_to_hand), mm (default: standard cell's)"
    )
    noise: NoiseModel = Field(default_factory=NoiseModel, description="sensor and robot noise of the cell")
    robot_error: RobotErrorModel | None = Field(
        None, description="geometric error of the simulated arm (a real arm's systematic error); absent: the arm "
        "is exactly its nominal model"
    )
    fov: FieldOfViewOverride | None = Field(
        None, description="the simulated sensor's field of view, over its sensor type's declared one")
    scan_object: Literal["none", "flat_plate", "car_door_panel"] = Field(
        "none", description="object placed at [scan] object_centre_mm (its surface at the centre)"
    )
    ball_bar_true_distance_mm: float | None = Field(
        None, gt=0, description="true centre distance of the simulated ball bar (default: the certified one)"
    )


class ExportConfig(BaseModel):
    """``[export]``: which exporters run and their settings. ``run`` lists exporters by
    name (default: every installed exporter that applies to the mounting and robot type;
    ``[]``: none, only ``result.json``); each ``[export.<exporter>]`` table holds one
    exporter's settings, validated by the plugin host against that exporter's own model
    (``spherecal plugins`` lists them). See docs/configuration.md."""

    model_config = ConfigDict(defer_build=True, frozen=True, extra="allow")

    run: list[str] | None = Field(
        None, description="exporters to run, by name (default: every one that applies to the run)"
    )

    @model_validator(mode="after")
    def _tables(self):
        for key, value in (self.model_extra or {}).items():
            if not isinstance(value, dict):
                raise ValueError(f"{key}: expected a table [export.{key}] of that exporter's settings, got "
                                 f"{type(value).__name__}")
        return self

class ReportConfig(_Section):
    """What the report and the result's provenance say besides the numbers."""

    operator: str | None = Field(None, max_length=200, description="who ran the calibration (--operator overrides)")
    cell: str | None = Field(None, max_length=200, description="the cell's name or number")
    point_distance_mm: float = Field(
        POINT_DISTANCE_MM, gt=0, le=10_000, description="the report gives the uncertainty of a point this far from the sensor, "
        "mm (along its line of sight)"
    )


class RunConfig(_Section):
    """The root of a configuration file."""

    mounting: MountingMode = Field(description="eye_in_hand (sensor on the flange) or eye_to_hand (sensor fixed)")
    output_dir: str = Field(description="folder for the journal, result, exports and report (relative: to this file)")
    robot: dict[str, Any] = Field(description="robot plugin section: type = '<name>' plus the plugin's settings")
    sensor: dict[str, Any] = Field(description="sensor plugin section: type = '<name>' plus the plugin's settings")
    sphere: SphereConfig
    nominal_transform: TransformConfig = Field(
        description="rough X from drawings: flange_from_sensor (eye_in_hand) or base_from_sensor (eye_to_hand)"
    )
    acquisition: AcquisitionConfig | None = Field(None, description="acquire with the devices")
    replay: str | None = Field(None, description="a recorded dataset (.jsonl) to calibrate instead of acquiring")
    calibration: CalibrationOptions = Field(default_factory=CalibrationOptions, description="estimator settings")
    simulation: SimulationConfig | None = Field(None, description="simulate the cell instead of using hardware")
    validation: ValidationConfig | None = Field(None, description="settings of `spherecal validate`")
    scan: ScanConfig | None = Field(None, description="settings of `spherecal scan`")
    export: ExportConfig = Field(default_factory=ExportConfig, description="exporters to run and their settings")
    report: ReportConfig = Field(default_factory=ReportConfig, description="operator, cell and report settings")

    @field_validator("robot", "sensor")
    @classmethod
    def _typed(cls, v):
        if "type" not in v or not isinstance(v["type"], str):
            raise ValueError("needs type = '<plugin name>' (see `spherecal plugins`)")
        return v

    @model_validator(mode="after")
    def _source(self):
        if (self.acquisition is None) == (self.replay is None):
            raise ValueError("give exactly one of [acquisition] (acquire with the devices) or replay = '<dataset>'")
        if self.calibration.nominal_transform is not None:
            raise ValueError("calibration.nominal_transform: give the rough transform as [nominal_transform] instead")
        if self.scan is not None and self.acquisition is not None and self.scan.speed_mm_s > self.acquisition.max_speed_mm_s:
            raise ValueError(
                f"scan.speed_mm_s = {self.scan.speed_mm_s} exceeds acquisition.max_speed_mm_s = "
                f"{self.acquisition.max_speed_mm_s}"
            )
        return self


def _format_errors(exc: ValidationError, where: str) -> str:
    lines = []
    for err in exc.errors():
        loc, given = err["loc"], err.get("input")
        msg = err["msg"]
        if err["type"] == "extra_forbidden":
            msg = "unknown key (a typo?)"
        elif err["type"] == "missing" and loc and isinstance(loc[-1], int) and isinstance(given, (list, tuple)):
            # a list one value short (two coordinates for x, y, z): said of the list, not as a missing key
            msg, loc = f"{len(given)} values given ({list(given)}); value {loc[-1] + 1} is missing", loc[:-1]
        path = ".".join(str(p) for p in loc) or "(top level)"
        lines.append(f"  {where}: {path}: {msg}")
    return "\n".join(lines)


class LoadedConfig:
    """A validated configuration and where it came from."""

    def __init__(self, config: RunConfig, path: Path):
        self.config = config
        self.path = path

    def resolve(self, relative: str) -> Path:
        p = Path(relative).expanduser()
        return p if p.is_absolute() else (self.path.parent / p).resolve()

    @property
    def output_dir(self) -> Path:
        return self.resolve(self.config.output_dir)


def _number_problems(value: Any, path: str, out: list[str]) -> None:
    """Every NaN, infinity or implausibly large number in parsed TOML, by dotted path."""
    if isinstance(value, bool):
        return
    if isinstance(value, float):
        if not math.isfinite(value):
            out.append(f"{path}: {value} is not allowed: give a finite number")
        elif abs(value) > MAX_ABS_NUMBER:
            out.append(f"{path}: {value:g} is implausibly large (at most {MAX_ABS_NUMBER:g} in magnitude)")
    elif isinstance(value, int):
        if abs(value) > 2**63:
            out.append(f"{path}: an integer of {len(str(abs(value)))} digits is too large")
        elif abs(value) > MAX_ABS_NUMBER and path.rsplit(".", 1)[-1] != "seed":
            out.append(f"{path}: {value} is implausibly large (at most {MAX_ABS_NUMBER:g} in magnitude)")
    elif isinstance(value, dict):
        for k, v in value.items():
            _number_problems(v, f"{path}.{k}" if path else str(k), out)
    elif isinstance(value, list):
        for i, v in enumerate(value):
            _number_problems(v, f"{path}[{i}]", out)


def _field_annotation(model: type, keys: list) -> Any:
    """The annotation of the field a dotted path of parsed TOML reaches in ``model``
    (through nested models and lists of models), or None when it leaves the models."""
    ann: Any = model
    for key in keys:
        ann = _unwrap(ann)
        if isinstance(key, int):
            args = get_args(ann)
            if get_origin(ann) in (list, tuple) and args:
                ann = args[0] if get_origin(ann) is list or len(args) == 1 or args[-1] is Ellipsis else (
                    args[key] if key < len(args) else None)
                continue
            return None
        if isinstance(ann, type) and issubclass(ann, BaseModel) and key in ann.model_fields:
            ann = ann.model_fields[key].annotation
            continue
        return None
    return _unwrap(ann)


def _unwrap(ann: Any) -> Any:
    while True:
        origin = get_origin(ann)
        if origin is Annotated:
            ann = get_args(ann)[0]
        elif origin in (Union, UnionType):
            args = [a for a in get_args(ann) if a is not type(None)]
            if len(args) != 1:
                return ann
            ann = args[0]
        else:
            return ann


def _bool_problems(value: Any, keys: list, out: list[str], root: type[BaseModel] = RunConfig,
                   prefix: str = "") -> None:
    """true/false or a string where the model wants a number: TOML booleans and strings
    are never numbers here (pydantic would read true as 1.0 and "19.1" as 19.1). ``root``
    is the model ``value`` is checked against; ``prefix`` leads every path in messages."""
    if isinstance(value, (bool, str)):
        ann = _field_annotation(root, keys)
        path = prefix + ".".join(str(k) if not isinstance(k, int) else f"[{k}]" for k in keys).replace(".[", "[")
        if ann in (float, int):
            shown = str(value).lower() if isinstance(value, bool) else repr(value)
            out.append(f"{path}: {shown:.40} is a {'boolean' if isinstance(value, bool) else 'string'}; "
                       "give a number")
        elif isinstance(value, bool) and ann is not None and ann is not bool and get_origin(ann) is not Literal \
                and ann is not Any:
            out.append(f"{path}: {str(value).lower()} is a boolean; expected {getattr(ann, '__name__', ann)}")
    elif isinstance(value, dict):
        for k, v in value.items():
            _bool_problems(v, [*keys, k], out, root, prefix)
    elif isinstance(value, list):
        for i, v in enumerate(value):
            _bool_problems(v, [*keys, i], out, root, prefix)


def not_numbers(table: Any, model: type[BaseModel], path: str) -> list[str]:
    """Every boolean or string in ``table`` (parsed TOML) where ``model`` wants a number,
    by dotted path under ``path``: pydantic would take them (true as 1.0, "2" as 2.0), a
    hand-written file must not. For plugin-owned sections (``[export.<name>]``)."""
    out: list[str] = []
    _bool_problems(table, [], out, model, f"{path}.")
    return out


def read_toml(path, what: str = "configuration") -> dict:
    """The TOML file at ``path`` as a dict, read with the input checks (a regular file of
    bounded size, a text encoding TOML allows); :class:`ConfigError` naming the file and
    ``what`` it should have been otherwise."""
    from spherecal.io.files import read_input, text_encoding_problem

    raw = read_input(path, ConfigError, f"the {what}", MAX_CONFIG_BYTES)
    problem = text_encoding_problem(raw)
    if problem:
        raise ConfigError(f"{path}: not a {what} as written: {problem}")
    try:
        return tomllib.loads(raw.decode("utf-8").removeprefix("\ufeff"))
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as exc:
        hint = ""
        if raw.lstrip().startswith(b"{") and what == "configuration":  # a dataset (JSON Lines) given for a configuration
            hint = "; it looks like a dataset (JSON Lines): solve it with `spherecal solve FILE`"
        raise ConfigError(f"{path}: not valid TOML: {exc}{hint}") from None
    except RecursionError:
        raise ConfigError(f"{path}: not a {what}: nested too deeply") from None


def load_config(path: str | Path) -> LoadedConfig:
    """Read and validate a configuration file; :class:`ConfigError` names the file and
    every bad key by its dotted path. Numbers must be finite and at most
    :data:`MAX_ABS_NUMBER` in magnitude; a boolean is never read as a number."""
    path = Path(path)
    data = read_toml(path, "configuration")
    if not data:
        raise ConfigError(f"{path}: the configuration is empty; see docs/configuration.md and examples/")
    problems: list[str] = []
    _number_problems(data, "", problems)
    _bool_problems(data, [], problems)
    if problems:
        raise ConfigError(f"{path}: invalid configuration:\n" + "\n".join(f"  {path}: {p}" for p in problems))
    try:
        cfg = RunConfig.model_validate(data)
    except ValidationError as exc:
        raise ConfigError(f"{path}: invalid configuration:\n{_format_errors(exc, str(path))}") from None
    return LoadedConfig(cfg, path.resolve())
