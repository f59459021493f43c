"""From a dataset to a :class:`CalibrationResult`: screening, two-step start, joint
refinement, outlier rejection, diagnostics."""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import Callable

import numpy as np

from spherecal.core import geometry as geo
from spherecal.core.errors import DegenerateDataError, FitBreakdownError, InputError
from spherecal.core.kinematics import ArmKinematics
from spherecal.core.models import (
    SPHERE_FRAME, TRANSFORM_NAME, CalibrationResult, Dataset, KinematicParameter, ObservationFlag, Pose, ResidualStats,
    RobotErrorSummary,
)
from spherecal.config import CalibrationOptions
from spherecal.estimation.circle import CircleFit, fit_circles
from spherecal.estimation.prediction import point_error_budget
from spherecal.estimation.problem import (
    KIND_CIRCLE, KIND_NAMES, KIND_PROFILE, KIND_SPHERE_CENTRE, Problem, build_problem,
    fill_unknown, screen_station_orientations,
)
from spherecal.estimation.options import kinematic_effects, station_effects
from spherecal.estimation.refine import NoiseAssumptions, RefineResult, refine
from spherecal.estimation.centres import (
    PAIR_UNDECIDED, leave_one_out_sizes, screen_table, settle_pairs, with_leave_one_out_size, within_station_noise,
)
from spherecal.estimation.robust import median, percentile
from spherecal.estimation.twostep import CentreShot, TwoStepResult, two_step

#: Before the joint fit, a profile whose sphere centre moved more than this many robust
#: SDs off the robot's move is left out (mis-pairs in the simulator: 30-130; clean data:
#: at most 8). Smaller inconsistencies are judged by the joint fit's chi^2 test.
GROSS_MOVE_OUTLIER_SDS = 20.0
#: Floor of the robust scale of those residuals, mm.
_MIN_MOVE_SCALE_MM = 0.002
#: Median of the chi distribution with 3 degrees of freedom.
_CHI3_MEDIAN = 1.5382


@dataclass
class Solution:
    """Everything :func:`solve` worked out; :attr:`result` is what users keep."""

    result: CalibrationResult
    problem: Problem  # the profiles that were used (points cleaned)
    two_step: TwoStepResult
    refined: RefineResult
    fits: dict[int, CircleFit]
    extras: dict = field(default_factory=dict)


#: A laser plane farther than this share of the radius from the sphere's centre cuts it
#: near its edge: the circle's radius there changes by more than the plane's offset does.
EDGE_PLANE_OFFSET_SHARE = 0.7


def likely_cause_of_inconsistent_profile(centre_in_sensor_mm, radius_mm: float) -> str:
    """The likely cause of a profile whose points lie far from the fitted sphere, from where
    its laser plane cuts the sphere (``centre_in_sensor_mm``: the sphere centre in the
    sensor frame as fitted, mm; the plane is x = 0). A cut near the edge turns the pose's
    error along the sweep into an in-plane error x / rho times larger (rho the circle's
    radius): a few hundredths of a millimetre of robot error look like a bad shot there,
    and the advice is to keep sweeps off the edge, not to suspect the pairing."""
    x = abs(float(centre_in_sensor_mm[0]))
    r = float(radius_mm)
    if x > EDGE_PLANE_OFFSET_SHARE * r:
        rho = float(np.sqrt(max(r * r - x * x, 0.0)))
        gain = x / rho if rho > 0 else float("inf")
        return (f"it cuts the sphere near its edge (laser plane {x:.1f} mm from the centre, circle radius "
                f"{rho:.1f} mm of {r:.1f} mm), where the robot's pose error along the sweep shows {gain:.1f} times "
                "larger in the profile; when several such shots are flagged, keep the sweeps off the edge "
                f"(acquisition.sweep.sweep_fraction at most {EDGE_PLANE_OFFSET_SHARE:g}); else a pose read at the "
                "wrong moment or a mis-paired shot")
    return "a pose read at the wrong moment or a mis-paired shot"


def _flag(problem: Problem, i: int, reason: str, station: str | None = None) -> ObservationFlag:
    return ObservationFlag(
        index=int(problem.obs_index[i]), station=station or problem.station_labels[problem.station_of[i]], reason=reason
    )


#: The orientation read noise the stations show (within-station scatter) replaces the
#: assumed one when it is more than this many times larger (``estimate_pose_noise``).
ROTATION_NOISE_SEEN_FACTOR = 2.0


#: What a solve that broke down numerically says: the data fit no sphere through these
#: poses, and the usual reasons, most common first.
BREAKDOWN_CAUSES = (
    "quaternions not in (w, x, y, z) order (ABB writes w first; SciPy and ROS write it last), the sphere's "
    "diameter given as its radius, the mounting (eye_in_hand or eye_to_hand) swapped, or profiles paired with the "
    "wrong poses")


def solve(
    dataset: Dataset,
    options: CalibrationOptions | None = None,
    flange_pose_from_joints: Callable[[np.ndarray], Pose] | None = None,
    progress: Callable[[str], None] | None = None,
    kinematics: ArmKinematics | None = None,
) -> Solution:
    """Calibrate ``dataset``; see the package docstring for the steps. ``kinematics``
    (the robot plugin's :class:`~spherecal.core.kinematics.ArmKinematics`) gives flange poses
    from joint readings where a pose is missing, and, with joints on every observation,
    the kinematic robot error model. Data so far from the model that its linear algebra
    breaks down (a singular matrix) raise :class:`~spherecal.core.errors.FitBreakdownError` naming the usual
    causes (:data:`BREAKDOWN_CAUSES`), never a bare NumPy error."""
    try:
        solution = _solve_dataset(dataset, options, flange_pose_from_joints, progress, kinematics)
    except np.linalg.LinAlgError as exc:
        raise FitBreakdownError(
            f"the fit broke down ({exc}): the data fit no sphere seen through these poses. Check, most common "
            f"first: {BREAKDOWN_CAUSES}") from None
    nominal = options.nominal_transform if options is not None else None
    if nominal is None:
        return solution
    # how far the result lies from the rough transform the user gave (the verdict judges it)
    X = solution.result.transform
    turn = geo.rotvec_from_matrix(nominal.rotation_matrix.T @ X.rotation_matrix)  # in the sensor frame
    angle = float(np.degrees(np.linalg.norm(turn)))
    about_z = bool(angle > 90.0 and abs(turn[2]) > 0.95 * np.linalg.norm(turn))
    diag = {**solution.result.diagnostics, "nominal_transform": {
        "rotation_deg": angle, "translation_mm": float(np.linalg.norm(X.translation - nominal.translation)),
        "half_turn_about_sensor_z": about_z}}
    return replace(solution, result=solution.result.model_copy(update={"diagnostics": diag}))


def _solve_dataset(dataset, options, flange_pose_from_joints, progress, kinematics) -> Solution:
    opt = options or CalibrationOptions()
    say = progress or (lambda msg: None)
    if kinematics is not None and flange_pose_from_joints is None:
        flange_pose_from_joints = kinematics.flange_pose_from_joints
    problem = build_problem(dataset, flange_pose_from_joints,
                            kinematics.model_joints_rad if kinematics is not None else None)
    if opt.identify_kinematics and problem.q_rad is None:
        raise InputError(
            "identify_kinematics needs joint readings (joints_deg) on every observation and the robot's kinematics "
            "(spherecal solve --robot TYPE)"
        )
    if opt.robot_error_model in ("kinematic", "kinematic+station") and (problem.q_rad is None or kinematics is None):
        # never a silent fallback: without the arm's error the robot's accuracy would drop out of the uncertainty
        missing = ("joint readings (joints_deg) on every observation" if problem.q_rad is None
                   else "the robot's kinematics (spherecal solve --robot TYPE)")
        raise InputError(
            f"robot_error_model = {opt.robot_error_model!r} (--robot-error-model) needs the arm's joints: this dataset "
            f"lacks {missing}; use 'station' (the robot's error shared within each station) or 'auto'")
    # the joints must describe the poses they came with: else the kinematic model would
    # take the robot's error from joints of another moment (or in other units)
    joint_flags, joints_note = [], None
    if problem.q_rad is not None and kinematics is not None:
        check = joints_against_poses(problem, kinematics, opt)
        if check.disqualified:
            if opt.robot_error_model != "auto" or opt.identify_kinematics:
                raise InputError(f"{check.text}; fix the joints, or solve with robot_error_model = 'station' "
                                 "(--robot-error-model station)")
            joints_note = f"{check.text}: the joints were not used (the station robot error model was)"
            say(f"warning: {joints_note}")
            problem = replace(problem, q_rad=None)
        else:
            joint_flags = [_flag(problem, int(i), reason) for i, reason in check.shots.items()]
    joints_known = problem.q_rad is not None
    # rows that are typos (units, signs, a circle larger than the sphere): left out, flagged
    table_keep, table_flags, pairs, moved = screen_table(problem)
    for f in joint_flags + _copied_profiles(problem):
        i = int(np.flatnonzero(problem.obs_index == f.index)[0])
        if table_keep[i]:
            table_keep[i] = False
            table_flags.append(f)
    for f in table_flags:
        say(f"observation {f.index}: {f.reason}")
    if not table_keep.any():
        raise DegenerateDataError("every observation was left out: " + "; ".join(
            f"observation {f.index}: {f.reason}" for f in table_flags[:5]))

    def attempt(keep, flags):
        try:
            return _solve(dataset, problem.subset(keep) if not keep.all() else problem, opt, say, kinematics,
                          joints_known, list(flags))
        except DegenerateDataError as exc:
            if not flags:
                raise
            raise DegenerateDataError(f"{exc} (left out before: " + "; ".join(
                f"observation {f.index}: {f.reason}" for f in flags[:5]) + ")") from None

    solution = attempt(table_keep, table_flags)
    if not pairs:
        return _with_joints_note(_size_moved_rows(solution, problem, moved), joints_note)
    # two rows of a station that disagree, nothing within it telling which is wrong: the
    # solution of the other observations may tell; the row that agrees with it is used
    ref = solution.refined
    noise_mm = ref.centre_noise_mm or float(solution.result.diagnostics["noise"]["point_noise_mm"])
    settled = settle_pairs(problem, pairs, ref.R, ref.t, ref.centre, np.hypot(noise_mm, opt.pose_translation_noise_mm),
                           opt.profile_outlier_chi2)
    if not settled:
        return _with_joints_note(_size_moved_rows(solution, problem, moved), joints_note)
    keep, flags = table_keep.copy(), list(table_flags)
    for good, bad, chi_good, chi_bad in settled:
        keep[good] = True
        moved = [i for i in moved if i != good]  # used after all: its flag, if any, is another check's
        g, b = int(problem.obs_index[good]), int(problem.obs_index[bad])
        flags = [f for f in flags if f.index != g]
        flags = [f.model_copy(update={"reason": f.reason.replace(
            PAIR_UNDECIDED,
            f"the typo is in this row (a sign, metres for millimetres?): the solution of the other observations puts "
            f"observation {g} where it was seen (chi2 {chi_good:.1f}, 3 dof) and this one not (chi2 {chi_bad:.3g})")})
                 if f.index == b else f for f in flags]
        say(f"observation {g} agrees with the solution of the others and is used; observation {b} is left out")
    return _with_joints_note(_size_moved_rows(attempt(keep, flags), problem, moved), joints_note)


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


def joints_against_poses(problem: Problem, kinematics: ArmKinematics, opt: CalibrationOptions) -> JointPoseCheck:
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


def _copied_profiles(problem: Problem) -> list[ObservationFlag]:
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
            flags.append(_flag(problem, i, f"its profile is observation {int(problem.obs_index[first[key]])}'s, "
                                           "point for point: the same shot written twice?"))
        else:
            first[key] = i
    return flags


def _with_joints_note(solution: Solution, note: str | None) -> Solution:
    """The result with the joints' check in its diagnostics (``joints_vs_poses``) when
    the joints were not used: the verdict says so."""
    if note is None:
        return solution
    diag = {**solution.result.diagnostics, "joints_vs_poses": {"used": False, "reason": note}}
    return replace(solution, result=solution.result.model_copy(update={"diagnostics": diag}))


def _size_moved_rows(solution: Solution, problem: Problem, moved: list[int]) -> Solution:
    """The flags of the rows the pure-translation check left out (``moved``, positions in
    ``problem``), each given the size of its error in mm from the solution of the others
    (:func:`.centres.leave_one_out_sizes`)."""
    used = np.isin(problem.obs_index, solution.problem.obs_index)
    rows = [i for i in moved if not used[i]]
    if not rows:
        return solution
    ref = solution.refined
    sizes = leave_one_out_sizes(problem, rows, ref.R, ref.t, ref.centre, used)
    by_index = {int(problem.obs_index[i]): (size, KIND_NAMES[problem.kinds[i]]) for i, size in sizes.items()}
    flagged = [with_leave_one_out_size(f, *by_index[f.index]) if f.index in by_index else f
               for f in solution.result.flagged]
    return replace(solution, result=solution.result.model_copy(update={"flagged": flagged}))


def _solve(dataset, problem, opt, say, kinematics, joints_known, table_flags) -> Solution:
    robot_effects = {
        "station_effects": station_effects(opt, joints_known),
        "kinematic_effects": kinematic_effects(opt, kinematics.chain)
        if kinematics is not None and opt.uses_kinematic_model(joints_known) and joints_known else None,
    }
    original_points = {int(i): len(p) for i, p in zip(problem.obs_index, problem.profiles)}
    # within a station the robot may only translate: turned shots are left out or split off
    ori = screen_station_orientations(
        problem, opt.station_rotation_tolerance_deg, opt.pose_rotation_noise_deg, opt.estimate_pose_noise,
        opt.min_profiles_per_station,
    )
    problem = ori.problem
    flags: list[ObservationFlag] = table_flags + list(ori.flags)
    for note in ori.notes:
        say(note)
    hint = _turned_hint(ori.flags, ori.diagnostics["tolerance_deg"])
    r = problem.radius_mm

    kinds = problem.kinds
    n_centres = int(np.count_nonzero(kinds != KIND_PROFILE))
    say(f"fitting circles to {problem.n_profiles - n_centres} profiles"
        + (f"; {n_centres} centre observations" if n_centres else ""))
    fits: dict[int, CircleFit | CentreShot] = {}
    enough = [i for i, pts in enumerate(problem.profiles)
              if kinds[i] == KIND_PROFILE and len(pts) >= opt.min_points_per_profile]
    circles = dict(zip(enough, fit_circles([problem.profiles[i] for i in enough], outlier_k=opt.point_outlier_k)))
    for i, pts in enumerate(problem.profiles):
        if kinds[i] != KIND_PROFILE:
            fits[i] = _centre_shot(problem, i)
            continue
        if len(pts) < opt.min_points_per_profile:
            flags.append(_flag(problem, i, f"only {len(pts)} points (needs {opt.min_points_per_profile}): "
                                           "the line barely touches the sphere or misses it"))
            continue
        fit = circles[i]
        if not fit.converged or fit.rms > opt.max_circle_rms_mm or fit.n_inliers < opt.min_points_per_profile:
            if (fit.converged and fit.n_inliers >= opt.min_points_per_profile and fit.rms <= 2 * opt.max_circle_rms_mm
                    and fit.radius <= 1.02 * r):
                # a circle of the sphere's size, its points just too scattered: the sensor's noise, not another object
                flags.append(_flag(problem, i, f"the points scatter about their circle by {fit.rms:.3f} mm (rms), more "
                                               f"than max_circle_rms_mm = {opt.max_circle_rms_mm:g} mm allows"))
            else:
                flags.append(_flag(problem, i, f"points do not lie on a circle (rms {fit.rms:.3f} mm): not the sphere?"))
            continue
        if fit.radius > 1.02 * r:
            flags.append(_flag(problem, i, f"circle radius {fit.radius:.3f} mm exceeds the sphere radius {r} mm: "
                                           "wrong sphere radius in the dataset, or not the sphere"))
            continue
        fits[i] = fit
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

    # profiles grossly inconsistent with the robot's moves (a pose read at the wrong moment,
    # a mis-paired shot): left out worst first, the two-step redone each time, before they
    # can pull the joint refinement away
    say("two-step solution (rotation from translations, translation from orientations)")
    nominal_R = opt.nominal_transform.rotation_matrix if opt.nominal_transform is not None else None
    max_reject = int(opt.max_rejected_profile_fraction * len(fits))
    rejected = 0
    while True:
        used = np.array(sorted(fits))
        sub = problem.subset(np.isin(np.arange(problem.n_profiles), used))
        sub_fits = {j: fits[i] for j, i in enumerate(used)}
        try:
            ts = two_step(sub, sub_fits, nominal_R)
        except DegenerateDataError as exc:
            raise _after_screening(exc, problem, sub, flags) from None
        worst = None if rejected >= max_reject else _worst_move_outlier(ts)
        if worst is None or worst[1] <= GROSS_MOVE_OUTLIER_SDS:
            break
        j, sds, off_mm, scale_mm = worst
        is_profile = sub.kinds[j] == KIND_PROFILE
        flags.append(_flag(sub, j, f"inconsistent with the other {'profiles' if is_profile else 'observations'}: its "
                                   f"sphere centre is {off_mm:.3f} mm off where the robot motion puts it ({sds:.0f} "
                                   f"robust SDs of {scale_mm:.3f} mm): "
                                   + ("a pose read at the wrong moment or a mis-paired shot" if is_profile else
                                      "a typo in the row (a sign, metres for millimetres), a pose read at the wrong "
                                      "moment or a mis-paired shot")))
        del fits[int(used[j])]
        rejected += 1
        _drop_thin_stations_of_fits(problem, fits, flags, opt, "left once others were left out ")
        if not fits:
            raise DegenerateDataError(
                f"no station has {opt.min_profiles_per_station} consistent profiles: check the pairing of poses "
                f"and profiles and re-acquire{hint}"
            )

    circle_fits = [f for f in sub_fits.values() if isinstance(f, CircleFit)]
    if opt.point_noise_mm is not None:
        sigma = opt.point_noise_mm
    elif circle_fits:
        num = sum(f.rms**2 * f.n_inliers for f in circle_fits)
        den = sum(max(f.n_inliers - 3, 1) for f in circle_fits)
        sigma = float(np.sqrt(num / den))
    else:
        sigma = DEFAULT_POINT_NOISE_MM  # no profile: the points' noise enters only the point-error budget
    # the orientation readings' noise: what the stations show when it is more than assumed
    # (a station's shots share one orientation, so their scatter is the read noise alone;
    # assumed 10 times too small, the station scales ran off and took the translation with them)
    rotation_noise_deg = opt.pose_rotation_noise_deg
    seen = float(ori.diagnostics.get("rotation_noise_seen_deg", 0.0))
    if opt.estimate_pose_noise and seen > ROTATION_NOISE_SEEN_FACTOR * rotation_noise_deg:
        say(f"the orientation readings scatter by {seen:.4f} deg per axis within the stations, more than the "
            f"assumed pose_rotation_noise_deg = {rotation_noise_deg:g}: {seen:.4f} deg is used")
        rotation_noise_deg = seen
    noise = NoiseAssumptions(max(sigma, 1e-7), opt.pose_translation_noise_mm, rotation_noise_deg)

    clean = sub.with_profiles([sub_fits[j].inlier_points(p) if isinstance(sub_fits[j], CircleFit) else p
                               for j, p in enumerate(sub.profiles)])
    say(f"joint refinement over {sum(len(p) for p in clean.profiles)} points"
        + (f" and {int(np.count_nonzero(clean.kinds != KIND_PROFILE))} centre observations" if clean.has_centres else ""))
    ref = refine(clean, ts.R, ts.t, ts.centre, noise, opt.fit_radius, opt.estimate_pose_noise,
                     **robot_effects)
    # data that fit nothing (another mounting's data, poses in other units): the refinement
    # does not converge and leaves residuals many times the noise. Screening them would
    # only refit, once per profile left out, each refit as slow and as futile (minutes);
    # the result is left as it is, its residuals showing the misfit (RED, the runner names
    # the likely cause)
    absurd = _fits_nothing(ref, clean, noise)
    if absurd:
        say(f"the refinement did not converge and leaves the points {absurd:.3g} mm RMS from the predicted circles, "
            f"more than {ABSURD_RESIDUAL_RATIO:g} times the noise: the data fit nothing, screening skipped (another "
            "mounting's data, poses in other units, another sphere?)")

    # stray points the circle fits kept: trim on the joint residuals and refit once. A
    # profile that would lose too many points (or keep too few) has no strays: its pose is
    # wrong. It is left out and flagged (worst first, refitting after each), never refitted
    # empty; once the rejection budget is spent, only profiles that would keep too few
    # points are left out, the others are trimmed.
    keep_pts = [np.ones(len(e), dtype=bool) for e in ref.residuals]
    while not absurd and (clean.kinds == KIND_PROFILE).any():
        is_profile = clean.kinds == KIND_PROFILE
        all_res = np.concatenate(ref.residuals)
        limit = opt.point_outlier_k * max(1.4826 * median(np.abs(all_res)), noise.point_noise_mm)
        keep_pts = [np.abs(e) <= limit for e in ref.residuals]
        lost = np.array([int((~k).sum()) for k in keep_pts])
        counts = np.array([len(k) for k in keep_pts])
        too_few = is_profile & (counts - lost < opt.min_points_per_profile)
        bad = too_few | (is_profile & (lost > opt.max_stray_point_fraction * counts))
        if rejected < max_reject and bad.any():
            drop = [int(np.argmax(np.where(bad, lost / np.maximum(counts, 1), -1.0)))]
        elif too_few.any():
            drop = np.flatnonzero(too_few).tolist()
        else:
            break
        keep = np.ones(clean.n_profiles, dtype=bool)
        for j in drop:
            keep[j] = False
            flags.append(_flag(clean, j, f"inconsistent with the other profiles: {lost[j]} of {counts[j]} points "
                                         f"({lost[j] / counts[j]:.0%}) lie far from the sphere they agree on (beyond "
                                         f"{limit:.3f} mm): "
                                         + likely_cause_of_inconsistent_profile(ref.predicted[j], ref.radius)))
        rejected += len(drop)
        clean = _drop_profiles(clean, keep, flags, opt, "left once others were left out ")
        ref = refine(clean, ref.R, ref.t, ref.centre, noise, opt.fit_radius, opt.estimate_pose_noise,
                     **robot_effects)
    if any(not k.all() for k in keep_pts):
        clean = clean.with_profiles([p if k.all() else p[k] for p, k in zip(clean.profiles, keep_pts)])
        ref = refine(clean, ref.R, ref.t, ref.centre, noise, opt.fit_radius, opt.estimate_pose_noise,
                     **robot_effects)

    # profiles inconsistent with the rest (a pose read at the wrong moment, a bad pairing)
    while not absurd and rejected < max_reject:
        chi2 = np.asarray(ref.diagnostics["profile_chi2"])
        worst = int(np.argmax(chi2))
        if chi2[worst] <= opt.profile_outlier_chi2:
            break
        if clean.kinds[worst] == KIND_PROFILE:
            shift = float(np.sqrt(chi2[worst] * np.trace(ref.centre_cov[worst]) / 3))
            flags.append(_flag(clean, worst, f"inconsistent with the other profiles (chi2 {chi2[worst]:.1f} on 3 dof, "
                                             f"about {shift:.3f} mm): a pose read at the wrong moment or a bad pairing"))
        else:
            off = float(np.linalg.norm(ref.centre_residuals[worst]))
            flags.append(_flag(clean, worst, f"inconsistent with the other observations (chi2 {chi2[worst]:.1f} on 3 "
                                             f"dof): its {KIND_NAMES[clean.kinds[worst]]} is {off:.3f} mm from where the "
                                             "fit puts it: a typo in the row, a pose read at the wrong moment or a bad "
                                             "pairing"))
        keep = np.ones(clean.n_profiles, dtype=bool)
        keep[worst] = False
        clean = _drop_profiles(clean, keep, flags, opt, "left once others were left out ")
        rejected += 1
        ref = refine(clean, ref.R, ref.t, ref.centre, noise, opt.fit_radius, opt.estimate_pose_noise,
                     **robot_effects)

    if not (clean.kinds == KIND_PROFILE).any() and opt.point_noise_mm is None:
        # no profile shows the sensor's point noise: the centres' per-axis noise stands in
        # for it (in the expected residual and the point-error budget)
        noise = replace(noise, point_noise_mm=_typical_centre_sd(clean, ref))
    n_point_rejected = sum(original_points.get(int(i), 0) - len(p) for i, p in zip(clean.obs_index, clean.profiles))
    orientations = len(clean.station_labels)
    result = _result(dataset, clean, ts, ref, flags, n_point_rejected, orientations, noise, opt)
    result = result.model_copy(update={"diagnostics": {**result.diagnostics, "station_orientation": ori.diagnostics}})
    return Solution(result, clean, ts, ref, fits, extras={"kinds": {o.index: o.kind for o in dataset.observations}})


#: Residual RMS over the noise (point noise and pose noise) beyond which an unconverged
#: refinement is taken as data that fit nothing (:func:`_fits_nothing`).
ABSURD_RESIDUAL_RATIO = 20.0


def _fits_nothing(ref: RefineResult, clean: Problem, noise: NoiseAssumptions) -> float:
    """The profiles' residual RMS (mm) when the refinement did not converge and leaves
    them more than :data:`ABSURD_RESIDUAL_RATIO` times the noise, else 0."""
    if ref.converged:
        return 0.0
    res = [e for e, k in zip(ref.residuals, clean.kinds) if k == KIND_PROFILE and len(e)]
    if not res:
        return 0.0
    rms = float(np.sqrt(np.mean(np.concatenate(res) ** 2)))
    expected = float(np.hypot(noise.point_noise_mm, noise.pose_translation_noise_mm))
    return rms if rms > ABSURD_RESIDUAL_RATIO * expected else 0.0


#: Point noise assumed, for the point-error budget only, when no profile shows it, mm.
DEFAULT_POINT_NOISE_MM = 0.01


def _centre_shot(problem: Problem, i: int) -> CentreShot:
    """A centre observation as the two-step takes it (:class:`.twostep.CentreShot`)."""
    v = problem.centre_meas[i]
    if problem.kinds[i] == KIND_CIRCLE:
        return CentreShot(v[:2].copy(), float(v[2]))
    r = problem.radius_mm
    return CentreShot(v[1:].copy(), float(np.sqrt(max(r * r - v[0] ** 2, 0.0))), float(v[0]))


def _typical_centre_sd(problem: Problem, ref: RefineResult) -> float:
    """RMS per-axis standard deviation of the centre observations, mm: the estimated one
    for those given without a covariance, the given ones' otherwise."""
    var = np.trace(fill_unknown(problem.centre_cov, (ref.centre_noise_mm or 0.0) ** 2), axis1=1, axis2=2) / 3
    return float(np.sqrt(np.mean(var[problem.kinds != KIND_PROFILE])))


def station_minimum(kinds: np.ndarray, opt: "CalibrationOptions") -> tuple[int, str, str]:
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


def _turned_hint(turned: list[ObservationFlag], tolerance_deg: float) -> str:
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
                flags.append(_flag(problem, i, f"station {label} has only {len(members)} usable {what} {context}"
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
    cause to fix is theirs (issue: "all 1 station(s) share one orientation" of a file
    with four stations, three of them screened out)."""
    dropped = sorted(set(problem.station_labels) - set(left.station_labels))
    if not dropped:
        return exc
    theirs = [f for f in flags if f.station in dropped]
    reasons = _left_out_summary(theirs)
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


def _left_out_summary(flags: list[ObservationFlag]) -> str:
    """``21 x points do not lie on a circle; 9 x too few usable profiles left in the station``."""
    why: dict[str, int] = {}
    for f in flags:
        kind = _flag_kind(f.reason)
        why[kind] = why.get(kind, 0) + 1
    return "; ".join(f"{n} x {kind}" for kind, n in sorted(why.items(), key=lambda kv: -kv[1])[:3])


def _drop_profiles(problem: Problem, keep: np.ndarray, flags: list[ObservationFlag], opt, context: str) -> Problem:
    """``problem`` without the profiles not kept (already flagged) and without the
    stations left too thin (flagged here); raises when what is left cannot determine
    the transform."""
    if keep.all():
        return problem
    keep = _thin_stations(problem, keep, flags, opt, context)
    left = problem.subset(keep)
    if left.n_profiles == 0:
        raise DegenerateDataError(
            f"no station has {opt.min_profiles_per_station} consistent profiles: check the pairing of poses and "
            "profiles and re-acquire"
        )
    dropped = sorted(set(problem.station_labels) - set(left.station_labels))
    if dropped:
        Rs = [left.R_A[np.flatnonzero(left.station_of == k)[0]] for k in range(len(left.station_labels))]
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


def calibrate(
    dataset: Dataset,
    options: CalibrationOptions | None = None,
    flange_pose_from_joints: Callable[[np.ndarray], Pose] | None = None,
    progress: Callable[[str], None] | None = None,
) -> CalibrationResult:
    """Calibrate ``dataset`` and return the result (see :func:`solve` for the details)."""
    return solve(dataset, options, flange_pose_from_joints, progress).result


def station_consistency(clean: Problem, ts: TwoStepResult, ref: RefineResult) -> dict[str, dict]:
    """Pure-translation consistency: within a station the sphere centre must move in the
    sensor frame by exactly what the robot moved. Compares the centres measured by the
    circle fits (sign resolved) with those the refined transform predicts, both relative
    to the station mean; RMS and max in mm."""
    out = {}
    obs_pos = {int(o): j for j, o in enumerate(clean.obs_index)}
    for st, ch in zip(ts.stations, ts.choice):
        measured, predicted = [], []
        for row, i in enumerate(st.profiles):
            j = obs_pos.get(int(ts_obs_index(ts, i)))
            if j is None:
                continue
            measured.append(st.candidates[ch][row])
            predicted.append(ref.predicted[j])
        if len(measured) < 2:
            continue
        m = np.array(measured)
        p = np.array(predicted)
        dev = np.linalg.norm((m - m.mean(axis=0)) - (p - p.mean(axis=0)), axis=1)
        out[st.label] = {"n_profiles": len(m), "rms_mm": float(np.sqrt(np.mean(dev**2))), "max_mm": float(dev.max())}
    return out


def ts_obs_index(ts: TwoStepResult, i: int) -> int:
    return ts.diagnostics["obs_index"][i]


#: Names of the point-error parts, as the terminal and the report say them.
POINT_ERROR_PARTS = {
    "transform_and_sphere_mm": "the calibration (transform and sphere)",
    "robot_station_to_station_mm": "the robot's systematic error",
    "robot_pose_noise_mm": "the robot's repeatability",
    "sensor_point_noise_mm": "the sensor's point noise",
}


def _robot_error_summary(clean: Problem, ref: RefineResult, noise: NoiseAssumptions, opt) -> RobotErrorSummary:
    budget = point_error_budget(clean, ref, noise)
    parts = budget["parts_rms_mm"]
    se = ref.diagnostics.get("station_effects")
    ke = ref.diagnostics.get("kinematic_effects")
    cov = ref.covariance_robot_frame if ref.covariance_robot_frame is not None else ref.covariance
    sd = np.sqrt(np.maximum(np.diag(cov)[:6], 0.0))
    params = None
    ev = ref.diagnostics.get("kinematic_evidence")
    choice = None
    if ev and ev["selected"] in ("kinematic", "none"):
        choice = (f"auto: the data show the arm's geometric error (likelihood ratio {ev['likelihood_ratio']:.1f} "
                  f"> {ev['threshold']:g}): the kinematic model" if ev["selected"] == "kinematic" else
                  f"auto: the data show no geometric error of the arm (likelihood ratio {ev['likelihood_ratio']:.1f} "
                  f"< {ev['threshold']:g}): pose noise only, the arm's geometry considered in the uncertainty")
    if ke and not (ev and ev["selected"] == "none"):
        params = []
        for k, name in enumerate(ke["names"]):
            angle = name.endswith(("zero_offset", "tilt_u", "tilt_v"))
            f = float(np.degrees(1.0)) if angle else 1.0
            params.append(KinematicParameter(
                name=name, unit="deg" if angle else "mm", value=ke["estimate"][k] * f, std=ke["sd"][k] * f,
                identifiable=ke["identifiable"][k], identified=ke["identified"][k]))
    return RobotErrorSummary(
        model=("kinematic+station" if se else "kinematic") if params is not None else ("station" if se else "none"),
        kinematic_parameters=params,
        kinematic_prior_scale=ke["prior_scale"] if params is not None else None,
        model_choice=choice,
        station_rotation_deg=float(np.degrees(ref.station_effect_scales[0])),
        station_translation_mm=float(ref.station_effect_scales[1]),
        estimated=bool(se and all(se["estimated"])),
        common_rotation_deg=float(se["common_rotation_deg"]) if se else 0.0,
        common_translation_mm=float(se["common_translation_mm"]) if se else 0.0,
        std_rotation_deg_robot_frame=tuple(np.degrees(sd[:3]).tolist()),
        std_translation_mm_robot_frame=tuple(sd[3:6].tolist()),
        point_error_k2_mm=budget["k2_mm"],
        point_error_parts_rms_mm=parts,
        dominant=max(parts, key=parts.get),
    )


def _result(dataset, clean, ts, ref, flags, n_point_rejected, orientations, noise, opt) -> CalibrationResult:
    # the transform's and sphere's block (the identified geometric parameters' spreads go to
    # robot_error.kinematic_parameters): result.covariance is that block, as readers check
    n_geo = 10 if opt.fit_radius else 9
    cov = ref.covariance[:n_geo, :n_geo] * 1.0
    sd = np.sqrt(np.maximum(np.diag(cov), 0.0))
    res = np.concatenate(ref.residuals)
    n_points = int(res.size)
    per_station = {}
    centre_res = ref.centre_residuals
    centre_stats = {}
    if centre_res is not None:
        # the components of the centre residuals join the points' (docs/estimation.md)
        used = ~np.isnan(centre_res[:, 0])
        res = np.concatenate([res, centre_res[used].ravel()])
        lengths = np.linalg.norm(centre_res[used], axis=1)
        centre_stats = {"n_centres_used": int(used.sum()), "centre_rms_mm": float(np.sqrt(np.mean(lengths**2))),
                        "centre_max_mm": float(lengths.max())}
    for k, label in enumerate(clean.station_labels):
        members = np.flatnonzero(clean.station_of == k)
        e = np.concatenate([ref.residuals[i] for i in members])
        if centre_res is not None:
            c = centre_res[members]
            e = np.concatenate([e, c[~np.isnan(c[:, 0])].ravel()])
        per_station[label] = float(np.sqrt(np.mean(e**2)))
    mode = dataset.mounting
    return CalibrationResult(
        robot_error=_robot_error_summary(clean, ref, noise, opt),
        mounting=mode,
        transform_name=TRANSFORM_NAME[mode],
        transform=Pose.from_rt(ref.R, ref.t),
        std_rotation_deg=tuple(np.degrees(sd[:3]).tolist()),
        std_translation_mm=tuple(sd[3:6].tolist()),
        sphere_centre_frame=SPHERE_FRAME[mode],
        sphere_centre_mm=tuple(ref.centre.tolist()),
        std_sphere_centre_mm=tuple(sd[6:9].tolist()),
        sphere_radius_mm=float(ref.radius),
        radius_fitted=opt.fit_radius,
        std_sphere_radius_mm=float(sd[9]) if opt.fit_radius else None,
        covariance=cov.tolist(),
        covariance_robot_frame=None if ref.covariance_robot_frame is None else ref.covariance_robot_frame.tolist(),
        variance_factor=ref.variance_factor,
        residuals=ResidualStats(
            rms_mm=float(np.sqrt(np.mean(res**2))),
            max_abs_mm=float(np.abs(res).max()),
            p95_abs_mm=float(percentile(np.abs(res), 95)),
            n_points_used=n_points,
            n_points_rejected=int(n_point_rejected),
            n_profiles_used=int(np.count_nonzero(clean.kinds == KIND_PROFILE)),
            per_station_rms_mm=per_station,
            **centre_stats,
        ),
        flagged=sorted(flags, key=lambda f: f.index),
        method="two-step (Ren, Yin and Zhu 2012) start, then joint refinement over all points "
        "(generalised least squares with robot pose noise, stray points and inconsistent profiles rejected)"
        + (" and centre observations, each with its covariance" if clean.has_centres else ""),
        two_step_transform=Pose.from_rt(ts.R, ts.t),
        diagnostics={
            "orientations": orientations,
            "two_step": {k: v for k, v in ts.diagnostics.items() if k != "obs_index"},
            "two_step_vs_refined": {
                "rotation_deg": geo.rotation_angle_deg(ts.R, ref.R),
                "translation_mm": float(np.linalg.norm(ts.t - ref.t)),
            },
            "station_consistency": station_consistency(clean, ts, ref),
            "refinement": {
                "iterations": ref.iterations,
                "converged": ref.converged,
                "information_condition_number": ref.diagnostics["information_condition_number"],
                "profile_variance_factor": ref.diagnostics["profile_variance_factor"],
            },
            "noise": {
                "point_noise_mm": noise.point_noise_mm,
                "pose_translation_noise_mm": noise.pose_translation_noise_mm * np.sqrt(ref.pose_noise_scale),
                "pose_rotation_noise_deg": noise.pose_rotation_noise_deg * np.sqrt(ref.pose_noise_scale),
                "pose_noise_estimated": opt.estimate_pose_noise,
                **({"centre_noise_mm": ref.centre_noise_mm,
                    "centre_noise_within_stations_mm": within_station_noise(clean)} if centre_res is not None else {}),
            },
        },
        provenance={"dataset": dataset.provenance.get("source", "unknown")},
    )
