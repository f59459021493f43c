"""Circle fit of one profile and the sphere centre it implies.

A profile cuts the sphere (radius r) in a circle in the laser plane x = 0. Its centre
(yc, zc) and radius rc give the sphere centre (+-sqrt(r^2 - rc^2), yc, zc) in the
sensor frame; the sign is decided per station in :mod:`.twostep`.

The fit: an algebraic (Kasa) start, then Gauss-Newton on the geometric distance, with
points further than ``k`` robust standard deviations from the circle dropped and the fit
repeated (reflections and edge points). Minimum data: 3 points; we ask for more.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import numpy as np


@dataclass(frozen=True)
class CircleFit:
    """Result of :func:`fit_circle`; lengths in mm, in the laser plane (y, z)."""

    centre_yz: np.ndarray
    radius: float
    rms: float
    inliers: np.ndarray  # boolean mask over the input points
    converged: bool

    @cached_property
    def n_inliers(self) -> int:  # (asked for many times per fit: counted once)
        return int(self.inliers.sum())


def _kasa(p: np.ndarray) -> tuple[np.ndarray, float]:
    A = np.column_stack([2 * p, np.ones(len(p))])
    b = (p * p).sum(axis=1)
    sol, *_ = np.linalg.lstsq(A, b, rcond=None)
    c = sol[:2]
    return c, float(np.sqrt(max(sol[2] + c @ c, 0.0)))


def _gauss_newton(p: np.ndarray, c: np.ndarray, r: float, iterations: int = 20) -> tuple[np.ndarray, float, bool]:
    x = np.array([c[0], c[1], r])
    for _ in range(iterations):
        d = p - x[:2]
        dist = np.hypot(d[:, 0], d[:, 1])
        dist = np.maximum(dist, 1e-12)
        res = dist - x[2]
        # normal equations (3 x 3): the same step as a least-squares solve of J, a
        # fraction of its cost (a fit is a few of them; a dataset, thousands of fits)
        uy, uz = d[:, 0] / dist, d[:, 1] / dist
        A = np.array([[uy @ uy, uy @ uz, uy.sum()], [0.0, uz @ uz, uz.sum()], [0.0, 0.0, float(len(p))]])
        A = np.triu(A) + np.triu(A, 1).T
        rhs = np.array([uy @ res, uz @ res, res.sum()])  # J^T (-res), J = -(uy, uz, 1) per point
        try:
            step = np.linalg.solve(A, rhs)
        except np.linalg.LinAlgError:
            step = np.linalg.lstsq(np.column_stack([-uy, -uz, -np.ones(len(p))]), -res, rcond=None)[0]
        x += step
        if np.abs(step).max() < 1e-10:
            return x[:2], float(x[2]), True
    return x[:2], float(x[2]), False


def fit_circle(points_yz, outlier_k: float = 5.0, min_noise_mm: float = 0.002, rounds: int = 3) -> CircleFit:
    """Fit a circle to (N, 2) points (y, z), mm, robust to a few stray points.

    Points whose distance to the circle exceeds ``outlier_k`` times the robust standard
    deviation of the distances (median absolute deviation, floored at ``min_noise_mm``)
    are dropped and the fit repeated, up to ``rounds`` times.
    Raises ``ValueError`` with fewer than 3 points."""
    p = np.asarray(points_yz, dtype=float)
    if p.ndim != 2 or p.shape[1] != 2:
        raise ValueError(f"expected (N, 2) points, got shape {p.shape}")
    if len(p) < 3:
        raise ValueError(f"a circle needs at least 3 points, got {len(p)}")
    mask = np.ones(len(p), dtype=bool)
    c, r = _kasa(p)
    converged = False
    for _ in range(rounds):
        c, r, converged = _gauss_newton(p[mask], c, r)
        res = np.hypot(*(p - c).T) - r
        scale = max(1.4826 * np.median(np.abs(res[mask] - np.median(res[mask]))), min_noise_mm)
        new_mask = np.abs(res) <= outlier_k * scale
        if new_mask.sum() < 3 or np.array_equal(new_mask, mask):
            break
        mask = new_mask
    res = np.hypot(*(p[mask] - c).T) - r
    return CircleFit(np.asarray(c), float(r), float(np.sqrt(np.mean(res**2))), mask, converged)


def half_chord_depth(sphere_radius_mm: float, circle_radius_mm: float) -> float:
    """Distance of the sphere centre from the laser plane, |x| = sqrt(r^2 - rc^2) (>= 0).

    A circle larger than the sphere (noise near the equator) gives 0."""
    return float(np.sqrt(max(sphere_radius_mm**2 - circle_radius_mm**2, 0.0)))
