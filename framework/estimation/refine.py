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

from dataclasses import dataclass, field

import numpy as np

from .. import geometry as geo
from .problem import Problem


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
    return _Linearisation(res, J, W, C, SC)


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
) -> RefineResult:
    """Gauss-Newton over all points of ``problem.profiles`` (already cleaned)."""
    R = np.array(R, dtype=float)
    t = np.array(t, dtype=float)
    c = np.array(centre, dtype=float)
    r = float(problem.radius_mm)
    pts = _Points(problem)
    sigma = max(noise.point_noise_mm, 1e-7)
    pose_cov = _pose_cov(noise)
    n_par = 10 if fit_radius else 9
    scale = 1.0
    converged = False
    it = 0
    for outer in range(4 if estimate_pose_noise else 1):
        for it in range(1, max_iterations + 1):
            lin = _linearise(problem, pts, R, t, c, r, fit_radius, scale * pose_cov, sigma)
            step = np.linalg.lstsq(lin.W.apply(lin.J), -lin.W.apply(lin.res), rcond=None)[0]
            R = geo.matrix_from_rotvec(step[:3]) @ R
            t = t + step[3:6]
            c = c + step[6:9]
            if fit_radius:
                r = r + step[9]
            if np.abs(step[:3]).max() < tolerance and np.abs(step[3:]).max() < tolerance * 1e3:
                converged = True
                break
        # variance component of the pose noise: whitened chi^2 in the profiles' 3-D subspaces
        lin = _linearise(problem, pts, R, t, c, r, fit_radius, scale * pose_cov, sigma)
        dof_profiles = 3 * problem.n_profiles - n_par
        s2_profiles = float(lin.W.profile_chi2(lin.res).sum() / max(dof_profiles, 1))
        if not estimate_pose_noise or dof_profiles < 20 or pose_cov.max() == 0 or abs(s2_profiles - 1) < 0.05:
            break
        # move the assumed pose-noise variance toward what the profiles show, and refit
        scale = float(np.clip(scale * s2_profiles, 1e-8, 1e4))

    lin = _linearise(problem, pts, R, t, c, r, fit_radius, scale * pose_cov, sigma)
    Jw = lin.W.apply(lin.J)
    ew = lin.W.apply(lin.res)
    info = Jw.T @ Jw
    dof = max(len(lin.res) - n_par, 1)
    return RefineResult(
        R, t, c, r, np.linalg.pinv(info), np.split(lin.res, np.cumsum(pts.counts)[:-1]), lin.C, lin.SC, it,
        converged, float(ew @ ew / dof), scale,
        {
            "information_condition_number": float(np.linalg.cond(info)),
            "profile_variance_factor": s2_profiles,
            "point_noise_mm_assumed": sigma,
            "profile_chi2": lin.W.profile_chi2(lin.res).tolist(),
        },
    )


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
