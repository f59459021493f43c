"""The random effects' scales by restricted maximum likelihood (REML), and the evidence for them."""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    from spherecal.estimation.refine.state import RefineState


#: The largest station-to-station scales the fit estimates (deg, mm): a scale there is a
#: bound, not a measurement (the stations disagree by at least that much).
STATION_SCALE_CEILING_DEG = 5.0
STATION_SCALE_CEILING_MM = 50.0
#: Bounds of the estimated station-effect scales (rad, mm) and of the kinematic prior's factor.
_SCALE_BOUNDS = ((1e-7, np.radians(STATION_SCALE_CEILING_DEG)), (1e-5, STATION_SCALE_CEILING_MM))
_KIN_SCALE_BOUNDS = (1.0, 30.0)  # the stated prior is a floor
#: REML likelihood ratio (prior scale free against zero) above which the data show the
#: arm's geometric error. Under no such error it follows a 50:50 mixture of chi^2_0 and
#: chi^2_1: 5.41 is its 1 % point (1 exact arm in 100 gets the cautious kinematic fit).
#: Measured on the benchmark's worlds: 0-0.2 on an exact arm, 20-1,700 on an
#: uncalibrated one (docs/estimation.md).
KINEMATIC_EVIDENCE_LR = 5.41


def _neg2_reml_derivatives(sd, group, n_groups: int, A_tt, A_td, A_dd, b_t, b_d, yy):
    """-2 x REML log-likelihood of the linearised model ``y = J_t b + J_d delta + e``,
    e ~ N(0, I), delta ~ N(0, L L^T), from its normal-equation blocks, for a diagonal
    prior square root ``L = diag(sd)`` whose columns share ``n_groups`` scales
    (``group[j]``: the scale of column j), with its gradient and Hessian with respect
    to the logarithm of each scale: ``(value, (g,), (g, g))``. Woodbury and Sylvester
    keep every matrix small and stable as L -> 0.

    With V the marginal covariance of the whitened residuals (linear in the variances
    theta_j = sd_j^2), P = V^-1 - V^-1 X (X^T V^-1 X)^-1 X^T V^-1, M = J_d^T P J_d and
    p = J_d^T P y: d(-2 l) / d theta_j = M_jj - p_j^2 and
    d^2(-2 l) / d theta_j d theta_k = -M_jk^2 + 2 p_j M_jk p_k; a scale's logarithm
    moves theta_j of its columns by 2 theta_j. Exact derivatives let the search stop
    where the gradient vanishes, to rounding, rather than where a finite-difference
    estimate of it drowns in noise: the scales, and through them the transform, are a
    smooth function of the data (reproducible to about 1e-13 instead of 1e-7), and
    Gauss-Newton around them settles."""
    sd = np.asarray(sd, dtype=float)
    q = len(sd)
    B = np.eye(q) + sd[:, None] * A_dd * sd[None, :]
    cB = np.linalg.cholesky(B)
    logdet_V = 2.0 * np.sum(np.log(np.diag(cB)))
    Cmat = sd[:, None] * np.linalg.solve(B, np.diag(sd))  # (Sigma^-1 + A_dd)^-1 = D B^-1 D, D = diag(sd)
    C_dt = Cmat @ A_td.T  # (q, p)
    C_bd = Cmat @ b_d
    XVX = A_tt - A_td @ C_dt
    XVy = b_t - A_td @ C_bd
    yVy = yy - b_d @ C_bd
    sign, logdet_X = np.linalg.slogdet(XVX)
    if sign <= 0:
        return np.inf, np.zeros(n_groups), np.eye(n_groups)
    # J_d^T V^-1 J_d, J_d^T V^-1 X, J_d^T V^-1 y (V^-1 = I - J_d C J_d^T), then P's
    M_dd = A_dd - A_dd @ Cmat @ A_dd
    M_dt = A_td.T - A_dd @ C_dt
    m_d = b_d - A_dd @ C_bd
    sol = np.linalg.solve(XVX, np.column_stack([XVy, M_dt.T]))
    beta = sol[:, 0]
    value = float(logdet_V + logdet_X + yVy - XVy @ beta)
    M = M_dd - M_dt @ sol[:, 1:]
    M = 0.5 * (M + M.T)
    p = m_d - M_dt @ beta
    theta = sd**2
    g_theta = np.diag(M) - p**2
    H_theta = -M**2 + 2.0 * np.outer(p, p) * M
    E = np.zeros((q, n_groups))
    E[np.arange(q), np.asarray(group)] = 1.0
    grad = E.T @ (2.0 * theta * g_theta)
    hess = E.T @ (np.outer(2.0 * theta, 2.0 * theta) * H_theta) @ E + np.diag(E.T @ (4.0 * theta * g_theta))
    return value, grad, hess


def _reml_search(evaluate, x0, lower, upper, max_iterations: int = 60):
    """Minimise ``evaluate(x) -> (value, gradient, Hessian)`` over the box [lower, upper]
    by projected Newton steps: a variable at a bound that the gradient pushes outward is
    held there, the Hessian's eigenvalues are taken in absolute value (a descent direction
    also where the objective is not convex), a step moves no variable by more than 2 (a
    factor e^2 of a scale), and it is halved until the value falls; the variables the full
    step moves toward their lower bounds are also tried there, together and each alone
    (one whose floor alone did worse is not tried there again). Stops when a step
    moves no variable by more than 1e-10, the value no longer falls beyond rounding or the
    gradient is below 1e-8. Returns (x, value)."""
    lower, upper = np.asarray(lower, dtype=float), np.asarray(upper, dtype=float)
    x = np.clip(np.asarray(x0, dtype=float), lower, upper)
    f, g, H = evaluate(x)
    floor_lost = np.zeros(len(x), dtype=bool)
    for _ in range(max_iterations):
        held = ((x <= lower) & (g > 0)) | ((x >= upper) & (g < 0))
        free = ~held
        if not free.any() or not np.isfinite(f) or np.abs(g[free]).max() < 1e-8:
            break  # (a gradient of 1e-8: -2 log-likelihood flat to 1e-8 per factor e of a scale)
        w, V = np.linalg.eigh(H[np.ix_(free, free)])
        w = np.maximum(np.abs(w), 1e-12 * max(np.abs(w).max(), 1e-300))
        step = -V @ ((V.T @ g[free]) / w)
        step *= min(1.0, 2.0 / max(np.abs(step).max(), 1e-300))
        frac, moved = 1.0, False
        while frac > 1e-6:
            x_new = x.copy()
            x_new[free] = np.clip(x[free] + frac * step, lower[free], upper[free])
            f_new, g_new, H_new = evaluate(x_new)
            if f_new <= f:
                moved = True
                break
            frac *= 0.5
        if not moved:
            break
        # a scale on its way to its floor: Newton moves its logarithm by only about 0.5
        # a step there (the objective flattens like sigma^2), so try the floor itself
        falling = free.copy()
        falling[free] = (step < 0) & (g[free] > 0)
        falling &= (x_new > lower) & ~floor_lost
        # (each such scale alone, and all of them together: one at its floor can leave
        # another to a value between, that the flat floor would take many steps to climb;
        # a scale whose floor alone did worse is not tried there again)
        if frac == 1.0 and falling.any():
            tries = [falling] if falling.sum() == 1 else [falling] + [np.arange(len(x)) == i
                                                                       for i in np.flatnonzero(falling)]
            x_step = x_new
            for which in tries:
                x_floor = np.where(which, lower, x_step)
                f_floor, g_floor, H_floor = evaluate(x_floor)
                if f_floor < f_new:
                    x_new, f_new, g_new, H_new = x_floor, f_floor, g_floor, H_floor
                elif which.sum() == 1:
                    floor_lost |= which
        size, fell = np.abs(x_new - x).max(), f - f_new
        x, f, g, H = x_new, f_new, g_new, H_new
        if size < 1e-10 or fell <= 1e-13 * max(abs(f), 1.0):
            break  # (the value no longer falls beyond its rounding)
    return x, f


def _reml_batch(sd, blocks, block_size: int | None = None):
    """For each row of ``sd`` (g, q), the prior's standard deviations of the random
    effects: -2 x the REML log-likelihood of the linearised model (as
    :func:`_neg2_reml_derivatives`; inf where the fixed effects are not determined), and
    the generalised least-squares step of the fixed effects and its covariance with the
    random effects integrated out. Returns (values (g,), steps (g, p), covariances (g, p, p)).

    ``block_size``: A_dd is block-diagonal in blocks of that size (the station offsets
    alone: a shot belongs to one station), and only those blocks are factorised; the
    same numbers as the dense path to rounding, with 1/K of its factorisation work."""
    A_tt, A_td, A_dd, b_t, b_d, yy = blocks
    g, q = sd.shape
    p = A_tt.shape[0]
    b = block_size or q
    K = q // b
    idx = np.arange(K)
    A_blocks = A_dd.reshape(K, b, K, b)[idx, :, idx, :]  # (K, b, b), the diagonal blocks
    sdb = sd.reshape(g, K, b)
    B = np.eye(b) + sdb[..., :, None] * A_blocks[None] * sdb[..., None, :]  # (g, K, b, b)
    logdet_V = 2.0 * np.log(np.diagonal(np.linalg.cholesky(B), axis1=2, axis2=3)).sum(axis=(1, 2))
    Cmat = sdb[..., :, None] * np.linalg.inv(B) * sdb[..., None, :]  # (Sigma^-1 + A_dd)^-1, per block
    C_dt = (Cmat @ A_td.T.reshape(K, b, p)).reshape(g, q, p)  # C A_td^T, block by block
    C_bd = (Cmat @ b_d.reshape(K, b, 1)).reshape(g, q)
    XVX = A_tt[None] - A_td @ C_dt
    XVX = 0.5 * (XVX + np.swapaxes(XVX, 1, 2))
    XVy = b_t[None] - C_bd @ A_td.T
    yVy = yy - C_bd @ b_d
    sign, logdet_X = np.linalg.slogdet(XVX)
    ok = sign > 0
    cov = np.full_like(XVX, np.nan)
    cov[ok] = np.linalg.inv(XVX[ok])
    step = np.einsum("gij,gj->gi", cov, XVy)
    values = np.where(ok, logdet_V + logdet_X + yVy - np.einsum("gi,gi->g", XVy, step), np.inf)
    return values, step, cov


def _kinematic_evidence(blocks, prior_sd) -> dict:
    """How strongly the data ask for the arm's geometric error: the REML likelihood
    ratio of the linearised model with the kinematic prior's scale free (``lam`` >= 0,
    times the stated spread) against none (``lam`` = 0). ``blocks``: the normal-equation
    blocks (A_tt, A_td, A_dd, b_t, b_d, yy) of the transform's and the kinematic columns."""
    from scipy.optimize import minimize_scalar

    def f(lam):
        return _neg2_reml_derivatives(lam * prior_sd, np.zeros(len(prior_sd), dtype=int), 1, *blocks)[0]

    f0 = f(0.0)
    best = minimize_scalar(lambda x: f(np.exp(x)), bounds=(np.log(1e-4), np.log(_KIN_SCALE_BOUNDS[1])),
                           method="bounded")
    lam = float(np.exp(best.x)) if best.fun < f0 else 0.0
    return {"likelihood_ratio": float(max(f0 - best.fun, 0.0)), "scale_free": lam}


def search_scales(fit: RefineState, blocks, lam_now: bool) -> None:
    """The random effects' scales by REML on the linearised model with normal-equation
    ``blocks`` (A_tt, A_td, A_dd, b_t, b_d, yy): the free station scales and, with
    ``lam_now``, the kinematic prior's factor, set in ``fit.s_hat`` and ``fit.lam``.
    The search (:func:`_reml_search`, on their logarithms) starts from the last scales
    and, while a scale sits near its floor, from the first start too."""
    free, se, fixed, s_hat, lam = fit.free, fit.se, fit.fixed, fit.s_hat, fit.lam

    def unpack(x):
        sv = s_hat.copy()
        sv[free] = np.exp(x[:len(free)])
        for i in range(2):
            if se is not None and fixed[i] is not None:
                sv[i] = fixed[i]
        return sv, (float(np.exp(x[-1])) if lam_now else lam)

    # each prior column's scale: a free station scale, the kinematic
    # factor, or held (the last group, no gradient wanted)
    n_x = len(free) + int(lam_now)
    group = np.concatenate([
        np.tile([free.index(g) if g in free else n_x for g in (0, 0, 0, 1, 1, 1)], fit.K)
        if se is not None else np.zeros(0, dtype=int),
        np.full(len(fit.rand_cols), len(free) if lam_now else n_x, dtype=int)]).astype(int)

    def objective(x):
        sv, lam_ = unpack(x)
        value, grad, hess = _neg2_reml_derivatives(fit.prior_sd(sv, lam_), group, n_x + 1, *blocks)
        return value, grad[:n_x], hess[:n_x, :n_x]

    bounds = [(np.log(_SCALE_BOUNDS[i][0]), np.log(_SCALE_BOUNDS[i][1])) for i in free]
    x0 = [np.log(s_hat[i]) for i in free]
    if lam_now:
        bounds.append((np.log(_KIN_SCALE_BOUNDS[0]), np.log(_KIN_SCALE_BOUNDS[1])))
        x0.append(np.log(lam))
    lo_hi = ([b[0] for b in bounds], [b[1] for b in bounds])
    # from the last scales and from the first start: near its floor a
    # scale's gradient vanishes (it moves sigma^2 by 2 sigma^2), so a
    # scale that once fell there could not leave it from the last scales
    # alone, however much the data came to ask for it
    starts = [np.clip(x0, *lo_hi)]
    first = np.clip([np.log(fit.s_start[i]) for i in free] + ([np.log(lam)] if lam_now else []), *lo_hi)
    near_floor = starts[0][:len(free)] < np.array(lo_hi[0][:len(free)]) + np.log(100.0)
    if near_floor.any() and np.abs(first - starts[0]).max() > 1e-3 and not fit.starts_agreed:
        starts.append(first)
    found = [_reml_search(objective, x, *lo_hi) for x in starts]
    best = min(found, key=lambda res: res[1])
    # once both starts end at the same scales, the first start adds nothing
    # more: from here the linearisation, and the pose noise's weight, move
    # little (a later search from one start leaves that as it was)
    if len(found) == 2:
        fit.starts_agreed = bool(np.abs(found[0][0] - found[1][0]).max() < 1e-6)
    fit.s_hat, fit.lam = unpack(best[0])
