"""Simulated acquisition: the planned stations (:mod:`spherecal.motion.planning`, with the cell's
true transform) measured on a :class:`~spherecal.sim.cell.SimulatedCell`."""

from __future__ import annotations

from datetime import datetime, timedelta, timezone

import numpy as np
from pydantic import BaseModel, ConfigDict, Field

from spherecal.core.models import Circle, Dataset, Observation, Profile
from spherecal.motion.planning import SweepPlan, plan_stations, with_standoff
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
    plan = with_standoff(plan or SweepPlan(), cell.fov)
    stations = plan_stations(
        cell.mounting, cell.true_transform, cell.sphere_centre_mm, cell.sphere_radius_mm, plan, reference_flange_rotation
    )
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
    robot = {}
    if arm is not None:
        e = np.array(flange_errors)
        robot = {"robot_error": arm.error.model_dump(), "flange_error_mm_range": [float(e[:, 0].min()), float(e[:, 0].max())],
                 "flange_error_deg_range": [float(e[:, 1].min()), float(e[:, 1].max())]}
    return Dataset(
        mounting=cell.mounting,
        sphere_radius_mm=cell.sphere_radius_mm,
        observations=obs,
        provenance={**_truth(cell, plan, "spherecal simulator"), "fov": cell.fov.model_dump(), **robot},
    )


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
    plan = with_standoff(plan or SweepPlan(), cell.fov)
    stations = plan_stations(
        cell.mounting, cell.true_transform, cell.sphere_centre_mm, cell.sphere_radius_mm, plan, reference_flange_rotation
    )
    sd_r = centre_noise_mm if radius_noise_mm is None else radius_noise_mm
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
    return Dataset(
        mounting=cell.mounting,
        sphere_radius_mm=r,
        observations=obs,
        provenance={**_truth(cell, plan, "spherecal simulator (centre observations)"),
                    "centre_noise_mm": centre_noise_mm, "radius_noise_mm": sd_r},
    )
