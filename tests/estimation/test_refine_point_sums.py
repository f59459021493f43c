"""The refinement's per-point work (:func:`spherecal.estimation.refine.linearisation._point_sums`), done
a block of whole profiles at a time, gives every residual and every profile's nine sums
as a profile-by-profile computation does, whatever the blocks: one point a block, blocks
that end on an empty profile, a profile longer than a block."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest
from reference_sensor import reference_fov

from spherecal.estimation.refine import linearisation as rf
from spherecal.estimation.problem import KIND_PROFILE, KIND_SPHERE_CENTRE


def _problem(counts, centre_at=()):
    rng = np.random.default_rng(sum(counts))
    profiles = [rng.normal(size=(k, 2)) * 5.0 for k in counts]
    kinds = np.full(len(counts), KIND_PROFILE)
    for i in centre_at:
        profiles[i] = np.zeros((0, 2))
        kinds[i] = KIND_SPHERE_CENTRE
    return SimpleNamespace(profiles=profiles, kinds=kinds)


def _expected(problem, C, rho):
    res, sums = [], []
    for i in np.flatnonzero(problem.kinds == KIND_PROFILE):
        p = problem.profiles[i]
        d = p - C[i, 1:]
        dist = np.hypot(d[:, 0], d[:, 1])
        r = dist - rho[i]
        u1, u2 = d[:, 0] / dist, d[:, 1] / dist
        res.append(r)
        sums.append([u1.sum(), u2.sum(), r.sum(), u1 @ u1, u1 @ u2, u2 @ u2, u1 @ r, u2 @ r, r @ r])
    return np.concatenate(res), np.array(sums).T


@pytest.mark.parametrize("block", [1, 7, 50, 10_000])
def test_point_sums_do_not_depend_on_the_blocks(monkeypatch, block):
    monkeypatch.setattr(rf, "BLOCK_POINTS", block)
    counts = [12, 0, 30, 5, 0, 0, 61, 3, 0]  # empty profiles inside and at the end of blocks
    problem = _problem(counts, centre_at=(4,))
    pts = rf._Points(problem)
    assert len(pts.blocks) >= (2 if block < 100 else 1)
    rng = np.random.default_rng(1)
    C = rng.normal(size=(len(counts), 3))
    rho = rng.uniform(5.0, 10.0, len(counts))
    res, sums = rf._point_sums(pts, C, rho)
    res_e, sums_e = _expected(problem, C, rho)
    np.testing.assert_allclose(res, res_e, rtol=1e-13, atol=1e-13)
    np.testing.assert_allclose(sums, sums_e, rtol=1e-12, atol=1e-11)
    assert pts.M == sum(counts)
    # the blocks cover every profile once, in order, none above the block size unless one profile is
    covered = [i for p0, p1, *_ in pts.blocks for i in range(p0, p1)]
    assert covered == list(range(len(pts.shots)))
    for p0, p1, a, b, _, _ in pts.blocks:
        assert b - a <= block or p1 - p0 == 1


def test_a_linearisation_at_the_same_centres_reuses_the_point_sums_and_gives_the_same_problem():
    """Another pose-noise scale at the same point: the per-point sums are reused (the
    cached arrays themselves) and the reduced problem equals one built afresh."""
    from spherecal.estimation.problem import build_problem
    from spherecal.sim import SweepPlan, simulate_dataset, standard_cell

    cell = standard_cell("eye_in_hand", seed=2, fov=reference_fov())
    problem = build_problem(simulate_dataset(cell, SweepPlan(profiles_per_station=4)), None, None)
    X = cell.true_transform
    R, t, c = X.rotation_matrix, np.asarray(X.translation_mm) + 0.2, np.asarray(cell.sphere_centre_mm)
    pose_cov = rf._pose_cov(rf.NoiseAssumptions(0.01, 0.02, 0.005))
    pts = rf._Points(problem)
    first = rf._linearise(problem, pts, R, t, c, problem.radius_mm, False, pose_cov, 0.01)
    again = rf._linearise(problem, pts, R, t, c, problem.radius_mm, False, 3.0 * pose_cov, 0.01)
    assert again.res is first.res  # reused, not recomputed
    fresh = rf._linearise(problem, rf._Points(problem), R, t, c, problem.radius_mm, False, 3.0 * pose_cov, 0.01)
    np.testing.assert_array_equal(again.red.W, fresh.red.W)
    np.testing.assert_array_equal(again.red.chi2, fresh.red.chi2)
    assert not np.array_equal(again.red.W, first.red.W)  # the scale did change the weights
    moved = rf._linearise(problem, pts, R, t + 0.01, c, problem.radius_mm, False, pose_cov, 0.01)
    assert moved.res is not first.res and not np.array_equal(moved.res, first.res)
