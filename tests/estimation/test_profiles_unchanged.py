"""Profile-only calibrations are unaffected by centre observations: the results of a few
simulated profile datasets, stored in data/profile_results_reference.json by
:func:`solve_cases`, are reproduced to 1e-9 relative (covariances: relative to their
largest element). Not bit for bit: the rotation conversions and the normal equations
reduced to each shot move the last bits (1e-12). The station model's REML search has
exact derivatives (a finite-difference search is precise to only about 2e-7), and the
kinematic model's covariance is not a difference of large terms (that formula loses
seven digits: the same shots in reverse order move it by 1.1e-7), so both reproduce
well within 1e-9. A change that is meant to alter profile results rewrites that file
on purpose, and says in its commit by how much each case moved:
``PYTHONPATH=tests:tests/estimation python -c "import test_profiles_unchanged as t; t.write_reference()"``."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from reference_sensor import reference_fov

REFERENCE = Path(__file__).parent / "data" / "profile_results_reference.json"


def solve_cases() -> dict:
    from spherecal.estimation import CalibrationOptions, solve
    from spherecal.plugins.host import PluginHost
    from spherecal.sim import NoiseModel, RobotErrorModel, SweepPlan, simulate_dataset, standard_cell

    noise = NoiseModel(point_noise_mm=0.01, pose_translation_noise_mm=0.02, pose_rotation_noise_deg=0.002,
                       stray_profile_fraction=0.2)
    kin = PluginHost().arm_kinematics({"type": "abb_irb2400"})
    cases = {
        "eye_in_hand-station": (standard_cell("eye_in_hand", seed=5, noise=noise, fov=reference_fov()),
                                "station", None),
        "eye_to_hand-none": (standard_cell("eye_to_hand", seed=5, noise=noise, fov=reference_fov()), "none", None),
        "eye_in_hand-auto-exact-arm": (standard_cell("eye_in_hand", seed=6, noise=noise, arm=kin,
                                                     fov=reference_fov()), "auto", kin),
        "eye_in_hand-kinematic": (standard_cell("eye_in_hand", seed=6, noise=noise, robot_error=RobotErrorModel(),
                                                arm=kin, fov=reference_fov()), "kinematic", kin),
    }
    out = {}
    for name, (cell, model, kinematics) in cases.items():
        ds = simulate_dataset(cell, SweepPlan(profiles_per_station=4 if model == "kinematic" else 6))
        r = solve(ds, CalibrationOptions(robot_error_model=model), kinematics=kinematics).result
        out[name] = {"transform": [*r.transform.translation_mm, *r.transform.quaternion_wxyz],
                     "sphere_centre_mm": list(r.sphere_centre_mm), "covariance": r.covariance,
                     "variance_factor": r.variance_factor, "rms_mm": r.residuals.rms_mm,
                     "n_points_used": r.residuals.n_points_used, "flagged": [f.index for f in r.flagged]}
    return out


def write_reference() -> None:
    REFERENCE.write_text(json.dumps(solve_cases(), indent=1) + "\n")


@pytest.mark.slow
def test_profile_only_results_are_the_reference_results():
    expected = json.loads(REFERENCE.read_text())
    got = solve_cases()
    assert set(got) == set(expected)
    for name in expected:
        for key, value in expected[name].items():
            value = np.asarray(value, float)
            atol = 1e-9 * np.abs(value).max() if key == "covariance" else 1e-12
            np.testing.assert_allclose(np.asarray(got[name][key], float), value, rtol=1e-9, atol=atol,
                                       err_msg=f"{name}: {key}")
