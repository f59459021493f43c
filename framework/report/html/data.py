"""What the report shows, computed from the solution: mapped points, residual statistics, samples, uncertainties."""

from __future__ import annotations

import numpy as np

from spherecal.core import geometry as geo
from spherecal.core.mapping import map_profile_list
from spherecal.core.models import CalibrationResult
from spherecal.estimation.blocks import BLOCK_POINTS, profile_blocks
from spherecal.estimation.problem import KIND_PROFILE, KIND_SPHERE_CENTRE

#: At most this many points are in the interactive view (an evenly spread sample); every
#: statistic printed or drawn as a line uses all the points.
MAX_POINTS_INTERACTIVE = 4_000
#: Bins of the residual statistics against position along the line and against depth.
RESIDUAL_BINS = 16
#: Coverage factor of the expanded uncertainty shown next to the 1-sigma (about 95 %).
K_EXPANDED = 2.0


def mapped_points(solution) -> list[np.ndarray]:
    """Each used profile's points mapped into the sphere frame through ``A_i X``:
    ``p = R_A_i (R p_sensor + t) + t_A_i`` with p_sensor = (0, y, z); ``A_i`` is
    ``base_from_flange_i`` (eye-in-hand) or ``flange_from_base_i`` (eye-to-hand). mm.
    (:func:`spherecal.core.mapping.map_profile_list`, the scan's mapping.)"""
    prob, ref = solution.problem, solution.refined
    R_A, t_A = prob.R_sphere_from_mount, prob.t_sphere_from_mount
    points, _ = map_profile_list(R_A @ ref.R, R_A @ np.asarray(ref.t, dtype=float) + t_A, prob.profiles)
    return np.split(points, np.cumsum([len(p) for p in prob.profiles])[:-1])


def mapped_centres(solution) -> dict[int, tuple[int, np.ndarray]]:
    """Each used centre observation mapped into the sphere frame through ``A_i X``, by
    position in the problem: a sphere centre as one point (1, 3) (it should fall on the
    fitted centre); a circle as points along it (it should lie on the fitted sphere). mm."""
    prob, ref = solution.problem, solution.refined
    out = {}
    theta = np.linspace(0.0, 2 * np.pi, 49)
    for i in centre_rows(solution):
        v = prob.centre_meas[i]
        if prob.kinds[i] == KIND_SPHERE_CENTRE:
            p_s = v[None, :]
        else:  # the circle lies in the laser plane x = 0
            p_s = np.column_stack([np.zeros_like(theta), v[0] + v[2] * np.cos(theta), v[1] + v[2] * np.sin(theta)])
        p_sphere = (p_s @ ref.R.T + ref.t) @ prob.R_sphere_from_mount[i].T + prob.t_sphere_from_mount[i]
        out[int(i)] = (int(prob.kinds[i]), p_sphere)
    return out


def is_profile(solution, index: int) -> bool:
    """Whether observation ``index`` of the dataset is a profile (the solution keeps the
    kinds of every observation, used or flagged)."""
    return solution.extras.get("kinds", {}).get(int(index), "profile") == "profile"


def centre_rows(solution) -> np.ndarray:
    """Positions of the centre observations used."""
    return np.flatnonzero(solution.problem.kinds != KIND_PROFILE)


def station_residuals(solution, members) -> np.ndarray:
    """The points' residuals and the centre residuals' components of shots ``members``, mm."""
    ref = solution.refined
    parts = [ref.residuals[i] for i in members]
    if ref.centre_residuals is not None:
        c = ref.centre_residuals[members]
        parts.append(c[~np.isnan(c[:, 0])].ravel())
    return np.concatenate(parts) if parts else np.zeros(0)


def row_percentiles(samples, qs) -> np.ndarray:
    """``np.percentile(v, qs)`` (its default, linear interpolation) of each of
    ``samples`` (non-empty arrays), (len(samples), len(qs)): thousands of profiles
    computed a block at a time (rows sorted together), not one call each."""
    qs = np.asarray(qs, dtype=float) / 100.0
    out = np.empty((len(samples), len(qs)))
    counts = np.array([len(v) for v in samples], dtype=int)
    for p0, p1 in profile_blocks(counts, BLOCK_POINTS):
        k = counts[p0:p1]
        rows = np.full((p1 - p0, k.max()), np.inf)
        rows[np.arange(k.max()) < k[:, None]] = np.concatenate([np.ravel(v) for v in samples[p0:p1]])
        has_nan = np.isnan(rows).any(axis=1)  # (NaN, as numpy gives it)
        rows.sort(axis=1)
        at = qs[None, :] * (k[:, None] - 1)
        lo = np.floor(at).astype(int)
        hi = np.minimum(lo + 1, k[:, None] - 1)
        a = np.take_along_axis(rows, lo, axis=1)
        b = np.take_along_axis(rows, hi, axis=1)
        g = at - lo
        diff = b - a
        # numpy's lerp: from the nearer end, so that a value between two equal ones is exact
        out[p0:p1] = np.where(g >= 0.5, b - diff * (1.0 - g), a + diff * g)
        out[p0:p1][has_nan] = np.nan
    return out


def plot_sample(n: int, limit: int) -> np.ndarray:
    """Indices of at most ``limit`` of ``n`` points, evenly spread over them (every k-th,
    deterministic): what a figure draws of a large dataset. Statistics use all points."""
    if n <= limit:
        return np.arange(n)
    return np.unique(np.linspace(0, n - 1, limit).round().astype(int))


def profile_points_and_residuals(solution) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Every used profile point: its position along the laser line (sensor y, mm), its
    depth (sensor z, the distance from the sensor along its line of sight, mm), and its
    residual (mm); as three arrays of equal length (empty without profiles)."""
    prob, ref = solution.problem, solution.refined
    rows = [i for i in range(prob.n_profiles) if prob.kinds[i] == KIND_PROFILE]
    if not rows:
        return np.zeros(0), np.zeros(0), np.zeros(0)
    yz = np.concatenate([np.asarray(prob.profiles[i], dtype=float) for i in rows])
    res = np.concatenate([np.asarray(ref.residuals[i], dtype=float) for i in rows])
    return yz[:, 0], yz[:, 1], res


def binned_residuals(x: np.ndarray, residuals: np.ndarray, bins: int = RESIDUAL_BINS) -> dict[str, np.ndarray]:
    """The residuals' statistics in ``bins`` equal-width bins of ``x`` (mm), from every
    point: ``centre_mm`` (bin centres), ``count``, ``mean_mm`` and ``rms_mm`` (NaN in an
    empty bin)."""
    x, residuals = np.asarray(x, dtype=float), np.asarray(residuals, dtype=float)
    lo, hi = (float(x.min()), float(x.max())) if x.size else (0.0, 1.0)
    if hi <= lo:
        hi = lo + 1e-9
    edges = np.linspace(lo, hi, bins + 1)
    k = np.clip(np.searchsorted(edges, x, side="right") - 1, 0, bins - 1)
    count = np.bincount(k, minlength=bins)
    total = np.bincount(k, weights=residuals, minlength=bins)
    squares = np.bincount(k, weights=residuals ** 2, minlength=bins)
    with np.errstate(invalid="ignore", divide="ignore"):
        mean = np.where(count > 0, total / count, np.nan)
        rms = np.where(count > 0, np.sqrt(squares / count), np.nan)
    return {"centre_mm": 0.5 * (edges[:-1] + edges[1:]), "count": count, "mean_mm": mean, "rms_mm": rms}


def residual_limit(res: np.ndarray) -> float:
    """The y range of a residual scatter: its 99.9th percentile of |r|, so that a few
    large residuals do not squash the 0.01 mm structure (they are counted, not hidden)."""
    return max(float(np.percentile(np.abs(res), 99.9)) * 1.15, 1e-3) if res.size else 1e-3


def sphere_directions(solution, pts: list[np.ndarray] | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Every used profile point's direction from the fitted centre in the sphere frame
    as azimuth and elevation (deg), with its residual (mm). ``pts``: the
    :func:`mapped_points` of ``solution`` when already at hand."""
    pts = mapped_points(solution) if pts is None else pts
    prob, ref = solution.problem, solution.refined
    rows = [i for i in range(prob.n_profiles) if prob.kinds[i] == KIND_PROFILE]
    if not rows:
        return np.zeros(0), np.zeros(0), np.zeros(0)
    d = np.concatenate([pts[i] for i in rows]) - np.asarray(ref.centre, dtype=float)
    res = np.concatenate([np.asarray(ref.residuals[i], dtype=float) for i in rows])
    az = np.degrees(np.arctan2(d[:, 1], d[:, 0]))
    el = np.degrees(np.arctan2(d[:, 2], np.hypot(d[:, 0], d[:, 1])))
    return az, el, res


def interactive_points(solution, limit: int = MAX_POINTS_INTERACTIVE, pts: list[np.ndarray] | None = None) -> dict:
    """The data of the interactive 3-D view: a sample of at most ``limit`` used profile
    points relative to the fitted centre in the sphere frame (mm, 3 decimals) with their
    residuals (mm, 4 decimals), the sphere's radius, the frame's name and the colour
    limit (mm)."""
    pts = mapped_points(solution) if pts is None else pts
    prob, ref = solution.problem, solution.refined
    rows = [i for i in range(prob.n_profiles) if prob.kinds[i] == KIND_PROFILE]
    if not rows:
        return {"points": [], "residuals": [], "radius_mm": float(ref.radius), "limit_mm": 1e-3, "frame": ""}
    d = np.concatenate([pts[i] for i in rows]) - np.asarray(ref.centre, dtype=float)
    res = np.concatenate([np.asarray(ref.residuals[i], dtype=float) for i in rows])
    pick = plot_sample(res.size, limit)
    return {"points": np.round(d[pick], 3).ravel().tolist(), "residuals": np.round(res[pick], 4).tolist(),
            "radius_mm": round(float(ref.radius), 4), "limit_mm": round(residual_limit(res), 4),
            "total": int(res.size)}


def point_uncertainty(result: CalibrationResult, distance_mm: float) -> dict:
    """The uncertainty, from the transform's, of a point measured ``distance_mm`` from
    the sensor along its line of sight (the point (0, 0, -d) in the sensor frame, whose
    z points towards the sensor), mapped into the transform's target frame:
    ``dp = w x (R p) + dt``. Returns its 1-sigma per target axis, its RMS 3-D error and
    the expanded 3-D figure (k = 2: twice the RMS), mm."""
    R = result.transform.rotation_matrix
    v = R @ np.array([0.0, 0.0, -float(distance_mm)])
    J = np.hstack([-geo.skew(v), np.eye(3)])
    cov = J @ np.asarray(result.covariance, dtype=float)[:6, :6] @ J.T
    sd = np.sqrt(np.maximum(np.diag(cov), 0.0))
    rms = float(np.sqrt(max(np.trace(cov), 0.0)))
    return {"distance_mm": float(distance_mm), "sd_mm": tuple(float(x) for x in sd), "rms_mm": rms,
            "expanded_k2_mm": K_EXPANDED * rms}
