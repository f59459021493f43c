"""Checks of a table of robot poses and sensor readings, row by row, before any fit.

A table typed by hand (a published experiment, an integrator's log) has typos. What a
typo does and what catches it, naming the row (the observation index):

- a quaternion that is not unit beyond rounding: refused when the file is read
  (:class:`spherecal.core.models.Pose`, norm within 1e-3);
- a translation in metres among millimetres (robot pose, sphere centre or circle): the
  row's magnitude is hundreds of times below the other rows' (:func:`screen_table`);
- a circle larger than the sphere: not the sphere, or the radius in other units;
- a sign flipped in one component of a pose or of a centre, or any other gross error
  within a station: a pure translation moves the sphere centre in the sensor frame by
  exactly what the robot moved, so the distance between two shots' centres equals the
  distance between their flange positions, whatever the unknown rotation. The row that
  breaks this with two or more rows of its station is left out (:func:`pairwise_move_check`);
  two rows that break it with each other only are left out together, and the solution of
  the others tells which is wrong (:func:`settle_pairs`). Once the others are solved, the
  row is flagged with the size of its error in mm: how far its
  centre is from where that solution puts it, relative to the rest of its station
  (:func:`leave_one_out_sizes`; a difference of distances understates an error across
  the move). A flipped quaternion component
  turns the pose: the station orientation screening
  (:func:`.problem.screen_station_orientations`) flags it with its angle.

Finer inconsistencies are judged after the two-step (the centre moved unlike the robot,
in robust standard deviations) and by the joint fit's chi^2; flagged rows are left out,
never used silently. Applies to centre observations; the units check of the robot poses
to every row.
"""

from __future__ import annotations

import numpy as np

from spherecal.core.models import ObservationFlag
from spherecal.estimation.problem import (
    KIND_CIRCLE, KIND_PROFILE, KIND_SPHERE_CENTRE, Problem, fill_unknown, orientation_groups, unknown_variances,
)
from spherecal.estimation.robust import median

__all__ = ["screen_table", "pairwise_move_check", "settle_pairs", "leave_one_out_sizes", "with_leave_one_out_size",
           "within_station_noise", "circles_from_profiles"]

#: A row whose magnitude is below the median of the others' divided by this looks like
#: metres among millimetres (a factor of 1000; 200 leaves room for real spread).
METRES_RATIO = 200.0
#: Below this median magnitude (mm) the units check says nothing (too little to compare).
METRES_MIN_MEDIAN_MM = 20.0
#: A flange translation this many times farther from the base than the others' median
#: (and farther than FAR_MIN_MM) is out of any cell's reach: a typo (a digit too many,
#: micrometres for millimetres).
FAR_RATIO = 10.0
FAR_MIN_MM = 5000.0
#: A circle this much larger than the sphere is not the sphere.
CIRCLE_RADIUS_SLACK = 1.02
#: Gross inconsistency between two shots of a station: the distance their centres moved
#: in the sensor frame and the distance the robot moved differ by more than this, mm
#: (plus GROSS_MOVE_RELATIVE of the move, and six standard deviations where the
#: covariances are given). Finer errors are left to the fits, which know the noise.
GROSS_MOVE_MM = 1.0
GROSS_MOVE_RELATIVE = 0.02
#: The end of the flag of each row of a pair :func:`pairwise_move_check` cannot settle
#: (:func:`settle_pairs` replaces it once the solution of the others tells which is wrong).
PAIR_UNDECIDED = ("one of the two rows has a typo (a sign, metres for millimetres) and nothing within the station "
                  "tells which: both left out")


def _flag(problem: Problem, i: int, reason: str) -> ObservationFlag:
    return ObservationFlag(index=int(problem.obs_index[i]), station=problem.station_labels[problem.station_of[i]],
                           reason=reason)


def _metres_rows(values: np.ndarray, rows: np.ndarray) -> list[tuple[int, float, float]]:
    """Rows (of ``rows``) whose magnitude is METRES_RATIO times below the median of the
    others': (row, its magnitude, the median)."""
    if len(rows) < 3:
        return []
    mag = np.linalg.norm(values[rows], axis=1)
    out = []
    for k, others in enumerate(_medians_of_the_others(mag)):
        if others >= METRES_MIN_MEDIAN_MM and mag[k] < others / METRES_RATIO:
            out.append((int(rows[k]), float(mag[k]), float(others)))
    return out


def _medians_of_the_others(x: np.ndarray) -> np.ndarray:
    """For each element, the median of all the others (as ``np.median(np.delete(x, k))``),
    from one sort: leaving out the element at sorted position p shifts the ones above it
    down by one."""
    n = len(x)
    order = np.argsort(x, kind="stable")
    s = x[order]
    pos = np.empty(n, dtype=int)
    pos[order] = np.arange(n)

    def kth_without(j):  # the j-th smallest of the others, for every element
        return np.where(j < pos, s[np.minimum(j, n - 1)], s[np.minimum(j + 1, n - 1)])

    m = n - 1
    if m % 2:
        return kth_without(np.full(n, m // 2))
    return (kth_without(np.full(n, m // 2 - 1)) + kth_without(np.full(n, m // 2))) / 2.0


def screen_table(problem: Problem) -> tuple[np.ndarray, list[ObservationFlag], list[tuple[int, int]], list[int]]:
    """Rows that are typos in units or size, and gross breaks of the pure-translation
    rule within a station (see the module docstring). Returns the rows to keep, the
    flags of those left out, and the pairs of rows (positions) left out together because
    nothing within their station told which of the two is wrong
    (:func:`settle_pairs` may tell it from the solution of the others), and the rows
    (positions) the pure-translation check left out (to be given their size once the
    others are solved, :func:`leave_one_out_sizes`)."""
    n = problem.n_profiles
    keep = np.ones(n, dtype=bool)
    flags: list[ObservationFlag] = []
    for i, mag, med in _metres_rows(problem.t0, np.arange(n)):
        keep[i] = False
        flags.append(_flag(problem, i, f"base_from_flange.translation_mm is {mag:.4g} from the base origin while "
                                       f"the other rows' are about {med:.4g}: metres among millimetres? "
                                       "Give every translation in mm"))
    if n >= 3:
        mag = np.linalg.norm(problem.t0, axis=1)
        medians = _medians_of_the_others(mag)
        for i in np.flatnonzero(keep):
            others = float(medians[i])
            if mag[i] > max(FAR_RATIO * others, FAR_MIN_MM):
                keep[i] = False
                flags.append(_flag(problem, i, f"base_from_flange.translation_mm is {mag[i]:.4g} mm from the base "
                                               f"origin while the other rows' are about {others:.4g} mm: out of the "
                                               "robot's reach, a typo (a digit too many) or other units"))
    if not problem.has_centres:
        return keep, flags, [], []
    kinds, meas, r = problem.kind, problem.centre_meas, problem.radius_mm
    sph = np.flatnonzero((kinds == KIND_SPHERE_CENTRE) & keep)
    for i, mag, med in _metres_rows(meas, sph):
        keep[i] = False
        flags.append(_flag(problem, i, f"sphere_centre_mm is {mag:.4g} from the sensor origin while the other rows' "
                                       f"are about {med:.4g}: metres among millimetres? Give the centre in mm"))
    cir = np.flatnonzero((kinds == KIND_CIRCLE) & keep)
    for i in cir:
        if meas[i, 2] > CIRCLE_RADIUS_SLACK * r:
            keep[i] = False
            flags.append(_flag(problem, i, f"circle.radius_mm {meas[i, 2]:.4g} exceeds the sphere radius {r:g} mm: "
                                           "not the sphere, a diameter for a radius, or other units"))
    cir = np.flatnonzero((kinds == KIND_CIRCLE) & keep)
    for i, mag, med in _metres_rows(meas, cir):
        keep[i] = False
        flags.append(_flag(problem, i, f"circle (centre_yz_mm, radius_mm) is {mag:.4g} in size while the other rows' "
                                       f"are about {med:.4g}: metres among millimetres? Give the circle in mm"))
    more_keep, more_flags, pairs = pairwise_move_check(problem, keep)
    moved = np.flatnonzero(keep & ~more_keep).tolist()
    return more_keep, flags + more_flags, pairs, moved


def _centre_distances(problem: Problem, i: int, j: int) -> tuple[float, ...]:
    """The possible distances (mm) between the sphere centres of shots i and j in the
    sensor frame: one for two sphere centres; for a circle, whose side of the laser plane
    is not decided here, one per side."""
    r = problem.radius_mm
    a, b = problem.centre_meas[i], problem.centre_meas[j]
    ka, kb = problem.kind[i], problem.kind[j]
    if ka == KIND_SPHERE_CENTRE and kb == KIND_SPHERE_CENTRE:
        return (float(np.linalg.norm(a - b)),)

    def split(kind, v):
        if kind == KIND_SPHERE_CENTRE:
            return v[1:], (v[0],)
        h = float(np.sqrt(max(r * r - v[2] ** 2, 0.0)))
        return v[:2], (h, -h)

    yz_a, xa = split(ka, a)
    yz_b, xb = split(kb, b)
    in_plane = float(np.sum((yz_a - yz_b) ** 2))
    return tuple(float(np.sqrt(in_plane + (p - q) ** 2)) for p in xa for q in xb)


#: Fewest pairs of centre observations within stations for :func:`within_station_noise`.
WITHIN_STATION_MIN_PAIRS = 3


def within_station_noise(problem: Problem) -> float | None:
    """The per-axis noise (mm) the centre observations show within their stations, where
    the robot only translated: a robust standard deviation (1.4826 times the median
    absolute value) of the difference between the distance a pair's sphere centres moved
    in the sensor frame and the distance the flange moved, over every pair of a station,
    divided by sqrt(2) (two noisy centres). It needs neither the transform nor the
    mounting, so it measures the noise of the centres and the robot's repeatability even
    when the model is wrong (another mounting's data, an absurd fit), where the noise
    estimated from the joint fit's residuals would take in the misfit. A circle's side of
    the laser plane is the one that agrees best (a lower bound). None with fewer than
    :data:`WITHIN_STATION_MIN_PAIRS` pairs."""
    gaps = []
    rows_of = [np.flatnonzero((problem.station_of == k) & (problem.kinds != KIND_PROFILE))
               for k in range(len(problem.station_labels))]
    for rows in rows_of:
        for a in range(len(rows)):
            for b in range(a + 1, len(rows)):
                i, j = int(rows[a]), int(rows[b])
                moved = float(np.linalg.norm(problem.t0[i] - problem.t0[j]))
                gaps.append(min(abs(d - moved) for d in _centre_distances(problem, i, j)))
    if len(gaps) < WITHIN_STATION_MIN_PAIRS:
        return None
    return float(1.4826 * median(gaps) / np.sqrt(2.0))


def _given_sd(problem: Problem, i: int) -> float:
    """Largest standard deviation of shot i's given covariance, mm (0 when none)."""
    C = problem.centre_cov[i]
    return 0.0 if unknown_variances(C).all() else float(np.sqrt(np.linalg.eigvalsh(fill_unknown(C, 0.0))[-1]))


#: Rows of a station whose orientations differ by more than this (deg, from the mean of
#: their orientation group) are not compared with each other by :func:`pairwise_move_check`:
#: the robot did not only translate between them, so the pure-translation rule does not
#: hold, and the orientation screening (:func:`.problem.screen_station_orientations`)
#: names them. 0.1 deg turns the sphere centre by at most 0.5 mm at a 300 mm lever, within
#: :data:`GROSS_MOVE_MM`.
SAME_ORIENTATION_DEG = 0.1


def pairwise_move_check(problem: Problem, keep: np.ndarray | None = None
                        ) -> tuple[np.ndarray, list[ObservationFlag], list[tuple[int, int]]]:
    """Within each station, the sphere centre must move in the sensor frame by the
    distance the flange moved (a pure translation): compares every pair of centre
    observations at one orientation (within :data:`SAME_ORIENTATION_DEG`; rows of a
    station at several orientations are a labelling error the orientation screening
    names, not typos). The row that disagrees with two or more rows of its station (worst
    first, then again without it) is left out and flagged with its inconsistency in mm;
    two rows that disagree with each other only (the rest of the station agreeing with
    both, or no rest) are both left out and flagged, and returned as a pair: the check
    cannot tell which is wrong, :func:`settle_pairs` may."""
    n = problem.n_profiles
    keep = np.ones(n, dtype=bool) if keep is None else keep.copy()
    flags: list[ObservationFlag] = []
    pairs: list[tuple[int, int]] = []
    kinds = problem.kinds
    for k in range(len(problem.station_labels)):
        rows = np.flatnonzero((problem.station_of == k) & keep & (kinds != KIND_PROFILE))
        if len(rows) < 2:
            continue
        for members in orientation_groups(problem.R0[rows], SAME_ORIENTATION_DEG):
            if len(members) >= 2:
                _check_moves(problem, [int(i) for i in rows[np.sort(members)]], keep, flags, pairs)
    return keep, flags, pairs


def _check_moves(problem: Problem, rows: list[int], keep: np.ndarray, flags: list[ObservationFlag],
                 pairs: list[tuple[int, int]]) -> None:
    """:func:`pairwise_move_check` on ``rows`` (positions in ``problem``, of one station
    and one orientation): updates ``keep``, ``flags`` and ``pairs``."""
    m = len(rows)
    excess = np.zeros((m, m))  # inconsistency beyond the tolerance, mm (0: consistent)
    gap = np.zeros((m, m))  # the inconsistency itself, mm
    moved = np.zeros((m, m))
    for a in range(m):
        for b in range(a + 1, m):
            i, j = rows[a], rows[b]
            D = float(np.linalg.norm(problem.t0[i] - problem.t0[j]))
            g = min(abs(d - D) for d in _centre_distances(problem, i, j))
            tol = GROSS_MOVE_MM + GROSS_MOVE_RELATIVE * D + 6.0 * np.hypot(_given_sd(problem, i), _given_sd(problem, j))
            gap[a, b] = gap[b, a] = g
            moved[a, b] = moved[b, a] = D
            excess[a, b] = excess[b, a] = max(g - tol, 0.0)
    alive = list(range(m))
    while len(alive) >= 2:
        sub = excess[np.ix_(alive, alive)]
        bad = (sub > 0).sum(axis=1)
        if not bad.any():
            break
        if bad.max() == 1:
            # every row that disagrees does so with one other row only, which disagrees
            # with it only: the rest of the station agrees with both, so nothing within
            # the station tells which of the two is wrong (a typo mostly across the
            # robot's moves changes only the distance to the row it was moved along,
            # and a station's first or last row has one such neighbour). Both are left
            # out as a pair, for the solution of the others to settle (settle_pairs).
            for u in range(len(alive)):
                w = int(np.flatnonzero(sub[u] > 0)[0]) if bad[u] else -1
                if w <= u:
                    continue
                a, b = alive[u], alive[w]
                for x, y in ((a, b), (b, a)):
                    i = rows[x]
                    keep[i] = False
                    flags.append(_flag(problem, i, (
                        f"inconsistent with observation {int(problem.obs_index[rows[y]])} of its station: the robot "
                        f"moved {moved[x, y]:.3f} mm between them, the sphere centre moved otherwise in the sensor "
                        f"frame (the distances differ by {gap[x, y]:.3f} mm, the least the error can be: within a "
                        "station of two rows only distances can be compared) (a pure translation moves both alike); "
                        + PAIR_UNDECIDED)))
                pairs.append((rows[a], rows[b]))
            break
        worst = max(range(len(alive)), key=lambda x: (bad[x], sub[x].sum()))
        x = alive[worst]
        i = rows[x]
        others = [y for y in alive if y != x]
        size = float(median(gap[x, others]))
        keep[i] = False
        flags.append(_flag(problem, i, (
            f"inconsistent with {bad[worst]} of the {len(others)} other rows of its station: its sphere centre "
            f"did not move in the sensor frame by the distance the robot moved (the distances differ by {size:.3f} "
            "mm, median; a pure translation moves both alike): a typo in the pose or the centre (a sign, metres for millimetres)?")))
        alive = others


def settle_pairs(problem: Problem, pairs: list[tuple[int, int]], R, t, centre, noise_mm: float,
                 limit: float) -> list[tuple[int, int, float, float]]:
    """Of each pair of rows left out together (:func:`pairwise_move_check`), the one that
    agrees with a solution of the other observations (``R``, ``t``, ``centre``) while the
    other does not: ``[(good, bad, chi2 of good, chi2 of bad), ...]`` (positions in
    ``problem``). A row's chi^2 (3 dof) is that of its centre residual under its given
    covariance, else ``noise_mm`` per axis; ``limit`` is the chi^2 above which a row
    disagrees."""
    from spherecal.estimation.twostep import centre_residuals

    e = centre_residuals(problem, R, t, centre)
    out = []

    def chi2(i):
        S = fill_unknown(problem.centre_cov[i], noise_mm**2)
        return float(e[i] @ np.linalg.solve(S, e[i]))

    for a, b in pairs:
        ca, cb = chi2(a), chi2(b)
        if ca <= limit < cb:
            out.append((a, b, ca, cb))
        elif cb <= limit < ca:
            out.append((b, a, cb, ca))
    return out


def leave_one_out_sizes(problem: Problem, rows, R, t, centre, used: np.ndarray) -> dict[int, float]:
    """The size (mm) of the error in each of ``rows`` (positions in ``problem``, rows left
    out of a solution ``R``, ``t``, ``centre`` of the others): the length of its centre
    residual (:func:`.twostep.centre_residuals`: x, y, z of a sphere centre; y, z and the
    cut radius of a circle) minus the median residual of its station's rows in ``used``
    (a boolean mask), so the robot's error common to the station does not count. A 2 mm
    typo in one coordinate reads about 2 mm, a sign flipped in a pose's 150 mm component
    about 300 mm."""
    from spherecal.estimation.twostep import centre_residuals

    e = centre_residuals(problem, R, t, centre)
    out = {}
    for i in rows:
        same = np.flatnonzero(used & (problem.station_of == problem.station_of[i]) & (problem.kinds != KIND_PROFILE))
        same = same[same != i]
        ref = median(e[same], axis=0) if len(same) else np.zeros(3)
        out[int(i)] = float(np.linalg.norm(e[i] - ref))
    return out


def with_leave_one_out_size(flag: ObservationFlag, size_mm: float, kind_name: str) -> ObservationFlag:
    """``flag`` (of :func:`pairwise_move_check`) with the size of the row's error first."""
    return flag.model_copy(update={"reason": (
        f"its {kind_name} is {size_mm:.3f} mm from where the solution of the other observations puts it (relative "
        f"to the rest of its station); {flag.reason}")})


def circles_from_profiles(dataset, min_points: int = 20, max_rms_mm: float = 0.5):
    """The dataset a sensor that fits on board would have given: each profile replaced
    by the circle fitted to it (:func:`.circle.fit_circle`, robust to stray points), its
    standard deviations left to the estimator. Profiles with fewer than ``min_points``
    points or a poor fit (rms above ``max_rms_mm``) are dropped, as such a sensor would
    report nothing. Other observations are kept as they are."""
    from spherecal.core.models import Circle, Dataset
    from spherecal.estimation.circle import fit_circle

    out = []
    for o in dataset.observations:
        if o.profile is None:
            out.append(o)
            continue
        if len(o.profile) < min_points:
            continue
        fit = fit_circle(o.profile.points_mm)
        if not fit.converged or fit.rms > max_rms_mm or fit.n_inliers < min_points:
            continue
        circle = Circle(centre_yz_mm=(float(fit.centre_yz[0]), float(fit.centre_yz[1])), radius_mm=fit.radius)
        out.append(o.model_copy(update={"profile": None, "circle": circle}))
    return Dataset(mounting=dataset.mounting, sphere_radius_mm=dataset.sphere_radius_mm, observations=out,
                   provenance={**dataset.provenance, "reduced_to": "circles fitted to the profiles"})
