"""Planning real motion lives next to acquisition (spherecal.motion.planning), not in the
simulated world: the planner and the kinematic planner import nothing of spherecal.sim,
and the simulated acquisition plans with the very same functions."""

from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest
from reference_sensor import reference_fov


@pytest.mark.parametrize("module", ["spherecal.motion.planning", "spherecal.motion.kinematic_plan"])
def test_the_planners_of_real_motion_load_no_simulated_world(module):
    code = (f"import sys, {module}; "
            "print(sorted(m for m in sys.modules if m == 'spherecal.sim' or m.startswith('spherecal.sim.')))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert out.strip() == "[]"


def test_the_simulated_acquisition_plans_with_the_planner_of_real_motion():
    from spherecal.motion import planning
    from spherecal import sim
    from spherecal.sim import simulate_dataset, standard_cell

    assert sim.SweepPlan is planning.SweepPlan and sim.plan_stations is planning.plan_stations
    cell = standard_cell("eye_in_hand", seed=3, fov=reference_fov())
    plan = planning.SweepPlan(profiles_per_station=5)
    ds = simulate_dataset(cell, plan)
    # the plan leaves its standoff, offsets and wander to the sensor: sized to the cell's field of view
    assert plan.standoff_z_mm is None and cell.fov.standoff_z_mm == -20.0
    assert ds.provenance["plan"] == {**plan.model_dump(), "standoff_z_mm": -20.0, "lateral_amplitude_mm": 4.0,
                                     "station_offsets_mm": [(0.0, 0.0), (10.0, -25.0), (-10.0, 18.0), (0.0, -30.0)]}
    # every shot was taken at a target of the plan (reported with the cell's pose noise, 0.02 mm per axis)
    targets = np.array([p.translation for _, poses in planning.plan_stations(
        cell.mounting, cell.true_transform, cell.sphere_centre_mm, cell.sphere_radius_mm, plan, field_of_view=cell.fov)
        for p in poses])
    for obs in ds.observations:
        assert np.min(np.linalg.norm(targets - np.asarray(obs.base_from_flange.translation), axis=1)) < 0.2
    assert len(ds.observations) > 0.8 * len(targets)


@pytest.mark.parametrize("diameter_mm, share", [(12.7, (0.5, 0.6)), (25.4, (0.85, 1.0))])
def test_the_standoff_is_sized_for_the_sphere_in_a_narrow_line(diameter_mm, share):
    """A profiler with a 25 mm line (22 mm near, 28 mm far, 40 mm range) that declares no
    standoff: a half-inch sphere is swept near (its diameter half the line there, the line
    at its narrowest so that most points fall on the sphere), an inch sphere far, where
    the line is widest (its diameter nearly the line's width); each sphere's section stays
    in the range with the stations' offsets. A declared standoff is kept."""
    from spherecal.core.field_of_view import SensorFieldOfView
    from spherecal.motion.planning import (STATION_OFFSETS_PERCENT, SweepPlan, sphere_standoff_z_mm,
                                           with_standoff)

    fov = SensorFieldOfView(z_near_mm=20.0, z_far_mm=-20.0, width_near_mm=22.0, width_far_mm=28.0, n_columns=1280)
    r = diameter_mm / 2
    z = sphere_standoff_z_mm(fov, r)
    assert share[0] <= diameter_mm / fov.width_at_mm(z) <= share[1], (z, fov.width_at_mm(z))
    plan = with_standoff(SweepPlan(), fov, r)
    assert plan.standoff_z_mm == z
    depth = fov.z_near_mm - fov.z_far_mm
    for _, dz in STATION_OFFSETS_PERCENT:  # each station's section in the range, with the wander
        centre = z + dz * depth / 100
        assert centre - plan.lateral_amplitude_mm >= fov.z_far_mm
        assert centre + r + plan.lateral_amplitude_mm <= fov.z_near_mm
    # the middle of the range is what a sphere of unknown size gets, and a declared standoff holds
    assert sphere_standoff_z_mm(fov) == 0.0
    assert sphere_standoff_z_mm(fov.model_copy(update={"standoff_z_mm": -5.0}), r) == -5.0
