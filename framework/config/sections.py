"""The sections of a configuration file, one pydantic model per concern, and the root
:class:`RunConfig` that composes them. The estimator's settings (:mod:`.calibration`) and
the report's (:mod:`.report`) have modules of their own, re-exported here: a ``solve``
needs them without the rest.

Every model is frozen and forbids unknown keys. Lengths in mm, angles in degrees,
quaternions (w, x, y, z). The robot and sensor sections belong to their plugins: the
root only checks that they name a ``type``. See docs/configuration.md.
"""

from __future__ import annotations

from typing import Annotated, Any, Literal

import numpy as np
from pydantic import AfterValidator, BaseModel, ConfigDict, Field, field_validator, model_validator

from spherecal.config.base import BASE_DIR_CONTEXT_KEY, CHI2_3DOF_1E4, POINT_DISTANCE_MM, Section  # noqa: F401
from spherecal.config.calibration import CalibrationOptions
from spherecal.config.report import ReportConfig
from spherecal.core.field_of_view import SensorBody
from spherecal.core.models import MountingMode, Pose, Vec3
from spherecal.core.workspace import WorkspaceBox

#: Most profiles one scan may ask for.
MAX_SCAN_PROFILES = 10_000_000
#: Default (max tilt, max turn) in deg per mounting mode. Eye-to-hand turns the sphere on
#: its stylus in front of the fixed sensor; 30 deg and 40 deg there leave the identification
#: poorly conditioned (about 1,000 on the example cell), 45 and 90 give 316. The simulated
#: cell does not model a stylus or flange hiding the sphere from the laser: on a real cell,
#: choose limits that keep them out of its view.
DEFAULT_LIMITS_DEG = {"eye_in_hand": (50.0, 90.0), "eye_to_hand": (45.0, 90.0)}

#: A point or a vector (x, y, z).
#: A quaternion (w, x, y, z).
Vec4 = tuple[float, float, float, float]


def _unit_quaternion(v: Vec4) -> Vec4:
    n = float(np.linalg.norm(v))
    if abs(n - 1.0) > 1e-3:
        raise ValueError(f"quaternion {list(v)} has norm {n:.6f}; give a unit quaternion (w, x, y, z)")
    return v


#: A unit quaternion (w, x, y, z), checked where it is read.
UnitQuaternion = Annotated[Vec4, AfterValidator(_unit_quaternion)]


class TransformConfig(Section):
    """A rigid transform written by hand: translation in mm, quaternion (w, x, y, z)."""

    translation_mm: Vec3 = Field(description="translation, mm")
    quaternion_wxyz: UnitQuaternion = Field(description="rotation, unit quaternion, scalar first (ABB order)")

    def pose(self) -> Pose:
        return Pose.from_xyz_quat_wxyz(self.translation_mm, self.quaternion_wxyz)


class SphereConfig(Section):
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


class SweepPlan(Section):
    """How to sweep the sphere: sensor-frame positions of the sphere centre per station.

    Within a station the flange only translates. The sphere centre crosses the laser
    plane along the sensor's x from ``-sweep_fraction * r`` to ``+sweep_fraction * r``
    while wandering by ``lateral_amplitude_mm`` in y and z, so that the moves of one
    station span three dimensions (this is what lets each station decide, on its own,
    on which side of the laser plane the centre lies)."""

    profiles_per_station: int = Field(10, ge=4, le=10_000, description="profiles taken per station")
    sweep_fraction: float = Field(0.8, gt=0, lt=1, description="sweep half-length as a fraction of the radius")
    standoff_z_mm: float | None = Field(
        None, description="sensor-frame z of the sphere centre, mm (default: the sensor's declared "
        "field of view's standoff, else sized for the sphere's radius: spherecal.motion.planning.sphere_standoff_z_mm)")
    lateral_amplitude_mm: float | None = Field(
        None, ge=0, le=1000, description="y/z wander within a sweep, mm (default: LATERAL_AMPLITUDE_PERCENT of the "
        "sensor's measuring range, 4 mm in a 100 mm range)")
    station_offsets_mm: list[tuple[float, float]] | None = Field(
        None,
        description="(y, z) shift of the sweep in the sensor frame, mm, per station (cycled): "
        "sweeps at different places of the field of view tie the rotation to the translation (default: "
        "STATION_OFFSETS_PERCENT of the sensor's field of view, [(0, 0), (10, -25), (-10, 18), (0, -30)] for a "
        "100 mm range and a line 40 mm wide at the standoff)",
    )
    tilts_deg: list[tuple[float, float, float]] = Field(
        default_factory=lambda: [(0.0, 0.0, 0.0), (30.0, 0.0, 0.0), (0.0, 30.0, 0.0), (0.0, 0.0, 45.0)],
        description="one rotation vector (deg) per station: about sensor axes (eye-in-hand) "
        "or base axes (eye-to-hand), applied to the reference orientation",
    )


class KinematicPlanSettings(Section):
    """``[acquisition.kinematic_plan]``: stations for kinematic calibration chosen by the
    planner (:mod:`spherecal.motion.kinematic_plan`) instead of listed in ``acquisition.sweep.tilts_deg``."""

    stations: int = Field(20, ge=4, le=200, description="stations to plan")
    candidates: int = Field(240, ge=8, le=5000, description="candidate orientations the stations are chosen from")
    max_tilt_deg: float | None = Field(
        None, gt=0, le=90, description="largest tilt of the view axis from the reference orientation, deg "
        "(default 50 eye-in-hand, 45 eye-to-hand)")
    max_turn_deg: float | None = Field(None, ge=0, le=180, description="largest turn about the view axis, deg (default 90)")
    seed: int = Field(0, ge=0, le=2**32 - 1, description="seed of the candidates' turns (the plan is the same for "
                      "the same seed and configuration)")

    @model_validator(mode="after")
    def _enough_candidates(self):
        if self.candidates < self.stations:
            raise ValueError(f"candidates = {self.candidates} must be at least stations = {self.stations}")
        return self

    def limits_deg(self, mounting: MountingMode) -> tuple[float, float]:
        tilt, turn = DEFAULT_LIMITS_DEG[mounting]
        return (tilt if self.max_tilt_deg is None else self.max_tilt_deg,
                turn if self.max_turn_deg is None else self.max_turn_deg)


class AcquisitionConfig(Section):
    """How to acquire: where the sphere roughly is, the sweeps, speeds and limits."""

    mode: Literal["stop_and_go", "on_the_fly", "manual"] = Field(
        "stop_and_go", description="stop_and_go (or its former name automatic): the program moves the robot and "
        "stops for every profile; on_the_fly: continuous sweeps while the robot streams its pose and the sensor its "
        "profiles (both must stream; [acquisition.on_the_fly] plans the sweeps); manual: the operator jogs, the "
        "program captures"
    )
    sphere_centre_mm: Vec3 = Field(
        description="rough sphere centre: in base (eye_in_hand) or in the flange frame (eye_to_hand), mm"
    )
    reference_flange_quaternion_wxyz: UnitQuaternion = Field(
        (0.0, 0.0, 1.0, 0.0), description="flange orientation of the first station, base_from_flange, (w, x, y, z)"
    )
    sweep: SweepPlan = Field(default_factory=SweepPlan, description="stations and sweeps")
    on_the_fly: OnTheFlyPlan = Field(
        default_factory=lambda: OnTheFlyPlan(), description="the continuous sweeps at each station of mode = "
        "\"on_the_fly\" (forth and back, at every speed, along every direction)")
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

    @field_validator("mode", mode="before")
    @classmethod
    def _former_mode_name(cls, v):
        return "stop_and_go" if v == "automatic" else v

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
        if self.mode == "on_the_fly":
            for v in self.on_the_fly.speeds_mm_s:
                if v > self.max_speed_mm_s:
                    raise ValueError(f"on_the_fly.speeds_mm_s: {v} mm/s exceeds max_speed_mm_s = {self.max_speed_mm_s}")
        return self


class SweepSite(Section):
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


class BallBarConfig(Section):
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


class FlatConfig(Section):
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


class MpeConfig(Section):
    """Maximum permissible errors, mm. Each has its own default; a figure is judged
    against its MPE whenever it is measured (the fields of
    :class:`~spherecal.core.metrology.MaximumPermissibleErrors`)."""

    probing_form_mm: float = Field(0.25, gt=0, description="MPE of P_F, mm")
    probing_size_mm: float = Field(0.06, gt=0, description="MPE of |P_S|, mm")
    sphere_spacing_mm: float = Field(0.1, gt=0, description="MPE of |SD|, mm")
    flatness_mm: float = Field(0.15, gt=0, description="MPE of F, mm")


class ValidationConfig(Section):
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


class ScanConfig(Section):
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
    mode: Literal["stop_and_go", "on_the_fly"] | None = Field(
        None, description="stop_and_go: one profile every step_mm, the robot standing; on_the_fly: continuous passes "
        "at speed_mm_s, the robot streaming its pose and the sensor its profiles, every profile mapped through the "
        "pose at its exposure by the calibration's clock relation (docs/on-the-fly.md, \"Scanning on the fly\"); "
        "default: on_the_fly when [acquisition] mode is, else stop_and_go")
    rate_hz: float | None = Field(None, gt=0, le=100_000, description="on the fly: profiles a second while "
                                  "streaming, Hz (default: the sensor's configured rate)")
    clock_offset_ms: float | None = Field(
        None, description="on the fly with a calibration that holds no clock relation (a stop-and-go one): "
        "t_robot = t_sensor + clock_offset_ms, GIVEN, not estimated, no drift. Its error moves every point by speed "
        "x error along the pass, unseen by anything: give it only when it is known (both devices stamping one "
        "synchronised clock), ms. Ignored (refused) with a calibration that has its own clock relation")
    max_timing_error_mm: float = Field(
        0.1, gt=0, le=100, description="on the fly: the largest position error the clock relation's uncertainty may "
        "give a profile (k = 2, at the flange's speed), mm; a pass beyond it is not mapped and the scan stops")

    @model_validator(mode="after")
    def _bounded(self):
        n = (self.length_mm / self.step_mm + 1) * self.passes
        if n > MAX_SCAN_PROFILES:
            raise ValueError(f"length_mm / step_mm x passes asks for {n:.3g} profiles (at most {MAX_SCAN_PROFILES:g}): "
                             "a longer step_mm or fewer passes")
        return self


class FieldOfViewOverride(Section):
    """``[simulation.fov]``: fields of the simulated sensor's field of view that replace
    its sensor type's declared ones (:class:`spherecal.devices.contract.SensorFieldOfView`); a
    sensor type that declares none needs the four geometric fields here."""

    z_near_mm: float | None = Field(None, description="near end of the measuring range (z, mm)")
    z_far_mm: float | None = Field(None, description="far end of the measuring range (z, mm)")
    width_near_mm: float | None = Field(None, gt=0, description="line width at the near end, mm")
    width_far_mm: float | None = Field(None, gt=0, description="line width at the far end, mm")
    n_columns: int | None = Field(None, ge=16, le=100_000, description="points across the full line")
    standoff_z_mm: float | None = Field(None, description="z of the sphere centre in a calibration sweep, mm")


class NoiseModel(Section):
    """Noise of the simulated cell. Standard deviations, per axis."""

    point_noise_mm: float = Field(0.01, ge=0, description="sensor point noise, each of y and z, mm")
    pose_translation_noise_mm: float = Field(0.02, ge=0, description="robot position noise, each base axis, mm")
    pose_rotation_noise_deg: float = Field(0.0, ge=0, description="robot orientation noise, about each base axis, deg")
    stray_profile_fraction: float = Field(0.0, ge=0, le=1, description="share of profiles that get stray points")
    strays_per_profile: int = Field(4, ge=0, le=100_000, description="stray points added to such a profile")
    stray_offset_mm: tuple[float, float] = Field((0.3, 3.0), description="range of a stray's distance off the surface, mm")


def _range(lo_default: float, hi_default: float, what: str):
    return Field(
        (lo_default, hi_default),
        description=f"{what}: each error's magnitude is drawn uniformly from this range, with a random sign",
    )


class RobotErrorModel(Section):
    """Geometric error of the simulated arm (defaults: an uncalibrated IRB 2400-class
    arm, flange 0.5-2 mm and 0.03-0.15 deg off its nominal pose)."""

    joint_zero_offset_deg: tuple[float, float] = _range(0.02, 0.05, "zero offset of every joint, deg")
    link_length_mm: tuple[float, float] = _range(0.1, 0.3, "error of each joint placement along the link, mm")
    link_offset_mm: tuple[float, float] = _range(0.0, 0.2, "error of each joint placement across the link, mm")
    axis_tilt_deg: tuple[float, float] = _range(0.0, 0.02, "tilt of every joint axis, deg")
    joint_compliance_deg_per_m: tuple[float, float] = Field(
        (0.0, 0.0), description="gravity sag of every joint: it turns by this much (deg) per metre of "
        "horizontal lever from its axis to the flange (drawn uniformly per joint, always with gravity). Not a "
        "geometric error: it changes with the arm's configuration, so no kinematic model holds it"
    )
    seed: int | None = Field(
        None, ge=0, le=2**63 - 1, description="seed of this arm's errors (default: the cell's seed)"
    )

    @model_validator(mode="after")
    def _ordered(self):
        for name in ("joint_zero_offset_deg", "link_length_mm", "link_offset_mm", "axis_tilt_deg",
                     "joint_compliance_deg_per_m"):
            lo, hi = getattr(self, name)
            if not (np.isfinite(lo) and np.isfinite(hi) and 0 <= lo <= hi <= 100):
                raise ValueError(f"{name}: expected 0 <= low <= high <= 100, got ({lo}, {hi})")
        return self


class OnTheFlyPlan(Section):
    """Continuous sweeps for an on-the-fly recording: at each station of a stop-and-go
    plan (:class:`SweepPlan`: its flange orientation, and where in the field of view the
    sphere crosses the laser plane) the robot makes straight MoveL sweeps that carry the
    laser plane through the sphere, each forth and back, at every speed of ``speeds_mm_s``
    and along every direction of ``directions_in_sensor``, with a trapezoidal speed
    profile and a standstill of ``pause_s`` after each sweep.

    Forth and back at two speeds is what separates a time offset from the sphere's
    position (an offset moves every profile of a sweep by speed x offset along it); two
    directions per station let each station span a plane of moves. A sweep cruises at
    full speed while the laser plane is within ``crossing_fraction`` radii of the sphere
    centre, so the sphere is crossed at constant speed and the ramps lie outside it."""

    speeds_mm_s: tuple[float, ...] = Field(
        (50.0, 100.0), min_length=1, max_length=4,
        description="sweep speeds at the tool point, mm/s: every direction is swept forth and back at each")
    acceleration_mm_s2: float = Field(800.0, ge=10, le=20_000,
                                      description="acceleration and deceleration of every move, mm/s^2")
    directions_in_sensor: list[Vec3] = Field(
        default_factory=lambda: [(1.0, 0.0, 0.0), (0.866, 0.354, 0.354)], min_length=1, max_length=6,
        validate_default=True,
        description="directions in which the sphere centre moves in the sensor frame during a forth sweep "
        "(normalised; the back sweep reverses it); each needs a component along the sensor's x (the laser "
        "plane's normal) of at least 0.25 of its length (default: along x, and 30 deg off x towards y and z)")
    crossing_fraction: float = Field(1.25, ge=1.0, le=5.0, description="half the range of the sensor's x "
                                     "swept at full speed, in sphere radii (above 1: the laser plane leaves the "
                                     "sphere before the ramps, so profiles at the sweep's ends see nothing)")
    pause_s: float = Field(0.2, ge=0.0, le=60.0, description="standstill after each sweep and each transit, s")
    transit_speed_mm_s: float = Field(200.0, gt=0, le=2000, description="speed of the moves between sweeps, mm/s")
    transit_speed_deg_s: float = Field(30.0, gt=0, le=360, description="reorientation speed of the moves "
                                       "between stations, deg/s")
    stations: int | None = Field(None, ge=1, le=1000, description="sweep only the first this many stations of "
                                 "the stop-and-go plan (None: all of them)")

    @field_validator("speeds_mm_s")
    @classmethod
    def _speeds(cls, v):
        for s in v:
            if not (np.isfinite(s) and 0 < s <= 2000):
                raise ValueError(f"speed {s} mm/s: expected 0 < speed <= 2000 mm/s")
        return v

    @field_validator("directions_in_sensor")
    @classmethod
    def _directions(cls, v):
        out = []
        for d in v:
            a = np.asarray(d, dtype=float)
            n = float(np.linalg.norm(a))
            if not (np.all(np.isfinite(a)) and n > 1e-9):
                raise ValueError(f"direction {list(d)}: expected a non-zero finite vector (x, y, z), sensor frame")
            if abs(a[0]) < 0.25 * n:
                raise ValueError(f"direction {list(d)}: its component along the sensor's x (the laser plane's "
                                 f"normal) is {abs(a[0]) / n:.3f} of its length, below 0.25; a sweep along it "
                                 "would barely cross the laser plane")
            out.append(tuple(float(c) for c in a / n))
        return out

    @classmethod
    def quick(cls, **update) -> "OnTheFlyPlan":
        """A short plan for tests: one station, both directions, both speeds, short sweeps
        and pauses (about 9 s of motion, 2,700 profiles at the default 300 Hz)."""
        values = {"stations": 1, "crossing_fraction": 1.15, "pause_s": 0.05, **update}
        return cls(**values)


class PoseStreamSettings(Section):
    """The simulated robot's pose stream: what the controller samples, stamps and loses.

    The pose noise is the robot's repeatability: the true flange moves off the pose the
    controller reports by an error that is smooth in time, a first-order Gauss-Markov
    process per base axis (standard deviation ``*_noise_*``, correlation time
    ``noise_correlation_s``: its autocorrelation after dt is exp(-dt / correlation)).
    At 0.02 mm over 50 ms this looks, at 100 mm/s, like 0.1-0.4 ms of timing error."""

    period_s: float = Field(0.004, ge=1e-4, le=1.0, description="sample period on the robot's clock, s "
                            "(ABB EGM and KUKA RSI 0.004, UR RTDE 0.002 or 0.008)")
    translation_noise_mm: float = Field(0.02, ge=0, le=10, description="repeatability noise, SD per base axis, mm")
    rotation_noise_deg: float = Field(0.002, ge=0, le=1, description="repeatability noise, SD about each base "
                                      "axis, deg")
    noise_correlation_s: float = Field(0.05, gt=0, le=100, description="correlation time of the noise, s")
    stamp_jitter_s: float = Field(2e-5, ge=0, le=1e-2, description="SD of the difference between a sample's "
                                  "stamp and the instant its pose was taken, s (cut at a quarter period)")
    drop_rate: float = Field(0.001, ge=0, le=0.5, description="share of samples lost one at a time")
    burst_rate_per_s: float = Field(0.02, ge=0, le=100, description="bursts of lost samples per second")
    burst_length: tuple[int, int] = Field((2, 5), description="samples lost in a burst: drawn uniformly in "
                                          "this range, both ends included")
    joints: bool = Field(True, description="send the joints with each pose (when the cell has an arm)")
    first_seq: int = Field(1000, ge=0, le=2**62, description="sequence number of the first sample")

    @field_validator("burst_length")
    @classmethod
    def _burst(cls, v):
        if not 1 <= v[0] <= v[1] <= 10_000:
            raise ValueError(f"burst_length {list(v)}: expected 1 <= low <= high <= 10000 samples")
        return v


class SensorStreamSettings(Section):
    """The simulated profiler's stream: it exposes at its own rate on its own clock."""

    rate_hz: float = Field(300.0, gt=0, le=20_000, description="profile rate on the sensor's clock, Hz")
    stamp_jitter_s: float = Field(1e-5, ge=0, le=1e-2, description="SD of the difference between a profile's "
                                  "stamp and its exposure's middle (less the latencies), s (cut at a quarter period)")
    latency_s: float = Field(0.0, ge=0, le=10, description="constant delay of every stamp after the exposure's "
                             "middle, s (a sensor that stamps at readout); part of the true offset")
    extra_latency_s: float = Field(0.0, ge=-1, le=10, description="a further constant delay of the stamps that "
                                   "the recording does not declare (an unmodelled latency), s; part of the true "
                                   "offset too, and given apart in the provenance")
    frame_drop_rate: float = Field(0.0, ge=0, le=0.5, description="share of profiles lost (their frame numbers "
                                   "are missing)")
    first_frame: int = Field(0, ge=0, le=2**62, description="frame counter of the first exposure")


class ClockSettings(Section):
    """The two clocks against true time T (s, 0 at the recording's start): the robot's
    reads ``robot_epoch_s + (1 + robot_rate_error_ppm 1e-6) T``, the sensor's
    ``sensor_epoch_s + (1 + sensor_rate_error_ppm 1e-6) T``. Crystal clocks differ by
    20-100 ppm. Defaults: the robot counting from power-on an hour ago, the sensor from
    1970 (2026-01-01 UTC), 35 ppm apart."""

    robot_epoch_s: float = Field(3725.25, ge=0, le=1e10, description="robot clock at the recording's start, s")
    robot_rate_error_ppm: float = Field(20.0, ge=-1000, le=1000, description="robot clock's rate error, ppm")
    sensor_epoch_s: float = Field(1767225600.0, ge=0, le=1e10, description="sensor clock at the recording's start, s")
    sensor_rate_error_ppm: float = Field(-15.0, ge=-1000, le=1000, description="sensor clock's rate error, ppm")


class StreamSimSettings(Section):
    """Everything an on-the-fly simulation draws that the plan does not say (defaults:
    an EGM-like 250 Hz pose stream with 0.02 mm of smooth noise, a 300 Hz profiler, two
    free-running clocks 35 ppm apart)."""

    pose: PoseStreamSettings = Field(default_factory=PoseStreamSettings, description="the robot's pose stream")
    sensor: SensorStreamSettings = Field(default_factory=SensorStreamSettings, description="the profiler's stream")
    clocks: ClockSettings = Field(default_factory=ClockSettings, description="the two clocks")
    lead_in_s: float = Field(0.2, ge=0, le=60, description="standstill before the first sweep, s")
    seed: int | None = Field(None, ge=0, le=2**63 - 1, description="seed of the streams' noise, jitter and "
                             "losses (None: the cell's seed)")


class SimulationConfig(Section):
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


class KeepOutConfig(Section):
    """``[keep_out]``: the check, before any motion, that no planned pose or move brings the
    sensor's body closer than ``clearance_mm`` to the reference sphere or what holds it
    (:mod:`spherecal.core.keep_out`). The sphere is held by a rod of ``stand_radius_mm``:
    eye-in-hand a vertical stand from its centre ``stand_length_mm`` down (base -z),
    eye-to-hand the stem from its centre to the flange's origin."""

    clearance_mm: float = Field(5.0, ge=0, le=1000, description="least gap allowed between the sensor's body and "
                                "the sphere or its stand (stem), mm")
    stand_radius_mm: float = Field(10.0, ge=0, le=1000, description="radius of the rod holding the sphere (the "
                                   "stand eye-in-hand, the stem to the flange eye-to-hand), mm")
    stand_length_mm: float = Field(300.0, ge=0, le=10_000, description="eye_in_hand: how far the stand reaches "
                                   "down (base -z) from the sphere's centre, mm (0: no stand)")
    sensor_body: SensorBody | None = Field(
        None, description="the sensor's housing as a box in the sensor frame, min_mm and max_mm (x, y, z), mm "
        "(default: the sensor type's declared body)")


class RunConfig(Section):
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
    keep_out: KeepOutConfig = Field(default_factory=KeepOutConfig, description="the sensor's body against the "
                                    "sphere and its stand, checked before any motion")

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
