"""The estimator's memory and time work (issue 13) changed how the joint refinement
sums its normal equations, not what it estimates: the results of two simulated
datasets with many points a profile (3,200 sensor columns, about 2,300 points a
profile, 40 profiles: 93 k points, strays in a fifth of the profiles), solved by the
code before that work (branch ``scale`` at commit 712ea57, stored in
data/large_profile_results_before_scale.json by :func:`solve_cases`), are reproduced
to 1e-9 (relative, and 1e-12 absolute). A change that is meant to alter the results
regenerates that file on purpose:
``python -c "import tests.core.test_large_profiles_unchanged as t; t.write_reference()"``."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

REFERENCE = Path(__file__).parent / "data" / "large_profile_results_before_scale.json"


def solve_cases() -> dict:
    from spherecal.estimation import CalibrationOptions, solve
    from spherecal.sim import NoiseModel, SensorFieldOfView, SweepPlan, simulate_dataset, standard_cell

    noise = NoiseModel(point_noise_mm=0.01, pose_translation_noise_mm=0.02, pose_rotation_noise_deg=0.002,
                       stray_profile_fraction=0.2, strays_per_profile=20)
    fov = SensorFieldOfView(n_columns=3200)
    out = {}
    for name, mounting, model in (("eye_in_hand-station", "eye_in_hand", "station"),
                                  ("eye_to_hand-none", "eye_to_hand", "none")):
        ds = simulate_dataset(standard_cell(mounting, seed=13, noise=noise, fov=fov), SweepPlan(profiles_per_station=10))
        r = solve(ds, CalibrationOptions(robot_error_model=model)).result
        out[name] = {"transform": [*r.transform.translation_mm, *r.transform.quaternion_wxyz],
                     "sphere_centre_mm": list(r.sphere_centre_mm), "covariance": r.covariance,
                     "variance_factor": r.variance_factor, "rms_mm": r.residuals.rms_mm,
                     "n_points_used": r.residuals.n_points_used, "n_points_rejected": r.residuals.n_points_rejected,
                     "flagged": [f.index for f in r.flagged]}
    return out


def write_reference() -> None:
    REFERENCE.write_text(json.dumps(solve_cases(), indent=1) + "\n")


def test_results_on_many_points_a_profile_are_those_before_the_scale_work():
    before = json.loads(REFERENCE.read_text())
    now = solve_cases()
    assert set(now) == set(before)
    for name in before:
        assert now[name]["n_points_used"] > 80_000, name  # the sets are as large as the docstring says
        for key, value in before[name].items():
            np.testing.assert_allclose(np.asarray(now[name][key], float), np.asarray(value, float), rtol=1e-9,
                                       atol=1e-12, err_msg=f"{name}: {key}")
