"""The covariances the refinement reports at its solution, robot errors integrated out or considered."""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from spherecal.core.kinematics import chain_with_errors, flange_error_jacobian
from spherecal.estimation.refine.effects import _common_error_design, _effect_blocks
from spherecal.estimation.refine.linearisation import _Linearisation
from spherecal.estimation.refine.reml import KINEMATIC_EVIDENCE_LR, _SCALE_BOUNDS, _kinematic_evidence, _reml_batch

if TYPE_CHECKING:
    from spherecal.estimation.refine.state import RefineState


#: A marginalised kinematic parameter whose posterior spread stays above this share of its
#: prior's is one the data barely see: left out of the robot-frame covariance.
SEEN_POSTERIOR_SHARE = 0.5


#: Grid points per free station scale where the covariance is averaged over the scales'
#: posterior (:func:`_scale_averaged_covariance`), and how far the grid reaches: to where
#: -2 x the REML log-likelihood has risen this much above its minimum (e^-15 of its peak).
_SCALE_GRID_POINTS = 16
_SCALE_GRID_RISE = 20.0


def _scale_averaged_covariance(blocks, column_scale, free, s_hat, bounds):
    """The transform's covariance with the station-effect scales' own uncertainty in it.

    REML estimates each scale from the K stations' offsets: from 3 K numbers, a few
    stations give a spread of that estimate of tens of percent, and it often lands on its
    floor (no station-to-station error) when the stations happen to agree. The
    covariance at the estimated scales alone then says the transform is known better
    than it is (NEES 9-13 instead of 6 in the benchmark's worlds with systematic robot
    error, up to 28 on the seeds whose scale fell to its floor).

    Here the covariance is averaged over the scales' posterior: the REML likelihood with a
    uniform prior on each free scale (not on its logarithm, which would pile the
    posterior up at the floor; a uniform prior on a standard deviation is the usual
    choice with few groups), on a grid of :data:`_SCALE_GRID_POINTS` log-spaced points
    per free scale over three decades below the scale where -2 x the likelihood has risen
    :data:`_SCALE_GRID_RISE` above its value at ``s_hat``, each point weighted by its
    scales (ds = s dlog s). Each point's conditional covariance and the shift of its
    estimate from the one at ``s_hat`` are averaged by the posterior weights: the mean
    squared error about the reported estimate.

    ``blocks``: the normal-equation blocks (A_tt, A_td, A_dd, b_t, b_d, yy) at the
    solution, with the station offsets as estimated; ``column_scale`` (q,): which scale
    (0 rotation, rad; 1 translation, mm) is each random-effect column's standard
    deviation; ``free``: the indices of the estimated scales; ``bounds``: their (floor,
    ceiling)."""
    s_hat = np.asarray(s_hat, dtype=float)

    def sds(points):  # grid points (g, len(free)) -> prior sd rows (g, q)
        scales = np.tile(s_hat, (len(points), 1))
        scales[:, free] = points
        return scales[:, column_scale]

    at_hat, step_hat, _ = _reml_batch(sds(s_hat[free][None]), blocks, 6)
    reach = []
    for j, i in enumerate(free):
        floor, ceiling = bounds[i]
        ladder = max(s_hat[i], 2.0 * floor) * 1.25 ** np.arange(int(np.ceil(np.log(ceiling / floor) / np.log(1.25))) + 1)
        ladder = np.minimum(ladder, ceiling)
        points = np.tile(s_hat[free], (len(ladder), 1))
        points[:, j] = ladder
        values = _reml_batch(sds(points), blocks, 6)[0]
        above = np.flatnonzero(values - at_hat[0] > _SCALE_GRID_RISE)
        reach.append(ladder[above[0]] if len(above) else ceiling)
    axes = [top * np.logspace(-3.0, 0.0, _SCALE_GRID_POINTS) for top in reach]
    points = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, len(free))
    values, steps, covs = _reml_batch(sds(points), blocks, 6)
    finite = np.isfinite(values)
    w = np.zeros(len(values))
    w[finite] = np.exp(-0.5 * (values[finite] - values[finite].min())) * np.prod(points[finite], axis=1)
    w /= w.sum()
    shifts = steps[finite] - step_hat[0]
    return (np.einsum("g,gij->ij", w[finite], covs[finite])
            + np.einsum("g,gi,gj->ij", w[finite], shifts, shifts))


@dataclass
class Covariances:
    """The covariances of the parameters (w, t, c[, r], identified kinematic parameters)
    at the refinement's solution, and what is reported with them."""

    reported: np.ndarray  # the robot's random errors integrated out, considered errors added
    without_robot_error: np.ndarray  # as if the robot's errors were known
    robot_frame: np.ndarray  # relative to the robot's own frame (without its common error)
    robot_frame_at_scales: np.ndarray | None  # the station model's robot_frame at the estimated scales
    information_condition: float  # condition number of the transform's and sphere's information
    kinematic_sd: np.ndarray  # (6 joints,) posterior standard deviation of each kinematic parameter
    kinematic_terms: dict | None  # see RefineResult.kinematic_terms
    kinematic_evidence: dict | None  # the evidence for the arm's geometric error, where judged here


def covariances_at_solution(fit: RefineState, lin: _Linearisation) -> Covariances:
    """The covariances at the estimate in ``fit``, linearised in ``lin``: GLS with the
    random robot errors integrated out (the joint normal matrix's inverse), the kinematic
    parameters' posterior, the robot-frame covariance without the parameters the data
    barely see, the considered kinematic parameters or the robot's common error added,
    and in the station model the average over the scales' posterior."""
    At, As, Ak = fit.design(lin)
    # the normal-equation blocks at the solution (with the random effects' right-hand
    # sides: the station model's averaged covariance reuses them whole)
    blocks = _effect_blocks(lin.red, At, As, Ak, fit.shift(As, Ak) if fit.any_random else None, fit.station_shots)
    A_tt, A_tr, A_rr = blocks[:3]
    cov_fixed = np.linalg.pinv(A_tt)  # with the random robot errors known (none)
    condition = float(np.linalg.cond(A_tt[:fit.n_geo, :fit.n_geo]))
    kin_sd = np.zeros(fit.n_kin)
    Lp = fit.sqrt_prior(fit.s_hat, fit.lam)
    cov_robot_frame, Cinv = _marginalised(fit, A_tt, A_tr, A_rr, Lp, cov_fixed)
    cov = cov_robot_frame
    off = 6 * fit.K if fit.se is not None else 0
    rand_cols = fit.rand_cols
    post = None
    evidence = None
    if len(rand_cols):
        post, kin_sd[rand_cols], hidden = _kinematic_posterior(A_tt, A_tr, A_rr, Lp, off)
        if fit.se is None and not len(fit.id_cols):
            evidence = {
                **_kinematic_evidence(_effect_blocks(lin.red, At, None, Ak, Ak @ fit.kappa[rand_cols], []),
                                      fit.kin_prior[rand_cols]),
                "threshold": KINEMATIC_EVIDENCE_LR, "selected": "stated"}
        if hidden.any():
            cov_robot_frame = _without_hidden(A_tt, A_tr, A_rr, Lp, off + np.flatnonzero(hidden))
    if len(fit.consider_cols):
        cov, evidence = _considered_kinematics(fit, lin, At, cov, cov_fixed)
    kinematic_terms = _kinematic_terms(fit, cov, cov_robot_frame, A_tr, A_rr, Cinv, off, post)
    cov_at_scales = None
    if fit.se is not None and fit.ke is None:
        cov, cov_robot_frame, cov_at_scales = _with_common_error(fit, lin, At, As, blocks, cov, Cinv)
    elif fit.common_only is not None and fit.ke is None:
        cov = _with_common_error_only(fit, lin, At, cov)
    if len(fit.id_cols):
        kin_sd[fit.id_cols] = np.sqrt(np.maximum(np.diag(cov)[fit.n_geo:fit.n_geo + len(fit.id_cols)], 0.0))
    return Covariances(cov, cov_fixed, cov_robot_frame, cov_at_scales, condition, kin_sd, kinematic_terms, evidence)


def _marginalised(fit: RefineState, A_tt, A_tr, A_rr, Lp, cov_fixed):
    """GLS covariance with the random robot errors integrated out (``cov_fixed`` when
    there are none), and ``Cinv`` = L (I + L^T A_rr L)^-1 L^T."""
    n_rand = (6 * fit.K if fit.se is not None else 0) + len(fit.rand_cols)
    if not n_rand:
        return cov_fixed, np.zeros((0, 0))
    B = np.eye(n_rand) + Lp.T @ A_rr @ Lp
    Cinv = Lp @ np.linalg.solve(B, Lp.T)
    # = (A_tt - A_tr Cinv A_tr^T)^-1, the top-left block of the inverse of the joint
    # normal matrix in (theta, eta): no subtraction of the large terms the random
    # effects share with the transform (that difference lost seven digits when the
    # arm's parameters absorb most of the information)
    N = np.block([[A_tt, A_tr @ Lp], [Lp.T @ A_tr.T, B]])
    return np.linalg.pinv(N)[:fit.n_par, :fit.n_par], Cinv


def _kinematic_posterior(A_tt, A_tr, A_rr, Lp, off: int):
    """The random kinematic parameters' posterior covariance (their prior's square root
    is ``Lp`` from row ``off`` on), their posterior spread, and which of them the data
    barely see."""
    Lk = Lp[off:, off:]
    S_rr = A_rr - A_tr.T @ np.linalg.pinv(A_tt) @ A_tr
    post = Lk @ np.linalg.solve(np.eye(len(Lk)) + Lk.T @ S_rr[off:, off:] @ Lk, Lk.T)
    sd = np.sqrt(np.maximum(np.diag(post), 0.0))
    # relative to the robot's own frame: without the parameters the data barely see
    # (posterior spread over SEEN_POSTERIOR_SHARE of the prior's): they move the poses
    # nearly alike, and the transform or the sphere absorbs them as it absorbs the
    # robot's common error in the station model
    hidden = sd >= SEEN_POSTERIOR_SHARE * np.diag(Lk)
    return post, sd, hidden


def _without_hidden(A_tt, A_tr, A_rr, Lp, hidden_columns):
    """The covariance with the random effects integrated out but for the prior columns
    ``hidden_columns``, held at zero."""
    L_rf = Lp.copy()
    L_rf[hidden_columns, hidden_columns] = 0.0
    B_rf = np.eye(len(Lp)) + L_rf.T @ A_rr @ L_rf
    return np.linalg.pinv(A_tt - A_tr @ (L_rf @ np.linalg.solve(B_rf, L_rf.T)) @ A_tr.T)


def _considered(cov, A_tr, Cinv, cols_t, cols_d, prior_cov):
    """Covariance added by parameters left at zero in the fit, with prior ``prior_cov``."""
    S = cov @ (cols_t - A_tr @ Cinv @ cols_d)
    return S @ prior_cov @ S.T


def _considered_kinematics(fit: RefineState, lin: _Linearisation, At, cov, cov_fixed):
    """``cov`` with the arm's parameters considered: what the data leave of their prior
    (the posterior at the stated spread; the prior itself where one sphere cannot see
    them) through the estimator; and the evidence for the arm's geometric error."""
    Kc = fit.kin_columns(lin)[:, :, fit.consider_cols]
    prior_c = fit.kin_prior[fit.consider_cols]
    JtK = lin.red.gram(At, Kc)
    S_kk = lin.red.gram(Kc, Kc) - JtK.T @ cov_fixed @ JtK
    post_c = prior_c[:, None] * np.linalg.solve(np.eye(len(prior_c)) + prior_c[:, None] * S_kk * prior_c,
                                                np.diag(prior_c))
    S = cov @ JtK
    cov = cov + S @ post_c @ S.T
    evidence = {**_kinematic_evidence(_effect_blocks(lin.red, At, None, Kc, None, []), prior_c),
                "threshold": KINEMATIC_EVIDENCE_LR, "selected": "stated"}
    return cov, evidence


def _kinematic_terms(fit: RefineState, cov, cov_robot_frame, A_tr, A_rr, Cinv, off: int, post) -> dict | None:
    """The kinematic parameters' part of the point-error budget (RefineResult.kinematic_terms)."""
    ke = fit.ke
    if ke is not None and len(fit.id_cols):
        # kinematic calibration: a new pose is mapped through the identified model, so its
        # error is that of the transform, sphere and identified parameters, jointly
        return {
            "identified_design": flange_error_jacobian(chain_with_errors(ke.chain, fit.kappa),
                                                       fit.problem.q_rad)[:, :, fit.id_cols],
            "covariance": cov_robot_frame[:fit.n_par - fit.n_time, :fit.n_par - fit.n_time], "n_geo": fit.n_geo,
        }
    if ke is not None and len(fit.rand_cols):
        # how the arm's true geometric error moves the estimate (GLS with it marginalised)
        return {
            "design": flange_error_jacobian(ke.chain, fit.problem.q_rad)[:, :, fit.rand_cols],
            "influence": cov @ (A_tr[:, off:] - A_tr @ Cinv @ A_rr[:, off:]),
            "posterior_mean": fit.kappa[fit.rand_cols].copy(),
            "posterior_cov": post,
        }
    return None


def _with_common_error_only(fit: RefineState, lin: _Linearisation, At, cov):
    """``cov`` (no station offsets) with the robot's common error added as a 'consider'
    parameter, as the station model adds it (:func:`_with_common_error`): rows that share
    no orientation have no station offsets to estimate, and their robot's error shared
    by every row is still not measured by one sphere location. In eye-in-hand it is
    considered in the base axes and as an error constant in the flange frame too (the
    wrist's and flange's own error, at every orientation the same on the flange), which
    the transform on the flange takes whole; the station model's station offsets, turned
    with their stations, stand in for that part on station data."""
    ce = fit.common_only
    problem = fit.current()
    common = np.diag([np.radians(ce.common_rotation_deg) ** 2] * 3 + [ce.common_translation_mm**2] * 3)
    S = cov @ lin.red.gram(At, lin.columns(_common_error_design(problem, lin.Jd)))
    out = cov + S @ common @ S.T
    if problem.mounting == "eye_in_hand":
        M = np.zeros((problem.n_profiles, 6, 6))  # flange-frame (omega, tau) in base axes: R0 each
        M[:, :3, :3] = problem.R0
        M[:, 3:, 3:] = problem.R0
        S = cov @ lin.red.gram(At, lin.columns(lin.Jd @ M))
        out = out + S @ common @ S.T
    return out


def _with_common_error(fit: RefineState, lin: _Linearisation, At, As, blocks, cov, Cinv):
    """The station model's covariances: (reported, robot frame, robot frame at the
    estimated scales). The robot frame's is averaged over the free scales' posterior
    (:func:`_scale_averaged_covariance`); the reported one adds the robot's common error
    as a 'consider' parameter: not estimated (one sphere location cannot tell it), its
    prior spread propagated through the estimator."""
    se = fit.se
    Xc = lin.columns(_common_error_design(fit.current(), lin.Jd))
    cols_c_t = lin.red.gram(At, Xc)
    cols_c_d = np.concatenate([lin.red.gram(As[rows], Xc[rows], rows) for rows in fit.station_shots])
    common = np.diag([np.radians(se.common_rotation_deg) ** 2] * 3 + [se.common_translation_mm**2] * 3)
    cov_robot_frame = cov_at_scales = cov
    if fit.free:
        # the scales are estimates too: their uncertainty widens the covariance
        cov_robot_frame = _scale_averaged_covariance(
            blocks, np.tile([0, 0, 0, 1, 1, 1], fit.K), fit.free, fit.s_hat, _SCALE_BOUNDS)
    reported = cov_robot_frame + _considered(cov_at_scales, blocks[1], Cinv, cols_c_t, cols_c_d, common)
    return reported, cov_robot_frame, cov_at_scales
