"""Residuals and the whitened least-squares problem of one linearisation, reduced to each shot.

The residual of a profile point and the noise model are those of :mod:`spherecal.estimation.refine`:
per shot, the sphere centre in the sensor frame ``C_i``, its Jacobians and its covariance
from the pose noise; the per-point work is nine sums a profile (:func:`_point_sums`).
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import numpy as np

from spherecal.core import geometry as geo
from spherecal.estimation.blocks import BLOCK_POINTS, profile_blocks
from spherecal.estimation.problem import (
    KIND_CIRCLE, KIND_PROFILE, KIND_SPHERE_CENTRE, Problem, fill_unknown, unknown_variances,
)


@dataclass(frozen=True)
class NoiseAssumptions:
    """Noise the estimator assumes (standard deviations, per axis)."""

    point_noise_mm: float
    pose_translation_noise_mm: float
    pose_rotation_noise_deg: float


def _centres(problem: Problem, R, t, c):
    """u_i = R_A^T (c - tA_i) - t and C_i = R^T u_i, (n, 3) each."""
    u = np.einsum("nji,nj->ni", problem.R_sphere_from_mount, c - problem.t_sphere_from_mount) - t
    return u, u @ R


def _centre_jacobian(problem: Problem, R, u):
    """dC_i/d(w, t, c): (n, 3, 9)."""
    n = len(u)
    J = np.empty((n, 3, 9))
    J[:, :, 0:3] = R.T @ geo.skew(u)
    J[:, :, 3:6] = -R.T
    J[:, :, 6:9] = R.T @ np.swapaxes(problem.R_sphere_from_mount, 1, 2)
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


class _Reduced:
    """The whitened least-squares problem of one linearisation, reduced to each shot.

    Every Jacobian column of a profile point m of shot i is ``g_m A_i``: ``g_m`` =
    (d res / d C, 1), a 4-vector per point, times a (4, P) matrix per shot (the sphere
    centre's derivatives, and the radius in the fourth row). The residuals of a profile
    have covariance ``sigma^2 I + G_i S_i G_i^T`` (S_i: its centre's covariance from the
    pose noise), so, with ``T_i = sum_m g_m g_m^T`` and ``s_i = sum_m g_m res_m`` (push
    through and Woodbury, no subtraction of large terms):

    * ``J^T Cov^-1 J`` sums ``A_i^T W_i A_i`` with ``W_i = (sigma^2 I + T_i Sigma_i)^-1 T_i``,
    * ``J^T Cov^-1 res`` sums ``A_i^T w_i`` with ``w_i = (sigma^2 I + T_i Sigma_i)^-1 s_i``,
    * ``res^T Cov^-1 res`` sums ``c_i = (sum_m res_m^2 - s_i^T Sigma_i w_i) / sigma^2``,

    ``Sigma_i`` = diag(S_i, 0). A centre observation is the same with its three rows:
    ``g`` = (d res / d C | radius column) (3, 4) and its covariance. So the normal
    equations cost O(points) once per linearisation (nine sums a point,
    :func:`_point_sums`) and O(shots) for any set of columns, and no per-point Jacobian
    is ever built. ``chi2`` (each shot's whitened chi^2 in its 3-D pose subspace) is
    computed when first asked for: the refinement needs it once a pass."""

    def __init__(self, W, w, c, chi2):
        self.W, self.w, self.c = W, w, c  # (n, 4, 4), (n, 4), (n,)
        self._chi2 = chi2  # (n,), or a function that computes it

    @cached_property
    def chi2(self) -> np.ndarray:
        return self._chi2() if callable(self._chi2) else self._chi2

    def cost(self) -> float:
        return float(self.c.sum())

    def gram(self, X, Y, rows=slice(None)):
        """sum_i X_i^T W_i Y_i for per-shot columns X (n, 4, p), Y (n, 4, q) (of the
        shots ``rows`` only, X and Y holding theirs)."""
        # (a strided view, as the kinematic columns are, goes through matmul's slow
        # loop: 90 ms for 2,000 shots x 36 columns, against 1 ms once contiguous)
        WY = self.W[rows] @ np.ascontiguousarray(Y)
        return np.ascontiguousarray(X).reshape(-1, X.shape[2]).T @ WY.reshape(-1, WY.shape[2])

    def rhs(self, X, z=None, rows=slice(None)):
        """J_X^T Cov^-1 (-res + J z): sum_i X_i^T (W_i z_i - w_i), z (n, 4) per shot."""
        v = -self.w[rows] if z is None else np.einsum("nab,nb->na", self.W[rows], z[rows]) - self.w[rows]
        return X.reshape(-1, X.shape[2]).T @ v.ravel()

    def quad(self, z=None) -> float:
        """(-res + J z)^T Cov^-1 (-res + J z)."""
        if z is None:
            return self.cost()
        return float(self.c.sum() - 2.0 * np.sum(z * self.w) + np.einsum("na,nab,nb->", z, self.W, z))


def _blocks(counts: np.ndarray, target: int) -> list[tuple[int, int, int, int, np.ndarray, np.ndarray]]:
    """:func:`.blocks.profile_blocks` of profiles with ``counts`` points, with per block
    (first profile, end profile, first point, end point, the non-empty profiles'
    positions in the block, their first points relative to the block's)."""
    ends = np.cumsum(counts)
    starts = ends - counts
    out = []
    for p, q in profile_blocks(counts, target):
        nz = np.flatnonzero(counts[p:q])
        out.append((p, q, int(starts[p]), int(ends[q - 1]), nz, starts[p:q][nz] - starts[p]))
    return out


def _point_sums(pts: "_Points", C: np.ndarray, rho: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The residual of every profile point, ``|p - C_yz| - rho`` (M,), and per profile
    (in ``pts.shots`` order) nine sums over its points (9, n): of u_y, u_z, res, u_y^2,
    u_y u_z, u_z^2, u_y res, u_z res and res^2, with u = (p - C_yz) / |p - C_yz| (d res /
    d C_yz = -u). One pass over the points, a block of whole profiles at a time
    (:mod:`.blocks`), every temporary a block long."""
    res = np.empty(pts.M)
    sums = np.zeros((9, len(pts.shots)))
    if not pts.M:
        return res, sums
    cy, cz, rh = C[pts.shots, 1], C[pts.shots, 2], rho[pts.shots]
    cap = pts.block_cap
    buf, dy, dz, dist = np.empty((9, cap)), np.empty(cap), np.empty(cap), np.empty(cap)
    for p0, p1, a, b, nz, local_starts in pts.blocks:
        m = b - a
        if not m:
            continue
        n_per = pts.n_points[p0:p1]
        y, z, d, B = dy[:m], dz[:m], dist[:m], buf[:, :m]
        np.subtract(pts.Py[a:b], np.repeat(cy[p0:p1], n_per), out=y)
        np.subtract(pts.Pz[a:b], np.repeat(cz[p0:p1], n_per), out=z)
        np.multiply(y, y, out=d)
        np.multiply(z, z, out=B[0])
        d += B[0]
        np.sqrt(d, out=d)
        np.maximum(d, 1e-12, out=d)
        r = res[a:b]
        np.subtract(d, np.repeat(rh[p0:p1], n_per), out=r)
        np.divide(y, d, out=B[0])
        np.divide(z, d, out=B[1])
        B[2] = r
        np.multiply(B[0], B[0], out=B[3])
        np.multiply(B[0], B[1], out=B[4])
        np.multiply(B[1], B[1], out=B[5])
        np.multiply(B[0], r, out=B[6])
        np.multiply(B[1], r, out=B[7])
        np.multiply(r, r, out=B[8])
        sums[:, p0 + nz] = np.add.reduceat(B, local_starts, axis=1)
    return res, sums


def _per_shot_sums(g0, sums, pts: "_Points", n):
    """Per shot (n): T = sum g g^T (n, 4, 4), s = sum g res (n, 4) and sum res^2, with
    g = (g0, -u_y, -u_z, 1) (``g0`` (n,): d res / d C_x, one number per shot), from the
    profiles' sums of :func:`_point_sums`."""
    T = np.zeros((n, 4, 4))
    s = np.zeros((n, 4))
    rr = np.zeros(n)
    shots = pts.shots
    su1, su2, sr, s11, s12, s22, s1r, s2r, srr = sums
    g = g0[shots]
    cnt = pts.n_points.astype(float)
    entries = {(0, 0): g * g * cnt, (0, 1): -g * su1, (0, 2): -g * su2, (0, 3): g * cnt,
               (1, 1): s11, (1, 2): s12, (1, 3): -su1, (2, 2): s22, (2, 3): -su2, (3, 3): cnt}
    for (a, b), v in entries.items():
        T[shots, a, b] = T[shots, b, a] = v
    s[shots] = np.column_stack([g * sr, -s1r, -s2r, sr])
    rr[shots] = srr
    return T, s, rr


def _reduce_profiles(T, s, rr, SC, sigma):
    """W, w, c and (a function giving) the pose-subspace chi^2 of profiles with sums T,
    s, rr (see :class:`_Reduced`) and centre covariances SC (n, 3, 3)."""
    n = len(T)
    Sig = np.zeros((n, 4, 4))
    Sig[:, :3, :3] = SC
    Mx = sigma**2 * np.eye(4) + T @ Sig
    W = np.linalg.solve(Mx, T)
    W = 0.5 * (W + np.swapaxes(W, 1, 2))
    w = np.linalg.solve(Mx, s[:, :, None])[:, :, 0]
    c = (rr - np.einsum("na,nab,nb->n", s, Sig, w)) / sigma**2

    def chi2():
        # whitened chi^2 of each profile's 3-D 'pose' subspace: H = G L (L L^T = S_C), with
        # H^T H = V diag(lam) V^T and u = H^T res = L^T s: sum_j (v_j^T u)^2 / (lam_j (sigma^2 + lam_j))
        L = np.linalg.cholesky(SC + 1e-18 * np.eye(3))
        HtH = np.swapaxes(L, 1, 2) @ T[:, :3, :3] @ L
        lam, V = np.linalg.eigh(HtH)
        lam = np.maximum(lam, 0.0)
        ok = np.sqrt(lam) > 1e-12 * max(np.sqrt(lam).max(), 1e-300)
        proj = np.einsum("nab,na->nb", V, np.einsum("nba,nb->na", L, s[:, :3]))
        return np.sum(np.where(ok, proj**2 / np.where(ok, lam * (sigma**2 + lam), 1.0), 0.0), axis=1)

    return W, w, c, chi2


@dataclass
class _Linearisation:
    res: np.ndarray  # (M,) residuals, mm (then 3 per centre observation)
    red: _Reduced  # the whitened problem reduced to each shot
    C: np.ndarray  # (n, 3) predicted sensor-frame centres
    SC: np.ndarray  # (n, 3, 3) their covariance from pose noise
    Jd: np.ndarray  # (n, 3, 6) d C / d(pose error) per shot
    Jc: np.ndarray  # (n, 3, P) d C / d(w, t, c) per shot
    radius_column: np.ndarray | None = None  # (n,) d res / d r per profile point (fitting the radius), else None
    centre_parts: tuple | None = None  # centre residuals (m, 3), their pose-noise covariance (m, 3, 3), given (m, 3, 3), used (m, 3, 3)

    def columns(self, A3: np.ndarray, radius: bool = False) -> np.ndarray:
        """Per-shot columns (n, 4, P) of C-derivatives ``A3`` (n, 3, P) (fourth row: the
        radius, with ``radius`` as the last column)."""
        A = np.zeros((A3.shape[0], 4, A3.shape[2] + int(radius)))
        A[:, :3, :A3.shape[2]] = A3
        if radius:
            A[:, 3, -1] = self.radius_column
        return A


class _Points:
    """All profile points stacked by coordinate (``Py``, ``Pz``: every per-point operation
    reads them contiguously), profile after profile; ``shots``: the shot of each profile,
    ``n_points``: its point count; ``blocks``: the profiles grouped for
    :func:`_point_sums`. The centre observations (``centre_shots``) have no points. The
    last per-point sums are kept (``cache``): a linearisation at the same sphere centres
    (another pose-noise scale, the end of a pass) reuses them."""

    def __init__(self, problem: Problem):
        counts = np.array([len(p) for p in problem.profiles], dtype=int)
        self.counts = counts  # (every shot's, centre observations' 0)
        self.centre_shots = np.flatnonzero(problem.kinds != KIND_PROFILE)
        self.shots = np.flatnonzero(problem.kinds == KIND_PROFILE)
        self.n_points = counts[self.shots]
        self.M = int(self.n_points.sum())
        self.blocks = _blocks(self.n_points, BLOCK_POINTS)
        self.Py, self.Pz = np.empty(self.M), np.empty(self.M)
        for p0, p1, a, b, _, _ in self.blocks:
            if b > a:
                block = np.concatenate([problem.profiles[i] for i in self.shots[p0:p1]])
                self.Py[a:b], self.Pz[a:b] = block[:, 0], block[:, 1]
        self.block_cap = max((b - a for _, _, a, b, _, _ in self.blocks), default=0)
        self.cache = None  # (C, rho, res, sums) of the last linearisation


def _pose_cov(noise: NoiseAssumptions) -> np.ndarray:
    return np.diag([np.radians(noise.pose_rotation_noise_deg) ** 2] * 3 + [noise.pose_translation_noise_mm**2] * 3)


def _linearise(problem, pts: _Points, R, t, c, r, fit_radius, pose_cov, sigma, s2_centre=None,
               centre_cov_frozen: np.ndarray | None = None) -> _Linearisation:
    """Residuals and the whitened problem reduced to each shot (:class:`_Reduced`) at
    (R, t, c, r); see the module docstring. ``s2_centre`` (mm^2, per axis): the variance
    of centre observations given without one. ``centre_cov_frozen`` (m, 3, 3): the centre
    observations' covariance to whiten with instead of the one at (R, t, c, r) (see
    :class:`.state.RefineState`)."""
    n = problem.n_profiles
    u, C = _centres(problem, R, t, c)
    rho = np.sqrt(np.maximum(r * r - C[:, 0] ** 2, 1e-6))
    cached = pts.cache
    if cached is not None and np.array_equal(cached[0], C) and np.array_equal(cached[1], rho):
        res, sums = cached[2], cached[3]
    else:
        pts.cache = None  # (its arrays go before the new ones are made)
        res, sums = _point_sums(pts, C, rho)
        pts.cache = (C.copy(), rho.copy(), res, sums)
    Jc = _centre_jacobian(problem, R, u)
    radius_column = -(r / rho)
    Jd = _pose_noise_jacobian(problem, R, c)
    SC = Jd @ pose_cov @ np.swapaxes(Jd, 1, 2)
    # d res / d C = (C_x / rho, -u_y, -u_z) per point: the first is one number per profile
    T, s, rr = _per_shot_sums(C[:, 0] / rho, sums, pts, n)
    W, w, cc, chi2 = _reduce_profiles(T, s, rr, SC, sigma)
    if not len(pts.centre_shots):
        return _Linearisation(res, _Reduced(W, w, cc, chi2), C, SC, Jd, Jc, radius_column if fit_radius else None)
    cs = pts.centre_shots
    res_c, Gc, Wc, parts = _centre_rows(problem, cs, C, rho, SC, s2_centre, centre_cov_frozen)
    Ci = np.swapaxes(Wc, 1, 2) @ Wc  # covariance^-1
    e = parts[0]
    W[cs] = np.swapaxes(Gc, 1, 2) @ Ci @ Gc
    w[cs] = np.einsum("mba,mbc,mc->ma", Gc, Ci, e)
    cc[cs] = np.einsum("ma,mab,mb->m", e, Ci, e)
    profile_chi2 = chi2

    def chi2():
        out = profile_chi2()
        out[cs] = cc[cs]
        return out

    return _Linearisation(np.concatenate([res, res_c]), _Reduced(W, w, cc, chi2), C, SC, Jd, Jc,
                          radius_column if fit_radius else None, parts)


def _centre_rows(problem, cs, C, rho, SC, s2_centre, cov_frozen=None):
    """Residuals (3 m,), d res / d (C, r) (m, 3, 4: the radius's column last, as
    :meth:`_Linearisation.columns` puts it) and whitening matrices (m, 3, 3) of the
    centre observations ``cs``. A sphere centre: C_i minus the measured centre. A
    circle: (C_y, C_z) minus the measured centre and the radius of the circle the laser
    plane cuts from the predicted sphere, ``sqrt(r^2 - C_x^2)``, minus the measured
    radius (no side of the plane needed). Covariance: the given one (else ``s2_centre``
    I) plus the pose noise's ``G S_C G^T``, or ``cov_frozen`` (m, 3, 3) when given. The
    returned parts carry the covariance used, (m, 3, 3), last."""
    kinds, meas, given = problem.kind[cs], problem.centre_meas[cs], problem.centre_cov[cs]
    m = len(cs)
    Gc = np.zeros((m, 3, 4))
    res = np.zeros((m, 3))
    sph, cir = kinds == KIND_SPHERE_CENTRE, kinds == KIND_CIRCLE
    Gc[sph, :, :3] = np.eye(3)
    res[sph] = C[cs[sph]] - meas[sph]
    Cc, rc = C[cs[cir]], rho[cs[cir]]
    Gc[cir, 0, 1] = 1.0
    Gc[cir, 1, 2] = 1.0
    Gc[cir, 2, 0] = -Cc[:, 0] / rc
    Gc[cir, 2, 3] = -1.0  # (the radius column holds -r / rho: d res / d r = r / rho)
    res[cir] = np.column_stack([Cc[:, 1:] - meas[cir, :2], rc - meas[cir, 2]])
    G3 = Gc[:, :, :3]
    pose_part = G3 @ SC[cs] @ np.swapaxes(G3, 1, 2)
    S = fill_unknown(given, s2_centre if s2_centre is not None else 1.0)
    cov = S + pose_part if cov_frozen is None else cov_frozen
    Wc = np.linalg.inv(np.linalg.cholesky(cov))
    return res.ravel(), Gc, Wc, (res, pose_part, given, cov)


#: Bounds of the estimated variance of centre observations given without one, mm^2.
_CENTRE_VARIANCE_BOUNDS = (1e-8, 2500.0)


def _centre_variance(parts, dof: float, s2_start: float) -> float:
    """The per-axis variance ``s2`` (mm^2) of the centre observations given without a
    covariance that makes the centres' whitened chi^2 equal its degrees of freedom
    (a variance component; the given covariances and the pose noise stay as they are).
    Bisection on log s2: chi^2 falls as s2 grows."""
    e, P, given = parts[:3]
    if not unknown_variances(given).any() or dof <= 0:
        return s2_start

    def chi2(s2):
        S = fill_unknown(given, s2) + P
        return float(np.einsum("mi,mi->", e, np.linalg.solve(S, e[:, :, None])[:, :, 0]))

    lo, hi = np.log(_CENTRE_VARIANCE_BOUNDS[0]), np.log(_CENTRE_VARIANCE_BOUNDS[1])
    if chi2(np.exp(lo)) <= dof:
        return float(np.exp(lo))
    if chi2(np.exp(hi)) >= dof:
        return float(np.exp(hi))
    for _ in range(60):
        mid = 0.5 * (lo + hi)
        if chi2(np.exp(mid)) > dof:
            lo = mid
        else:
            hi = mid
    return float(np.exp(0.5 * (lo + hi)))
