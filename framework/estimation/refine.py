"""Joint refinement over every raw profile point, with its covariance.

Model: for profile i the sphere centre in the sensor frame is
``C_i = X^-1 A_i^-1 c`` (see :mod:`.problem`); the laser plane x = 0 cuts the sphere in
the circle of centre (C_y, C_z) and radius ``rho_i = sqrt(r^2 - C_x^2)``. The residual of
point p = (y, z) is its in-plane distance to that circle, ``|p - C_yz| - rho_i``: the
maximum-likelihood residual for isotropic Gaussian noise in the laser plane.

Noise model: point noise sigma (each of y, z) and robot pose noise (rotation and
translation, base frame) that is shared by all points of one profile. The residuals of a
profile are therefore correlated, ``Cov_i = sigma^2 I + G_i S_Ci G_i^T`` with
``S_Ci`` the covariance of C_i due to the pose noise; we whiten with ``Cov_i^-1/2``
(a rank-3 update, cheap) and solve by Gauss-Newton on the rotation manifold
(``R <- exp([w]) R``, w about the target frame's axes). Unknowns: w (3), t (3), c (3)
and optionally r. The pose-noise scale is re-estimated from the data (variance
component) unless fixed. The covariance is ``(J_w^T J_w)^-1`` of the whitened problem.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np

from .. import geometry as geo
from .problem import Problem, sphere_frame_from_base


@dataclass(frozen=True)
class NoiseAssumptions:
    """Noise the estimator assumes (standard deviations, per axis)."""

    point_noise_mm: float
    pose_translation_noise_mm: float
    pose_rotation_noise_deg: float


@dataclass
class RefineResult:
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
    station_offsets: np.ndarray | None = None  # (K, 6) estimated (omega rad, tau mm) per station
    station_effect_scales: tuple[float, float] = (0.0, 0.0)  # station-to-station s_rot (rad), s_trans (mm)


def _centres(problem: Problem, R, t, c):
    """u_i = R_A^T (c - tA_i) - t and C_i = R^T u_i, (n, 3) each."""
    u = np.einsum("nji,nj->ni", problem.R_A, c - problem.t_A) - t
    return u, u @ R


def _centre_jacobian(problem: Problem, R, u):
    """dC_i/d(w, t, c): (n, 3, 9)."""
    n = len(u)
    J = np.empty((n, 3, 9))
    J[:, :, 0:3] = R.T @ geo.skew(u)
    J[:, :, 3:6] = -R.T
    J[:, :, 6:9] = R.T @ np.swapaxes(problem.R_A, 1, 2)
    return J


def _pose_noise_jacobian(problem: Problem, R, c):
    """dC_i/d(eps_r, eps_t) of base_from_flange noise (base frame): (n, 3, 6)."""
    n = problem.n_profiles
    Ju = np.empty((n, 3, 6))
    R0T = np.swapaxes(problem.R0, 1, 2)
    if problem.mounting == "eye_in_hand":
        Ju[:, :, :3] = R0T @ geo.skew(c - problem.t0)
        Ju[:, :, 3:] = -R0T
    else:
        Ju[:, :, :3] = -geo.skew(np.einsum("nij,j->ni", problem.R0, c))
        Ju[:, :, 3:] = np.eye(3)
    return R.T @ Ju


class _Whitener:
    """Cov_i^-1/2 for each profile, applied to stacked per-point arrays."""

    def __init__(self, G, pid, starts, L, sigma):
        H_rows = np.einsum("mk,mkl->ml", G, L[pid])  # rows of H_i = G_i L_i
        HtH = np.add.reduceat(H_rows[:, :, None] * H_rows[:, None, :], starts, axis=0)
        S2, V = np.linalg.eigh(HtH)
        S2 = np.maximum(S2, 0.0)
        S = np.sqrt(S2)
        ok = S > 1e-12 * max(S.max(), 1e-300)
        inv_S = np.where(ok, 1.0 / np.where(ok, S, 1.0), 0.0)
        self.Q = np.einsum("ml,mlk->mk", H_rows, (V * inv_S[:, None, :])[pid])
        self.gain = np.where(ok, 1.0 / np.sqrt(1.0 + S2 / sigma**2) - 1.0, 0.0)  # (n, 3)
        self.pid, self.starts, self.sigma = pid, starts, sigma

    def project(self, x):
        """Q_i^T x_i per profile: (n, 3, K) for x (M, K)."""
        return np.add.reduceat(self.Q[:, :, None] * x[:, None, :], self.starts, axis=0)

    def apply(self, x):
        x2 = x if x.ndim == 2 else x[:, None]
        Y = self.project(x2) * self.gain[:, :, None]
        out = (x2 + np.einsum("mk,mkj->mj", self.Q, Y[self.pid])) / self.sigma
        return out if x.ndim == 2 else out[:, 0]

    def profile_chi2(self, e):
        """Whitened chi^2 of each profile's 3-D 'pose' subspace, (n,)."""
        Y = self.project(e[:, None])[:, :, 0] * (self.gain + 1.0) / self.sigma
        return np.sum(Y**2, axis=1)


@dataclass
class _Linearisation:
    res: np.ndarray  # (M,) residuals, mm
    J: np.ndarray  # (M, P) d res / d params
    W: _Whitener
    C: np.ndarray  # (n, 3) predicted sensor-frame centres
    SC: np.ndarray  # (n, 3, 3) their covariance from pose noise
    G: np.ndarray  # (M, 3) d res / d C per point
    Jd: np.ndarray  # (n, 3, 6) d C / d(pose error) per profile


class _Points:
    """All profile points stacked, with the profile of each."""

    def __init__(self, problem: Problem):
        counts = np.array([len(p) for p in problem.profiles])
        self.counts = counts
        self.starts = np.concatenate([[0], np.cumsum(counts)[:-1]])
        self.pid = np.repeat(np.arange(problem.n_profiles), counts)
        self.P = np.vstack(problem.profiles)


def _pose_cov(noise: NoiseAssumptions) -> np.ndarray:
    return np.diag([np.radians(noise.pose_rotation_noise_deg) ** 2] * 3 + [noise.pose_translation_noise_mm**2] * 3)


def _linearise(problem, pts: _Points, R, t, c, r, fit_radius, pose_cov, sigma) -> _Linearisation:
    """Residuals, Jacobian and whitening at (R, t, c, r); see the module docstring."""
    pid = pts.pid
    u, C = _centres(problem, R, t, c)
    rho = np.sqrt(np.maximum(r * r - C[:, 0] ** 2, 1e-6))
    d = pts.P - C[pid, 1:]
    dist = np.maximum(np.hypot(d[:, 0], d[:, 1]), 1e-12)
    res = dist - rho[pid]
    G = np.column_stack([(C[:, 0] / rho)[pid], -d[:, 0] / dist, -d[:, 1] / dist])
    J = np.einsum("mk,mkp->mp", G, _centre_jacobian(problem, R, u)[pid])
    if fit_radius:
        J = np.column_stack([J, -(r / rho)[pid]])
    Jd = _pose_noise_jacobian(problem, R, c)
    SC = Jd @ pose_cov @ np.swapaxes(Jd, 1, 2)
    W = _Whitener(G, pid, pts.starts, np.linalg.cholesky(SC + 1e-18 * np.eye(3)), sigma)
    return _Linearisation(res, J, W, C, SC, G, Jd)


@dataclass(frozen=True)
class StationEffects:
    """Systematic robot error shared by the shots of a station (a random effect).

    Station k's flange poses are off by one small pose error ``delta_k = (omega_k,
    tau_k)``, rotation (rad, base axes, about the flange) and translation (mm, base), on
    top of the per-shot pose noise: ``R0 <- exp(omega_k) R0``, ``t0 <- t0 + tau_k``.
    Prior: ``delta_k = delta_common + delta'_k``. ``delta'_k`` is independent per
    station with per-axis standard deviations ``(rotation_deg, translation_mm)``,
    estimated from the data by REML unless given: the station-to-station inconsistency
    is its evidence. ``delta_common`` is shared by every station, per-axis standard
    deviations ``(common_rotation_deg, common_translation_mm)``: the robot's error over
    the calibration region, which one sphere location cannot measure (it moves the
    sphere centre or the transform as a whole), so it enters as prior uncertainty only,
    from the robot's stated accuracy."""

    enabled: bool = True
    rotation_deg: float | None = None
    translation_mm: float | None = None
    common_rotation_deg: float = 0.0
    common_translation_mm: float = 0.0


#: Bounds of the estimated station-effect scales (rad, mm).
_SCALE_BOUNDS = ((1e-7, np.radians(5.0)), (1e-5, 50.0))


def _station_sqrt_cov(n_stations: int, s_rot: float, s_trans: float) -> np.ndarray:
    """A square root ``L`` of the prior covariance of the stacked station-to-station
    offsets (6K,): ``L L^T = I (x) diag(s_rot^2 I3, s_trans^2 I3)``. (The common part is
    a consider parameter, handled in the covariance only.)"""
    return np.kron(np.eye(n_stations), np.diag([s_rot] * 3 + [s_trans] * 3))


def _apply_station_offsets(problem: Problem, delta: np.ndarray) -> Problem:
    """``problem`` with station k's flange poses moved by ``delta[k]`` (see StationEffects)."""
    if not np.any(delta):
        return problem
    d = delta[problem.station_of]
    R0 = geo.matrix_from_rotvec(d[:, :3]) @ problem.R0
    t0 = problem.t0 + d[:, 3:]
    R_A, t_A = sphere_frame_from_base(problem.mounting, R0, t0)
    return replace(problem, R0=R0, t0=t0, R_A=R_A, t_A=t_A)


def _neg2_reml(L, A_tt, A_td, A_dd, b_t, b_d, yy) -> float:
    """-2 x REML log-likelihood of the linearised model ``y = J_t b + J_d delta + e``,
    e ~ N(0, I), delta ~ N(0, L L^T), from its normal-equation blocks (Woodbury and
    Sylvester keep every matrix small and stable as L -> 0)."""
    B = np.eye(L.shape[1]) + L.T @ A_dd @ L
    cB = np.linalg.cholesky(B)
    logdet_V = 2.0 * np.sum(np.log(np.diag(cB)))

    def Cinv(u):  # (Sigma^-1 + A_dd)^-1 u = L B^-1 L^T u
        return L @ np.linalg.solve(B, L.T @ u)

    XVX = A_tt - A_td @ Cinv(A_td.T)
    XVy = b_t - A_td @ Cinv(b_d)
    yVy = yy - b_d @ Cinv(b_d)
    sign, logdet_X = np.linalg.slogdet(XVX)
    if sign <= 0:
        return np.inf
    quad = yVy - XVy @ np.linalg.solve(XVX, XVy)
    return float(logdet_V + logdet_X + quad)


def _station_blocks(Jw_t, Jw_d, yw, station_rows):
    """Normal-equation blocks with the station effects' columns kept per station."""
    K = len(station_rows)
    p = Jw_t.shape[1]
    A_td = np.zeros((p, 6 * K))
    A_dd = np.zeros((6 * K, 6 * K))
    b_d = np.zeros(6 * K)
    for k, rows in enumerate(station_rows):
        Jd = Jw_d[rows]
        sl = slice(6 * k, 6 * k + 6)
        A_td[:, sl] = Jw_t[rows].T @ Jd
        A_dd[sl, sl] = Jd.T @ Jd
        b_d[sl] = Jd.T @ yw[rows]
    return Jw_t.T @ Jw_t, A_td, A_dd, Jw_t.T @ yw, b_d


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
) -> RefineResult:
    """Gauss-Newton over all points of ``problem.profiles`` (already cleaned).

    With ``station_effects`` enabled (and two or more stations) each station's flange
    poses carry one shared, unknown pose error with a Gaussian prior (see
    :class:`StationEffects`): the fit estimates the transform with those offsets
    marginalised, and their scale by restricted maximum likelihood (REML) on the
    linearised model. The covariance is that of the transform with the offsets
    integrated out."""
    from scipy.optimize import minimize

    R = np.array(R, dtype=float)
    t = np.array(t, dtype=float)
    c = np.array(centre, dtype=float)
    r = float(problem.radius_mm)
    pts = _Points(problem)
    sigma = max(noise.point_noise_mm, 1e-7)
    pose_cov = _pose_cov(noise)
    n_par = 10 if fit_radius else 9
    K = len(problem.station_labels)
    se = station_effects if station_effects is not None and station_effects.enabled and K >= 2 else None
    delta = np.zeros((K, 6))
    station_rows = [np.flatnonzero(problem.station_of[pts.pid] == k) for k in range(K)]
    fixed = (None if se is None else
             (None if se.rotation_deg is None else np.radians(se.rotation_deg),
              se.translation_mm))
    s_hat = np.array([np.radians(0.01), 0.1])  # start of the station-effect scales
    scale = 1.0
    converged = False
    it = 0
    s2_profiles = 1.0

    def linearise(scale_):
        return _linearise(_apply_station_offsets(problem, delta), pts, R, t, c, r, fit_radius, scale_ * pose_cov, sigma)

    for outer in range(4 if estimate_pose_noise else 1):
        for it in range(1, max_iterations + 1):
            lin = linearise(scale)
            Jw = lin.W.apply(lin.J)
            ew = lin.W.apply(lin.res)
            if se is None:
                step = np.linalg.lstsq(Jw, -ew, rcond=None)[0]
            else:
                Jw_d = _station_jacobian(lin, pts)
                yw = -ew + _stack_station_effect(Jw_d, delta, problem.station_of[pts.pid])
                A_tt, A_td, A_dd, b_t, b_d = _station_blocks(Jw, Jw_d, yw, station_rows)
                yy = float(yw @ yw)
                free = [i for i in range(2) if fixed[i] is None]
                if free:
                    def objective(log_s):
                        sv = s_hat.copy()
                        sv[free] = np.exp(log_s)
                        for i in range(2):
                            if fixed[i] is not None:
                                sv[i] = fixed[i]
                        return _neg2_reml(_station_sqrt_cov(K, *sv), A_tt, A_td, A_dd, b_t, b_d, yy)

                    lo = [np.log(_SCALE_BOUNDS[i][0]) for i in free]
                    hi = [np.log(_SCALE_BOUNDS[i][1]) for i in free]
                    x0 = np.clip(np.log(s_hat[free]), lo, hi)
                    best = minimize(objective, x0, method="L-BFGS-B", bounds=list(zip(lo, hi)))
                    s_hat[free] = np.exp(best.x)
                for i in range(2):
                    if fixed[i] is not None:
                        s_hat[i] = fixed[i]
                Lp = _station_sqrt_cov(K, *s_hat)
                # MAP step in (d theta, eta) with delta = L eta: normal matrix stays regular as L -> 0
                N = np.block([[A_tt, A_td @ Lp], [Lp.T @ A_td.T, Lp.T @ A_dd @ Lp + np.eye(Lp.shape[1])]])
                sol = np.linalg.solve(N, np.concatenate([b_t, Lp.T @ b_d]))
                step = sol[:n_par]
                new_delta = (Lp @ sol[n_par:]).reshape(K, 6)
                step_delta = np.abs(new_delta - delta).max()
                delta = new_delta
            R = geo.matrix_from_rotvec(step[:3]) @ R
            t = t + step[3:6]
            c = c + step[6:9]
            if fit_radius:
                r = r + step[9]
            small = np.abs(step[:3]).max() < tolerance and np.abs(step[3:]).max() < tolerance * 1e3
            if se is not None:
                small = small and step_delta < tolerance * 1e3
            if small:
                converged = True
                break
        # variance component of the pose noise: whitened chi^2 in the profiles' 3-D subspaces
        lin = linearise(scale)
        dof_profiles = 3 * problem.n_profiles - n_par - (6 * K if se else 0)
        s2_profiles = float(lin.W.profile_chi2(lin.res).sum() / max(dof_profiles, 1))
        if not estimate_pose_noise or dof_profiles < 20 or pose_cov.max() == 0 or abs(s2_profiles - 1) < 0.05:
            break
        # move the assumed pose-noise variance toward what the profiles show, and refit
        scale = float(np.clip(scale * s2_profiles, 1e-8, 1e4))

    lin = linearise(scale)
    Jw = lin.W.apply(lin.J)
    ew = lin.W.apply(lin.res)
    info = Jw.T @ Jw
    cov_fixed = np.linalg.pinv(info)  # with the station offsets known (no systematic error)
    diagnostics = {
        "information_condition_number": float(np.linalg.cond(info)),
        "profile_variance_factor": s2_profiles,
        "point_noise_mm_assumed": sigma,
        "profile_chi2": lin.W.profile_chi2(lin.res).tolist(),
    }
    cov = cov_robot_frame = cov_fixed
    if se is not None:
        Jw_d = _station_jacobian(lin, pts)
        A_tt, A_td, A_dd, _, _ = _station_blocks(Jw, Jw_d, np.zeros(len(ew)), station_rows)
        # GLS covariance with the station-to-station offsets integrated out ...
        Lp = _station_sqrt_cov(K, *s_hat)
        B = np.eye(Lp.shape[1]) + Lp.T @ A_dd @ Lp

        def Cinv(u):
            return Lp @ np.linalg.solve(B, Lp.T @ u)

        cov_robot_frame = np.linalg.pinv(A_tt - A_td @ Cinv(A_td.T))
        # ... plus the common offset as a 'consider' parameter: not estimated (one sphere
        # location cannot tell it), its prior spread propagated through the estimator
        sum_cols = np.kron(np.ones((K, 1)), np.eye(6))  # the common offset moves every station
        A_tc, A_dc = A_td @ sum_cols, A_dd @ sum_cols
        S = cov_robot_frame @ (A_tc - A_td @ Cinv(A_dc))
        common = np.diag([np.radians(se.common_rotation_deg) ** 2] * 3 + [se.common_translation_mm**2] * 3)
        cov = cov_robot_frame + S @ common @ S.T
        diagnostics["station_effects"] = {
            "rotation_deg": float(np.degrees(s_hat[0])),
            "translation_mm": float(s_hat[1]),
            "estimated": [fixed[0] is None, fixed[1] is None],
            "common_rotation_deg": se.common_rotation_deg,
            "common_translation_mm": se.common_translation_mm,
            "offsets": {lab: {"rotation_deg": np.degrees(delta[k, :3]).tolist(), "translation_mm": delta[k, 3:].tolist()}
                        for k, lab in enumerate(problem.station_labels)},
        }
    dof = max(len(lin.res) - n_par, 1)
    return RefineResult(
        R, t, c, r, cov, np.split(lin.res, np.cumsum(pts.counts)[:-1]), lin.C, lin.SC, it,
        converged, float(ew @ ew / dof), scale, diagnostics, covariance_without_robot_error=cov_fixed,
        covariance_robot_frame=cov_robot_frame, station_offsets=delta, station_effect_scales=(float(s_hat[0]), float(s_hat[1])) if se else (0.0, 0.0),
    )


def _station_jacobian(lin: "_Linearisation", pts: _Points) -> np.ndarray:
    """Whitened d res / d(station offset), (M, 6): each point against its station's offset."""
    return lin.W.apply(np.einsum("mk,mkp->mp", lin.G, lin.Jd[pts.pid]))


def _stack_station_effect(Jw_d, delta, station_of_point):
    """J_d delta per point (whitened), for the station of each point."""
    return np.einsum("mp,mp->m", Jw_d, delta[station_of_point])


def cramer_rao_bound(problem_true: Problem, R, t, centre, noise: NoiseAssumptions, fit_radius: bool = False) -> np.ndarray:
    """Cramer-Rao bound of (w, t, c[, r]) for the noise model of :mod:`.refine`,
    evaluated at the true parameters on the noise-free profile points of
    ``problem_true`` (poses = true poses). Linearised Gaussian model: Fisher information
    ``sum_i J_i^T Cov_i^-1 J_i``."""
    lin = _linearise(problem_true, _Points(problem_true), np.asarray(R, float), np.asarray(t, float),
                     np.asarray(centre, float), problem_true.radius_mm, fit_radius, _pose_cov(noise),
                     max(noise.point_noise_mm, 1e-9))
    Jw = lin.W.apply(lin.J)
    return np.linalg.inv(Jw.T @ Jw)
