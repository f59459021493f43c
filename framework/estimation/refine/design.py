"""What a design lets the refinement identify: centre Jacobians, identifiability, Cramer-Rao bound."""

from __future__ import annotations

import numpy as np

from spherecal.core.kinematics import SerialChain, flange_error_jacobian
from spherecal.estimation.problem import Problem, sphere_from_mount
from spherecal.estimation.refine.linearisation import (
    NoiseAssumptions, _centre_jacobian, _centres, _linearise, _Points, _pose_cov, _pose_noise_jacobian,
)


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
    """Cramer-Rao bound of (w, t, c[, r]) for the noise model of :mod:`spherecal.estimation.refine`,
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
