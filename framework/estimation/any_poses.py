"""The solve's start when the rows are not stations of pure translations: each row at an
orientation of its own (an ordinary hand-eye log), rows of several orientations under one
label, or too few rows at each orientation for the two-step.

Each row's sphere centre in the sensor frame (given, or a circle's with its side of the
laser plane decided) goes into the closed-form start of :mod:`.linear_start`, rows grossly
inconsistent with the others left out first; the joint fit follows as for station data.
For the station robot error model the rows are grouped by orientation
(:func:`orientation_stations`); when no two rows share one, the model that fits the data
is taken (:func:`robot_error_without_stations`) and the result says so.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from spherecal.core import geometry as geo
from spherecal.core.errors import DegenerateDataError
from spherecal.core.models import ObservationFlag
from spherecal.estimation.circle import half_chord_depth
from spherecal.estimation.linear_start import (
    MIN_ROWS, SIDES_DECISIVE_CHI2, LinearStart, centres_start, side_free_sides, sides_and_offset,
)
from spherecal.estimation.problem import KIND_PROFILE, Problem, orientation_groups
from spherecal.estimation.refine import RefineResult
from spherecal.estimation.robust import median
from spherecal.estimation.screening import RejectionBudget, flag_shot
from spherecal.estimation.starts import SAME_SOLUTION_DEG
from spherecal.estimation.twostep import CentreShot, TwoStepResult

#: A row whose residual in the linear start is more than this many robust SDs of the
#: rows' (and more than :data:`GROSS_ROW_MM`) is left out before the joint fit, worst first.
GROSS_ROW_SDS = 20.0
GROSS_ROW_MM = 1.0
#: Floor of that robust scale, mm.
MIN_ROW_SCALE_MM = 0.002
#: Median of the chi distribution with 3 degrees of freedom.
_CHI3_MEDIAN = 1.5382
#: Rounds of deciding the sides of the laser plane from a start and solving again.
SIDE_ROUNDS = 6


def sensor_centres(problem: Problem, fits: dict) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Each row's sphere centre in the sensor frame (n, 3) mm, with x = +|x| where the
    side of the laser plane is not known; |x| (n,); and whether the side is known (a
    sphere centre row). ``fits``: a circle fit or :class:`.twostep.CentreShot` per row."""
    n = problem.n_profiles
    C = np.zeros((n, 3))
    known = np.zeros(n, dtype=bool)
    for i in range(n):
        f = fits[i]
        x = getattr(f, "x_mm", None)
        if x is not None:
            C[i] = [x, *f.centre_yz]
            known[i] = True
        else:
            C[i] = [half_chord_depth(problem.radius_mm, f.radius), *f.centre_yz]
    return C, np.abs(C[:, 0]), known


def sides_from(problem: Problem, C: np.ndarray, depth: np.ndarray, known: np.ndarray, R, t, centre) -> np.ndarray:
    """``C`` with the side of the laser plane of each row not ``known`` taken from where
    the transform (R, t) and sphere ``centre`` put the sphere centre in the sensor frame."""
    R_A, t_A = problem.R_sphere_from_mount, problem.t_sphere_from_mount
    predicted = (np.einsum("nji,nj->ni", R_A, np.asarray(centre, float) - t_A) - t) @ R
    out = C.copy()
    out[~known, 0] = np.where(predicted[~known, 0] >= 0.0, 1.0, -1.0) * depth[~known]
    return out


def sides_from_nominal(problem: Problem, C: np.ndarray, depth: np.ndarray, known: np.ndarray, R, t) -> np.ndarray:
    """``C`` with the sides decided from a rough transform (R, t) alone: each row's two
    candidate centres mapped into the sphere frame through it; the sphere centre is where
    the candidates gather (from the median of the rows' midpoints, each row then taking
    its nearer candidate, until that settles)."""
    R_A, t_A = problem.R_sphere_from_mount, problem.t_sphere_from_mount
    plus, minus = C.copy(), C.copy()
    minus[~known, 0] = -depth[~known]
    plus[~known, 0] = depth[~known]
    P = np.einsum("nij,nj->ni", R_A, plus @ R.T + t) + t_A
    M = np.einsum("nij,nj->ni", R_A, minus @ R.T + t) + t_A
    centre = median((P + M) / 2.0, axis=0)
    take_plus = None
    for _ in range(20):
        choice = np.linalg.norm(P - centre, axis=1) <= np.linalg.norm(M - centre, axis=1)
        if take_plus is not None and np.array_equal(choice, take_plus):
            break
        take_plus = choice
        centre = median(np.where(take_plus[:, None], P, M), axis=0)
    return np.where(take_plus[:, None], plus, minus)


def _without_gross_rows(problem: Problem, C: np.ndarray, flags: list[ObservationFlag], budget: RejectionBudget,
                        keep: np.ndarray) -> LinearStart:
    """The linear start of the rows ``keep`` (updated in place), the rows grossly
    inconsistent with the others left out worst first and flagged, within the budget."""
    while True:
        rows = np.flatnonzero(keep)
        start = centres_start(problem.R_sphere_from_mount[rows], problem.t_sphere_from_mount[rows], C[rows])
        err = start.row_error_mm
        scale = max(float(median(err)) / _CHI3_MEDIAN, MIN_ROW_SCALE_MM)
        worst = int(np.argmax(err))
        if (budget.rejected >= budget.max_reject or len(rows) <= MIN_ROWS or err[worst] <= GROSS_ROW_MM
                or err[worst] <= GROSS_ROW_SDS * scale):
            return start
        i = int(rows[worst])
        kind = "profiles" if problem.kinds[i] == KIND_PROFILE else "observations"
        flags.append(flag_shot(problem, i, f"inconsistent with the other {kind}: its sphere centre is "
                                           f"{err[worst]:.3f} mm off where the start from any orientations puts it "
                                           f"({err[worst] / scale:.0f} robust SDs of {scale:.3f} mm): a typo in the "
                                           "row (a sign, metres for millimetres), a pose read at the wrong moment or "
                                           "a mis-paired shot"))
        keep[i] = False
        budget.rejected += 1


def linear_start_of_rows(problem: Problem, fits: dict, flags: list[ObservationFlag], budget: RejectionBudget,
                         nominal=None) -> tuple[LinearStart, np.ndarray]:
    """The start from any orientations of the rows of ``problem`` (every row in
    ``fits``), and the rows it kept. Rows whose side of the laser plane is not known (a
    circle, a profile) take it from the ``nominal`` transform (a :class:`Pose`), else from
    the circles alone (:func:`.linear_start.side_free_sides`, which refuses when the rows
    do not decide it), then from each start in turn until the sides settle."""
    C, depth, known = sensor_centres(problem, fits)
    undecided = ~known & (depth > 0)
    side_figures = {}
    if undecided.any() and nominal is not None:
        C = sides_from_nominal(problem, C, depth, known, nominal.rotation_matrix, nominal.translation)
    elif undecided.any():
        x, side_figures = side_free_sides(problem.R_sphere_from_mount, problem.t_sphere_from_mount, C[:, 1:], depth)
        C[~known, 0] = x[~known]
    keep = np.ones(problem.n_profiles, dtype=bool)
    rounds = SIDE_ROUNDS if undecided.any() else 0
    # the sides first, from every row (a row on the wrong side would pass for a gross one),
    # then the gross rows left out, then the sides again from what is left
    for _ in range(rounds):
        start = centres_start(problem.R_sphere_from_mount, problem.t_sphere_from_mount, C)
        C, settled = _resided(problem, C, depth, known, start)
        if settled:
            break
    start = _without_gross_rows(problem, C, flags, budget, keep)
    for _ in range(rounds):
        C, settled = _resided(problem, C, depth, known, start)
        if settled:
            break
        start = _without_gross_rows(problem, C, flags, budget, keep)
    start.diagnostics["sides_decided"] = int(undecided.sum())
    if undecided.any():
        start.diagnostics["sides_from"] = "nominal" if nominal is not None else "circles alone"
        start.diagnostics.update(side_figures)
        if known[keep].any():
            return start, keep  # a sphere centre's known side fixes the others'
        start.diagnostics["twin"] = _twin_check(problem, start, depth, keep, nominal)
    return start, keep


#: A nominal transform tells apart two solutions that differ by a move along the laser
#: plane's normal when it lies within this share of their distance of the one kept.
NOMINAL_TWIN_SHARE = 0.25


def _twin_check(problem: Problem, start: LinearStart, depth: np.ndarray, keep: np.ndarray, nominal) -> dict:
    """Whether another choice of the sides fits the circles alike: the same rotation with
    the translation moved along the laser plane's normal (the sphere at about one distance
    from the laser plane in every row). Refuses unless the ``nominal`` transform lies
    within :data:`NOMINAL_TWIN_SHARE` of their distance of the one kept."""
    R_A, t_A = problem.R_sphere_from_mount[keep], problem.t_sphere_from_mount[keep]
    p = (np.einsum("nji,nj->ni", R_A, start.centre - t_A) - start.t) @ start.R[:, 0]  # predicted x
    _, _, figures = sides_and_offset(p, depth[keep])
    if figures["margin_chi2"] >= SIDES_DECISIVE_CHI2:
        return {"margin_chi2": figures["margin_chi2"]}
    apart = figures["other_offset_mm"] - figures["offset_mm"]
    todo = ("add rows with the sphere at other distances on both sides of the laser plane, or give sphere centres "
            "instead of circles")
    if nominal is None:
        raise DegenerateDataError(
            f"two choices of the sides of the laser plane fit the circles alike, the translation {abs(apart):.2f} mm "
            f"apart along the laser plane's normal: give a nominal transform, or {todo}")
    along = float((nominal.translation - start.t) @ start.R[:, 0]) - figures["offset_mm"]
    if abs(along) > NOMINAL_TWIN_SHARE * abs(apart):
        raise DegenerateDataError(
            f"two choices of the sides of the laser plane fit the circles alike, the translation {abs(apart):.2f} mm "
            f"apart along the laser plane's normal (the sphere at about one distance from the laser plane in every "
            f"row), and the nominal transform lies {abs(along):.2f} and {abs(along - apart):.2f} mm from them along "
            f"it: too far to tell (within {NOMINAL_TWIN_SHARE * abs(apart):.2f} mm of one is needed); {todo}")
    return {"margin_chi2": figures["margin_chi2"], "apart_mm": abs(apart), "nominal_from_kept_mm": abs(along)}


def _resided(problem: Problem, C: np.ndarray, depth: np.ndarray, known: np.ndarray, start: LinearStart):
    """``C`` with the sides of the laser plane from ``start``, and whether none changed."""
    C_new = sides_from(problem, C, depth, known, start.R, start.t, start.centre)
    return C_new, bool(np.array_equal(np.sign(C_new[:, 0]), np.sign(C[:, 0])))


def orientation_stations(problem: Problem, tolerance_deg: float) -> tuple[Problem, dict[str, int], int]:
    """``problem`` with its stations regrouped by orientation: the rows of one label
    within ``tolerance_deg`` of their group's mean orientation form a station (a label
    holding several orientations is split: ``S1``, ``S1/2``, ...); the labels split, with
    how many orientations each held; and the size of the largest group."""
    labels: list[str] = []
    station_of = np.empty(problem.n_profiles, dtype=int)
    split: dict[str, int] = {}
    largest = 0
    for k, label in enumerate(problem.station_labels):
        idx = np.flatnonzero(problem.station_of == k)
        groups = orientation_groups(problem.R0[idx], tolerance_deg) if len(idx) else []
        if len(groups) > 1:
            split[label] = len(groups)
        for j, members in enumerate(groups):
            labels.append(label if j == 0 else f"{label}/{j + 1}")
            station_of[idx[members]] = len(labels) - 1
            largest = max(largest, len(members))
    return replace(problem, station_of=station_of, station_labels=labels), split, largest


def stations_of_single_rows(problem: Problem, tolerance_deg: float) -> tuple[Problem, str | None]:
    """A table whose every label holds one row carries no stations: its rows at one
    orientation (within ``tolerance_deg`` of their group's mean) are taken as one station,
    labelled by its first row's label, so that the two-step and the station robot error
    model see the stations the robot made. Returns the problem (unchanged when a label
    holds two rows or no two rows share an orientation) and what was done, to say."""
    n = problem.n_profiles
    if n < 2 or len(problem.station_labels) != n:
        return problem, None
    groups = [np.sort(g) for g in orientation_groups(problem.R0, tolerance_deg)]
    if max(len(g) for g in groups) < 2:
        return problem, None
    groups.sort(key=lambda g: g[0])
    station_of = np.empty(n, dtype=int)
    labels = []
    for k, members in enumerate(groups):
        station_of[members] = k
        labels.append(problem.station_labels[problem.station_of[members[0]]])
    joined = [f"{labels[k]} ({len(g)} rows)" for k, g in enumerate(groups) if len(g) > 1]
    note = (f"every label holds one row: the rows at one orientation (within {tolerance_deg:.3g} deg) were taken as "
            f"one station each, labelled by their first row: {', '.join(joined[:8])}"
            + (f" and {len(joined) - 8} more" if len(joined) > 8 else ""))
    return replace(problem, station_of=station_of, station_labels=labels), note


def robot_error_without_stations(model: str, kinematic_known: bool) -> tuple[str, bool]:
    """What the solve says when no two rows share an orientation and the robot error
    ``model`` asks for station offsets, and whether it takes the kinematic model instead
    (``kinematic_known``: the joints and the robot's kinematics are there): the station
    model needs shots that share an orientation, so the model that fits the data is taken."""
    if model == "kinematic+station":
        return ("robot_error_model 'kinematic+station': no two rows share an orientation, so there are no station "
                "offsets to estimate: the kinematic model alone was used", True)
    if kinematic_known:
        return (f"robot_error_model {model!r}: the station model needs shots that share an orientation and no two "
                "rows do: the kinematic model (the arm's geometric error, from the joints) was used", True)
    return (f"robot_error_model {model!r}: the station model needs shots that share an orientation and no two rows "
            "do: the robot's error at each row was taken as pose noise ('none', its size estimated from the "
            "residuals), and its error shared by every row (its stated accuracy, robot_accuracy_mm and "
            "robot_accuracy_deg) is in the uncertainty as the station model puts it; record joints with the poses "
            "for the kinematic model", False)


def as_start(start: LinearStart) -> TwoStepResult:
    """The linear start in the place of a two-step result (no stations, no side choices)."""
    return TwoStepResult(start.R, start.t, start.centre, [], (), {"start": "linear", **start.diagnostics})


def compare_starts(two_step_R, two_step_t, linear: LinearStart, refined_R, refined_t, cov6: np.ndarray) -> dict:
    """How the two starts compare: each one's distance from the refined transform (deg,
    mm), the linear start's from the two-step's, and the linear start's chi^2 (6 dof)
    against the refined covariance (rotation about the target frame's axes, then
    translation)."""
    w = geo.rotvec_from_matrix(linear.R @ np.asarray(refined_R).T)
    e = np.concatenate([w, linear.t - refined_t])
    try:
        chi2 = float(e @ np.linalg.solve(cov6, e))
    except np.linalg.LinAlgError:
        chi2 = float("inf")
    return {
        "linear_vs_two_step": {"rotation_deg": geo.rotation_angle_deg(linear.R, two_step_R),
                               "translation_mm": float(np.linalg.norm(linear.t - two_step_t))},
        "linear_vs_refined": {"rotation_deg": geo.rotation_angle_deg(linear.R, refined_R),
                              "translation_mm": float(np.linalg.norm(linear.t - refined_t)), "chi2_6dof": chi2},
        "linear_rows": linear.diagnostics["rows"],
    }


def linear_start_beside(sub: Problem, ts: TwoStepResult, opt):
    """The start from any orientations of the rows the two-step used, with the sides of
    the laser plane it decided (a recording: none, its profiles are thousands); None
    where it does not apply (too few rows, orientations about one axis)."""
    if sub.t_sensor_s is not None or not ts.stations:
        return None
    C = np.full((sub.n_profiles, 3), np.nan)
    for st, ch in zip(ts.stations, ts.choice):
        C[st.profiles] = st.candidates[ch]
    if np.isnan(C).any():
        return None
    fits = {i: CentreShot(C[i, 1:], 0.0, float(C[i, 0])) for i in range(sub.n_profiles)}
    try:
        return linear_start_of_rows(sub, fits, [], RejectionBudget(int(opt.max_rejected_profile_fraction
                                                                       * sub.n_profiles)))[0]
    except DegenerateDataError:
        return None


def beside_the_linear_start(clean: Problem, ts: TwoStepResult, ref: RefineResult, linear, refit, cost, say):
    """Station data: the two-step's result (``ref``) beside the start from any orientations
    (``linear``). When the linear start lies beyond the result's stated uncertainty
    (chi^2 on 6 dof above :data:`STARTS_AGREE_CHI2`), the fit is refined from it too and
    the solution that fits better (lower -2 log-likelihood at both solutions' noise) is
    kept. Returns the solution kept and the comparison's figures."""
    compared = compare_starts(ts.R, ts.t, linear, ref.R, ref.t, ref.covariance[:6, :6])
    chi2 = compared["linear_vs_refined"]["chi2_6dof"]
    compared["agree"] = bool(chi2 <= STARTS_AGREE_CHI2)
    if compared["agree"]:
        return ref, compared
    say(f"the start from any orientations lies {compared['linear_vs_refined']['rotation_deg']:.3f} deg and "
        f"{compared['linear_vs_refined']['translation_mm']:.3f} mm from the result of the two-step's (chi2 "
        f"{chi2:.1f} on 6 dof): refining from it too")
    try:
        other = refit(clean, linear)
    except (np.linalg.LinAlgError, DegenerateDataError) as exc:
        compared["refined_from_linear"] = f"broke down ({exc})"
        return ref, compared
    apart = geo.rotation_angle_deg(other.R, ref.R)
    compared["refined_from_linear"] = {"rotation_deg": apart, "translation_mm": float(np.linalg.norm(other.t - ref.t))}
    scales = sorted({ref.pose_noise_scale, other.pose_noise_scale})
    better = apart > SAME_SOLUTION_DEG and all(cost(other, s) < cost(ref, s) for s in scales)
    compared["chosen"] = "linear" if better else "two-step"
    if better:
        say("the solution from the start from any orientations fits better: it is kept")
        return other, compared
    return ref, compared


def start_diagnostics(ts: TwoStepResult, ref: RefineResult, compared: dict | None) -> dict:
    """``result.diagnostics.start``: which start the joint fit began from, its figures
    and, for the linear start, how far it lies from the result; for the two-step, its
    comparison with the linear start where both applied."""
    if ts.diagnostics.get("start") == "linear":
        figures = {k: v for k, v in ts.diagnostics.items() if k != "start"}
        return {"method": "linear", **figures, "vs_refined": {
            "rotation_deg": geo.rotation_angle_deg(ts.R, ref.R), "translation_mm": float(np.linalg.norm(ts.t - ref.t))}}
    return {"method": "two-step", **({"linear": compared} if compared is not None else {})}


#: The two starts agree when the linear start lies within this chi^2 (6 dof) of the
#: result under its stated covariance: exceeded with probability 1e-4 by chance.
STARTS_AGREE_CHI2 = 27.86
