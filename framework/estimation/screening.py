"""The checks that flag and leave out observations before and during the solve.

Each check appends an :class:`~spherecal.core.models.ObservationFlag` with its reason to
the solve's list of flags; ``opt`` is the solve's
:class:`~spherecal.estimation.pipeline.CalibrationOptions`. The profiles left out as
inconsistent with the others share one budget (:class:`RejectionBudget`).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np

from spherecal.core import geometry as geo
from spherecal.core.errors import DegenerateDataError
from spherecal.core.kinematics import ArmKinematics
from spherecal.core.models import ObservationFlag
from spherecal.estimation.circle import CircleFit
from spherecal.estimation.problem import KIND_NAMES, KIND_PROFILE, KIND_SPHERE_CENTRE, Problem
from spherecal.estimation.refine import NoiseAssumptions, RefineResult
from spherecal.estimation.robust import median
from spherecal.estimation.centres import GROSS_MOVE_MM, GROSS_MOVE_RELATIVE
from spherecal.estimation.linear_start import MIN_ROWS
from spherecal.estimation.twostep import (
    StationCentres, TwoStepResult, rotation_from_translations, station_centres, two_step,
)


#: Before the joint fit, a profile whose sphere centre moved more than this many robust
#: SDs off the robot's move is left out (mis-pairs in the simulator: 30-130; clean data:
#: at most 8). Smaller inconsistencies are judged by the joint fit's chi^2 test.
GROSS_MOVE_OUTLIER_SDS = 20.0
#: Floor of the robust scale of those residuals, mm.
_MIN_MOVE_SCALE_MM = 0.002
#: Median of the chi distribution with 3 degrees of freedom.
_CHI3_MEDIAN = 1.5382


#: A laser plane farther than this share of the radius from the sphere's centre cuts it
#: near its edge: the circle's radius there changes by more than the plane's offset does.
EDGE_PLANE_OFFSET_SHARE = 0.7


def likely_cause_of_inconsistent_profile(centre_in_sensor_mm, radius_mm: float, recording: bool = False) -> str:
    """The likely cause of a profile whose points lie far from the fitted sphere, from where
    its laser plane cuts the sphere (``centre_in_sensor_mm``: the sphere centre in the
    sensor frame as fitted, mm; the plane is x = 0). A cut near the edge turns the pose's
    error along the sweep into an in-plane error x / rho times larger (rho the circle's
    radius): a few hundredths of a millimetre of robot error look like a bad shot there,
    and the advice is to keep sweeps off the edge, not to suspect the pairing. The sweeps
    of a ``recording`` (on the fly) cross the whole sphere by design (their length is
    ``[acquisition.on_the_fly] crossing_fraction``, at least one radius, not
    ``sweep_fraction``): profiles at the edge are expected there and left out, and only
    many of them say something."""
    x = abs(float(centre_in_sensor_mm[0]))
    r = float(radius_mm)
    if x > EDGE_PLANE_OFFSET_SHARE * r:
        rho = float(np.sqrt(max(r * r - x * x, 0.0)))
        gain = x / rho if rho > 0 else float("inf")
        where = (f"it cuts the sphere near its edge (laser plane {x:.1f} mm from the centre, circle radius "
                 f"{rho:.1f} mm of {r:.1f} mm), where the robot's pose error along the sweep shows {gain:.1f} times "
                 "larger in the profile; ")
        if recording:
            return where + ("a sweep on the fly crosses the whole sphere, so such profiles are expected and left "
                            "out: nothing to change unless they are many (then suspect the arm's path error or the "
                            "clock relation); else a pose read at the wrong moment")
        return where + ("when several such shots are flagged, keep the sweeps off the edge "
                        f"(acquisition.sweep.sweep_fraction at most {EDGE_PLANE_OFFSET_SHARE:g}); else a pose read "
                        "at the wrong moment or a mis-paired shot")
    return "a pose read at the wrong moment or a mis-paired shot"


def flag_shot(problem: Problem, i: int, reason: str, station: str | None = None) -> ObservationFlag:
    """The flag of row ``i`` of ``problem`` (its observation index and station), with ``reason``."""
    return ObservationFlag(
        index=int(problem.obs_index[i]), station=station or problem.station_labels[problem.station_of[i]], reason=reason
    )


#: Where the robot's model may put the flange for a shot's joints, relative to the pose
#: reported with them: a station's median difference within the larger of these and 4 x
#: the stated robot accuracy (a calibrated model differs from the controller's nominal one
#: by about the arm's accuracy), and each shot within these of its station's median (the
#: poses' read noise is a few hundredths of a millimetre).
JOINT_POSE_STATION_MM, JOINT_POSE_STATION_DEG = 3.0, 0.3
JOINT_POSE_SHOT_MM, JOINT_POSE_SHOT_DEG = 1.0, 0.1


@dataclass
class JointPoseCheck:
    """:func:`joints_against_poses`: ``disqualified`` when most shots' joints do not
    describe their poses (``text`` says how far off, and the likely causes); else
    ``shots`` maps the row of each shot that disagrees to the reason it is left out."""

    disqualified: bool
    text: str
    shots: dict[int, str]


def joints_against_poses(problem: Problem, kinematics: ArmKinematics, opt) -> JointPoseCheck:
    """Compare each shot's reported ``base_from_flange`` with the flange pose the robot's
    model gives for the shot's joints (a pose computed from the joints agrees with itself).
    The difference is taken per station (its median: a calibrated model's offset from the
    nominal one changes little over a sweep) and per shot (off its station's median:
    joints of another moment move by the sweep's step)."""
    T = kinematics.chain.flange_matrices(problem.q_rad)
    e = T[:, :3, 3] - problem.t0  # mm, base
    rv = np.degrees(np.array([geo.rotvec_from_matrix(Ri @ R0.T) for Ri, R0 in zip(T[:, :3, :3], problem.R0)]))
    tol_mm = max(JOINT_POSE_STATION_MM, 4.0 * opt.robot_accuracy_mm)
    tol_deg = max(JOINT_POSE_STATION_DEG, 4.0 * opt.robot_accuracy_deg)
    bad = np.zeros(len(e), dtype=bool)
    shots: dict[int, str] = {}
    for k in np.unique(problem.station_of):
        rows = np.flatnonzero(problem.station_of == k)
        e_k, rv_k = median(e[rows], axis=0), median(rv[rows], axis=0)
        if np.linalg.norm(e_k) > tol_mm or np.linalg.norm(rv_k) > tol_deg:
            bad[rows] = True
            continue
        for i in rows:
            d_mm, d_deg = float(np.linalg.norm(e[i] - e_k)), float(np.linalg.norm(rv[i] - rv_k))
            if d_mm > JOINT_POSE_SHOT_MM or d_deg > JOINT_POSE_SHOT_DEG:
                bad[i] = True
                shots[i] = (f"its joints put the flange {float(np.linalg.norm(e[i])):.2f} mm and "
                            f"{float(np.linalg.norm(rv[i])):.3f} deg from the pose given with them ({d_mm:.2f} mm, "
                            f"{d_deg:.3f} deg off its station's other shots): joints read at another moment than "
                            "the pose?")
    d_all, a_all = np.linalg.norm(e, axis=1), np.linalg.norm(rv, axis=1)
    text = (f"the joint readings do not match the reported flange poses: for {int(bad.sum())} of {len(bad)} shots "
            f"the robot's model puts the flange {float(median(d_all[bad])) if bad.any() else 0.0:.3g} mm and "
            f"{float(median(a_all[bad])) if bad.any() else 0.0:.3f} deg (median) from the pose given (at most "
            f"{tol_mm:g} mm and {tol_deg:g} deg expected): joints in radians or not in the controller's convention, "
            "read at another moment than the poses, or another robot's model")
    return JointPoseCheck(bool(bad.sum() > 0.5 * len(bad)), text, shots)


def copied_profiles(problem: Problem) -> list[ObservationFlag]:
    """Profiles equal point for point to an earlier observation's: no sensor measures the
    same points twice to the last digit, so the shot was written twice (a file appended to
    itself, a repeated line under a new index). Counted twice, it would shrink the stated
    uncertainty; each copy after the first is flagged."""
    first: dict[bytes, int] = {}
    flags = []
    for i, pts in enumerate(problem.profiles):
        if problem.kinds[i] != KIND_PROFILE or len(pts) == 0:
            continue
        key = np.ascontiguousarray(pts, dtype=float).tobytes()
        if key in first:
            flags.append(flag_shot(problem, i, f"its profile is observation {int(problem.obs_index[first[key]])}'s, "
                                           "point for point: the same shot written twice?"))
        else:
            first[key] = i
    return flags


def station_minimum(kinds: np.ndarray, opt) -> tuple[int, str, str]:
    """The fewest usable shots a station of these kinds needs, and why. Profiles:
    ``min_profiles_per_station`` (each decides its side of the laser plane and is checked
    against the others). Sphere centres only: 1 (each gives its centre; the translation
    needs one shot per orientation). With circles: 2 (a move within the station decides
    their side of the laser plane)."""
    if (kinds == KIND_PROFILE).all():
        return opt.min_profiles_per_station, "profiles", "add profiles to its sweep"
    if (kinds == KIND_SPHERE_CENTRE).all():
        return 1, "observations", "add a shot to the station"
    return 2, "observations", "a move within the station decides the side of the laser plane: add a shot to it"


def turned_hint(turned: list[ObservationFlag], tolerance_deg: float) -> str:
    """What to do about the shots left out as turned within their station (``turned``),
    appended to the message when too little is left; empty when there are none."""
    if not turned:
        return ""
    return (f"; {len(turned)} shot(s) were left out because they turned within their station (beyond "
            f"{tolerance_deg:.3f} deg): keep each station's orientation fixed, or, if the robot's orientation "
            "readings are noisier than that, set calibration.pose_rotation_noise_deg or "
            "station_rotation_tolerance_deg (spherecal solve --station-rotation-tolerance-deg)")


def _thin_stations(problem: Problem, keep: np.ndarray, flags: list[ObservationFlag], opt, context: str) -> np.ndarray:
    """Leave out (flagged) the profiles of stations with fewer than the minimum of kept
    profiles; returns the updated ``keep``."""
    keep = keep.copy()
    for k, label in enumerate(problem.station_labels):
        members = np.flatnonzero((problem.station_of == k) & keep)
        if not len(members):
            continue
        need, what, advice = station_minimum(problem.kinds[members], opt)
        if len(members) < need:
            for i in members:
                flags.append(flag_shot(problem, i, f"station {label} has only {len(members)} usable {what} {context}"
                                               f"(needs {need}): {advice}"))
            keep[members] = False
    return keep


def _drop_thin_stations_of_fits(problem: Problem, fits: dict, flags: list[ObservationFlag], opt, context: str) -> None:
    keep = _thin_stations(problem, np.isin(np.arange(problem.n_profiles), list(fits)), flags, opt, context)
    for i in list(fits):
        if not keep[i]:
            del fits[i]


def _after_screening(exc: DegenerateDataError, problem: Problem, left: Problem,
                     flags: list[ObservationFlag]) -> DegenerateDataError:
    """``exc`` (the stations left do not determine the transform), saying which stations
    the screening left out and why, when it left any out: the data had them, and the
    cause to fix is theirs (rather than a bare "all 1 station(s) share one orientation"
    for a file with four stations, three of them screened out)."""
    dropped = sorted(set(problem.station_labels) - set(left.station_labels))
    if not dropped:
        return exc
    theirs = [f for f in flags if f.station in dropped]
    reasons = _left_out_summary(theirs) if len(theirs) > _LISTED_FLAGS else _listed(theirs)
    todo = "; " + _NOISY_HINT if _dominant_kind(theirs) == _NOISY_KIND else ""
    return DegenerateDataError(
        f"the screening left out station(s) {', '.join(dropped)} ({reasons}), and the station(s) left "
        f"({', '.join(left.station_labels)}) cannot determine the transform: {exc}. Fix what left them out "
        f"before changing the plan{todo}")


#: The screening's reason for a profile of the sphere's size whose points scatter too much
#: (the sensor's noise), and what to do when it is what left the data out.
_NOISY_KIND = "the points scatter about their circle"
_NOISY_HINT = ("the sensor's points scatter more than max_circle_rms_mm allows (its exposure, a dull, dirty or wet "
               "sphere, ambient light); if that is the noise this sensor gives, raise the calibration setting "
               "max_circle_rms_mm above it")


def _flag_kind(reason: str) -> str:
    """The kind of a screening reason, without its figures."""
    if reason.startswith("station "):
        return "too few usable profiles left in the station"
    for cut in (" (", ":", " by "):
        reason = reason.split(cut)[0]
    return reason


def _dominant_kind(flags: list[ObservationFlag]) -> str | None:
    kinds = [_flag_kind(f.reason) for f in flags if not f.reason.startswith("station ")]
    return max(set(kinds), key=kinds.count) if kinds else None


#: Up to this many flags are listed one by one where the screening says what it left out.
_LISTED_FLAGS = 6


def _listed(flags: list[ObservationFlag]) -> str:
    """``observations 6, 7: <reason>; observation 9: <reason>``: the flags, those with one
    reason together."""
    by_reason: dict[str, list[int]] = {}
    for f in flags:
        by_reason.setdefault(f.reason, []).append(f.index)
    return "; ".join(f"observation{'s' if len(ix) > 1 else ''} {', '.join(map(str, ix))}: {reason}"
                     for reason, ix in by_reason.items())


def _left_out_summary(flags: list[ObservationFlag]) -> str:
    """``21 x points do not lie on a circle; 9 x too few usable profiles left in the station``."""
    why: dict[str, int] = {}
    for f in flags:
        kind = _flag_kind(f.reason)
        why[kind] = why.get(kind, 0) + 1
    return "; ".join(f"{n} x {kind}" for kind, n in sorted(why.items(), key=lambda kv: -kv[1])[:3])


def _drop_profiles(problem: Problem, keep: np.ndarray, flags: list[ObservationFlag], opt, context: str,
                   stations: bool = True) -> Problem:
    """``problem`` without the profiles not kept (already flagged) and, with ``stations``,
    without the stations left too thin (flagged here); raises when what is left cannot
    determine the transform (without ``stations``: fewer rows than the start from any
    orientations needs)."""
    if keep.all():
        return problem
    if not stations:
        left = problem.subset(keep)
        if left.n_profiles < MIN_ROWS:
            raise DegenerateDataError(
                f"{left.n_profiles} row(s) are left once the rows inconsistent with the others were left out, and "
                f"the start from any orientations needs at least {MIN_ROWS}: check the pairing of poses and "
                "profiles and re-acquire")
        return left
    keep = _thin_stations(problem, keep, flags, opt, context)
    left = problem.subset(keep)
    if left.n_profiles == 0:
        raise DegenerateDataError(
            f"no station has {opt.min_profiles_per_station} consistent profiles: check the pairing of poses and "
            "profiles and re-acquire"
        )
    dropped = sorted(set(problem.station_labels) - set(left.station_labels))
    if dropped:
        Rs = [left.R_sphere_from_mount[np.flatnonzero(left.station_of == k)[0]]
              for k in range(len(left.station_labels))]
        M = np.vstack([np.hstack([R, -np.eye(3)]) for R in Rs])
        sv = np.linalg.svd(M, compute_uv=False)
        if len(sv) < 6 or sv[-1] < 1e-3 * sv[0]:
            raise DegenerateDataError(
                f"after leaving out station(s) {', '.join(dropped)} (too few consistent profiles), the stations "
                f"left ({', '.join(left.station_labels)}) do not determine the translation: re-acquire the "
                "stations left out, or add stations tilted about two different axes"
            )
    return left


def _worst_move_outlier(ts: TwoStepResult):
    """The profile whose sphere centre (circle fit, side of the laser plane resolved)
    moved least like the robot: within a station the centre must move in the sensor frame
    by the robot's displacement rotated by the two-step rotation. Residuals are taken
    about the station's median, so one bad profile does not shift the others; the scale
    is robust, pooled over the stations (per axis, from the median residual length).
    Returns ``(profile, residual in robust SDs, residual mm, scale mm)`` or None."""
    rows = []
    for st in ts.stations:
        if len(st.profiles) == 0:
            continue
        # a station whose moves span less than 3-D leaves two mirror candidates; the one
        # that agrees with the pooled rotation is the one to judge its profiles by
        best = None
        for cand in st.candidates:
            e = cand @ ts.R.T - st.d
            e = np.linalg.norm(e - median(e, axis=0), axis=1)
            if best is None or median(e) < median(best):
                best = e
        rows.extend(zip(st.profiles.tolist(), best.tolist()))
    if not rows:
        return None
    scale = max(float(median([e for _, e in rows])) / _CHI3_MEDIAN, _MIN_MOVE_SCALE_MM)
    i, e = max(rows, key=lambda r: r[1])
    return int(i), e / scale, e, scale


def _move_error(st: StationCentres, R: np.ndarray) -> tuple[float, float]:
    """How far a station's sphere centres moved otherwise than the robot's moves rotated
    by ``R`` (mm): twice the median distance of its rows' ``e = C R^T - d`` from their
    median (a station of two rows: the error of its one move; of more, a typical move's,
    which a single bad row does not make large), of the candidate (side of the laser
    plane) that agrees best; and the robot's move measured alike (mm)."""
    best = None
    for cand in st.candidates:
        e = cand @ R.T - st.d
        size = 2.0 * float(median(np.linalg.norm(e - median(e, axis=0), axis=1)))
        if best is None or size < best:
            best = size
    move = 2.0 * float(median(np.linalg.norm(st.d - median(st.d, axis=0), axis=1)))
    return best, move


def _gross_move_tolerance(move_mm: float, rotation_sd: float) -> float:
    """The pure-translation check's tolerance for a move of ``move_mm`` (mm)
    (:data:`.centres.GROSS_MOVE_MM` + :data:`.centres.GROSS_MOVE_RELATIVE` of the move),
    plus six standard deviations of a reference rotation known to ``rotation_sd`` rad."""
    return GROSS_MOVE_MM + GROSS_MOVE_RELATIVE * move_mm + 6.0 * rotation_sd * move_mm


@dataclass
class StationsOffTheRotation:
    """:func:`stations_off_the_reference_rotation`: the station whose moves gave the
    reference rotation, the stations that agree with it, and for each that does not (by
    index into the stations) its move error and the robot's move (mm)."""

    reference: str
    agreeing: list[str]
    off: dict[int, tuple[float, float]]


def stations_off_the_reference_rotation(stations: list[StationCentres]) -> StationsOffTheRotation | None:
    """Stations whose moves disagree grossly with the rotation a station whose moves
    span 3-D gives on its own. The pooled rotation takes in every station's moves, so two
    stations of two rows whose centres moved the right distance in a wrong direction (a
    typo across the move, which the pure-translation distance check cannot see) pull it
    tens of degrees off, and judged against it no row stands out. A station whose moves
    span 3-D (one side of the laser plane, its own moves consistent) determines the
    rotation alone; each one is tried as the reference, and the one most other stations
    agree with is kept (ties: the best-conditioned moves). Its verdict counts only when at
    least one other station agrees with it and the stations that agree are at least as
    many as those that do not; else None (nothing to flag)."""
    judged = [j for j, st in enumerate(stations) if len(st.profiles) >= 2 and st.candidates]
    best = None
    for k in judged:
        st = stations[k]
        if st.rank != 3 or len(st.candidates) != 1:
            continue
        R, diag = rotation_from_translations([st], (0,))
        sv = diag["displacement_singular_values_mm"]
        rotation_sd = max(diag["rms_mm"], _MIN_MOVE_SCALE_MM) / sv[-1]
        own, own_move = _move_error(st, R)
        if max(own, 2.0 * diag["rms_mm"]) > _gross_move_tolerance(own_move, 0.0):
            continue  # its own moves disagree: a bad row of its own, not a reference
        errors = {j: _move_error(stations[j], R) for j in judged if j != k}
        off = {j: e for j, e in errors.items() if e[0] > _gross_move_tolerance(e[1], rotation_sd)}
        agreeing = [st.label] + [stations[j].label for j in errors if j not in off]
        key = (len(agreeing), sv[-1])
        if best is None or key > best[0]:
            best = (key, StationsOffTheRotation(st.label, agreeing, off))
    if best is None or not best[1].off:
        return None
    found = best[1]
    if len(found.agreeing) < 2 or len(found.agreeing) < len(found.off):
        return None
    return found


def leave_out_stations_off_the_rotation(problem: Problem, fits: dict, flags: list[ObservationFlag],
                                        budget: RejectionBudget) -> None:
    """The stations :func:`stations_off_the_reference_rotation` finds, every row left out
    (removed from ``fits``, counted in ``budget``) and flagged with the size of its
    station's move error in mm: within a station of two rows nothing tells which row is
    wrong."""
    used = np.array(sorted(fits))
    sub = problem.subset(np.isin(np.arange(problem.n_profiles), used))
    sub_fits = {j: fits[i] for j, i in enumerate(used)}
    stations = [station_centres(sub, sub_fits, k) for k in range(len(sub.station_labels))]
    found = stations_off_the_reference_rotation(stations)
    if found is None:
        return
    rotation = (f"the rotation the moves within station {found.reference} give (station(s) "
                f"{', '.join(found.agreeing[1:])} agree with it)")
    for j, (size, move) in found.off.items():
        rows = [int(i) for i in stations[j].profiles]
        if len(rows) != 2:
            continue  # its rows are judged one by one against the pooled rotation, without these stations
        for x, i in enumerate(rows):
            flags.append(flag_shot(sub, i, (
                f"inconsistent with observation {int(sub.obs_index[rows[1 - x]])} of its station under {rotation}: "
                f"the robot moved {move:.3f} mm between them and the sphere centre moved {size:.3f} mm away from "
                "where that puts it in the sensor frame (a pure translation moves both alike); a typo in one of the "
                "two rows (a sign, swapped coordinates) and nothing tells which: both left out")))
            del fits[int(used[i])]
            budget.rejected += 1


@dataclass
class RejectionBudget:
    """How many shots the screening may leave out as inconsistent with the others
    (``max_reject``, a share of the usable ones), and how many it has (``rejected``)."""

    max_reject: int
    rejected: int = 0
    #: whether each station must keep its minimum of shots (the two-step's stations); the
    #: start from any orientations needs none, only its minimum of rows in all
    stations: bool = True


#: A line sensor sees the side of the sphere that faces it: a profile's points lie above
#: its circle's centre in z (z points towards the sensor, docs/conventions.md). A point
#: whose direction from the centre dips below it by more than this sine (6 deg) is on the
#: far side.
FAR_SIDE_SINE = 0.1
#: Share of the profiles' points on the far side beyond which the arcs face the wrong
#: way. Simulated profiles (both mountings, 19.1 and 12.7 mm spheres, 25-48 mm lines,
#: point noise 0.05 mm, strays on half the profiles, partial arcs): 0; the same with y and
#: z swapped: 0.38-0.44.
FAR_SIDE_SHARE = 0.2
#: Points looked at, at most (every k-th point of each profile above it).
FAR_SIDE_POINTS = 200_000


def arcs_facing_away(problem: Problem, fits: dict) -> str | None:
    """Why the profiles cannot have been measured as written, when their arcs face along
    y instead of towards the sensor (+z): y and z swapped in every profile. The base-frame
    points of such data are those of the sensor turned half a turn about its (0, 1, 1)
    axis, which fits them exactly, so no residual shows it; where the arcs face does. None
    when they face the sensor (or when too few points lie on the far side to say)."""
    rows = [i for i, f in fits.items() if isinstance(f, CircleFit)]
    if not rows:
        return None
    stride = max(1, -(-sum(int(fits[i].n_inliers) for i in rows) // FAR_SIDE_POINTS))
    parts = [(problem.profiles[i][fits[i].inliers][::stride] - fits[i].centre_yz) for i in rows]
    lengths = np.array([len(q) for q in parts])
    q = np.concatenate(parts)
    u = q / np.maximum(np.linalg.norm(q, axis=1), 1e-12)[:, None]
    far = u[:, 1] < -FAR_SIDE_SINE
    share = float(far.mean())
    if share <= FAR_SIDE_SHARE:
        return None
    ends = np.cumsum(lengths) - lengths
    facing = np.add.reduceat(u, ends) / lengths[:, None]  # each profile's mean direction from its centre
    many_far = int(np.count_nonzero(np.add.reduceat(far.astype(float), ends) > FAR_SIDE_SHARE * lengths))
    angle = float(np.degrees(np.arctan2(abs(float(median(facing[:, 0]))), float(median(facing[:, 1])))))
    if not 45.0 < angle < 135.0:
        return None  # not the signature of swapped coordinates
    return (f"the profiles' arcs face along y, not towards the sensor: {share:.0%} of their points lie below their "
            f"circle's centre in z, on the side of the sphere facing away from the sensor (more than "
            f"{FAR_SIDE_SHARE:.0%} in {many_far} of {len(rows)} profiles), which a line sensor cannot see (z points towards the sensor, "
            "docs/conventions.md); the arcs' median direction is "
            f"{angle:.0f} deg from +z. y and z probably swapped in every profile (each point written (z, y)): write "
            "the points as (y, z); a fit would give the sensor turned half a turn about its (0, 1, 1) axis")


def unusable_profile_reason(points: np.ndarray, fit: CircleFit | None, opt, radius_mm: float) -> str | None:
    """Why a profile with ``points`` and circle ``fit`` (None: too few points to fit)
    does not show the sphere of radius ``radius_mm``, or None when it does."""
    if len(points) < opt.min_points_per_profile:
        return (f"only {len(points)} points (needs {opt.min_points_per_profile}): "
                "the line barely touches the sphere or misses it")
    r = radius_mm
    if not fit.converged or fit.rms > opt.max_circle_rms_mm or fit.n_inliers < opt.min_points_per_profile:
        if (fit.converged and fit.n_inliers >= opt.min_points_per_profile and fit.rms <= 2 * opt.max_circle_rms_mm
                and fit.radius <= 1.02 * r):
            # a circle of the sphere's size, its points just too scattered: the sensor's noise, not another object
            return (f"the points scatter about their circle by {fit.rms:.3f} mm (rms), more "
                    f"than max_circle_rms_mm = {opt.max_circle_rms_mm:g} mm allows")
        return f"points do not lie on a circle (rms {fit.rms:.3f} mm): not the sphere?"
    if fit.radius > 1.02 * r:
        return (f"circle radius {fit.radius:.3f} mm exceeds the sphere radius {r} mm: "
                "wrong sphere radius in the dataset, or not the sphere")
    return None


def require_usable_stations(problem: Problem, fits: dict, flags: list[ObservationFlag], opt, hint: str) -> None:
    """Leave out (flagged) the stations with too few usable shots in ``fits``; raises
    :class:`DegenerateDataError` when no shot or no station is left (``hint``: why shots
    turned within their station were left out, if any were)."""
    if not fits:
        todo = (_NOISY_HINT if _dominant_kind(flags) == _NOISY_KIND
                else "check that the plan puts the sphere in the field of view")
        raise DegenerateDataError(
            f"no profile shows the sphere (every profile was left out: {_left_out_summary(flags) or 'none'}): {todo}"
        )
    _drop_thin_stations_of_fits(problem, fits, flags, opt, "")
    if not fits:
        todo = _NOISY_HINT if _dominant_kind(flags) == _NOISY_KIND else "add profiles to each sweep"
        raise DegenerateDataError(
            f"no station has {opt.min_profiles_per_station} usable profiles (left out: {_left_out_summary(flags)}): "
            f"{todo}{hint}"
        )


def two_step_without_gross_outliers(problem: Problem, fits: dict, flags: list[ObservationFlag], opt, hint: str,
                                    budget: RejectionBudget) -> tuple[TwoStepResult, Problem, dict]:
    """The two-step solution of the shots in ``fits``, with the shots grossly inconsistent
    with the robot's moves (a pose read at the wrong moment, a mis-paired shot) left out
    worst first, the two-step redone each time, before they can pull the joint refinement
    away: beyond :data:`GROSS_MOVE_OUTLIER_SDS` robust SDs, within the ``budget``.
    Removes them from ``fits``; returns the two-step result, the problem of the shots
    used and their fits (by row of that problem)."""
    nominal_R = opt.nominal_transform.rotation_matrix if opt.nominal_transform is not None else None
    leave_out_stations_off_the_rotation(problem, fits, flags, budget)
    while True:
        used = np.array(sorted(fits))
        sub = problem.subset(np.isin(np.arange(problem.n_profiles), used))
        sub_fits = {j: fits[i] for j, i in enumerate(used)}
        try:
            ts = two_step(sub, sub_fits, nominal_R)
        except DegenerateDataError as exc:
            raise _after_screening(exc, problem, sub, flags) from None
        worst = None if budget.rejected >= budget.max_reject else _worst_move_outlier(ts)
        if worst is None or worst[1] <= GROSS_MOVE_OUTLIER_SDS:
            return ts, sub, sub_fits
        j, sds, off_mm, scale_mm = worst
        is_profile = sub.kinds[j] == KIND_PROFILE
        flags.append(flag_shot(sub, j, f"inconsistent with the other {'profiles' if is_profile else 'observations'}: its "
                                   f"sphere centre is {off_mm:.3f} mm off where the robot motion puts it ({sds:.0f} "
                                   f"robust SDs of {scale_mm:.3f} mm): "
                                   + ("a pose read at the wrong moment or a mis-paired shot" if is_profile else
                                      "a typo in the row (a sign, metres for millimetres), a pose read at the wrong "
                                      "moment or a mis-paired shot")))
        del fits[int(used[j])]
        budget.rejected += 1
        _drop_thin_stations_of_fits(problem, fits, flags, opt, "left once others were left out ")
        if not fits:
            raise DegenerateDataError(
                f"no station has {opt.min_profiles_per_station} consistent profiles: check the pairing of poses "
                f"and profiles and re-acquire{hint}"
            )


#: Refits the joint refinement of a problem from a solution (R, t and centre of the second).
Refit = Callable[[Problem, RefineResult], RefineResult]


def trim_stray_points(clean: Problem, ref: RefineResult, noise: NoiseAssumptions, opt, flags: list[ObservationFlag],
                      budget: RejectionBudget, refit: Refit, batch: bool = False,
                      recording: bool = False) -> tuple[Problem, RefineResult]:
    """Stray points the circle fits kept: trimmed on the joint residuals of ``ref`` and
    refitted once. A profile that would lose too many points (or keep too few) has no
    strays: its pose is wrong. It is left out and flagged (worst first, refitting after
    each; with ``batch``, for the thousands of profiles of a recording, all such profiles
    at once within the budget), never refitted empty; once the ``budget`` is spent, only
    profiles that would keep too few points are left out, the others are trimmed.
    ``recording``: the profiles are a recording's (swept on the fly), for the flags' likely
    cause (:func:`likely_cause_of_inconsistent_profile`)."""
    keep_pts = [np.ones(len(e), dtype=bool) for e in ref.residuals]
    while (clean.kinds == KIND_PROFILE).any():
        is_profile = clean.kinds == KIND_PROFILE
        all_res = np.concatenate(ref.residuals)
        limit = opt.point_outlier_k * max(1.4826 * median(np.abs(all_res)), noise.point_noise_mm)
        keep_pts = [np.abs(e) <= limit for e in ref.residuals]
        lost = np.array([int((~k).sum()) for k in keep_pts])
        counts = np.array([len(k) for k in keep_pts])
        too_few = is_profile & (counts - lost < opt.min_points_per_profile)
        bad = too_few | (is_profile & (lost > opt.max_stray_point_fraction * counts))
        if budget.rejected < budget.max_reject and bad.any():
            share = np.where(bad, lost / np.maximum(counts, 1), -1.0)
            drop = ([int(np.argmax(share))] if not batch else
                    np.argsort(-share)[:min(int(bad.sum()), budget.max_reject - budget.rejected)].tolist())
            drop = sorted(set(drop) | set(np.flatnonzero(too_few).tolist())) if batch else drop
        elif too_few.any():
            drop = np.flatnonzero(too_few).tolist()
        else:
            break
        keep = np.ones(clean.n_profiles, dtype=bool)
        for j in drop:
            keep[j] = False
            flags.append(flag_shot(clean, j, f"inconsistent with the other profiles: {lost[j]} of {counts[j]} points "
                                         f"({lost[j] / counts[j]:.0%}) lie far from the sphere they agree on (beyond "
                                         f"{limit:.3f} mm): "
                                         + likely_cause_of_inconsistent_profile(ref.predicted[j], ref.radius,
                                                                                recording)))
        budget.rejected += len(drop)
        clean = _drop_profiles(clean, keep, flags, opt, "left once others were left out ", budget.stations)
        ref = refit(clean, ref)
    if any(not k.all() for k in keep_pts):
        clean = clean.with_profiles([p if k.all() else p[k] for p, k in zip(clean.profiles, keep_pts)])
        ref = refit(clean, ref)
    return clean, ref


def reject_inconsistent_shots(clean: Problem, ref: RefineResult, opt, flags: list[ObservationFlag],
                              budget: RejectionBudget, refit: Refit, batch: bool = False) -> tuple[Problem, RefineResult]:
    """Shots inconsistent with the rest (a pose read at the wrong moment, a bad pairing, a
    typo in a centre row): while the worst one's whitened chi^2 exceeds
    ``opt.profile_outlier_chi2``, it is left out and flagged and the rest refitted,
    within the ``budget``. With ``batch`` (thousands of profiles of a recording, where a
    refit per shot would take minutes) every shot beyond the threshold goes at once, worst
    first within the budget, before each refit."""
    while budget.rejected < budget.max_reject:
        chi2 = np.asarray(ref.diagnostics["profile_chi2"])
        beyond = np.flatnonzero(chi2 > opt.profile_outlier_chi2)
        if not len(beyond):
            break
        if batch:
            worst_first = beyond[np.argsort(-chi2[beyond])][:budget.max_reject - budget.rejected]
            keep = np.ones(clean.n_profiles, dtype=bool)
            keep[worst_first] = False
            for j in worst_first:
                flags.append(flag_shot(clean, int(j), f"inconsistent with the other profiles (chi2 {chi2[j]:.1f} on 3 "
                                                      "dof): its pose and its profile disagree"))
            clean = _drop_profiles(clean, keep, flags, opt, "left once others were left out ", budget.stations)
            budget.rejected += len(worst_first)
            ref = refit(clean, ref)
            continue
        worst = int(np.argmax(chi2))
        if clean.kinds[worst] == KIND_PROFILE:
            shift = float(np.sqrt(chi2[worst] * np.trace(ref.centre_cov[worst]) / 3))
            flags.append(flag_shot(clean, worst, f"inconsistent with the other profiles (chi2 {chi2[worst]:.1f} on 3 dof, "
                                             f"about {shift:.3f} mm): a pose read at the wrong moment or a bad pairing"))
        else:
            off = float(np.linalg.norm(ref.centre_residuals[worst]))
            flags.append(flag_shot(clean, worst, f"inconsistent with the other observations (chi2 {chi2[worst]:.1f} on 3 "
                                             f"dof): its {KIND_NAMES[clean.kinds[worst]]} is {off:.3f} mm from where the "
                                             "fit puts it: a typo in the row, a pose read at the wrong moment or a bad "
                                             "pairing"))
        keep = np.ones(clean.n_profiles, dtype=bool)
        keep[worst] = False
        clean = _drop_profiles(clean, keep, flags, opt, "left once others were left out ", budget.stations)
        budget.rejected += 1
        ref = refit(clean, ref)
    return clean, ref
