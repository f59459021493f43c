"""The published two-step method (Ren, Yin and Zhu, Opt. Eng. 51(11) 114204, 2012),
for both mounting modes at once (see :mod:`.problem`).

Step 1, rotation: within a station the flange only translates, so the sphere centre
moves in the sensor frame by the robot's displacement rotated by X^T. Pooling the
stations' centred displacements, ``Rx a_i = d_i`` is an orthogonal Procrustes problem
solved by SVD, always returning a proper rotation.

Where the sensor-frame centres come from: a circle fit per profile gives (y, z) and the
distance |x| = sqrt(r^2 - rc^2) from the laser plane; the sign of x is decided per
station from the robot's moves (:func:`station_centres`), never per profile.

Step 2, translation: with Rx known and Tx = 0 the points of station k lie on a sphere
of radius r centred at ``Xb_k = c - R_Ak Tx``; stacking ``R_Ak Tx - c = -Xb_k`` over
stations gives [Tx; c] by linear least squares (the paper's eqs. 13-20, solved directly).
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass, field

import numpy as np

from .. import geometry as geo
from ..errors import DegenerateDataError
from .circle import CircleFit, half_chord_depth
from .problem import Problem

#: Relative singular value under which a direction counts as not excited.
RANK_TOLERANCE = 0.05
#: ... and the RMS extent (mm) under which it counts as not excited.
MIN_EXTENT_MM = 0.5


@dataclass
class StationCentres:
    """Sensor-frame sphere centres of one station."""

    label: str
    profiles: np.ndarray  # indices into the problem
    d: np.ndarray  # (n, 3) robot displacement from the station mean, sphere frame rotated into A's axes
    candidates: list[np.ndarray]  # one or two (n, 3) arrays of centres (x sign resolved)
    rank: int  # dimension spanned by the station's moves


@dataclass
class TwoStepResult:
    R: np.ndarray
    t: np.ndarray
    centre: np.ndarray
    stations: list[StationCentres]
    choice: tuple[int, ...]
    diagnostics: dict = field(default_factory=dict)


def _signs_and_offset(u: np.ndarray, h: np.ndarray) -> np.ndarray:
    """x_i with |x_i| ~ h_i and x_i = a + u_i: choose a, return s_i h_i."""
    cands = np.concatenate([h - u, -h - u])
    costs = [np.sum((np.abs(a + u) - h) ** 2) for a in cands]
    a = cands[int(np.argmin(costs))]
    s = np.where(a + u >= 0, 1.0, -1.0)
    a = np.mean(s * h - u)
    s = np.where(a + u >= 0, 1.0, -1.0)
    return s * h


def station_centres(problem: Problem, fits: dict[int, CircleFit], label_index: int) -> StationCentres:
    """Sphere centres in the sensor frame for one station, sign of x resolved.

    The y and z of the centres are affine in the robot's displacement d (rows 2 and 3
    of X^T); orthonormality of X^T gives its first row up to sign, and det X = +1 fixes
    the sign when the moves span 3-D. With planar or collinear moves two mirror
    candidates remain; :func:`two_step` keeps the one the whole dataset agrees with."""
    idx = np.array([i for i in np.flatnonzero(problem.station_of == label_index) if i in fits])
    if len(idx) == 0:
        return StationCentres(problem.station_labels[label_index], idx, np.zeros((0, 3)), [], 0)
    yz = np.array([fits[i].centre_yz for i in idx])
    h = np.array([half_chord_depth(problem.radius_mm, fits[i].radius) for i in idx])
    R_A = problem.R_A[idx[0]]
    tA = problem.t_A[idx]
    d = -(tA - tA.mean(axis=0)) @ R_A  # rows: R_A^T (tA_mean - tA_i)
    _, s, Vt = np.linalg.svd(d, full_matrices=False)
    n = len(idx)
    k = int(np.sum((s > RANK_TOLERANCE * max(s[0], 1e-12)) & (s / np.sqrt(n) > MIN_EXTENT_MM)))
    label = problem.station_labels[label_index]
    if k == 0:
        return StationCentres(label, idx, d, [], 0)
    B = Vt[:k].T
    c = d @ B
    design = np.column_stack([np.ones(n), c])
    coef_y = np.linalg.lstsq(design, yz[:, 0], rcond=None)[0][1:]
    coef_z = np.linalg.lstsq(design, yz[:, 1], rcond=None)[0][1:]
    gram = np.eye(k) - np.outer(coef_y, coef_y) - np.outer(coef_z, coef_z)
    w, V = np.linalg.eigh(gram)
    v = np.sqrt(max(w[-1], 0.0)) * V[:, -1]
    if k == 3:
        m_y, m_z = B @ coef_y, B @ coef_z
        if (B @ v) @ np.cross(m_y, m_z) < 0:
            v = -v
        signs = [v]
    else:
        signs = [v, -v]
    candidates = [np.column_stack([_signs_and_offset(c @ vv, h), yz]) for vv in signs]
    return StationCentres(label, idx, d, candidates, k)


def rotation_from_translations(stations: list[StationCentres], choice) -> tuple[np.ndarray, dict]:
    """Step 1: pooled Procrustes over the stations' centred displacements."""
    A = np.vstack([st.candidates[ch] - st.candidates[ch].mean(axis=0) for st, ch in zip(stations, choice)])
    Bm = np.vstack([st.d for st in stations])
    sv = np.linalg.svd(Bm, compute_uv=False)
    if sv[1] < RANK_TOLERANCE * sv[0] or sv[1] / np.sqrt(len(Bm)) < MIN_EXTENT_MM:
        raise DegenerateDataError(
            "the pure-translation moves are all along one line: the rotation is not determined; "
            "add moves in a second direction (sweep across the sphere and also along the laser line)"
        )
    R = geo.proper_procrustes(A.T, Bm.T)
    resid = A @ R.T - Bm
    return R, {
        "displacement_singular_values_mm": sv.tolist(),
        "rms_mm": float(np.sqrt(np.mean(np.sum(resid**2, axis=1)))),
    }


def fit_sphere_fixed_radius(points: np.ndarray, radius: float, start: np.ndarray, iterations: int = 30) -> np.ndarray:
    """Centre of the sphere of given radius closest (least squares) to 3-D points."""
    c = np.asarray(start, dtype=float).copy()
    for _ in range(iterations):
        dvec = points - c
        dist = np.maximum(np.linalg.norm(dvec, axis=1), 1e-12)
        J = -dvec / dist[:, None]
        step = np.linalg.lstsq(J, -(dist - radius), rcond=None)[0]
        c += step
        if np.abs(step).max() < 1e-11:
            break
    return c


def points_3d(profile_yz: np.ndarray) -> np.ndarray:
    """(N, 2) laser-plane points to (N, 3) sensor-frame points (0, y, z)."""
    return np.column_stack([np.zeros(len(profile_yz)), profile_yz])


def translation_from_orientations(
    problem: Problem, R: np.ndarray, stations: list[StationCentres], choice, inlier_profiles: list[np.ndarray]
) -> tuple[np.ndarray, np.ndarray, dict]:
    """Step 2: [Tx; c] by linear least squares over the stations' fitted centres."""
    rows, rhs = [], []
    for st, ch in zip(stations, choice):
        R_A = problem.R_A[st.profiles[0]]
        pts = np.vstack([points_3d(inlier_profiles[i]) @ R.T @ R_A.T + problem.t_A[i] for i in st.profiles])
        start = np.mean(st.candidates[ch] @ R.T @ R_A.T + problem.t_A[st.profiles], axis=0)
        xb = fit_sphere_fixed_radius(pts, problem.radius_mm, start)
        rows.append(np.hstack([R_A, -np.eye(3)]))
        rhs.append(-xb)
    M = np.vstack(rows)
    sv = np.linalg.svd(M, compute_uv=False)
    cond = sv[0] / max(sv[-1], 1e-300) if len(sv) == 6 else float("inf")
    if len(sv) < 6 or sv[-1] < 1e-3 * sv[0]:
        raise DegenerateDataError(_orientation_advice(problem, stations))
    sol = np.linalg.lstsq(M, np.concatenate(rhs), rcond=None)[0]
    return sol[:3], sol[3:], {"condition_number": float(cond), "singular_values": sv.tolist()}


def _orientation_advice(problem: Problem, stations: list[StationCentres]) -> str:
    Rs = [problem.R_A[st.profiles[0]] for st in stations]
    rel = [geo.rotvec_from_matrix(Rs[0].T @ Ri) for Ri in Rs[1:]]
    big = [r for r in rel if np.linalg.norm(r) > np.radians(1.0)]
    if not big:
        return (
            f"all {len(stations)} station(s) share one orientation: the translation is not determined; "
            "add at least two stations at other orientations, tilted about two different axes (10-30 deg)"
        )
    axes = np.array([r / np.linalg.norm(r) for r in big])
    return (
        "the stations' orientations differ only by rotations about one axis "
        f"(about {np.round(axes[0], 3).tolist()} in the sphere frame): one component of the translation is "
        "not determined; add a station tilted about a different axis (10-30 deg)"
    )


def point_rms(problem: Problem, R, t, centre, profiles) -> float:
    """RMS distance (mm) of all mapped points to the sphere |A_i X p - c| = r."""
    sq, n = 0.0, 0
    for i, p in enumerate(profiles):
        q = (points_3d(p) @ R.T + t) @ problem.R_A[i].T + problem.t_A[i]
        res = np.linalg.norm(q - centre, axis=1) - problem.radius_mm
        sq += float(res @ res)
        n += len(res)
    return float(np.sqrt(sq / max(n, 1)))


def two_step(
    problem: Problem,
    fits: dict[int, CircleFit],
    nominal_R: np.ndarray | None = None,
    max_combinations: int = 256,
    ambiguity_ratio: float = 1.5,
) -> TwoStepResult:
    """The paper's two steps, with the per-station sign candidates settled by the
    dataset: every combination of mirror candidates is solved and the one whose points
    fit the sphere best is kept. When stations' moves are coplanar, solutions that differ
    by a large rotation can fit equally well (within ``ambiguity_ratio`` of the best
    RMS); ``nominal_R`` (the rough rotation of X, e.g. from the configuration) then picks
    one, and without it a :class:`DegenerateDataError` says what to add."""
    inliers = [p[fits[i].inliers] if i in fits else p[:0] for i, p in enumerate(problem.profiles)]
    stations = [station_centres(problem, fits, k) for k in range(len(problem.station_labels))]
    stations = [st for st in stations if st.candidates]
    if not stations:
        raise DegenerateDataError(
            "no station has enough usable profiles with moves between them: each station needs "
            "profiles taken at different positions of a pure-translation sweep across the sphere"
        )
    options = [range(len(st.candidates)) for st in stations]
    combos = list(itertools.islice(itertools.product(*options), max_combinations))
    solutions = []
    for choice in combos:
        R, diag1 = rotation_from_translations(stations, choice)
        t, c, diag2 = translation_from_orientations(problem, R, stations, choice, inliers)
        solutions.append((point_rms(problem, R, t, c, inliers), R, t, c, choice, diag1, diag2))
    solutions.sort(key=lambda s: s[0])
    best = solutions[0]
    rivals = [s for s in solutions[1:] if s[0] <= ambiguity_ratio * best[0] + 1e-9
              and geo.rotation_angle_deg(s[1], best[1]) > 1.0]
    if rivals:
        if nominal_R is None:
            angle = geo.rotation_angle_deg(rivals[0][1], best[1])
            raise DegenerateDataError(
                f"two solutions {angle:.1f} deg apart fit the data equally well: the moves within each station "
                "are coplanar, so the side of the laser plane the sphere centre is on cannot be decided; add moves "
                "out of that plane (vary the stand-off and the position along the line during each sweep), or give "
                "a nominal transform to choose between them"
            )
        pool = [best] + rivals
        best = min(pool, key=lambda s: geo.rotation_angle_deg(s[1], nominal_R))
    score, R, t, c, choice, diag1, diag2 = best
    return TwoStepResult(
        R, t, c, stations, choice,
        {
            "rotation_step": diag1,
            "translation_step": diag2,
            "point_rms_mm": score,
            "station_move_rank": {st.label: st.rank for st in stations},
            "sign_combinations_tried": len(combos),
            "equally_good_alternatives": len(rivals),
            "obs_index": problem.obs_index.tolist(),
        },
    )
