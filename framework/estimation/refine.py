"""Joint refinement over every raw profile point, with its covariance.

Model: for profile i the sphere centre in the sensor frame is
``C_i = X^-1 A_i^-1 c`` (see :mod:`.problem`); the laser plane x = 0 cuts the sphere in
the circle of centre (C_y, C_z) and radius ``rho_i = sqrt(r^2 - C_x^2)``. The residual of
point p = (y, z) is its in-plane distance to that circle, ``|p - C_yz| - rho_i``: the
maximum-likelihood residual for isotropic Gaussian noise in the laser plane.

Noise model: point noise sigma (each of y, z) and robot pose noise (rotation and
translation, base frame) that is shared by all points of one profile. The residuals of a
profile are therefore correlated, ``Cov_i = sigma^2 I + G_i S_Ci G_i^T`` with
``S_Ci`` the covariance of C_i due to the pose noise. Gauss-Newton on the rotation
manifold (``R <- exp([w]) R``, w about the target frame's axes) solves the generalised
least-squares problem, reduced to each shot (:class:`_Reduced`: no per-point Jacobian).
Unknowns: w (3), t (3), c (3) and optionally r. The pose-noise scale is re-estimated
from the data (variance component) unless fixed. The covariance is ``(J^T Cov^-1 J)^-1``.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from functools import cached_property

import numpy as np

from spherecal.core import geometry as geo
from spherecal.core.kinematics import (
    SerialChain, chain_with_errors, error_parameter_names, flange_corrections, flange_error_jacobian,
)
from spherecal.estimation.blocks import BLOCK_POINTS, profile_blocks
from spherecal.estimation.problem import (
    KIND_CIRCLE, KIND_PROFILE, KIND_SPHERE_CENTRE, Problem, fill_unknown, sphere_from_mount, unknown_variances,
)


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
        WY = self.W[rows] @ Y
        return X.reshape(-1, X.shape[2]).T @ WY.reshape(-1, WY.shape[2])

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
    :func:`refine`)."""
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


@dataclass(frozen=True)
class KinematicEffects:
    """Systematic robot error as the arm's geometric error (needs each shot's joints).

    The flange pose of shot i is off by ``K(q_i) kappa``: ``kappa`` (6 per joint, see
    :mod:`spherecal.core.kinematics`) are the arm's joint zero offsets, joint origin
    displacements and axis tilts, ``K`` their first-order effect on the flange pose at the
    shot's joints, applied exactly through the chain. Unlike a per-station offset, this
    ties the error of every shot to every other through the arm's geometry, including its
    change along a sweep.

    ``prior_sd`` (rad and mm, per parameter) is the spread of an uncalibrated arm, a
    floor: the fit may widen it by a factor estimated from the data (REML) unless
    ``estimate_scale`` is False. With ``identify`` the parameters the data determine (the identifiability test
    of :func:`identifiable_kinematic_parameters`) are estimated without prior (kinematic
    calibration); the others keep their prior, unscaled, and only widen the covariance.

    With ``select_by_evidence`` (the ``auto`` robot error model) the data decide: when
    they show no geometric error of the arm (the REML likelihood ratio of the prior's
    scale free against zero, :func:`_kinematic_evidence`, below
    :data:`KINEMATIC_EVIDENCE_LR`), the fit is the pose-noise-only one, efficient on an
    exact or calibrated arm, and the parameters the data barely see are *considered*:
    not estimated, their prior spread propagated into the covariance.
    ``consider_columns`` (set by that choice) selects that mode directly."""

    chain: SerialChain
    prior_sd: np.ndarray
    estimate_scale: bool = True
    identify: bool = False
    select_by_evidence: bool = False
    consider_columns: tuple[int, ...] | None = None


#: A marginalised kinematic parameter whose posterior spread stays above this share of its
#: prior's is one the data barely see: left out of the robot-frame covariance.
SEEN_POSTERIOR_SHARE = 0.5
#: Bounds of the estimated station-effect scales (rad, mm) and of the kinematic prior's factor.
_SCALE_BOUNDS = ((1e-7, np.radians(5.0)), (1e-5, 50.0))
_KIN_SCALE_BOUNDS = (1.0, 30.0)  # the stated prior is a floor
#: REML likelihood ratio (prior scale free against zero) above which the data show the
#: arm's geometric error. Under no such error it follows a 50:50 mixture of chi^2_0 and
#: chi^2_1: 5.41 is its 1 % point (1 exact arm in 100 gets the cautious kinematic fit).
#: Measured on the benchmark's worlds: 0-0.2 on an exact arm, 20-1,700 on an
#: uncalibrated one (docs/estimation.md).
KINEMATIC_EVIDENCE_LR = 5.41
#: Relative size below which a kinematic parameter's effect, once the transform, sphere
#: and the parameters before it are projected out, counts as not identifiable.
IDENTIFIABILITY_TOLERANCE = 1e-4


def identifiable_kinematic_parameters(J_fixed: np.ndarray, J_kin: np.ndarray, prior_sd: np.ndarray,
                                      tolerance: float = IDENTIFIABILITY_TOLERANCE):
    """Which kinematic parameters the data can tell apart from the transform, the sphere
    and each other: Gram-Schmidt in parameter order over the columns of ``J_kin`` (scaled
    by ``prior_sd``), after projecting out those of ``J_fixed``. A parameter whose column
    keeps less than ``tolerance`` of its norm is not identifiable. Returns the mask and,
    per parameter, that kept share (1: independent, 0: fully absorbed)."""
    B = np.asarray(J_kin, float) * np.asarray(prior_sd, float)
    norms = np.linalg.norm(B, axis=0)  # each column's size before anything is projected out
    Qf, _ = np.linalg.qr(np.asarray(J_fixed, float))
    B = B - Qf @ (Qf.T @ B)
    kept: list[np.ndarray] = []
    share = np.zeros(B.shape[1])
    mask = np.zeros(B.shape[1], dtype=bool)
    ref = max(norms.max(), 1e-300)
    for k in range(B.shape[1]):
        b = B[:, k].copy()
        for q in kept:
            b -= q * (q @ b)
        for q in kept:  # twice is enough (numerical re-orthogonalisation)
            b -= q * (q @ b)
        share[k] = np.linalg.norm(b) / max(norms[k], 1e-300)
        if np.linalg.norm(b) > tolerance * ref and share[k] > tolerance:
            mask[k] = True
            kept.append(b / np.linalg.norm(b))
    return mask, share


def _apply_station_offsets(problem: Problem, delta: np.ndarray) -> Problem:
    """``problem`` with station k's flange poses moved by ``delta[k]`` (see StationEffects)."""
    if not np.any(delta):
        return problem
    d = delta[problem.station_of]
    R0 = geo.matrix_from_rotvec(d[:, :3]) @ problem.R0
    t0 = problem.t0 + d[:, 3:]
    R_sm, t_sm = sphere_from_mount(problem.mounting, R0, t0)
    return replace(problem, R0=R0, t0=t0, R_sphere_from_mount=R_sm, t_sphere_from_mount=t_sm)


def _common_error_design(problem: Problem, Jd: np.ndarray) -> np.ndarray:
    """Per-shot derivatives (n, 3, 6) of the predicted sphere centres with respect to the
    robot's common error (rotation rad, translation mm, base axes): the part of the
    robot's error that the transform absorbs, which one sphere location cannot tell apart
    from it. ``Jd``: their derivatives with respect to a flange pose error (omega about
    the flange, tau; see :class:`StationEffects`).

    In eye-to-hand it is an error of the arm's motion as seen from the base, a rotation of
    the work region about its centre p and a shift: shot i's flange turns by ``omega``
    and moves by ``omega x (t_i - p) + tau``. It turns every sweep's direction too, so
    it is not a station offset: a common offset of the stations' offsets would leave the
    transform's rotation out. In eye-in-hand it is the flange's own error, which the
    transform on the flange takes whole, kept as it was: ``omega`` and ``tau`` common to
    every shot (base axes), station by station."""
    n = problem.n_profiles
    M = np.zeros((n, 6, 6))
    M[:, :3, :3] = np.eye(3)
    M[:, 3:, 3:] = np.eye(3)
    if problem.mounting == "eye_to_hand":
        M[:, 3:, :3] = -geo.skew(problem.t0 - problem.t0.mean(axis=0))  # omega x d = -[d]x omega
    return Jd @ M


def _apply_kinematic_errors(problem: Problem, chain: SerialChain, kappa: np.ndarray) -> Problem:
    """``problem`` with each reported flange pose corrected by what the geometric errors
    ``kappa`` change at its joints: ``R0 <- R_k R_n^T R0``, ``t0 <- t0 + t_k - t_n`` (k:
    the chain with errors, n: the nominal chain). Exact for poses the nominal model reports."""
    if not np.any(kappa):
        return problem
    dR, dt = flange_corrections(chain, chain_with_errors(chain, kappa), problem.q_rad)
    R0 = dR @ problem.R0
    t0 = problem.t0 + dt
    R_sm, t_sm = sphere_from_mount(problem.mounting, R0, t0)
    return replace(problem, R0=R0, t0=t0, R_sphere_from_mount=R_sm, t_sphere_from_mount=t_sm)


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


#: A Gauss-Newton step the line search had to cut ends the iterations when the whole step
#: is at most this share of each parameter's standard deviation: the estimate is then
#: within 1/20 of its uncertainty of where the steps lead, where the cost's curvature is
#: no longer the linearisation's (seen with 0.02 deg of orientation read noise in
#: eye-to-hand: steps of 1-2.5 % of a sd cut to 1/256, fifty times over, "not converged").
STALLED_STEP_SHARE = 0.05
#: ... after this many cut steps in a row (a step cut once near the end of a normal
#: convergence leaves the tolerance to end it, as before).
STALLED_CUT_STEPS = 3


#: Grid points per free station scale where the covariance is averaged over the scales'
#: posterior (:func:`_scale_averaged_covariance`), and how far the grid reaches: to where
#: -2 x the REML log-likelihood has risen this much above its minimum (e^-15 of its peak).
_SCALE_GRID_POINTS = 16
_SCALE_GRID_RISE = 20.0


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


def _effect_blocks(red: _Reduced, At, As, Ak, z, station_shots):
    """Normal-equation blocks of ``y = J_t b + [J_s | J_k] d + e`` with y = -res + J z
    (``z`` (n, 4) per shot, or None): per-shot fixed-effect columns ``At`` (n, 4, p),
    station-offset columns ``As`` (n, 4, 6) (each shot against its own station's six,
    ``station_shots[k]`` the shots of station k) and dense kinematic columns ``Ak``
    (n, 4, q); either may be None. Returns (A_tt, A_td, A_dd, b_t, b_d, yy)."""
    K = len(station_shots) if As is not None else 0
    q = Ak.shape[2] if Ak is not None else 0
    p = At.shape[2]
    A_td = np.zeros((p, 6 * K + q))
    A_dd = np.zeros((6 * K + q, 6 * K + q))
    b_d = np.zeros(6 * K + q)
    for k, rows in enumerate(station_shots[:K]):
        Xs = As[rows]
        sl = slice(6 * k, 6 * k + 6)
        A_td[:, sl] = red.gram(At[rows], Xs, rows)
        A_dd[sl, sl] = red.gram(Xs, Xs, rows)
        b_d[sl] = red.rhs(Xs, z, rows)
        if q:
            A_dd[sl, 6 * K:] = red.gram(Xs, Ak[rows], rows)
            A_dd[6 * K:, sl] = A_dd[sl, 6 * K:].T
    if q:
        A_td[:, 6 * K:] = red.gram(At, Ak)
        A_dd[6 * K:, 6 * K:] = red.gram(Ak, Ak)
        b_d[6 * K:] = red.rhs(Ak, z)
    return red.gram(At, At), A_td, A_dd, red.rhs(At, z), b_d, red.quad(z)


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
) -> RefineResult:
    """Gauss-Newton over all points of ``problem.profiles`` (already cleaned).

    With ``station_effects`` enabled (and two or more stations) each station's flange
    poses carry one shared, unknown pose error with a Gaussian prior (see
    :class:`StationEffects`); with ``kinematic_effects`` (and joints in the problem) every
    pose carries the error of the arm's geometry (see :class:`KinematicEffects`). The fit
    estimates the transform with those errors marginalised, and their scales by
    restricted maximum likelihood (REML) on the linearised model. The covariance is that
    of the transform with the errors integrated out."""
    R = np.array(R, dtype=float)
    t = np.array(t, dtype=float)
    c = np.array(centre, dtype=float)
    r = float(problem.radius_mm)
    pts = _Points(problem)
    sigma = max(noise.point_noise_mm, 1e-7)
    pose_cov = _pose_cov(noise)
    n_geo = 10 if fit_radius else 9
    K = len(problem.station_labels)
    se = station_effects if station_effects is not None and station_effects.enabled and K >= 2 else None
    ke = kinematic_effects if kinematic_effects is not None and problem.q_rad is not None else None
    delta = np.zeros((K, 6))
    station_shots = [np.flatnonzero(problem.station_of == k) for k in range(K)]
    # centre observations given without a covariance: one variance per axis, estimated
    # from their residuals (a variance component, like the pose noise's scale)
    n_shots = problem.n_profiles
    m_centres = len(pts.centre_shots)
    estimate_centre = bool(m_centres) and bool(unknown_variances(problem.centre_cov[pts.centre_shots]).any())
    s2_centre = None
    if m_centres:
        s2_centre = 1.0 if estimate_centre else None
        if estimate_centre:
            start = _linearise(problem, pts, R, t, c, r, fit_radius, pose_cov, sigma, 1.0)
            s2_centre = _centre_variance(start.centre_parts, 3 * m_centres - 9 * m_centres / n_shots, 1.0)
    fixed = (None if se is None else
             (None if se.rotation_deg is None else np.radians(se.rotation_deg),
              se.translation_mm))
    s_start = np.array([np.radians(0.01), 0.1])  # start of the station-effect scales
    s_hat = s_start.copy()
    # kinematic parameters: identified (fixed effects, in the parameter vector) or random
    n_kin = 0 if ke is None else 6 * ke.chain.n_joints
    kappa = np.zeros(n_kin)
    kin_prior = np.zeros(n_kin) if ke is None else np.asarray(ke.prior_sd, dtype=float)
    kin_identifiable = np.zeros(n_kin, dtype=bool)
    kin_share = np.zeros(n_kin)
    if ke is not None:
        Jc_geo, Jc_kin = _centre_design(problem, R, t, c, ke.chain, fit_radius)
        kin_identifiable, kin_share = identifiable_kinematic_parameters(Jc_geo, Jc_kin, kin_prior)
    id_cols = np.flatnonzero(kin_identifiable) if ke is not None and ke.identify else np.array([], dtype=int)
    rand_cols = np.flatnonzero(~np.isin(np.arange(n_kin), id_cols))  # (np.setdiff1d imports numpy.ma)
    rand_cols = rand_cols[kin_prior[rand_cols] > 0]
    consider_cols = np.array([], dtype=int)
    if ke is not None and ke.consider_columns is not None:
        consider_cols, rand_cols = np.asarray(ke.consider_columns, dtype=int), np.array([], dtype=int)
    if ke is not None and ke.select_by_evidence and se is None and not ke.identify and len(rand_cols):
        return _refine_by_evidence(problem, R, t, c, noise, fit_radius, estimate_pose_noise, max_iterations,
                                   tolerance, ke, rand_cols)
    n_kin_fitted = len(id_cols) + len(rand_cols)
    lam = 1.0
    n_par = n_geo + len(id_cols)
    scale = 1.0
    converged = False
    it = 0
    s2_profiles = 1.0
    step_delta = 0.0

    def current(problem_):
        p = problem_
        if ke is not None:
            p = _apply_kinematic_errors(p, ke.chain, kappa)
        return _apply_station_offsets(p, delta)

    # the centre observations' covariance depends on the parameters (the pose noise seen
    # through the transform and, for a circle, through where the plane cuts the sphere).
    # Within a pass of Gauss-Newton it is held at its value at the pass's start (iteratively
    # reweighted least squares), so that the cost the line search compares is the one the
    # step minimises; each pass re-evaluates it until a pass no longer moves the solution.
    # (Re-evaluated at every step, the step aims at the reweighted solution while the
    # line search judges by a cost with moving weights: where that covariance dominates,
    # as for exact centres with the centre noise at its floor, the two disagree by about
    # 1e-4 standard deviations and the steps crawl there, halved, for ever.)
    centre_cov_frozen = None

    def linearise(scale_):
        return _linearise(current(problem), pts, R, t, c, r, fit_radius, scale_ * pose_cov, sigma, s2_centre,
                          centre_cov_frozen=centre_cov_frozen)

    def kin_columns(lin):
        """Per-shot d res / d kappa (n, 4, n_kin)."""
        return lin.columns(lin.Jd @ flange_error_jacobian(chain_with_errors(ke.chain, kappa), problem.q_rad))

    def prior_sd(sv, lam_):
        """Prior spread of each random effect (station offsets (6 K,): s_rot, s_rot, s_rot,
        s_trans, ... per station; then the random kinematic parameters): the diagonal of
        the prior's square root L (L L^T = I (x) diag(s_rot^2 I3, s_trans^2 I3) for the
        stations; the common part is a consider parameter, in the covariance only)."""
        return np.concatenate([np.tile(np.repeat(sv, 3), K) if se is not None else [],
                               lam_ * kin_prior[rand_cols]])

    def sqrt_prior(sv, lam_):
        return np.diag(prior_sd(sv, lam_))

    def design(lin):
        """Per-shot fixed-effect columns, station columns, random kinematic columns."""
        At = lin.columns(lin.Jc, fit_radius)
        As = lin.columns(lin.Jd) if se is not None else None
        Ak = None
        if ke is not None:
            Kk = kin_columns(lin)
            if len(id_cols):
                At = np.concatenate([At, Kk[:, :, id_cols]], axis=2)
            Ak = Kk[:, :, rand_cols] if len(rand_cols) else None
        return At, As, Ak

    def shift(As, Ak):
        """J z of the random effects now, per shot (n, 4)."""
        z = np.zeros((n_shots, 4))
        if As is not None:
            z += np.einsum("nap,np->na", As, delta[problem.station_of])
        if Ak is not None:
            z += Ak @ kappa[rand_cols]
        return z

    # the prior's scale: the stated spread is a floor, the data may widen it (REML)
    estimate_lam = (ke is not None and ke.estimate_scale and not ke.identify
                    and bool(np.any(kin_identifiable[rand_cols])))
    any_random = se is not None or len(rand_cols) > 0
    free = [i for i in range(2) if se is not None and fixed[i] is None]

    def state():
        return R, t, c, r, delta.copy(), kappa.copy()

    def penalised_cost(lin_, sv, lam_):
        """The MAP objective: whitened residuals plus the random effects against their prior."""
        cost = lin_.red.cost()
        if any_random:
            d = np.concatenate([delta.ravel() if se is not None else [], kappa[rand_cols]])
            sd = prior_sd(sv, lam_)
            cost += float(np.sum(np.where(sd > 0, d / np.where(sd > 0, sd, 1.0), 0.0) ** 2))
        return cost

    starts_agreed = False  # the REML search's two starts ended at the same scales
    for outer in range(max(4 if estimate_pose_noise else 1, 8 if m_centres else 1)):
        lin = None
        near = False  # scales are re-estimated only near a solution, where the linearisation holds
        first_small = False  # the pass's first step was already below the tolerance
        cut_steps = 0  # Gauss-Newton steps in a row that the line search had to cut
        converged = False  # (of this pass: an earlier pass's convergence says nothing of this one)
        if m_centres:
            centre_cov_frozen = None
            centre_cov_frozen = linearise(scale).centre_parts[3]
        for it in range(1, max_iterations + 1):
            lin = lin if lin is not None else linearise(scale)
            At, As, Ak = design(lin)
            if not any_random:
                normal = lin.red.gram(At, At)
                step = np.linalg.lstsq(normal, lin.red.rhs(At), rcond=None)[0]
                d_new = None
            else:
                A_tt, A_td, A_dd, b_t, b_d, yy = _effect_blocks(lin.red, At, As, Ak, shift(As, Ak), station_shots)
                # the station scales from the start (as they always were); the kinematic
                # prior's factor only near a solution (far from it the misfit of the start
                # would pass for robot error and blow the prior up)
                if free or (estimate_lam and near):
                    lam_now = estimate_lam and near

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
                        np.tile([free.index(g) if g in free else n_x for g in (0, 0, 0, 1, 1, 1)], K)
                        if se is not None else np.zeros(0, dtype=int),
                        np.full(len(rand_cols), len(free) if lam_now else n_x, dtype=int)]).astype(int)

                    def objective(x):
                        sv, lam_ = unpack(x)
                        value, grad, hess = _neg2_reml_derivatives(prior_sd(sv, lam_), group, n_x + 1,
                                                                   A_tt, A_td, A_dd, b_t, b_d, yy)
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
                    first = np.clip([np.log(s_start[i]) for i in free] + ([np.log(lam)] if lam_now else []), *lo_hi)
                    near_floor = starts[0][:len(free)] < np.array(lo_hi[0][:len(free)]) + np.log(100.0)
                    if near_floor.any() and np.abs(first - starts[0]).max() > 1e-3 and not starts_agreed:
                        starts.append(first)
                    found = [_reml_search(objective, x, *lo_hi) for x in starts]
                    best = min(found, key=lambda res: res[1])
                    # once both starts end at the same scales, the first start adds nothing
                    # more: from here the linearisation, and the pose noise's weight, move
                    # little (a later search from one start leaves that as it was)
                    if len(found) == 2:
                        starts_agreed = bool(np.abs(found[0][0] - found[1][0]).max() < 1e-6)
                    s_hat, lam = unpack(best[0])
                if se is not None:
                    for i in range(2):
                        if fixed[i] is not None:
                            s_hat[i] = fixed[i]
                Lp = sqrt_prior(s_hat, lam)
                # MAP step in (d theta, eta) with d = L eta: normal matrix stays regular as L -> 0
                N = np.block([[A_tt, A_td @ Lp], [Lp.T @ A_td.T, Lp.T @ A_dd @ Lp + np.eye(Lp.shape[1])]])
                normal = N
                sol = np.linalg.solve(N, np.concatenate([b_t, Lp.T @ b_d]))
                step = sol[:n_par]
                d_new = Lp @ sol[n_par:]
            # take the step, halved while it makes the penalised cost worse (far from the
            # solution the linearisation can overshoot)
            before = state()
            cost0 = penalised_cost(lin, s_hat, lam)
            # the per-point design is rebuilt at the next point: let it go before the
            # line search builds linearisations (memory: one per-point set at a time)
            At = As = Ak = None
            d_old = np.concatenate([delta.ravel() if se is not None else [], kappa[rand_cols]]) if any_random else None
            frac = 1.0
            for _ in range(12):
                R, t, c, r, delta, kappa = before[0], before[1], before[2], before[3], before[4].copy(), before[5].copy()
                R = geo.matrix_from_rotvec(frac * step[:3]) @ R
                t = t + frac * step[3:6]
                c = c + frac * step[6:9]
                if fit_radius:
                    r = r + frac * step[9]
                if len(id_cols):
                    kappa[id_cols] += frac * step[n_geo:]
                if d_new is not None:
                    d = d_old + frac * (d_new - d_old)
                    if se is not None:
                        delta = d[:6 * K].reshape(K, 6)
                    if len(rand_cols):
                        kappa[rand_cols] = d[6 * K if se is not None else 0:]
                lin = None  # (the previous point's arrays go before the new ones are built)
                lin = linearise(scale)
                if penalised_cost(lin, s_hat, lam) <= cost0 * (1 + 1e-9) + 1e-12:
                    break
                frac *= 0.5
            step_delta = 0.0 if d_new is None else float(np.abs(frac * (d_new - d_old)).max())
            small = np.abs(frac * step[:3]).max() < tolerance and np.abs(frac * step[3:]).max() < tolerance * 1e3
            if any_random:
                small = small and step_delta < tolerance * 1e3
            cut_steps = cut_steps + 1 if frac < 1.0 else 0
            if not small and cut_steps >= STALLED_CUT_STEPS:
                # Gauss-Newton stalled (its steps raise the cost and are cut, again and again):
                # converged when the whole step is a sliver of each parameter's standard
                # deviation (the cost's curvature there is not the linearisation's)
                sd = np.sqrt(np.maximum(np.diag(np.linalg.pinv(normal))[:n_par], 0.0))
                small = bool(np.all(np.abs(step) <= STALLED_STEP_SHARE * sd))
            if it == 1:
                first_small = bool(small)
            was_near = near
            near = near or (np.abs(frac * step[:3]).max() < 1e-5 and np.abs(frac * step[3:6]).max() < 1e-2)
            if small and (was_near or not estimate_lam):
                converged = True
                break
        # variance component of the pose noise: whitened chi^2 in the profiles' 3-D subspaces
        centre_cov_frozen = None
        lin = linearise(scale)
        n_effects = (6 * K if se else 0) + (int(np.count_nonzero(kin_identifiable)) if n_kin_fitted else 0)
        if not m_centres:
            dof_profiles = 3 * problem.n_profiles - n_geo - n_effects
            s2_profiles = float(lin.red.chi2.sum() / max(dof_profiles, 1))
            update_centre = False
        else:
            # the degrees of freedom shared out between profiles and centres by their count
            dof_all = 3 * n_shots - n_geo - n_effects
            dof_profiles = dof_all * len(pts.shots) / n_shots
            s2_profiles = float(lin.red.chi2[pts.shots].sum() / max(dof_profiles, 1)) \
                if len(pts.shots) else 1.0
            update_centre = False
            if estimate_centre:
                s2_new = _centre_variance(lin.centre_parts, dof_all * m_centres / n_shots, s2_centre)
                update_centre = abs(s2_new / s2_centre - 1.0) >= 0.02
        update_pose = not (not estimate_pose_noise or dof_profiles < 20 or pose_cov.max() == 0
                           or abs(s2_profiles - 1) < 0.05)
        # the centres' covariance re-evaluated: one more pass unless this one started at its solution
        reweight = bool(m_centres) and not (converged and first_small)
        if not update_pose and not update_centre and not reweight:
            break
        if update_centre:
            s2_centre = s2_new
        if update_pose:
            # move the assumed pose-noise variance toward what the profiles show, and refit
            scale = float(np.clip(scale * s2_profiles, 1e-8, 1e4))

    lin = linearise(scale)
    At, As, Ak = design(lin)
    # the normal-equation blocks at the solution (with the random effects' right-hand
    # sides: the station model's averaged covariance reuses them whole)
    blocks = _effect_blocks(lin.red, At, As, Ak, shift(As, Ak) if any_random else None, station_shots)
    info, A_tr, A_rr = blocks[:3]
    cov_fixed = np.linalg.pinv(info)  # with the random robot errors known (none)
    diagnostics = {
        "information_condition_number": float(np.linalg.cond(info[:n_geo, :n_geo])),
        "profile_variance_factor": s2_profiles,
        "point_noise_mm_assumed": sigma,
        "profile_chi2": lin.red.chi2.tolist(),
    }
    cov = cov_robot_frame = cov_fixed
    cov_at_scales = None
    kin_posterior_sd = np.zeros(n_kin)
    kinematic_terms = None
    A_tt = info
    n_rand = (6 * K if se is not None else 0) + len(rand_cols)
    Lp = sqrt_prior(s_hat, lam)
    if n_rand:
        # GLS covariance with the random robot errors integrated out
        B = np.eye(n_rand) + Lp.T @ A_rr @ Lp
        Cinv = Lp @ np.linalg.solve(B, Lp.T)
        # = (A_tt - A_tr Cinv A_tr^T)^-1, the top-left block of the inverse of the joint
        # normal matrix in (theta, eta): no subtraction of the large terms the random
        # effects share with the transform (that difference lost seven digits when the
        # arm's parameters absorb most of the information)
        N = np.block([[A_tt, A_tr @ Lp], [Lp.T @ A_tr.T, B]])
        cov_robot_frame = np.linalg.pinv(N)[:n_par, :n_par]
    else:
        Cinv = np.zeros((0, 0))
    cov = cov_robot_frame
    off = 6 * K if se is not None else 0
    hidden = np.zeros(0, dtype=bool)
    if len(rand_cols):
        # posterior spread of the random kinematic parameters
        Lk = Lp[off:, off:]
        S_rr = A_rr - A_tr.T @ np.linalg.pinv(A_tt) @ A_tr
        post = Lk @ np.linalg.solve(np.eye(len(Lk)) + Lk.T @ S_rr[off:, off:] @ Lk, Lk.T)
        kin_posterior_sd[rand_cols] = np.sqrt(np.maximum(np.diag(post), 0.0))
        # relative to the robot's own frame: without the parameters the data barely see
        # (posterior spread over SEEN_POSTERIOR_SHARE of the prior's): they move the poses
        # nearly alike, and the transform or the sphere absorbs them as it absorbs the
        # robot's common error in the station model
        hidden = kin_posterior_sd[rand_cols] >= SEEN_POSTERIOR_SHARE * np.diag(Lk)
    if len(rand_cols) and se is None and not len(id_cols):
        diagnostics["kinematic_evidence"] = {
            **_kinematic_evidence(_effect_blocks(lin.red, At, None, Ak, Ak @ kappa[rand_cols], []),
                                  kin_prior[rand_cols]),
            "threshold": KINEMATIC_EVIDENCE_LR, "selected": "stated"}
    if hidden.any():
        L_rf = Lp.copy()
        L_rf[off + np.flatnonzero(hidden), off + np.flatnonzero(hidden)] = 0.0
        B_rf = np.eye(n_rand) + L_rf.T @ A_rr @ L_rf
        cov_robot_frame = np.linalg.pinv(A_tt - A_tr @ (L_rf @ np.linalg.solve(B_rf, L_rf.T)) @ A_tr.T)

    def consider(cols_t, cols_d, prior_cov):
        """Covariance added by parameters left at zero in the fit, with prior ``prior_cov``."""
        S = cov @ (cols_t - A_tr @ Cinv @ cols_d)
        return S @ prior_cov @ S.T

    if len(consider_cols):
        # the arm's parameters considered: what the data leave of their prior (the
        # posterior at the stated spread; the prior itself where one sphere cannot see
        # them) through the estimator
        Kc = kin_columns(lin)[:, :, consider_cols]
        prior_c = kin_prior[consider_cols]
        JtK = lin.red.gram(At, Kc)
        S_kk = lin.red.gram(Kc, Kc) - JtK.T @ cov_fixed @ JtK
        post_c = prior_c[:, None] * np.linalg.solve(np.eye(len(prior_c)) + prior_c[:, None] * S_kk * prior_c,
                                                    np.diag(prior_c))
        S = cov @ JtK
        cov = cov + S @ post_c @ S.T
        diagnostics["kinematic_evidence"] = {**_kinematic_evidence(_effect_blocks(lin.red, At, None, Kc, None, []),
                                                                   prior_c),
                                             "threshold": KINEMATIC_EVIDENCE_LR, "selected": "stated"}
    if ke is not None and len(id_cols):
        # kinematic calibration: a new pose is mapped through the identified model, so its
        # error is that of the transform, sphere and identified parameters, jointly
        kinematic_terms = {
            "identified_design": flange_error_jacobian(chain_with_errors(ke.chain, kappa), problem.q_rad)[:, :, id_cols],
            "covariance": cov_robot_frame, "n_geo": n_geo,
        }
    elif ke is not None and len(rand_cols):
        # how the arm's true geometric error moves the estimate (GLS with it marginalised)
        kinematic_terms = {
            "design": flange_error_jacobian(ke.chain, problem.q_rad)[:, :, rand_cols],
            "influence": cov @ (A_tr[:, off:] - A_tr @ Cinv @ A_rr[:, off:]),
            "posterior_mean": kappa[rand_cols].copy(),
            "posterior_cov": post,
        }
    if se is not None:
        if ke is None:
            # the common offset as a 'consider' parameter: not estimated (one sphere
            # location cannot tell it), its prior spread propagated through the estimator
            Xc = lin.columns(_common_error_design(current(problem), lin.Jd))
            cols_c_t = lin.red.gram(At, Xc)
            cols_c_d = np.concatenate([lin.red.gram(As[rows], Xc[rows], rows) for rows in station_shots])
            common = np.diag([np.radians(se.common_rotation_deg) ** 2] * 3 + [se.common_translation_mm**2] * 3)
            cov_robot_frame = cov_at_scales = cov
            if free:
                # the scales are estimates too: their uncertainty widens the covariance
                cov_robot_frame = _scale_averaged_covariance(
                    blocks, np.tile([0, 0, 0, 1, 1, 1], K), free, s_hat, _SCALE_BOUNDS)
            cov = cov_robot_frame + consider(cols_c_t, cols_c_d, common)
        diagnostics["station_effects"] = {
            "rotation_deg": float(np.degrees(s_hat[0])),
            "translation_mm": float(s_hat[1]),
            "estimated": [fixed[0] is None, fixed[1] is None],
            "common_rotation_deg": se.common_rotation_deg if ke is None else 0.0,
            "common_translation_mm": se.common_translation_mm if ke is None else 0.0,
            "offsets": {lab: {"rotation_deg": np.degrees(delta[k, :3]).tolist(), "translation_mm": delta[k, 3:].tolist()}
                        for k, lab in enumerate(problem.station_labels)},
        }
    if len(id_cols):
        kin_posterior_sd[id_cols] = np.sqrt(np.maximum(np.diag(cov)[n_geo:], 0.0))
    if ke is not None:
        diagnostics["kinematic_effects"] = {
            "names": error_parameter_names(ke.chain),
            "estimate": kappa.tolist(),
            "sd": kin_posterior_sd.tolist(),
            "identifiable": kin_identifiable.tolist(),
            "independent_share": kin_share.tolist(),
            "identified": [bool(i in set(id_cols.tolist())) for i in range(n_kin)],
            "prior_sd": kin_prior.tolist(),
            "prior_scale": float(lam),
            "prior_scale_estimated": bool(estimate_lam),
        }
    station_scales = (float(s_hat[0]), float(s_hat[1])) if se else (0.0, 0.0)
    if ke is not None and not ke.identify:
        # the station-to-station part of the robot's error, as the estimated geometry shows it
        E = flange_error_jacobian(ke.chain, problem.q_rad) @ kappa
        E = E - E.mean(axis=0)
        kin_scales = (float(np.sqrt(np.mean(E[:, :3] ** 2))), float(np.sqrt(np.mean(E[:, 3:] ** 2))))
        station_scales = tuple(float(np.hypot(a, b)) for a, b in zip(station_scales, kin_scales))
    dof = max(len(lin.res) - n_par, 1)
    centre_res = None
    if m_centres:
        centre_res = np.full((n_shots, 3), np.nan)
        centre_res[pts.centre_shots] = lin.centre_parts[0]
        diagnostics["centre_noise_mm"] = float(np.sqrt(s2_centre)) if estimate_centre else None
    return RefineResult(
        R, t, c, r, cov, np.split(lin.res[:pts.M], np.cumsum(pts.counts)[:-1]), lin.C, lin.SC, it,
        converged, lin.red.cost() / dof, scale, diagnostics, covariance_without_robot_error=cov_fixed,
        covariance_robot_frame=cov_robot_frame, covariance_robot_frame_at_scales=cov_at_scales,
        station_offsets=delta, station_effect_scales=station_scales,
        kinematic_errors=kappa if ke is not None else None,
        kinematic_sd=kin_posterior_sd if ke is not None else None, kinematic_terms=kinematic_terms,
        centre_residuals=centre_res, centre_noise_mm=float(np.sqrt(s2_centre)) if estimate_centre else None,
    )


def _refine_by_evidence(problem, R, t, c, noise, fit_radius, estimate_pose_noise, max_iterations, tolerance,
                        ke: KinematicEffects, cols) -> RefineResult:
    """The ``auto`` robot error model: the pose-noise-only fit at the stated noise, the
    evidence for the arm's geometric error at its solution, then the kinematic model if
    the data show that error, else the pose-noise-only fit (pose noise rescaled as asked)
    with the arm's geometry considered. The decision is made at the stated pose noise: a
    pose-noise scale learnt first would absorb the arm's error and hide it."""
    plain = replace(ke, select_by_evidence=False, consider_columns=tuple(int(i) for i in cols))
    first = refine(problem, R, t, c, noise, fit_radius, False, max_iterations, tolerance, None, plain)
    evidence = first.diagnostics["kinematic_evidence"]
    if evidence["likelihood_ratio"] >= KINEMATIC_EVIDENCE_LR:
        out = refine(problem, first.R, first.t, first.centre, noise, fit_radius, estimate_pose_noise, max_iterations,
                     tolerance, None, replace(ke, select_by_evidence=False))
        selected = "kinematic"
    else:
        out = first if not estimate_pose_noise else refine(
            problem, first.R, first.t, first.centre, noise, fit_radius, True, max_iterations, tolerance, None, plain)
        selected = "none"
    out.diagnostics["kinematic_evidence"] = {**evidence, "selected": selected}
    return out


def _centre_design(problem, R, t, c, chain, fit_radius: bool = False):
    """Per-profile sphere-centre Jacobians, stacked (3 n, .): of the transform, sphere
    (and radius) and of the kinematic parameters of ``chain`` at the problem's joints;
    noise-free, for identifiability."""
    u, _ = _centres(problem, R, t, c)
    Jg = _centre_jacobian(problem, R, u)
    if fit_radius:
        Jg = np.concatenate([Jg, np.zeros((len(Jg), 3, 1))], axis=2)
    Jk = _pose_noise_jacobian(problem, R, c) @ flange_error_jacobian(chain, problem.q_rad)
    return Jg.reshape(-1, Jg.shape[2]), Jk.reshape(-1, Jk.shape[2])


def cramer_rao_bound(problem_true: Problem, R, t, centre, noise: NoiseAssumptions, fit_radius: bool = False) -> np.ndarray:
    """Cramer-Rao bound of (w, t, c[, r]) for the noise model of :mod:`.refine`,
    evaluated at the true parameters on the noise-free profile points of
    ``problem_true`` (poses = true poses). Linearised Gaussian model: Fisher information
    ``sum_i J_i^T Cov_i^-1 J_i``."""
    lin = _linearise(problem_true, _Points(problem_true), np.asarray(R, float), np.asarray(t, float),
                     np.asarray(centre, float), problem_true.radius_mm, fit_radius, _pose_cov(noise),
                     max(noise.point_noise_mm, 1e-9))
    At = lin.columns(lin.Jc, fit_radius)
    return np.linalg.inv(lin.red.gram(At, At))


def plan_design(mounting: str, R0: np.ndarray, t0: np.ndarray, q_rad: np.ndarray, X, centre, chain: SerialChain):
    """The sphere-centre Jacobians a plan would give (noise-free, as the estimator's):
    ``(J_geo (3 n, 9), J_kin (3 n, 6 joints))`` of the transform and sphere and of the
    geometric parameters of ``chain``, for planned flange poses ``base_from_flange``
    (rotations ``R0`` (n, 3, 3), translations ``t0`` (n, 3), mm) with joints ``q_rad``
    (model convention), nominal transform ``X`` and sphere ``centre``."""
    R0, t0 = np.asarray(R0, dtype=float), np.asarray(t0, dtype=float)
    R_sm, t_sm = sphere_from_mount(mounting, R0, t0)
    n = len(R0)
    problem = Problem(mounting, 1.0, R0, t0, R_sm, t_sm, [np.zeros((0, 2))] * n, np.arange(n), np.zeros(n, dtype=int),
                      ["plan"], np.asarray(q_rad, dtype=float))
    return _centre_design(problem, X.rotation_matrix, X.translation, np.asarray(centre, dtype=float), chain)


def design_identifiability(J_geo: np.ndarray, J_kin: np.ndarray, prior_sd: np.ndarray) -> dict:
    """Identifiability of a design (:func:`plan_design`): the mask and independent share
    of :func:`identifiable_kinematic_parameters`, the singular values and right singular
    vectors (``singular_values``, ``directions`` (k, k), over the identifiable parameters)
    of the prior-scaled columns with the transform and sphere projected out, and their
    condition number."""
    mask, share = identifiable_kinematic_parameters(J_geo, J_kin, prior_sd)
    B = J_kin[:, mask] * prior_sd[mask]
    Q, _ = np.linalg.qr(J_geo)
    B = B - Q @ (Q.T @ B)
    if mask.any():
        _, sv, Vt = np.linalg.svd(B, full_matrices=False)
    else:
        sv, Vt = np.array([1.0]), np.zeros((0, 0))
    return {"identifiable": mask, "independent_share": share, "singular_values": sv, "directions": Vt,
            "condition_number": float(sv[0] / max(sv[-1], 1e-300))}
