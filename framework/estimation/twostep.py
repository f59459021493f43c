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

Centre observations (a circle fitted on board, or a sphere centre already resolved) enter
as :class:`CentreShot` beside the profiles' circle fits: a circle goes through the same
side-of-plane decision as a fitted profile's circle; a sphere centre's x is known. In
step 2 each centre shot gives its own rows ``R_Ai Tx - c = -(R_Ai Rx C_i + tA_i)``, so a
station of one sphere centre, or of two circles (one move decides the side), is usable.
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass, field

import numpy as np

from spherecal.core import geometry as geo
from spherecal.core.errors import DegenerateDataError
from spherecal.core.mapping import map_profile_list
from spherecal.core.models import TRANSFORM_NAME
from spherecal.estimation.circle import CircleFit, half_chord_depth
from spherecal.estimation.problem import KIND_CIRCLE, KIND_PROFILE, KIND_SPHERE_CENTRE, Problem

#: Relative singular value under which a direction counts as not excited.
RANK_TOLERANCE = 0.05
#: ... and the RMS extent (mm) under which it counts as not excited.
MIN_EXTENT_MM = 0.5


@dataclass(frozen=True)
class CentreShot:
    """A centre observation as the two-step sees it, in the place of a profile's circle
    fit: the circle (centre (y, z) and radius, laser plane, mm) and, for a sphere centre,
    its known x (else None). A sphere centre's ``radius`` is that of the circle the laser
    plane would cut, ``sqrt(max(r^2 - x^2, 0))``."""

    centre_yz: np.ndarray
    radius: float
    x_mm: float | None = None


def _depths(problem: Problem, fits: dict, idx: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """|x| of the sphere centre of each shot ``idx``, and its known x (NaN where the side
    of the laser plane is to be decided)."""
    h = half_chord_depth(problem.radius_mm, [fits[i].radius for i in idx])
    x_known = np.array([np.nan if getattr(fits[i], "x_mm", None) is None else fits[i].x_mm for i in idx])
    known = ~np.isnan(x_known)
    h[known] = np.abs(x_known[known])
    return h, x_known


def _apply_known_x(candidates: list[np.ndarray], x_known: np.ndarray) -> list[np.ndarray]:
    """Sphere centres whose x is known: keep the mirror candidate that agrees with them
    (the side of the laser plane is then decided) and put their measured x in."""
    known = ~np.isnan(x_known)
    if not known.any() or not candidates:
        return candidates
    best = min(candidates, key=lambda cand: float(np.sum((cand[known, 0] - x_known[known]) ** 2)))
    best = best.copy()
    best[known, 0] = x_known[known]
    return [best]


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
    # with no nominal transform: other choices of the sides of the laser plane that fit
    # nearly as well and give a rotation more than 1 deg away, best first; the joint
    # model decides between them (:mod:`.starts`)
    alternatives: list[TwoStepResult] = field(default_factory=list)


def _abs_fit_costs(a: np.ndarray, u: np.ndarray, h: np.ndarray) -> np.ndarray:
    """sum_i (|a_j + u_i| - h_i)^2 for every a_j, in O((m + n) log n): expanded as
    sum (a + u)^2 - 2 sum h |a + u| + sum h^2, the middle sum split where a + u_i changes
    sign (prefix sums over u sorted)."""
    order = np.argsort(u)
    us, hs = u[order], h[order]
    H = np.concatenate([[0.0], np.cumsum(hs)])
    HU = np.concatenate([[0.0], np.cumsum(hs * us)])
    k = np.searchsorted(us, -a, side="left")  # the u_i with a + u_i < 0
    abs_sum = (a * H[-1] + HU[-1]) - 2.0 * (a * H[k] + HU[k])
    return len(u) * a * a + 2.0 * a * u.sum() + u @ u - 2.0 * abs_sum + h @ h


def _signs_and_offset(u: np.ndarray, h: np.ndarray) -> np.ndarray:
    """x_i with |x_i| ~ h_i and x_i = a + u_i: choose a, return s_i h_i."""
    cands = np.concatenate([h - u, -h - u])
    # every candidate's cost at once; those within rounding of the least are summed
    # directly and the first of the least taken, as summing each directly would choose
    fast = _abs_fit_costs(cands, u, h)
    tol = 1e-8 * (np.abs(fast).min() + len(u) * (np.abs(h).max() + np.abs(u).max()) ** 2 * 1e-6) + 1e-11
    near = np.flatnonzero(fast <= fast.min() + tol)
    costs = [np.sum((np.abs(cands[j] + u) - h) ** 2) for j in near]
    a = cands[near[int(np.argmin(costs))]]
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
    idx = np.array([i for i in np.flatnonzero(problem.station_of == label_index).tolist() if i in fits], dtype=int)
    if len(idx) == 0:
        return StationCentres(problem.station_labels[label_index], idx, np.zeros((0, 3)), [], 0)
    yz = np.array([fits[i].centre_yz for i in idx.tolist()])
    h = half_chord_depth(problem.radius_mm, [fits[i].radius for i in idx.tolist()])
    centres = problem.has_centres and bool(np.any(problem.kinds[idx] != KIND_PROFILE))
    if centres:
        h, x_known = _depths(problem, fits, idx)
    R_A = problem.R_sphere_from_mount[idx[0]]
    tA = problem.t_sphere_from_mount[idx]
    d = -(tA - tA.mean(axis=0)) @ R_A  # rows: R_A^T (tA_mean - tA_i)
    _, s, Vt = np.linalg.svd(d, full_matrices=False)
    n = len(idx)
    k = int(np.sum((s > RANK_TOLERANCE * max(s[0], 1e-12)) & (s / np.sqrt(n) > MIN_EXTENT_MM)))
    label = problem.station_labels[label_index]
    if k == 0:
        if not centres:
            return StationCentres(label, idx, d, [], 0)
        # no move to decide the side of the laser plane: a station of centre observations
        # still serves the translation, each side a candidate (sphere centres: known)
        candidates = [np.column_stack([sign * h, yz]) for sign in (1.0, -1.0)]
        return StationCentres(label, idx, d, _apply_known_x(candidates, x_known), 0)
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
    if centres:
        candidates = _apply_known_x(candidates, x_known)
    return StationCentres(label, idx, d, candidates, k)


def _consistent_choices(stations: list[StationCentres]) -> list[tuple[int, ...]]:
    """Choices of each station's side of the laser plane that agree on one rotation,
    for when every combination is too many to try (20 stations of coplanar moves: 2^20).
    Each candidate of each station whose moves span a plane gives a rotation of its own
    (Procrustes on its moves alone); taking it as the rotation, every station keeps the
    candidate its moves fit best, and the choice is redone with the pooled rotation of
    that choice until it settles. The mirror candidates of a station differ by half a
    turn, so the true side agrees across stations and a wrong one does not."""
    anchors = [(k, ch) for k, st in enumerate(stations) if st.rank >= 2 for ch in range(len(st.candidates))]
    out: list[tuple[int, ...]] = []

    def pick(R):
        return tuple(int(np.argmin([np.sum(((c - c.mean(axis=0)) @ R.T - st.d) ** 2) for c in st.candidates]))
                     for st in stations)

    for k, ch in anchors:
        st = stations[k]
        A = st.candidates[ch] - st.candidates[ch].mean(axis=0)
        choice = pick(geo.proper_procrustes(A.T, st.d.T))
        for _ in range(5):
            try:
                R, _ = rotation_from_translations(stations, choice)
            except DegenerateDataError:
                break
            settled = pick(R)
            if settled == choice:
                break
            choice = settled
        if choice not in out:
            out.append(choice)
    return out


def rotation_from_translations(stations: list[StationCentres], choice) -> tuple[np.ndarray, dict]:
    """Step 1: pooled Procrustes over the stations' centred displacements."""
    A = np.vstack([st.candidates[ch] - st.candidates[ch].mean(axis=0) for st, ch in zip(stations, choice)])
    Bm = np.vstack([st.d for st in stations])
    sv = np.linalg.svd(Bm, compute_uv=False)
    if len(Bm) < 2 or not sv[0] > 0:
        raise DegenerateDataError(
            "no station has two shots the robot moved between by a pure translation: the rotation is not "
            "determined; each station needs shots at different positions of a pure-translation sweep"
        )
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


#: Above this condition number of the 3 x 3 normal matrix, :func:`fit_sphere_fixed_radius`
#: takes its step by least squares on the points instead (its conditioning is the square
#: root of the normal matrix's: points on one circle seen from its plane).
NORMAL_EQUATIONS_CONDITION = 1e8


def fit_sphere_fixed_radius(points: np.ndarray, radius: float, start: np.ndarray, iterations: int = 30) -> np.ndarray:
    """Centre of the sphere of given radius closest (least squares) to 3-D points:
    Gauss-Newton on the distances, each step from its 3 x 3 normal equations when they
    are well conditioned, else by least squares on the points (minimum norm: a direction
    the points do not determine is left as it is)."""
    c = np.asarray(start, dtype=float).copy()
    for _ in range(iterations):
        dvec = points - c
        dist = np.maximum(np.linalg.norm(dvec, axis=1), 1e-12)
        u = dvec / dist[:, None]  # d dist / d c = -u
        N = u.T @ u
        lam = np.linalg.eigvalsh(N)
        if lam[0] > lam[-1] / NORMAL_EQUATIONS_CONDITION:
            step = np.linalg.solve(N, u.T @ (dist - radius))
        else:
            step = np.linalg.lstsq(-u, -(dist - radius), rcond=None)[0]
        c += step
        if np.abs(step).max() < 1e-11:
            break
    return c


def translation_from_orientations(
    problem: Problem, R: np.ndarray, stations: list[StationCentres], choice, inlier_profiles: list[np.ndarray]
) -> tuple[np.ndarray, np.ndarray, dict]:
    """Step 2: [Tx; c] by linear least squares over the stations' fitted centres."""
    rows, rhs = [], []
    kinds = problem.kinds
    for st, ch in zip(stations, choice):
        R_A = problem.R_sphere_from_mount[st.profiles[0]]
        is_centre = kinds[st.profiles] != KIND_PROFILE
        if is_centre.any():
            # each centre shot: R_Ai Tx - c = -(R_Ai Rx C_i + tA_i)
            for i, C in zip(st.profiles[is_centre], st.candidates[ch][is_centre]):
                R_Ai, t_Ai = problem.R_sphere_from_mount[i], problem.t_sphere_from_mount[i]
                rows.append(np.hstack([R_Ai, -np.eye(3)]))
                rhs.append(-(R_Ai @ (R @ C) + t_Ai))
            if is_centre.all():
                continue
            prof = st.profiles[~is_centre]
            cands = st.candidates[ch][~is_centre]
        else:
            prof, cands = st.profiles, st.candidates[ch]
        # the station's points through R_A X (the station shares R_A), each shot's t_A added
        pts, _ = map_profile_list(np.broadcast_to(R_A @ R, (len(prof), 3, 3)), problem.t_sphere_from_mount[prof],
                                  [inlier_profiles[i] for i in prof], backend=MAPPING_BACKEND)
        start = np.mean(cands @ R.T @ R_A.T + problem.t_sphere_from_mount[prof], axis=0)
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


def rotation_determined(problem: Problem, stations: list[StationCentres], R: np.ndarray, diag: dict) -> str:
    """What the moves within ``stations`` still give when the translation is not
    determined: the rotation ``R`` (``diag``: :func:`rotation_from_translations`'), the
    stations it comes from (those whose moves span 3-D, else all), and about how well:
    the moves' residual RMS over their smallest singular value (rad), one sigma."""
    spanning = [st.label for st in stations if st.rank == 3] or [st.label for st in stations]
    q = geo.quat_wxyz_from_matrix(R)
    sd_deg = float(np.degrees(diag["rms_mm"] / diag["displacement_singular_values_mm"][-1]))
    return (f"the rotation is determined, by the moves within station(s) {', '.join(spanning)}, to about "
            f"{sd_deg:.2g} deg: {TRANSFORM_NAME[problem.mounting]} quaternion_wxyz "
            f"[{', '.join(f'{v:.5f}' for v in q)}]")


def _orientation_advice(problem: Problem, stations: list[StationCentres]) -> str:
    Rs = [problem.R_sphere_from_mount[st.profiles[0]] for st in stations]
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


def point_rms(problem: Problem, R, t, centre, profiles: list[np.ndarray]) -> float:
    """RMS distance (mm) of all mapped points to the sphere |A_i X p - c| = r; with
    centre observations, their residuals' components (:func:`centre_residuals`) join
    the points."""
    R_A, t_A = problem.R_sphere_from_mount, problem.t_sphere_from_mount
    q, _ = map_profile_list(R_A @ R, R_A @ t + t_A, profiles, backend=MAPPING_BACKEND)
    res = np.linalg.norm(q - centre, axis=1) - problem.radius_mm
    sq, n = float(res @ res), len(res)
    if problem.has_centres:
        e = centre_residuals(problem, R, t, centre)
        e = e[~np.isnan(e[:, 0])]
        sq += float(np.sum(e**2))
        n += e.size
    return float(np.sqrt(sq / max(n, 1)))


def predicted_sensor_centres(problem: Problem, R, t, centre) -> np.ndarray:
    """The sphere centre in the sensor frame at each shot, ``X^-1 A_i^-1 c`` (n, 3), mm."""
    R_A, t_A = problem.R_sphere_from_mount, problem.t_sphere_from_mount
    u = np.einsum("nji,nj->ni", R_A, np.asarray(centre, float) - t_A) - t
    return u @ R


def centre_residuals(problem: Problem, R, t, centre, radius: float | None = None) -> np.ndarray:
    """Residual of each centre observation (n, 3), mm; NaN rows for profiles. A sphere
    centre: predicted minus measured (x, y, z). A circle: (y, z) of the predicted centre
    minus the circle's, and the radius of the circle the laser plane cuts from the
    predicted sphere, ``sqrt(r^2 - x^2)``, minus the measured radius (no side of the
    plane is needed)."""
    r = problem.radius_mm if radius is None else radius
    C = predicted_sensor_centres(problem, R, t, centre)
    out = np.full((problem.n_profiles, 3), np.nan)
    if not problem.has_centres:
        return out
    kinds, meas = problem.kinds, problem.centre_meas
    sph = kinds == KIND_SPHERE_CENTRE
    out[sph] = C[sph] - meas[sph]
    cir = kinds == KIND_CIRCLE
    rho = np.sqrt(np.maximum(r * r - C[cir, 0] ** 2, 0.0))
    out[cir] = np.column_stack([C[cir, 1:] - meas[cir, :2], rho - meas[cir, 2]])
    return out


#: The mapping backend of the two-step: NumPy's, so that the start (and its choice of
#: signs) does not depend on whether numba is installed.
MAPPING_BACKEND = "numpy"

#: Points (all profiles) above which the two-step's sphere fits and its choice of signs
#: take every k-th point of each profile: they give the joint refinement its start, and
#: the refinement uses every point.
TWO_STEP_POINTS = 200_000


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
    one, and without it they are returned as ``alternatives`` for the joint model to
    decide (:func:`.starts.settle_alternative_starts`). With more combinations than
    ``max_combinations``, only those whose stations agree on one rotation are tried
    (:func:`_consistent_choices`)."""
    inliers = [fits[i].inlier_points(p) if isinstance(fits.get(i), CircleFit) else p[:0]
               for i, p in enumerate(problem.profiles)]
    # a start and a choice of signs: on very many points, every k-th point of each
    # profile is enough (the joint refinement then uses every point)
    stride = max(1, -(-sum(len(p) for p in inliers) // TWO_STEP_POINTS))
    if stride > 1:
        inliers = [p[::stride] for p in inliers]
    stations = [station_centres(problem, fits, k) for k in range(len(problem.station_labels))]
    stations = [st for st in stations if st.candidates]
    if not stations:
        raise DegenerateDataError(
            "no station has enough usable profiles with moves between them: each station needs "
            "profiles taken at different positions of a pure-translation sweep across the sphere"
        )
    options = [range(len(st.candidates)) for st in stations]
    n_combos = int(np.prod([len(o) for o in options], dtype=float))
    combos = (list(itertools.product(*options)) if n_combos <= max_combinations
              else _consistent_choices(stations)[:max_combinations])
    combos = combos or list(itertools.islice(itertools.product(*options), max_combinations))
    solutions = []
    for choice in combos:
        R, diag1 = rotation_from_translations(stations, choice)
        try:
            t, c, diag2 = translation_from_orientations(problem, R, stations, choice, inliers)
        except DegenerateDataError as exc:
            if len(combos) > 1:
                raise
            raise DegenerateDataError(f"{exc}; {rotation_determined(problem, stations, R, diag1)}") from None
        solutions.append((point_rms(problem, R, t, c, inliers), R, t, c, choice, diag1, diag2))
    solutions.sort(key=lambda s: s[0])
    best = solutions[0]
    rivals = [s for s in solutions[1:] if s[0] <= ambiguity_ratio * best[0] + 1e-9
              and geo.rotation_angle_deg(s[1], best[1]) > 1.0]
    if rivals and nominal_R is not None:
        pool = [best] + rivals
        best = min(pool, key=lambda s: geo.rotation_angle_deg(s[1], nominal_R))

    def result(sol, alternatives=()):
        score, R, t, c, choice, diag1, diag2 = sol
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
            list(alternatives),
        )

    return result(best, [result(s) for s in rivals] if nominal_R is None else [])
