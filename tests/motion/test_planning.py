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
