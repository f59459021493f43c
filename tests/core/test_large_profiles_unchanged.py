"""The estimator's memory and time work (issue 13) changed how the joint refinement
builds and sums its normal equations, not what it estimates (the pose-noise-only case,
above 65,536 points, sums them a block of profiles at a time): the results of two simulated
datasets with many points a profile (3,200 sensor columns, about 2,300 points a
profile, 40 profiles: 93 k points, strays in a fifth of the profiles), solved by the
code before that work (branch ``scale`` at commit 712ea57, stored in
data/large_profile_results_before_scale.json by :func:`solve_cases`), are reproduced
to 1e-9 (relative, and 1e-12 absolute). The station-model case was regenerated when the
REML search of the station scales got exact gradients (issue 14; it moved by at most
2e-7 relative, the finite-difference search's own precision): before that, its results
were reproducible to only about 1e-7, and no reordering of the sums could meet 1e-9. A change that is meant to alter the results
regenerates that file on purpose:
``python -c "import tests.core.test_large_profiles_unchanged as t; t.write_reference()"``."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
from reference_sensor import reference_fov

REFERENCE = Path(__file__).parent / "data" / "large_profile_results_before_scale.json"


def solve_cases() -> dict:
    from spherecal.estimation import CalibrationOptions, solve
    from spherecal.sim import NoiseModel, SweepPlan, simulate_dataset, standard_cell

    noise = NoiseModel(point_noise_mm=0.01, pose_translation_noise_mm=0.02, pose_rotation_noise_deg=0.002,
                       stray_profile_fraction=0.2, strays_per_profile=20)
    fov = reference_fov(n_columns=3200)
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


def test_normal_equations_summed_by_blocks_of_profiles_equal_the_whole():
    """The per-block sum (whitening is per profile) gives Jw^T Jw and -Jw^T ew of the
    whole stacked problem, to rounding, whatever the block size."""
    from spherecal.estimation import refine as rf
    from spherecal.estimation.problem import build_problem
    from spherecal.sim import SweepPlan, simulate_dataset, standard_cell

    cell = standard_cell("eye_to_hand", seed=4, fov=reference_fov())
    problem = build_problem(simulate_dataset(cell, SweepPlan(profiles_per_station=5)), None, None)
    pts = rf._Points(problem)
    X = cell.true_transform
    lin = rf._linearise(problem, pts, X.rotation_matrix, np.asarray(X.translation_mm) + 0.3, cell.sphere_centre_mm,
                        problem.radius_mm, True, rf._pose_cov(rf.NoiseAssumptions(0.01, 0.02, 0.005)), 0.01)
    ew = lin.W.apply(lin.res)
    Jw = lin.W.apply(lin.J)
    whole_A, whole_b = Jw.T @ Jw, Jw.T @ -ew
    for limit in (1, 700, 5_000, 10**9):
        chunks = rf._profile_chunks(pts.counts, limit)
        # consecutive, covering every profile once, within the limit unless one profile exceeds it
        assert chunks[0][0] == 0 and chunks[-1][1] == problem.n_profiles
        assert all(a[1] == b[0] for a, b in zip(chunks, chunks[1:]))
        assert all(pts.counts[lo:hi].sum() <= limit or hi - lo == 1 for lo, hi in chunks)
        A, b = rf._chunked_normal_equations(lin, pts, ew, chunks)
        np.testing.assert_allclose(A, whole_A, rtol=1e-12, atol=1e-12 * np.abs(whole_A).max())
        np.testing.assert_allclose(b, whole_b, rtol=1e-10, atol=1e-12 * np.abs(whole_b).max())
    assert len(rf._profile_chunks(pts.counts, 1)) == problem.n_profiles
