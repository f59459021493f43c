"""Simulated acquisition: the planned stations (:mod:`spherecal.motion.planning`, with the cell's
true transform), or shots each at an orientation of its own (:func:`general_pose_targets`),
measured on a :class:`~spherecal.sim.cell.SimulatedCell`."""

from __future__ import annotations

from datetime import datetime, timedelta, timezone

import numpy as np
from pydantic import BaseModel, ConfigDict, Field

from spherecal.core import geometry as geo
from spherecal.core.models import Circle, Dataset, Observation, Pose, Profile
from spherecal.motion.planning import FLANGE_DOWN, SweepPlan, plan_stations, sphere_standoff_z_mm, with_standoff
from spherecal.sim.cell import SimulatedCell


def _truth(cell: SimulatedCell, plan: SweepPlan, source: str) -> dict:
    """What a simulated dataset's provenance says of the truth behind it."""
    return {
        "source": source,
        "true_transform_name": cell.transform_name,
        "true_transform": cell.true_transform.model_dump(),
        "true_sphere_centre_mm": cell.sphere_centre_mm.tolist(),
        "noise": cell.noise.model_dump(),
        "plan": plan.model_dump(),
    }


def simulate_dataset(
    cell: SimulatedCell,
    plan: SweepPlan | None = None,
    reference_flange_rotation=None,
    min_points: int = 1,
) -> Dataset:
    """Run a simulated acquisition on ``cell`` and return the dataset (reported poses,
    noisy profiles). The truth goes into ``provenance``. Shots that see fewer than
    ``min_points`` points are skipped, as an acquisition would."""
    plan = with_standoff(plan or SweepPlan(), cell.fov, cell.sphere_radius_mm)
    stations = plan_stations(
        cell.mounting, cell.true_transform, cell.sphere_centre_mm, cell.sphere_radius_mm, plan, reference_flange_rotation
    )
    obs, flange_errors = _measure_profiles(cell, stations, min_points)
    return _profile_dataset(cell, obs, flange_errors, {**_truth(cell, plan, "spherecal simulator"),
                                                       "fov": cell.fov.model_dump()})


def _measure_profiles(cell: SimulatedCell, stations, min_points: int) -> tuple[list[Observation], list]:
    """The profiles of flange targets ``stations`` (``[(label, [pose, ...]), ...]``), as
    :func:`simulate_dataset` takes them; and the arm's flange error at each target."""
    t0 = datetime(2026, 1, 1, tzinfo=timezone.utc)
    obs = []
    arm = cell.arm
    joints = None
    flange_errors = []
    for label, poses in stations:
        for pose in poses:
            if arm is not None:  # the controller's nominal IK, the arm's true geometry
                joints = arm.joints_for(pose, joints)
                true_pose, commanded = arm.true_flange_pose(joints), arm.nominal_flange_pose(joints)
                flange_errors.append(arm.flange_error(joints))
            else:
                true_pose = commanded = pose
            cell.move_flange_to(true_pose)
            pts = cell.measure_profile()
            if len(pts) < max(min_points, 1):
                continue
            obs.append(
                Observation(
                    index=len(obs),
                    station=label,
                    timestamp=t0 + timedelta(seconds=2 * len(obs)),
                    base_from_flange=cell.report_pose(commanded),
                    joints_deg=None if joints is None else tuple(float(j) for j in joints),
                    profile=Profile.from_points(pts),
                )
            )
    return obs, flange_errors


def _profile_dataset(cell: SimulatedCell, obs: list[Observation], flange_errors: list, provenance: dict) -> Dataset:
    """A dataset of simulated profiles, with the arm's flange error range in its provenance."""
    arm = cell.arm
    robot = {}
    if arm is not None:
        e = np.array(flange_errors)
        robot = {"robot_error": arm.error.model_dump(), "flange_error_mm_range": [float(e[:, 0].min()), float(e[:, 0].max())],
                 "flange_error_deg_range": [float(e[:, 1].min()), float(e[:, 1].max())]}
    return Dataset(mounting=cell.mounting, sphere_radius_mm=cell.sphere_radius_mm, observations=obs,
                   provenance={**provenance, **robot})


def simulate_centre_dataset(
    cell: SimulatedCell,
    plan: SweepPlan | None = None,
    kind: str = "sphere_centre",
    centre_noise_mm: float = 0.01,
    radius_noise_mm: float | None = None,
    give_covariance: bool = False,
    reference_flange_rotation=None,
    min_points: int = 20,
) -> Dataset:
    """A simulated acquisition with a sensor that fits on board: each shot reports the
    sphere centre in the sensor frame (``kind`` 'sphere_centre') or the circle the laser
    plane cuts from the sphere ('circle': centre (y, z) and radius), from the true
    geometry plus Gaussian noise (``centre_noise_mm`` per axis; the radius'
    ``radius_noise_mm``, default the same). Poses carry the cell's pose noise and, with an
    arm attached, its geometric error and joint readings, as in :func:`simulate_dataset`. With ``give_covariance`` each observation carries its true
    noise (covariance or standard deviations); else the estimator has to estimate it.
    Shots where the line would show fewer than ``min_points`` points of the sphere are
    skipped. The truth goes into ``provenance``."""
    if kind not in ("sphere_centre", "circle"):
        raise ValueError(f"kind must be 'sphere_centre' or 'circle', got {kind!r}")
    plan = with_standoff(plan or SweepPlan(), cell.fov, cell.sphere_radius_mm)
    stations = plan_stations(
        cell.mounting, cell.true_transform, cell.sphere_centre_mm, cell.sphere_radius_mm, plan, reference_flange_rotation
    )
    sd_r = centre_noise_mm if radius_noise_mm is None else radius_noise_mm
    obs = _measure_centres(cell, stations, kind, centre_noise_mm, sd_r, give_covariance, min_points)
    return Dataset(
        mounting=cell.mounting,
        sphere_radius_mm=cell.sphere_radius_mm,
        observations=obs,
        provenance={**_truth(cell, plan, "spherecal simulator (centre observations)"),
                    "centre_noise_mm": centre_noise_mm, "radius_noise_mm": sd_r},
    )


def _measure_centres(cell: SimulatedCell, stations, kind: str, centre_noise_mm: float, sd_r: float,
                     give_covariance: bool, min_points: int) -> list[Observation]:
    """The centre observations of flange targets ``stations`` (``[(label, [pose, ...]),
    ...]``), as :func:`simulate_centre_dataset` takes them (``sd_r``: the radius' noise, mm)."""
    r = cell.sphere_radius_mm
    t0 = datetime(2026, 1, 1, tzinfo=timezone.utc)
    obs = []
    arm, joints = cell.arm, None
    for label, poses in stations:
        for target in poses:
            pose = commanded = target
            if arm is not None:  # as simulate_dataset: the controller's nominal IK, the arm's true geometry
                joints = arm.joints_for(target, joints)
                pose, commanded = arm.true_flange_pose(joints), arm.nominal_flange_pose(joints)
            c = cell.sphere_centre_in_sensor(pose)
            if abs(c[0]) >= r or len(cell.ideal_profile(pose)) < min_points:
                continue
            noisy = c + cell.rng.normal(0.0, centre_noise_mm, 3) if centre_noise_mm > 0 else c
            if kind == "sphere_centre":
                seen = {"sphere_centre_mm": tuple(float(v) for v in noisy)}
                if give_covariance:
                    seen["sphere_centre_covariance_mm2"] = tuple(
                        tuple(float(v) for v in row) for row in np.eye(3) * centre_noise_mm**2)
            else:
                radius = float(np.sqrt(r * r - c[0] ** 2)) + (cell.rng.normal(0.0, sd_r) if sd_r > 0 else 0.0)
                seen = {"circle": Circle(centre_yz_mm=(float(noisy[1]), float(noisy[2])), radius_mm=radius,
                                         centre_std_mm=centre_noise_mm if give_covariance else None,
                                         radius_std_mm=sd_r if give_covariance else None)}
            obs.append(Observation(index=len(obs), station=label, timestamp=t0 + timedelta(seconds=2 * len(obs)),
                                   base_from_flange=cell.report_pose(commanded),
                                   joints_deg=None if joints is None else tuple(float(j) for j in joints), **seen))
    return obs


def general_pose_targets(cell: SimulatedCell, n_shots: int, max_tilt_deg: float = 20.0, max_turn_deg: float = 20.0,
                         seed: int = 0, sweep_fraction: float = 0.8) -> list[tuple[str, list[Pose]]]:
    """True flange targets of ``n_shots`` shots, each at an orientation of its own, as an
    ordinary hand-eye log has them (no pure translations): the reference orientation of
    :func:`~spherecal.motion.planning.plan_stations` tilted by up to ``max_tilt_deg`` about
    a random direction across the view axis and turned by up to ``max_turn_deg`` about
    it (about the sensor's axes eye-in-hand, the base's eye-to-hand), with the sphere
    centre at a random place of the field of view: x within ``sweep_fraction`` of the
    radius of the laser plane, y within a quarter of the line's width, z from 30 % of the
    measuring range below the standoff to 18 % above it. Labelled ``P1``, ``P2``, ...,
    one station each. ``seed`` draws the plan (not the cell's noise)."""
    rng = np.random.default_rng([seed, 0x6E4])
    fov, r, X = cell.fov, cell.sphere_radius_mm, cell.true_transform
    standoff = sphere_standoff_z_mm(fov, r)
    depth = fov.z_near_mm - fov.z_far_mm
    width = fov.width_at_mm(standoff)
    centre = cell.sphere_centre_mm
    out = []
    for k in range(n_shots):
        direction = rng.normal(size=2)
        direction /= np.linalg.norm(direction)
        tilt = max_tilt_deg * np.sqrt(rng.uniform(0.0, 1.0))
        rotvec = np.radians([*(tilt * direction), rng.uniform(-max_turn_deg, max_turn_deg)])
        Rt = geo.matrix_from_rotvec(rotvec)
        c_s = np.array([rng.uniform(-sweep_fraction, sweep_fraction) * r, rng.uniform(-0.25, 0.25) * width,
                        standoff + rng.uniform(-0.30, 0.18) * depth])
        if cell.mounting == "eye_in_hand":
            R_bs = FLANGE_DOWN @ X.rotation_matrix @ Rt
            pose = Pose.from_rt(R_bs, centre - R_bs @ c_s) @ X.inverse()
        else:
            R_bf = Rt @ FLANGE_DOWN
            pose = Pose.from_rt(R_bf, X.apply(c_s) - R_bf @ centre)
        out.append((f"P{k + 1}", [pose]))
    return out


def simulate_general_dataset(
    cell: SimulatedCell,
    n_shots: int = 30,
    kind: str = "profile",
    max_tilt_deg: float = 20.0,
    max_turn_deg: float = 20.0,
    plan_seed: int = 0,
    centre_noise_mm: float = 0.01,
    min_points: int = 20,
) -> Dataset:
    """A simulated hand-eye log: ``n_shots`` shots each at an orientation of its own
    (:func:`general_pose_targets`), each its own station, measured as raw profiles
    (``kind`` 'profile', :func:`simulate_dataset`'s way) or as sphere centres or circles
    (:func:`simulate_centre_dataset`'s, noise ``centre_noise_mm`` per axis). Shots that
    see fewer than ``min_points`` points are skipped. The truth goes into ``provenance``."""
    if kind not in ("profile", "sphere_centre", "circle"):
        raise ValueError(f"kind must be 'profile', 'sphere_centre' or 'circle', got {kind!r}")
    targets = general_pose_targets(cell, n_shots, max_tilt_deg, max_turn_deg, plan_seed)
    truth = {"source": "spherecal simulator (general poses)", "true_transform_name": cell.transform_name,
             "true_transform": cell.true_transform.model_dump(), "true_sphere_centre_mm": cell.sphere_centre_mm.tolist(),
             "noise": cell.noise.model_dump(), "plan": {"general_poses": n_shots, "max_tilt_deg": max_tilt_deg,
                                                        "max_turn_deg": max_turn_deg, "plan_seed": plan_seed}}
    if kind == "profile":
        obs, flange_errors = _measure_profiles(cell, targets, min_points)
        return _profile_dataset(cell, obs, flange_errors, {**truth, "fov": cell.fov.model_dump()})
    obs = _measure_centres(cell, targets, kind, centre_noise_mm, centre_noise_mm, False, min_points)
    return Dataset(mounting=cell.mounting, sphere_radius_mm=cell.sphere_radius_mm, observations=obs,
                   provenance={**truth, "centre_noise_mm": centre_noise_mm, "radius_noise_mm": centre_noise_mm})
