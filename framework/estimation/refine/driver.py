"""The refinement itself: Gauss-Newton passes, the variance components between them, the result."""

from __future__ import annotations

import time
from dataclasses import dataclass, field, replace
from typing import Callable

import numpy as np

from spherecal.core import geometry as geo
from spherecal.core.kinematics import error_parameter_names, flange_error_jacobian
from spherecal.estimation.problem import Problem
from spherecal.estimation.refine.covariance import covariances_at_solution
from spherecal.estimation.refine.crossval import station_cross_validation
from spherecal.estimation.refine.effects import KinematicEffects, StationEffects, _effect_blocks
from spherecal.estimation.refine.linearisation import NoiseAssumptions, _centre_variance
from spherecal.estimation.refine.reml import KINEMATIC_EVIDENCE_LR, search_scales
from spherecal.estimation.refine.state import RefineState
from spherecal.estimation.refine.timing import TimeEffects, time_design, with_start


@dataclass
class RefineResult:
    """What :func:`refine` finds: the estimate, its covariances, residuals and diagnostics."""

    R: np.ndarray
    t: np.ndarray
    centre: np.ndarray
    radius: float
    covariance: np.ndarray  # (w, t, c[, r]); w in rad about target axes
    residuals: list[np.ndarray]  # per profile, per point, mm
    predicted: np.ndarray  # (n, 3) sphere centres in the sensor frame
    centre_cov: np.ndarray  # (n, 3, 3) covariance of predicted centres from pose noise
    iterations: int
    converged: bool
    variance_factor: float
    pose_noise_scale: float
    diagnostics: dict = field(default_factory=dict)
    covariance_without_robot_error: np.ndarray | None = None  # as if the station offsets were known
    covariance_robot_frame: np.ndarray | None = None  # without the robot's common error (relative to its frame)
    # the station model: covariance_robot_frame at the estimated station scales, before it
    # is averaged over their posterior; the point-error budget's transform share, which it
    # pairs with its station-to-station share at those same scales
    covariance_robot_frame_at_scales: np.ndarray | None = None
    station_offsets: np.ndarray | None = None  # (K, 6) estimated (omega rad, tau mm) per station
    station_effect_scales: tuple[float, float] = (0.0, 0.0)  # station-to-station s_rot (rad), s_trans (mm)
    kinematic_errors: np.ndarray | None = None  # (6 n,) estimated geometric errors (rad, mm)
    kinematic_sd: np.ndarray | None = None  # (6 n,) their standard deviations
    # the marginalised kinematic parameters' effect on the result, for the point-error budget:
    # design (n, 6, q) at each shot, influence (P, q) of their true values on the estimate,
    # prior covariance (q, q), posterior mean (q,) and covariance (q, q)
    kinematic_terms: dict | None = None
    # centre observations: residual of each shot (n, 3), mm (NaN rows for profiles), and the
    # per-axis standard deviation estimated for those given without a covariance (mm)
    centre_residuals: np.ndarray | None = None
    centre_noise_mm: float | None = None
    # a kinematic calibration: each station predicted by the fit of the others
    # (:func:`.crossval.station_cross_validation`), else None
    station_prediction: dict | None = None
    # a recording: the clock relation (offset_ms, drift_ppm), its covariance (2, 2) (the
    # drift's row and column zero when it was held), each shot's robot time (s)
    timing: dict | None = None


#: A Gauss-Newton step the line search had to cut ends the iterations when the whole step
#: is at most this share of each parameter's standard deviation: the estimate is then
#: within 1/20 of its uncertainty of where the steps lead, where the cost's curvature is
#: no longer the linearisation's (seen with 0.02 deg of orientation read noise in
#: eye-to-hand: steps of 1-2.5 % of a sd cut to 1/256, fifty times over, "not converged").
STALLED_STEP_SHARE = 0.05
#: ... after this many cut steps in a row (a step cut once near the end of a normal
#: convergence leaves the tolerance to end it).
STALLED_CUT_STEPS = 3
#: Gauss-Newton chatters when the cost is not smooth at the scale of its last steps (a
#: recording's poses are read from a sampled stream at each shot's time, piecewise linear
#: in the clock offset): steps of a hundredth of each parameter's standard
#: deviation, this many in a row, end the pass as converged. A smooth cost converges
#: quadratically through that range in one or two steps. Only a recording's fit takes the
#: rule: a stop-and-go fit that chatters fits nothing (another mounting's data) and must
#: say so.
CHATTER_STEP_SHARE = 1e-2
CHATTER_STEPS = 5
#: A recording's kinematic prior factor, re-estimated at every step near the solution,
#: jitters with the piecewise-smooth cost (2.4-2.9 on an eye-to-hand recording of an arm
#: with geometric error), and the transform follows it (0.05-0.2 mm a step, where the
#: arm's shared error and the sensor's position trade off): fifty steps, "not converged".
#: After this many steps near the solution the factor is held at the median of its last
#: values for the rest of the pass, and Gauss-Newton converges at it; the next pass (the
#: variance components' loop) estimates it again from there.
LAM_SETTLE_STEPS = 6
#: A refinement that runs longer says so this often (s): a recording of millions of points
#: with the arm's kinematic model takes minutes, which must not look like a hung program.
PROGRESS_EVERY_S = 15.0


def refine(
    problem: Problem,
    R,
    t,
    centre,
    noise: NoiseAssumptions,
    fit_radius: bool = False,
    estimate_pose_noise: bool = True,
    max_iterations: int = 50,
    tolerance: float = 1e-10,
    station_effects: StationEffects | None = None,
    kinematic_effects: KinematicEffects | None = None,
    time_effects: TimeEffects | None = None,
    progress: Callable[[str], None] | RefineProgress | None = None,
) -> RefineResult:
    """Gauss-Newton over all points of ``problem.profiles`` (already cleaned).

    With ``station_effects`` enabled (and two or more stations) each station's flange
    poses carry one shared, unknown pose error with a Gaussian prior (see
    :class:`StationEffects`); with ``kinematic_effects`` (and joints in the problem) every
    pose carries the error of the arm's geometry (see :class:`KinematicEffects`). The fit
    estimates the transform with those errors marginalised, and their scales by
    restricted maximum likelihood (REML) on the linearised model. The covariance is that
    of the transform with the errors integrated out.

    Passes of Gauss-Newton (:func:`_gauss_newton_pass`) alternate with the variance
    components (:func:`update_variance_components`) until those settle.

    With ``time_effects`` (a recording, :mod:`.timing`) the clock relation between the
    sensor and the robot is estimated with the rest, each shot's pose re-read from the
    pose stream as it moves.

    ``progress`` is told every :data:`PROGRESS_EVERY_S` seconds while the refinement runs
    (a :class:`RefineProgress` shared by the refinements of one solve counts from its first)."""
    fit = RefineState(problem, R, t, centre, noise, fit_radius, station_effects, kinematic_effects, time_effects)
    fit.progress = progress if isinstance(progress, RefineProgress) else RefineProgress(progress)
    ke = fit.ke
    if ke is not None and ke.select_by_evidence and fit.se is None and not ke.identify and len(fit.rand_cols):
        return _refine_by_evidence(problem, fit.R, fit.t, fit.c, noise, fit_radius, estimate_pose_noise,
                                   max_iterations, tolerance, ke, fit.rand_cols, time_effects, fit.progress)
    for _ in range(max(4 if estimate_pose_noise else 1, 8 if fit.m_centres else 1)):
        first_small = _gauss_newton_pass(fit, max_iterations, tolerance)
        if not update_variance_components(fit, first_small, estimate_pose_noise):
            break
    return _result(fit)


def _gauss_newton_pass(fit: RefineState, max_iterations: int, tolerance: float) -> bool:
    """One pass of Gauss-Newton at the pass's variance components: MAP steps (the random
    effects' scales re-estimated on the way, :func:`_step`), each halved while it makes
    the penalised cost worse (:func:`_line_search`), until a step is below the tolerance
    or stalls. Sets ``fit.converged`` and ``fit.iterations``; returns whether the pass's
    first step was already below the tolerance."""
    lin = None
    near = False  # scales are re-estimated only near a solution, where the linearisation holds
    first_small = False  # the pass's first step was already below the tolerance
    cut_steps = 0  # Gauss-Newton steps in a row that the line search had to cut
    chatter = 0  # steps in a row within a sliver of the standard deviations, above the tolerance
    fit.converged = False  # (of this pass: an earlier pass's convergence says nothing of this one)
    lams: list[float] = []  # the kinematic prior factor at each step near the solution (a recording's)
    lam_held = False
    if fit.m_centres:
        fit.centre_cov_frozen = None
        fit.centre_cov_frozen = fit.linearise(fit.scale).centre_parts[3]
    for it in range(1, max_iterations + 1):
        fit.iterations = it
        if fit.progress is not None:
            fit.progress.tick()
        lin = lin if lin is not None else fit.linearise(fit.scale)
        step, d_new, normal = _step(fit, lin, near and not lam_held)
        if near and fit.estimate_lam and fit.te is not None and not lam_held:
            lams.append(fit.lam)
            if len(lams) >= LAM_SETTLE_STEPS:
                fit.lam, lam_held = float(np.median(lams[-LAM_SETTLE_STEPS:])), True
                continue  # (the step was taken at the last factor: step again at the held one)
        cost0 = fit.penalised_cost(lin, fit.s_hat, fit.lam)
        lin = None  # (its arrays go before the line search builds linearisations)
        lin, frac, step_delta = _line_search(fit, step, d_new, cost0)
        small = np.abs(frac * step[:3]).max() < tolerance and np.abs(frac * step[3:]).max() < tolerance * 1e3
        if fit.any_random:
            small = small and step_delta < tolerance * 1e3
        cut_steps = cut_steps + 1 if frac < 1.0 else 0
        sd = None
        if not small and cut_steps >= STALLED_CUT_STEPS:
            # Gauss-Newton stalled (its steps raise the cost and are cut, again and again):
            # converged when the whole step is a sliver of each parameter's standard
            # deviation (the cost's curvature there is not the linearisation's)
            sd = np.sqrt(np.maximum(np.diag(np.linalg.pinv(normal))[:fit.n_par], 0.0))
            small = bool(np.all(np.abs(step) <= STALLED_STEP_SHARE * sd))
        if not small and fit.te is not None:  # (a recording: its cost is piecewise smooth in the clock offset)
            if sd is None:
                sd = np.sqrt(np.maximum(np.diag(np.linalg.pinv(normal))[:fit.n_par], 0.0))
            chatter = chatter + 1 if np.all(np.abs(frac * step) <= CHATTER_STEP_SHARE * sd) else 0
            small = chatter >= CHATTER_STEPS
        if it == 1:
            first_small = bool(small)
        was_near = near
        near = near or (np.abs(frac * step[:3]).max() < 1e-5 and np.abs(frac * step[3:6]).max() < 1e-2)
        if small and (was_near or not fit.estimate_lam or lam_held):
            fit.converged = True
            break
    return first_small


class RefineProgress:
    """Says, every :data:`PROGRESS_EVERY_S` seconds, how long the joint refinement has run
    (over every refinement it is given to)."""

    def __init__(self, say: Callable[[str], None] | None):
        self.say, self.start = say, time.monotonic()
        self.said = self.start
        self.steps = 0

    def tick(self) -> None:
        self.steps += 1
        now = time.monotonic()
        if self.say is not None and now - self.said >= PROGRESS_EVERY_S:
            self.said = now
            self.say(f"  joint refinement still running: {now - self.start:.0f} s, {self.steps} steps so far")


def _step(fit: RefineState, lin, near: bool):
    """The Gauss-Newton step at ``lin``: (step of the fixed effects, the random effects'
    new values or None, the normal matrix). With random effects, a MAP step in
    (d theta, eta) with d = L eta, after the station scales (from the start) and the
    kinematic prior's factor (only ``near`` a solution: far from it the misfit of the
    start would pass for robot error and blow the prior up) are re-estimated."""
    At, As, Ak = fit.design(lin)
    if not fit.any_random:
        normal = lin.red.gram(At, At)
        return np.linalg.lstsq(normal, lin.red.rhs(At), rcond=None)[0], None, normal
    blocks = _effect_blocks(lin.red, At, As, Ak, fit.shift(As, Ak), fit.station_shots)
    A_tt, A_td, A_dd, b_t, b_d, _ = blocks
    if fit.free or (fit.estimate_lam and near):
        search_scales(fit, blocks, fit.estimate_lam and near)
    if fit.se is not None:
        for i in range(2):
            if fit.fixed[i] is not None:
                fit.s_hat[i] = fit.fixed[i]
    Lp = fit.sqrt_prior(fit.s_hat, fit.lam)
    # the normal matrix stays regular as L -> 0
    N = np.block([[A_tt, A_td @ Lp], [Lp.T @ A_td.T, Lp.T @ A_dd @ Lp + np.eye(Lp.shape[1])]])
    sol = np.linalg.solve(N, np.concatenate([b_t, Lp.T @ b_d]))
    return sol[:fit.n_par], Lp @ sol[fit.n_par:], N


def _line_search(fit: RefineState, step, d_new, cost0: float):
    """Take ``step`` (and move the random effects toward ``d_new``), halved while it
    makes the penalised cost worse than ``cost0`` (far from the solution the
    linearisation can overshoot), at most 11 times. Returns the linearisation at the new
    estimate, the share of the step taken and the largest move of a random effect."""
    before = fit.snapshot()
    d_old = fit.random_effects() if fit.any_random else None
    K, n_geo = fit.K, fit.n_geo
    frac = 1.0
    lin = None
    for _ in range(12):
        R, t, c, r, delta, kappa = before[0], before[1], before[2], before[3], before[4].copy(), before[5].copy()
        R = geo.matrix_from_rotvec(frac * step[:3]) @ R
        t = t + frac * step[3:6]
        c = c + frac * step[6:9]
        if fit.fit_radius:
            r = r + frac * step[9]
        n_id = len(fit.id_cols)
        if n_id:
            kappa[fit.id_cols] += frac * step[n_geo:n_geo + n_id]
        if fit.te is not None:
            tau = before[6].copy()
            tau[:fit.n_time] += frac * step[n_geo + n_id:]
            fit.set_tau(tau)
        if d_new is not None:
            d = d_old + frac * (d_new - d_old)
            if fit.se is not None:
                delta = d[:6 * K].reshape(K, 6)
            if len(fit.rand_cols):
                kappa[fit.rand_cols] = d[6 * K if fit.se is not None else 0:]
        fit.R, fit.t, fit.c, fit.r, fit.delta, fit.kappa = R, t, c, r, delta, kappa
        lin = None  # (the previous point's arrays go before the new ones are built)
        lin = fit.linearise(fit.scale)
        if fit.penalised_cost(lin, fit.s_hat, fit.lam) <= cost0 * (1 + 1e-9) + 1e-12:
            break
        frac *= 0.5
    step_delta = 0.0 if d_new is None else float(np.abs(frac * (d_new - d_old)).max())
    return lin, frac, step_delta


def update_variance_components(fit: RefineState, first_small: bool, estimate_pose_noise: bool) -> bool:
    """After a pass of Gauss-Newton: the whitened chi^2 of the profiles in their 3-D pose
    subspaces against its degrees of freedom (the pose noise's variance component, in
    ``fit.s2_profiles``) and, for centre observations given without a covariance, their
    variance (:func:`_centre_variance`). Moves the pose-noise scale toward what the
    profiles show and takes the new centre variance when either is off by more than a
    few percent. Returns whether another pass is due: a variance moved, or the centre
    observations' covariance, held within the pass, still moved the solution (the pass
    did not start at its solution)."""
    fit.centre_cov_frozen = None
    lin = fit.linearise(fit.scale)
    n_effects = (6 * fit.K if fit.se else 0) + (
        int(np.count_nonzero(fit.kin_identifiable)) if fit.n_kin_fitted else 0)
    pts, n_shots, m_centres = fit.pts, fit.n_shots, fit.m_centres
    if not m_centres:
        dof_profiles = 3 * fit.problem.n_profiles - fit.n_geo - n_effects
        s2_profiles = float(lin.red.chi2.sum() / max(dof_profiles, 1))
        update_centre = False
    else:
        # the degrees of freedom shared out between profiles and centres by their count
        dof_all = 3 * n_shots - fit.n_geo - n_effects
        dof_profiles = dof_all * len(pts.shots) / n_shots
        s2_profiles = float(lin.red.chi2[pts.shots].sum() / max(dof_profiles, 1)) \
            if len(pts.shots) else 1.0
        update_centre = False
        if fit.estimate_centre:
            s2_new = _centre_variance(lin.centre_parts, dof_all * m_centres / n_shots, fit.s2_centre)
            update_centre = abs(s2_new / fit.s2_centre - 1.0) >= 0.02
    fit.s2_profiles = s2_profiles
    update_pose = not (not estimate_pose_noise or dof_profiles < 20 or fit.pose_cov.max() == 0
                       or abs(s2_profiles - 1) < 0.05)
    # the centres' covariance re-evaluated: one more pass unless this one started at its solution
    reweight = bool(m_centres) and not (fit.converged and first_small)
    if not update_pose and not update_centre and not reweight:
        return False
    if update_centre:
        fit.s2_centre = s2_new
    if update_pose:
        # move the assumed pose-noise variance toward what the profiles show, and refit
        fit.scale = float(np.clip(fit.scale * s2_profiles, 1e-8, 1e4))
    return True


def _result(fit: RefineState) -> RefineResult:
    """The result at the estimate in ``fit``: covariances, residuals and diagnostics."""
    lin = fit.linearise(fit.scale)
    covs = covariances_at_solution(fit, lin)
    diagnostics = {
        "information_condition_number": covs.information_condition,
        "profile_variance_factor": fit.s2_profiles,
        "point_noise_mm_assumed": fit.sigma,
        "profile_chi2": lin.red.chi2.tolist(),
    }
    if covs.kinematic_evidence is not None:
        diagnostics["kinematic_evidence"] = covs.kinematic_evidence
    if fit.se is not None:
        diagnostics["station_effects"] = _station_diagnostics(fit)
    ke = fit.ke
    if ke is not None:
        diagnostics["kinematic_effects"] = {
            "names": error_parameter_names(ke.chain),
            "estimate": fit.kappa.tolist(),
            "sd": covs.kinematic_sd.tolist(),
            "identifiable": fit.kin_identifiable.tolist(),
            "independent_share": fit.kin_share.tolist(),
            "identified": [bool(i in set(fit.id_cols.tolist())) for i in range(fit.n_kin)],
            "prior_sd": fit.kin_prior.tolist(),
            "prior_scale": float(fit.lam),
            "prior_scale_estimated": bool(fit.estimate_lam),
        }
    dof = max(len(lin.res) - fit.n_par, 1)
    centre_res = None
    centre_noise = float(np.sqrt(fit.s2_centre)) if fit.estimate_centre else None
    if fit.m_centres:
        centre_res = np.full((fit.n_shots, 3), np.nan)
        centre_res[fit.pts.centre_shots] = lin.centre_parts[0]
        diagnostics["centre_noise_mm"] = centre_noise
    pts = fit.pts
    timing = None
    if fit.te is not None:
        n0 = fit.n_par - fit.n_time
        tcov = np.zeros((2, 2))
        tcov[:fit.n_time, :fit.n_time] = covs.reported[n0:, n0:]
        # the offset's spread were everything else known: the reported one against it
        # tells whether the sweeps separate the offset from the geometry
        offset = lin.columns(lin.Jd @ time_design(fit.problem, fit.te, fit.twist)[:, :, :1])
        diagnostics["offset_std_ms_known_geometry"] = float(1.0 / np.sqrt(max(lin.red.gram(offset, offset)[0, 0],
                                                                              1e-300)))
        timing = {"offset_ms": float(fit.tau[0]), "drift_ppm": float(fit.tau[1]), "covariance": tcov,
                  "drift_estimated": fit.te.estimate_drift,
                  "t_robot_s": fit.te.robot_times(fit.base_problem.t_sensor_s, fit.tau)}
    return RefineResult(
        fit.R, fit.t, fit.c, fit.r, covs.reported, np.split(lin.res[:pts.M], np.cumsum(pts.counts)[:-1]), lin.C,
        lin.SC, fit.iterations, fit.converged, lin.red.cost() / dof, fit.scale, diagnostics,
        covariance_without_robot_error=covs.without_robot_error, covariance_robot_frame=covs.robot_frame,
        covariance_robot_frame_at_scales=covs.robot_frame_at_scales, station_offsets=fit.delta,
        station_effect_scales=_station_to_station_scales(fit),
        kinematic_errors=fit.kappa if ke is not None else None,
        kinematic_sd=covs.kinematic_sd if ke is not None else None, kinematic_terms=covs.kinematic_terms,
        centre_residuals=centre_res, centre_noise_mm=centre_noise,
        station_prediction=station_cross_validation(fit, lin), timing=timing,
    )


def cost_at(problem: Problem, ref: RefineResult, noise: NoiseAssumptions, fit_radius: bool, scale: float,
            station_effects: StationEffects | None = None, kinematic_effects: KinematicEffects | None = None,
            time_effects: TimeEffects | None = None) -> float:
    """-2 log-likelihood (up to a constant) of ``ref``'s solution at the pose-noise scale
    ``scale``: the whitened residuals plus the random effects against their prior (the
    MAP objective :meth:`.RefineState.penalised_cost`), so that two solutions of one
    problem are compared at one noise model."""
    if time_effects is not None:
        time_effects = with_start(time_effects, ref.timing)
    fit = RefineState(problem, ref.R, ref.t, ref.centre, noise, fit_radius, station_effects, kinematic_effects,
                      time_effects)
    fit.r = float(ref.radius)
    if fit.se is not None and ref.station_offsets is not None:
        fit.delta = np.array(ref.station_offsets, dtype=float)
        se = ref.diagnostics.get("station_effects") or {}
        fit.s_hat = np.array([np.radians(se.get("rotation_deg", 0.01)), se.get("translation_mm", 0.1)])
    if fit.ke is not None and ref.kinematic_errors is not None:
        fit.kappa = np.array(ref.kinematic_errors, dtype=float)
        fit.lam = float((ref.diagnostics.get("kinematic_effects") or {}).get("prior_scale", 1.0))
    if fit.m_centres and ref.centre_noise_mm is not None:
        fit.s2_centre = ref.centre_noise_mm**2
    fit.scale = scale
    return fit.penalised_cost(fit.linearise(scale), fit.s_hat, fit.lam)


def _station_diagnostics(fit: RefineState) -> dict:
    """The station model's scales and each station's estimated offset."""
    se, s_hat, delta = fit.se, fit.s_hat, fit.delta
    return {
        "rotation_deg": float(np.degrees(s_hat[0])),
        "translation_mm": float(s_hat[1]),
        "estimated": [fit.fixed[0] is None, fit.fixed[1] is None],
        "common_rotation_deg": se.common_rotation_deg if fit.ke is None else 0.0,
        "common_translation_mm": se.common_translation_mm if fit.ke is None else 0.0,
        "offsets": {lab: {"rotation_deg": np.degrees(delta[k, :3]).tolist(), "translation_mm": delta[k, 3:].tolist()}
                    for k, lab in enumerate(fit.problem.station_labels)},
    }


def _station_to_station_scales(fit: RefineState) -> tuple[float, float]:
    """The station-to-station part of the robot's error (rad, mm): the station scales,
    with the spread across the shots of the arm's error as its estimated geometry shows it."""
    ke, s_hat = fit.ke, fit.s_hat
    station_scales = (float(s_hat[0]), float(s_hat[1])) if fit.se else (0.0, 0.0)
    if ke is not None and not ke.identify:
        E = flange_error_jacobian(ke.chain, fit.problem.q_rad) @ fit.kappa
        E = E - E.mean(axis=0)
        kin_scales = (float(np.sqrt(np.mean(E[:, :3] ** 2))), float(np.sqrt(np.mean(E[:, 3:] ** 2))))
        station_scales = tuple(float(np.hypot(a, b)) for a, b in zip(station_scales, kin_scales))
    return station_scales


def _refine_by_evidence(problem, R, t, c, noise, fit_radius, estimate_pose_noise, max_iterations, tolerance,
                        ke: KinematicEffects, cols, te: TimeEffects | None = None,
                        progress: RefineProgress | None = None) -> RefineResult:
    """The ``auto`` robot error model: the pose-noise-only fit at the stated noise, the
    evidence for the arm's geometric error at its solution, then the kinematic model if
    the data show that error, else the pose-noise-only fit (pose noise rescaled as asked)
    with the arm's geometry considered. The decision is made at the stated pose noise: a
    pose-noise scale learnt first would absorb the arm's error and hide it."""
    plain = replace(ke, select_by_evidence=False, consider_columns=tuple(int(i) for i in cols))
    first = refine(problem, R, t, c, noise, fit_radius, False, max_iterations, tolerance, None, plain, te, progress)
    evidence = first.diagnostics["kinematic_evidence"]
    te_first = te if te is None else with_start(te, first.timing)
    if evidence["likelihood_ratio"] >= KINEMATIC_EVIDENCE_LR:
        out = refine(problem, first.R, first.t, first.centre, noise, fit_radius, estimate_pose_noise, max_iterations,
                     tolerance, None, replace(ke, select_by_evidence=False), te_first, progress)
        selected = "kinematic"
    else:
        out = first if not estimate_pose_noise else refine(
            problem, first.R, first.t, first.centre, noise, fit_radius, True, max_iterations, tolerance, None, plain,
            te_first, progress)
        selected = "none"
    out.diagnostics["kinematic_evidence"] = {**evidence, "selected": selected}
    return out
