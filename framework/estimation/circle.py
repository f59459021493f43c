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

from spherecal.estimation.blocks import BLOCK_POINTS, profile_blocks


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

    def inlier_points(self, points: np.ndarray) -> np.ndarray:
        """The fitted points' inliers: ``points`` itself when every point is one (most
        profiles: no copy)."""
        return points if self.n_inliers == len(points) else points[self.inliers]


def _kasa(p: np.ndarray) -> tuple[np.ndarray, float]:
    A = np.column_stack([2 * p, np.ones(len(p))])
    b = (p * p).sum(axis=1)
    sol, *_ = np.linalg.lstsq(A, b, rcond=None)
    c = sol[:2]
    return c, float(np.sqrt(max(sol[2] + c @ c, 0.0)))


class _Block:
    """Profiles laid out as rows of a rectangle (profiles x the longest one's points,
    zeros after each profile's end, ``valid`` marking its points), so that every
    per-profile sum, median and step is one operation over the block."""

    def __init__(self, profiles: list[np.ndarray]):
        self.n = np.array([len(p) for p in profiles])
        self.valid = np.arange(self.n.max()) < self.n[:, None]
        stacked = np.concatenate(profiles)
        self.Y, self.Z = np.zeros(self.valid.shape), np.zeros(self.valid.shape)
        self.Y[self.valid], self.Z[self.valid] = stacked[:, 0], stacked[:, 1]

    def distances(self, x: np.ndarray, rows=slice(None)) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(y - yc, z - zc, distance) of every point of ``rows`` to its row's centre x (rows, 3)."""
        dy, dz = self.Y[rows] - x[:, 0:1], self.Z[rows] - x[:, 1:2]
        return dy, dz, np.maximum(np.sqrt(dy * dy + dz * dz), 1e-12)


def _masked_median(v: np.ndarray, mask: np.ndarray) -> np.ndarray:
    """Each row's median of its entries under ``mask`` (each row has some), as
    ``np.median`` gives it (the mean of the middle two of an even count)."""
    s = np.sort(np.where(mask, v, np.inf), axis=1)
    k = mask.sum(axis=1)
    rows = np.arange(len(v))
    return (s[rows, (k - 1) // 2] + s[rows, k // 2]) / 2


def _kasa_rows(block: _Block) -> np.ndarray:
    """The algebraic (Kasa) circle of each row, (g, 3) of (yc, zc, r): the linear least
    squares of y^2 + z^2 = 2 a y + 2 b z + k, solved about each row's mean point. Rows
    whose points lie on a line take the minimum-norm solution, as a profile alone does."""
    w = block.valid.astype(float)
    mean_y, mean_z = (block.Y * w).sum(axis=1) / block.n, (block.Z * w).sum(axis=1) / block.n
    Y, Z = (block.Y - mean_y[:, None]) * w, (block.Z - mean_z[:, None]) * w
    q = Y * Y + Z * Z
    A = np.stack([np.einsum("ij,ij->i", Y, Y), np.einsum("ij,ij->i", Y, Z),
                  np.einsum("ij,ij->i", Y, Z), np.einsum("ij,ij->i", Z, Z)], axis=1).reshape(-1, 2, 2)
    rhs = 0.5 * np.stack([np.einsum("ij,ij->i", Y, q), np.einsum("ij,ij->i", Z, q)], axis=1)
    det = A[:, 0, 0] * A[:, 1, 1] - A[:, 0, 1] ** 2
    ok = det > 1e-12 * (A[:, 0, 0] + A[:, 1, 1]) ** 2
    x = np.empty((len(A), 3))
    ab = np.linalg.solve(A[ok], rhs[ok][:, :, None])[:, :, 0]
    x[ok, 0], x[ok, 1] = mean_y[ok] + ab[:, 0], mean_z[ok] + ab[:, 1]
    x[ok, 2] = np.sqrt(np.maximum(q[ok].sum(axis=1) / block.n[ok] + (ab * ab).sum(axis=1), 0.0))
    for j in np.flatnonzero(~ok):
        c, r = _kasa(np.column_stack([block.Y[j, :block.n[j]], block.Z[j, :block.n[j]]]))
        x[j] = c[0], c[1], r
    return x


def _gauss_newton_rows(block: _Block, rows: np.ndarray, mask: np.ndarray, x: np.ndarray,
                       iterations: int = 20) -> tuple[np.ndarray, np.ndarray]:
    """Gauss-Newton on the geometric distance of each row's points under ``mask``, from
    x (rows, 3); a row stops once its step is below 1e-10 mm (converged). Returns x and
    the converged flags."""
    x = x.copy()
    w = mask.astype(float)
    count = w.sum(axis=1)
    done = np.zeros(len(rows), dtype=bool)
    for _ in range(iterations):
        dy, dz, dist = block.distances(x, rows)
        res = dist - x[:, 2:3]
        uy, uz = dy / dist * w, dz / dist * w  # (outside the mask: 0)
        # normal equations (3 x 3) of J = -(uy, uz, 1) per point; rhs J^T (-res)
        s_yy, s_yz, s_zz = (np.einsum("ij,ij->i", a, b) for a, b in ((uy, uy), (uy, uz), (uz, uz)))
        s_y, s_z = uy.sum(axis=1), uz.sum(axis=1)
        A = np.stack([s_yy, s_yz, s_y, s_yz, s_zz, s_z, s_y, s_z, count], axis=1).reshape(-1, 3, 3)
        rhs = np.stack([np.einsum("ij,ij->i", uy, res), np.einsum("ij,ij->i", uz, res),
                        np.einsum("ij,ij->i", w, res)], axis=1)
        try:
            step = np.linalg.solve(A, rhs[:, :, None])[:, :, 0]
        except np.linalg.LinAlgError:  # a singular row: each row alone, least squares where singular
            step = np.empty_like(rhs)
            for j in range(len(A)):
                try:
                    step[j] = np.linalg.solve(A[j], rhs[j])
                except np.linalg.LinAlgError:
                    m = mask[j]
                    J = -np.column_stack([uy[j, m], uz[j, m], np.ones(int(m.sum()))])
                    step[j] = np.linalg.lstsq(J, -res[j, m], rcond=None)[0]
        live = ~done
        x[live] += step[live]
        done |= live & (np.abs(step).max(axis=1) < 1e-10)
        if done.all():
            break
    return x, done


def _fit_block(profiles: list[np.ndarray], outlier_k: float, min_noise_mm: float, rounds: int) -> list[CircleFit]:
    """:func:`fit_circle` of each profile of a block, every profile's rounds as its own."""
    block = _Block(profiles)
    g = len(profiles)
    x = _kasa_rows(block)
    mask = block.valid.copy()
    converged = np.zeros(g, dtype=bool)
    active = np.ones(g, dtype=bool)  # still in its rounds of dropping stray points
    for _ in range(rounds):
        rows = np.flatnonzero(active)
        if not len(rows):
            break
        x[rows], converged[rows] = _gauss_newton_rows(block, rows, mask[rows], x[rows])
        res = block.distances(x[rows], rows)[2] - x[rows, 2:3]
        m = mask[rows]
        med = _masked_median(res, m)
        scale = np.maximum(1.4826 * _masked_median(np.abs(res - med[:, None]), m), min_noise_mm)
        new = (np.abs(res) <= outlier_k * scale[:, None]) & block.valid[rows]
        stop = (new.sum(axis=1) < 3) | np.all(new == m, axis=1)
        mask[rows[~stop]] = new[~stop]
        active[rows[stop]] = False
    res = block.distances(x)[2] - x[:, 2:3]
    rms = np.sqrt(np.where(mask, res * res, 0.0).sum(axis=1) / mask.sum(axis=1))
    return [CircleFit(x[j, :2].copy(), float(x[j, 2]), float(rms[j]), mask[j, :block.n[j]].copy(), bool(converged[j]))
            for j in range(g)]


def fit_circles(profiles, outlier_k: float = 5.0, min_noise_mm: float = 0.002, rounds: int = 3) -> list[CircleFit]:
    """:func:`fit_circle` of each of ``profiles`` ((N, 2) points (y, z) each, mm), the
    same fits computed a block of profiles at a time (:mod:`.blocks`): thousands of
    profiles in a fraction of the time of one call each. (Sums in another order: the
    circles agree with one call each to rounding and the inliers exactly; on a short
    arc, where the last steps are at rounding level, ``converged`` can fall either side
    of its 1e-10 mm test in either.)"""
    arrays = [np.asarray(p, dtype=float) for p in profiles]
    for p in arrays:
        if p.ndim != 2 or p.shape[1] != 2:
            raise ValueError(f"expected (N, 2) points, got shape {p.shape}")
        if len(p) < 3:
            raise ValueError(f"a circle needs at least 3 points, got {len(p)}")
    fits: list[CircleFit] = []
    for p, q in profile_blocks([len(a) for a in arrays], BLOCK_POINTS):
        fits += _fit_block(arrays[p:q], outlier_k, min_noise_mm, rounds)
    return fits


def fit_circle(points_yz, outlier_k: float = 5.0, min_noise_mm: float = 0.002, rounds: int = 3) -> CircleFit:
    """Fit a circle to (N, 2) points (y, z), mm, robust to a few stray points.

    An algebraic start, then Gauss-Newton on the geometric distance; points whose
    distance to the circle exceeds ``outlier_k`` times the robust standard deviation of
    the distances (median absolute deviation, floored at ``min_noise_mm``) are dropped
    and the fit repeated, up to ``rounds`` times (until the inliers no longer change).
    Raises ``ValueError`` with fewer than 3 points."""
    return fit_circles([points_yz], outlier_k, min_noise_mm, rounds)[0]


def half_chord_depth(sphere_radius_mm: float, circle_radius_mm):
    """Distance of the sphere centre from the laser plane, |x| = sqrt(r^2 - rc^2) (>= 0),
    of one circle radius (a float) or of each of an array of them.

    A circle larger than the sphere (noise near the equator) gives 0."""
    depth = np.sqrt(np.maximum(sphere_radius_mm**2 - np.asarray(circle_radius_mm, dtype=float) ** 2, 0.0))
    return float(depth) if depth.ndim == 0 else depth
