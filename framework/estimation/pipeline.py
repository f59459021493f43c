"""From a dataset to a :class:`CalibrationResult`: screening, two-step start, joint
refinement, outlier rejection, diagnostics."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Callable, Literal

import numpy as np
from pydantic import BaseModel, ConfigDict, Field

from .. import geometry as geo
from ..errors import DegenerateDataError
from ..models import (
    SPHERE_FRAME, TRANSFORM_NAME, CalibrationResult, Dataset, ObservationFlag, Pose, ResidualStats, RobotErrorSummary,
)
from .circle import CircleFit, fit_circle
from .prediction import point_error_budget
from .problem import Problem, build_problem
from .refine import NoiseAssumptions, RefineResult, StationEffects, refine
from .twostep import TwoStepResult, two_step

#: chi^2 with 3 degrees of freedom exceeded with probability 1e-4.
CHI2_3DOF_1E4 = 21.108


class CalibrationOptions(BaseModel):
    """Settings of the estimator. Lengths in mm, angles in degrees."""

    model_config = ConfigDict(frozen=True, extra="forbid")

    fit_radius: bool = Field(False, description="estimate the sphere radius too (else the certified one is used)")
    point_noise_mm: float | None = Field(
        None, gt=0, description="sensor point noise (each of y, z), mm; None: estimated from the circle fits"
    )
    pose_translation_noise_mm: float = Field(0.02, ge=0, description="robot position noise, each axis, mm")
    pose_rotation_noise_deg: float = Field(0.002, ge=0, description="robot orientation noise, each axis, deg")
    estimate_pose_noise: bool = Field(True, description="rescale the pose noise to what the data show")
    min_points_per_profile: int = Field(20, ge=3, description="profiles with fewer points are left out")
    min_profiles_per_station: int = Field(4, ge=3, description="stations with fewer usable profiles are left out")
    max_circle_rms_mm: float = Field(0.5, gt=0, description="a profile whose circle fit is worse is not the sphere")
    point_outlier_k: float = Field(5.0, gt=2, description="points beyond k robust standard deviations are strays")
    profile_outlier_chi2: float = Field(
        CHI2_3DOF_1E4, gt=0, description="profiles whose whitened chi^2 (3 dof) exceeds this are left out"
    )
    max_rejected_profile_fraction: float = Field(0.2, ge=0, le=1, description="stop rejecting profiles beyond this share")
    nominal_transform: Pose | None = Field(
        None, description="rough X (flange_from_sensor or base_from_sensor), used only to choose between "
        "solutions the data cannot tell apart"
    )
    station_rotation_tolerance_deg: float = Field(
        0.05, gt=0, description="observations of one station may differ in orientation by at most this"
    )
    robot_error_model: Literal["station", "none"] = Field(
        "station", description="'station': the robot's systematic error is a pose offset shared by the shots of "
        "a station, estimated and marginalised (docs/estimation.md); 'none': the robot has pose noise only"
    )
    station_rotation_error_deg: float | None = Field(
        None, ge=0, le=5, description="station-to-station robot orientation error, per axis, deg (None: estimated)"
    )
    station_translation_error_mm: float | None = Field(
        None, ge=0, le=50, description="station-to-station robot position error, per axis, mm (None: estimated)"
    )
    robot_accuracy_mm: float = Field(
        0.75, ge=0, le=50, description="the robot's position error shared by every station of the plan, per axis, "
        "1 sigma, mm (an uncalibrated industrial arm: 0.3-1.2); one sphere location cannot measure it, so it "
        "enters the uncertainty only (docs/estimation.md)"
    )
    robot_accuracy_deg: float = Field(
        0.06, ge=0, le=5, description="the robot's orientation error shared by every station, per axis, 1 sigma, deg"
    )

    def station_effects(self) -> StationEffects:
        return StationEffects(
            self.robot_error_model == "station", self.station_rotation_error_deg,
            self.station_translation_error_mm, self.robot_accuracy_deg, self.robot_accuracy_mm,
        )


@dataclass
class Solution:
    """Everything :func:`solve` worked out; :attr:`result` is what users keep."""

    result: CalibrationResult
    problem: Problem  # the profiles that were used (points cleaned)
    two_step: TwoStepResult
    refined: RefineResult
    fits: dict[int, CircleFit]
    extras: dict = field(default_factory=dict)


def _flag(problem: Problem, i: int, reason: str, station: str | None = None) -> ObservationFlag:
    return ObservationFlag(
        index=int(problem.obs_index[i]), station=station or problem.station_labels[problem.station_of[i]], reason=reason
    )


def solve(
    dataset: Dataset,
    options: CalibrationOptions | None = None,
    flange_pose_from_joints: Callable[[np.ndarray], Pose] | None = None,
    progress: Callable[[str], None] | None = None,
) -> Solution:
    """Calibrate ``dataset``; see the package docstring for the steps."""
    opt = options or CalibrationOptions()
    say = progress or (lambda msg: None)
    problem = build_problem(dataset, flange_pose_from_joints, opt.station_rotation_tolerance_deg)
    r = problem.radius_mm
    flags: list[ObservationFlag] = []

    say(f"fitting circles to {problem.n_profiles} profiles")
    fits: dict[int, CircleFit] = {}
    for i, pts in enumerate(problem.profiles):
        if len(pts) < opt.min_points_per_profile:
            flags.append(_flag(problem, i, f"only {len(pts)} points (needs {opt.min_points_per_profile}): "
                                           "the line barely touches the sphere or misses it"))
            continue
        fit = fit_circle(pts, outlier_k=opt.point_outlier_k)
        if not fit.converged or fit.rms > opt.max_circle_rms_mm or fit.n_inliers < opt.min_points_per_profile:
            flags.append(_flag(problem, i, f"points do not lie on a circle (rms {fit.rms:.3f} mm): not the sphere?"))
            continue
        if fit.radius > 1.02 * r:
            flags.append(_flag(problem, i, f"circle radius {fit.radius:.3f} mm exceeds the sphere radius {r} mm: "
                                           "wrong sphere radius in the dataset, or not the sphere"))
            continue
        fits[i] = fit
    if not fits:
        raise DegenerateDataError(
            "no profile shows the sphere (every profile was left out: "
            f"{flags[0].reason if flags else 'none'}): check that the plan puts the sphere in the field of view"
        )
    # stations with too few usable profiles
    for k, label in enumerate(problem.station_labels):
        members = [i for i in np.flatnonzero(problem.station_of == k) if i in fits]
        if 0 < len(members) < opt.min_profiles_per_station:
            for i in members:
                flags.append(_flag(problem, i, f"station {label} has only {len(members)} usable profiles "
                                               f"(needs {opt.min_profiles_per_station}): add profiles to its sweep"))
                del fits[i]
    used = np.array(sorted(fits))
    if len(used) == 0:
        raise DegenerateDataError(
            f"no station has {opt.min_profiles_per_station} usable profiles: add profiles to each sweep"
        )
    sub = problem.subset(np.isin(np.arange(problem.n_profiles), used))
    sub_fits = {j: fits[i] for j, i in enumerate(used)}

    say("two-step solution (rotation from translations, translation from orientations)")
    nominal_R = opt.nominal_transform.rotation_matrix if opt.nominal_transform is not None else None
    ts = two_step(sub, sub_fits, nominal_R)
    orientations = len(sub.station_labels)

    if opt.point_noise_mm is not None:
        sigma = opt.point_noise_mm
    else:
        num = sum(f.rms**2 * f.n_inliers for f in sub_fits.values())
        den = sum(max(f.n_inliers - 3, 1) for f in sub_fits.values())
        sigma = float(np.sqrt(num / den))
    noise = NoiseAssumptions(max(sigma, 1e-7), opt.pose_translation_noise_mm, opt.pose_rotation_noise_deg)

    clean = sub.with_profiles([p[sub_fits[j].inliers] for j, p in enumerate(sub.profiles)])
    say(f"joint refinement over {sum(len(p) for p in clean.profiles)} points")
    ref = refine(clean, ts.R, ts.t, ts.centre, noise, opt.fit_radius, opt.estimate_pose_noise,
                     station_effects=opt.station_effects())

    # stray points the circle fits kept: trim on the joint residuals and refit once
    all_res = np.concatenate(ref.residuals)
    scale = max(1.4826 * np.median(np.abs(all_res)), noise.point_noise_mm)
    keep_pts = [np.abs(e) <= opt.point_outlier_k * scale for e in ref.residuals]
    n_point_rejected = sum(int((~f.inliers).sum()) for f in sub_fits.values())
    if any(not k.all() for k in keep_pts):
        n_point_rejected += sum(int((~k).sum()) for k in keep_pts)
        clean = clean.with_profiles([p[k] for p, k in zip(clean.profiles, keep_pts)])
        ref = refine(clean, ref.R, ref.t, ref.centre, noise, opt.fit_radius, opt.estimate_pose_noise,
                     station_effects=opt.station_effects())

    # profiles inconsistent with the rest (a pose read at the wrong moment, a bad pairing)
    max_reject = int(opt.max_rejected_profile_fraction * clean.n_profiles)
    rejected = 0
    while rejected < max_reject:
        chi2 = np.asarray(ref.diagnostics["profile_chi2"])
        worst = int(np.argmax(chi2))
        if chi2[worst] <= opt.profile_outlier_chi2:
            break
        station = clean.station_labels[clean.station_of[worst]]
        shift = float(np.sqrt(chi2[worst] * np.trace(ref.centre_cov[worst]) / 3))
        flags.append(_flag(clean, worst, f"inconsistent with the other profiles (chi2 {chi2[worst]:.1f} on 3 dof, "
                                         f"about {shift:.3f} mm): a pose read at the wrong moment or a bad pairing",
                           station))
        keep = np.ones(clean.n_profiles, dtype=bool)
        keep[worst] = False
        clean = clean.subset(keep)
        rejected += 1
        for k in range(len(clean.station_labels)):
            if np.sum(clean.station_of == k) < opt.min_profiles_per_station:
                raise DegenerateDataError(
                    f"station {clean.station_labels[k]} has fewer than {opt.min_profiles_per_station} consistent "
                    "profiles left after rejecting inconsistent ones: re-acquire it"
                )
        ref = refine(clean, ref.R, ref.t, ref.centre, noise, opt.fit_radius, opt.estimate_pose_noise,
                     station_effects=opt.station_effects())

    result = _result(dataset, clean, ts, ref, flags, n_point_rejected, orientations, noise, opt)
    return Solution(result, clean, ts, ref, fits)


def calibrate(
    dataset: Dataset,
    options: CalibrationOptions | None = None,
    flange_pose_from_joints: Callable[[np.ndarray], Pose] | None = None,
    progress: Callable[[str], None] | None = None,
) -> CalibrationResult:
    """Calibrate ``dataset`` and return the result (see :func:`solve` for the details)."""
    return solve(dataset, options, flange_pose_from_joints, progress).result


def station_consistency(clean: Problem, ts: TwoStepResult, ref: RefineResult) -> dict[str, dict]:
    """Pure-translation consistency: within a station the sphere centre must move in the
    sensor frame by exactly what the robot moved. Compares the centres measured by the
    circle fits (sign resolved) with those the refined transform predicts, both relative
    to the station mean; RMS and max in mm."""
    out = {}
    obs_pos = {int(o): j for j, o in enumerate(clean.obs_index)}
    for st, ch in zip(ts.stations, ts.choice):
        measured, predicted = [], []
        for row, i in enumerate(st.profiles):
            j = obs_pos.get(int(ts_obs_index(ts, i)))
            if j is None:
                continue
            measured.append(st.candidates[ch][row])
            predicted.append(ref.predicted[j])
        if len(measured) < 2:
            continue
        m = np.array(measured)
        p = np.array(predicted)
        dev = np.linalg.norm((m - m.mean(axis=0)) - (p - p.mean(axis=0)), axis=1)
        out[st.label] = {"n_profiles": len(m), "rms_mm": float(np.sqrt(np.mean(dev**2))), "max_mm": float(dev.max())}
    return out


def ts_obs_index(ts: TwoStepResult, i: int) -> int:
    return ts.diagnostics["obs_index"][i]


#: Names of the point-error parts, as the terminal and the report say them.
POINT_ERROR_PARTS = {
    "transform_and_sphere_mm": "the calibration (transform and sphere)",
    "robot_station_to_station_mm": "the robot's systematic error",
    "robot_pose_noise_mm": "the robot's repeatability",
    "sensor_point_noise_mm": "the sensor's point noise",
}


def _robot_error_summary(clean: Problem, ref: RefineResult, noise: NoiseAssumptions, opt) -> RobotErrorSummary:
    budget = point_error_budget(clean, ref, noise)
    parts = budget["parts_rms_mm"]
    se = ref.diagnostics.get("station_effects")
    cov = ref.covariance_robot_frame if ref.covariance_robot_frame is not None else ref.covariance
    sd = np.sqrt(np.maximum(np.diag(cov)[:6], 0.0))
    return RobotErrorSummary(
        model="station" if se else "none",
        station_rotation_deg=float(np.degrees(ref.station_effect_scales[0])),
        station_translation_mm=float(ref.station_effect_scales[1]),
        estimated=bool(se and all(se["estimated"])),
        common_rotation_deg=float(se["common_rotation_deg"]) if se else 0.0,
        common_translation_mm=float(se["common_translation_mm"]) if se else 0.0,
        std_rotation_deg_robot_frame=tuple(np.degrees(sd[:3]).tolist()),
        std_translation_mm_robot_frame=tuple(sd[3:6].tolist()),
        point_error_k2_mm=budget["k2_mm"],
        point_error_parts_rms_mm=parts,
        dominant=max(parts, key=parts.get),
    )


def _result(dataset, clean, ts, ref, flags, n_point_rejected, orientations, noise, opt) -> CalibrationResult:
    cov = ref.covariance * 1.0
    sd = np.sqrt(np.maximum(np.diag(cov), 0.0))
    res = np.concatenate(ref.residuals)
    per_station = {}
    for k, label in enumerate(clean.station_labels):
        e = np.concatenate([ref.residuals[i] for i in np.flatnonzero(clean.station_of == k)])
        per_station[label] = float(np.sqrt(np.mean(e**2)))
    mode = dataset.mounting
    return CalibrationResult(
        robot_error=_robot_error_summary(clean, ref, noise, opt),
        mounting=mode,
        transform_name=TRANSFORM_NAME[mode],
        transform=Pose.from_rt(ref.R, ref.t),
        std_rotation_deg=tuple(np.degrees(sd[:3]).tolist()),
        std_translation_mm=tuple(sd[3:6].tolist()),
        sphere_centre_frame=SPHERE_FRAME[mode],
        sphere_centre_mm=tuple(ref.centre.tolist()),
        std_sphere_centre_mm=tuple(sd[6:9].tolist()),
        sphere_radius_mm=float(ref.radius),
        radius_fitted=opt.fit_radius,
        std_sphere_radius_mm=float(sd[9]) if opt.fit_radius else None,
        covariance=cov.tolist(),
        variance_factor=ref.variance_factor,
        residuals=ResidualStats(
            rms_mm=float(np.sqrt(np.mean(res**2))),
            max_abs_mm=float(np.abs(res).max()),
            p95_abs_mm=float(np.percentile(np.abs(res), 95)),
            n_points_used=int(res.size),
            n_points_rejected=int(n_point_rejected),
            n_profiles_used=clean.n_profiles,
            per_station_rms_mm=per_station,
        ),
        flagged=sorted(flags, key=lambda f: f.index),
        method="two-step (Ren, Yin and Zhu 2012) start, then joint refinement over all points "
        "(generalised least squares with robot pose noise, stray points and inconsistent profiles rejected)",
        two_step_transform=Pose.from_rt(ts.R, ts.t),
        diagnostics={
            "orientations": orientations,
            "two_step": {k: v for k, v in ts.diagnostics.items() if k != "obs_index"},
            "two_step_vs_refined": {
                "rotation_deg": geo.rotation_angle_deg(ts.R, ref.R),
                "translation_mm": float(np.linalg.norm(ts.t - ref.t)),
            },
            "station_consistency": station_consistency(clean, ts, ref),
            "refinement": {
                "iterations": ref.iterations,
                "converged": ref.converged,
                "information_condition_number": ref.diagnostics["information_condition_number"],
                "profile_variance_factor": ref.diagnostics["profile_variance_factor"],
            },
            "noise": {
                "point_noise_mm": noise.point_noise_mm,
                "pose_translation_noise_mm": noise.pose_translation_noise_mm * np.sqrt(ref.pose_noise_scale),
                "pose_rotation_noise_deg": noise.pose_rotation_noise_deg * np.sqrt(ref.pose_noise_scale),
                "pose_noise_estimated": opt.estimate_pose_noise,
            },
        },
        provenance={"dataset": dataset.provenance.get("source", "unknown")},
    )
