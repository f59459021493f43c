"""Two-step starts that fit nearly alike, decided by the joint model.

With coplanar moves in every station the two-step cannot tell, station by station, on
which side of the laser plane the sphere centre lies; its choices are judged by how well
the points fit the sphere through the *nominal* poses. When the robot's own error
dominates those residuals (an uncalibrated arm, before a kinematic calibration), choices
that give rotations a degree or more apart fit nearly alike there. The joint model
(the arm's error modelled, every point used) tells them apart: each start is refined,
and their -2 log-likelihoods are compared at one noise model. Only when the better one
is not decisively better (a likelihood ratio below :data:`DECISIVE_LIKELIHOOD_RATIO`)
is the data refused, saying by how much they differ.
"""

from __future__ import annotations

import math
from typing import Callable

import numpy as np

from spherecal.core import geometry as geo
from spherecal.core.errors import DegenerateDataError
from spherecal.estimation.problem import Problem
from spherecal.estimation.refine import RefineResult
from spherecal.estimation.twostep import TwoStepResult

#: The joint model's better solution is taken when its likelihood is at least this many
#: times the other's (at either solution's noise).
DECISIVE_LIKELIHOOD_RATIO = 1000.0
#: Alternative starts refined at most (the best first; the two-step's rivals are sorted).
MAX_ALTERNATIVES = 3
#: Two refined solutions closer than this (deg) are one answer: both starts led to it.
SAME_SOLUTION_DEG = 0.01


def _distinct(starts: list[TwoStepResult]) -> list[TwoStepResult]:
    """The starts more than 1 deg from every one kept before them."""
    kept: list[TwoStepResult] = []
    for s in starts:
        if all(geo.rotation_angle_deg(s.R, k.R) > 1.0 for k in kept):
            kept.append(s)
    return kept


def settle_alternative_starts(
    problem: Problem, ts: TwoStepResult, refit: Callable[[Problem, TwoStepResult], RefineResult],
    cost: Callable[[RefineResult, float], float], say: Callable[[str], None],
) -> tuple[TwoStepResult, RefineResult]:
    """Refine from the two-step's best start and its ``alternatives`` (at most
    :data:`MAX_ALTERNATIVES` more), and keep the solution the joint model prefers.
    ``cost(ref, scale)`` is a solution's -2 log-likelihood at a pose-noise scale
    (:func:`.refine.cost_at`). The preference must hold at both solutions' noise scales
    by a likelihood ratio of :data:`DECISIVE_LIKELIHOOD_RATIO`; else
    :class:`DegenerateDataError` says how far apart they are and by how much their
    likelihoods differ. Starts that lead to one solution are one answer."""
    starts = _distinct([ts, *ts.alternatives])[:1 + MAX_ALTERNATIVES]
    say(f"{len(starts)} two-step starts fit the points through the nominal poses nearly alike (rotations "
        f"{max(geo.rotation_angle_deg(s.R, ts.R) for s in starts):.1f} deg apart): refining from each")
    solved: list[tuple[TwoStepResult, RefineResult]] = []
    failed = None
    for start in starts:
        try:
            solved.append((start, refit(problem, start)))
        except (np.linalg.LinAlgError, DegenerateDataError) as exc:
            failed = exc
    if not solved:
        raise failed  # every start broke down: the same error as a single start's
    scales = sorted({r.pose_noise_scale for _, r in solved})
    table = np.array([[cost(r, s) for s in scales] for _, r in solved])  # (solution, scale)
    finite = np.all(np.isfinite(table), axis=1)  # a refinement that ran off is no contender
    if finite.any():
        solved, table = [sv for sv, ok in zip(solved, finite) if ok], table[finite]
    order = np.argsort(table[:, 0])
    best = int(order[0])
    R_best = solved[best][1].R
    rivals = [int(k) for k in order[1:] if geo.rotation_angle_deg(solved[int(k)][1].R, R_best) > SAME_SOLUTION_DEG]
    needed = 2.0 * math.log(DECISIVE_LIKELIHOOD_RATIO)
    for k in rivals:
        delta = float(np.min(table[k] - table[best]))  # the weaker of the two noise models' verdicts
        if delta < needed:
            angle = geo.rotation_angle_deg(solved[k][1].R, R_best)
            ratio = math.exp(min(max(delta, 0.0), 700.0) / 2.0)
            raise DegenerateDataError(
                f"two solutions {angle:.2f} deg apart fit the data equally well, also through the joint model: their "
                f"-2 log-likelihoods differ by {max(delta, 0.0):.1f} (a likelihood ratio of {ratio:.3g}:1, under the "
                f"{DECISIVE_LIKELIHOOD_RATIO:g}:1 needed to choose). The moves within each station are coplanar, so "
                "the side of the laser plane the sphere centre is on is not decided station by station; add moves out "
                "of that plane (vary the stand-off and the position along the line during each sweep), or give a "
                "nominal transform to choose between them")
    chosen_ts, chosen = solved[best]
    margin = min((float(np.min(table[k] - table[best])) for k in rivals), default=None)
    chosen_ts.diagnostics["joint_model_choice"] = {
        "starts_refined": len(solved),
        "distinct_solutions": 1 + len(rivals),
        "neg2_log_likelihood_margin": margin,
        "rotation_from_two_step_best_deg": geo.rotation_angle_deg(chosen.R, ts.R),
    }
    if rivals:
        say(f"the joint model prefers one of them by a -2 log-likelihood margin of {margin:.1f} (a likelihood ratio "
            f"above {DECISIVE_LIKELIHOOD_RATIO:g}:1)")
    return chosen_ts, chosen
