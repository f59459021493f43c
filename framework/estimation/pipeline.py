"""From a dataset to a :class:`CalibrationResult`: the solve step by step (the checks
that leave observations out are :mod:`.screening`'s), two-step start, joint refinement,
diagnostics."""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import Callable

import numpy as np

from spherecal.core import geometry as geo
from spherecal.core.errors import DegenerateDataError, FitBreakdownError, InputError
from spherecal.core.kinematics import ArmKinematics
from spherecal.core.models import (
    SPHERE_FRAME, TRANSFORM_NAME, CalibrationResult, Dataset, KinematicParameter, ObservationFlag, Pose, ResidualStats,
    ResultDiagnostics, RobotErrorSummary,
)
from spherecal.config import CalibrationOptions
from spherecal.estimation.circle import CircleFit, fit_circles
from spherecal.estimation.prediction import (nominal_arm_point_error_k2_mm, point_error_budget,
                                             station_prediction_summary)
from spherecal.estimation.problem import (
    KIND_CIRCLE, KIND_NAMES, KIND_PROFILE, Problem, build_problem,
    fill_unknown, screen_station_orientations, several_stations_under_one_label, spread_per_station,
)
from spherecal.estimation.options import kinematic_effects, station_effects, station_rotation_tolerance_deg
from spherecal.estimation.refine import NoiseAssumptions, RefineProgress, RefineResult, cost_at, refine
from spherecal.estimation.refine.timing import with_start
from spherecal.estimation.centres import (
    PAIR_UNDECIDED, leave_one_out_sizes, screen_table, settle_pairs, with_leave_one_out_size, within_station_noise,
)
from spherecal.estimation.robust import median, percentile
from spherecal.estimation.screening import (
    RejectionBudget, arcs_facing_away, copied_profiles, flag_shot, joints_against_poses, reject_inconsistent_shots,
    require_usable_stations, trim_stray_points, turned_hint, two_step_without_gross_outliers, unusable_profile_reason,
)
from spherecal.estimation.profile_artefacts import artefacts_note, name_profile_artefacts
from spherecal.estimation.starts import settle_alternative_starts
from spherecal.estimation.any_poses import (
    as_start, beside_the_linear_start, linear_start_beside, linear_start_of_rows, orientation_stations,
    robot_error_without_stations, start_diagnostics, stations_of_single_rows,
)
from spherecal.estimation.twostep import CentreShot, TwoStepResult

@dataclass
class Solution:
    """Everything :func:`solve` worked out; :attr:`result` is what users keep."""

    result: CalibrationResult
    problem: Problem  # the profiles that were used (points cleaned)
    two_step: TwoStepResult
    refined: RefineResult
    fits: dict[int, CircleFit]
    extras: dict = field(default_factory=dict)




#: What a result of circles alone, without a nominal transform, cannot exclude: a circle
#: (y, z, radius) leaves the side of the laser plane open, so the sensor turned half a turn
#: about its (0, 1, 1) axis, which maps (x, y, z) to (-x, z, y), fits the same circles with
#: y and z swapped exactly as this result fits them (profiles show it: their arcs face the
#: sensor).
CIRCLE_TWIN = (
    "a twin of this result cannot be excluded: the sensor turned half a turn about its (0, 1, 1) axis fits this table "
    "with y and z swapped in every circle exactly as well, and circles carry no arc to show which side faces the "
    "sensor. Give a nominal transform (calibration.nominal_transform; spherecal solve --nominal) to tell them "
    "apart, or profiles instead of circles")


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
    except DegenerateDataError as exc:
        note = artefacts_note(dataset)
        if note is None:
            raise
        raise type(exc)(f"{exc}; {note}") from None
    flagged = name_profile_artefacts(solution.result.flagged, dataset)
    if flagged != solution.result.flagged:
        solution = replace(solution, result=solution.result.model_copy(update={"flagged": flagged}))
    return with_nominal_comparison(solution, options.nominal_transform if options is not None else None)


#: A nominal transform whose quaternion, read (x, y, z, w), lies this close to the result
#: was written scalar last (the order of ROS and SciPy) where w comes first, deg.
QUATERNION_ORDER_DEG = 10.0


def with_nominal_comparison(solution: Solution, nominal: Pose | None) -> Solution:
    """``solution`` with how far its transform lies from the rough one the user gave
    (``diagnostics.nominal_transform``: ``rotation_deg``, ``translation_mm``, and the
    likely cause of a large turn, which the verdict names), or as it is without one."""
    if nominal is None:
        return solution
    X = solution.result.transform
    turn = geo.rotvec_from_matrix(nominal.rotation_matrix.T @ X.rotation_matrix)  # in the sensor frame
    angle = float(np.degrees(np.linalg.norm(turn)))
    about_z = bool(angle > 90.0 and abs(turn[2]) > 0.95 * np.linalg.norm(turn))
    # half a turn about (0, 1, 1) maps the laser plane's (y, z) to (z, y): y and z swapped in the data
    about_yz = bool(angle > 90.0 and abs(turn[1] + turn[2]) / np.sqrt(2.0) > 0.95 * np.linalg.norm(turn))
    w, x, y, z = nominal.quaternion_wxyz
    scalar_last = geo.matrix_from_quat_wxyz((z, w, x, y))  # the nominal's (w, x, y, z) read as written (x, y, z, w)
    off_deg = geo.rotation_angle_deg(scalar_last, X.rotation_matrix)
    quaternion_order = bool(angle > 2 * QUATERNION_ORDER_DEG and off_deg < QUATERNION_ORDER_DEG)
    cause = None
    if quaternion_order:
        cause = (f"the nominal's quaternion, read as written scalar last (x, y, z, w: the order of ROS and SciPy), "
                 f"lies {off_deg:.1f} deg from the result: give it w first (quaternion_wxyz); calibrate's reach and "
                 "keep-out checks take the nominal as given")
    elif about_z:
        cause = ("turned about the sensor's z axis. A sensor whose y axis runs the other way (its profile points "
                 "mirrored, y -> -y) fits such data exactly as one turned half a turn does; check the sign of the "
                 "sensor's y, or the nominal")
    elif about_yz:
        cause = ("turned half a turn about the sensor's (0, 1, 1) axis, which is what data with y and z swapped in "
                 "every profile or circle give (each written (z, y)); check the order of the coordinates, or the "
                 "nominal")
    diag = solution.result.diagnostics.model_copy(update={"nominal_transform": {
        "rotation_deg": angle, "translation_mm": float(np.linalg.norm(X.translation - nominal.translation)),
        "half_turn_about_sensor_z": about_z, "half_turn_about_sensor_yz": about_yz,
        "quaternion_scalar_last": quaternion_order, "likely_cause": cause}})
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
            joint_flags = [flag_shot(problem, int(i), reason) for i, reason in check.shots.items()]
    joints_known = problem.q_rad is not None
    # rows that are typos (units, signs, a circle larger than the sphere): left out, flagged
    table_keep, table_flags, pairs, moved = screen_table(problem)
    for f in joint_flags + copied_profiles(problem):
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
    noise_mm = ref.centre_noise_mm or float(solution.result.diagnostics.noise["point_noise_mm"])
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



def _with_joints_note(solution: Solution, note: str | None) -> Solution:
    """The result with the joints' check in its diagnostics (``joints_vs_poses``) when
    the joints were not used: the verdict says so."""
    if note is None:
        return solution
    diag = solution.result.diagnostics.model_copy(update={"joints_vs_poses": {"used": False, "reason": note}})
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


def _solve(dataset, problem, opt, say, kinematics, joints_known, table_flags, time_effects=None,
           reweigh=None) -> Solution:
    """Solve ``problem`` (the table's screening done, its flags in ``table_flags``): the
    orientation screening, a circle per profile, the two-step start without the gross
    outliers, the joint refinement, then the stray points and the inconsistent shots
    left out (:mod:`.screening`), and the result. With ``time_effects`` (a recording) the
    clock relation is estimated in the joint refinement (:mod:`.refine.timing`);
    ``reweigh`` (problem, refined, noise) -> noise or None: after the screening, other
    noise assumptions to refit with (a recording's pose noise widened for its correlation
    in time), the pose noise then held."""
    robot_effects = {
        "station_effects": station_effects(opt, joints_known),
        "kinematic_effects": kinematic_effects(opt, kinematics.chain)
        if kinematics is not None and opt.uses_kinematic_model(joints_known) and joints_known else None,
    }
    original_points = {int(i): len(p) for i, p in zip(problem.obs_index, problem.profiles)}
    every_point = None
    thin = _thinning(problem) if time_effects is not None else 1
    if thin > 1:
        # a recording of millions of points: circles, start, fit and screening on every
        # thin-th point of each profile, then the fit once more on every point (_every_point)
        every_point = problem
        problem = problem.with_profiles([p[::thin] if len(p) >= 2 * thin else p for p in problem.profiles])
        say(f"screening on every {thin}th point of each profile ({sum(len(p) for p in problem.profiles)} points)")
    # labels of one row each carry no stations: the rows that share an orientation make them
    problem, grouped = stations_of_single_rows(problem, station_rotation_tolerance_deg(opt))
    if grouped:
        say(grouped)
    # within a station the robot may only translate: turned shots are left out or split off
    unscreened = problem
    # (rows of sphere centres need no sweep: two at one orientation make a station)
    centres_only = bool(len(problem.kinds)) and not (problem.kinds == KIND_PROFILE).any()
    ori = screen_station_orientations(
        problem, opt.station_rotation_tolerance_deg, opt.pose_rotation_noise_deg, opt.estimate_pose_noise,
        min(opt.min_profiles_per_station, 2) if centres_only else opt.min_profiles_per_station,
    )
    problem = ori.problem
    flags: list[ObservationFlag] = table_flags + list(ori.flags)
    for note in ori.notes:
        say(note)
    hint = turned_hint(ori.flags, ori.diagnostics["tolerance_deg"])
    fits = _fit_shots(problem, opt, flags, say)
    facing = arcs_facing_away(problem, fits)
    if facing is not None:
        raise DegenerateDataError(facing)
    orientation_diagnostics, start_notes = ori.diagnostics, []
    try:
        ts, sub, sub_fits, budget = _station_start(problem, fits, flags, opt, hint, say, time_effects)
    except DegenerateDataError as exc:
        scattered = ori.diagnostics.get("scattered_stations")
        # what is left says too little because a label held several stations: that is the cause to name
        cause = exc if not scattered else DegenerateDataError(
            f"{several_stations_under_one_label(scattered)}; the observations left cannot determine the transform")
        if time_effects is not None:
            raise cause from (exc if scattered else None)
        # rows the pure-translation rule showed wrong stay out: that rule holds whatever the start
        wrong = [f for f in flags[len(table_flags):] if f.reason.startswith("inconsistent")]
        general = _any_pose_start(unscreened, opt, table_flags + wrong, say, cause, ori.diagnostics, robot_effects,
                                  kinematics, joints_known)
        ts, sub, sub_fits, budget, flags, orientation_diagnostics, robot_effects, start_notes = general
    noise = _noise_assumptions(opt, sub_fits, orientation_diagnostics, say)

    told = RefineProgress(say)  # one clock for every refinement of this solve

    def refit(clean_: Problem, start) -> RefineResult:
        timing = {} if time_effects is None else {"time_effects": with_start(time_effects, getattr(start, "timing", None))}
        return refine(clean_, start.R, start.t, start.centre, noise, opt.fit_radius, opt.estimate_pose_noise,
                      **robot_effects, **timing, progress=told)

    clean = sub.with_profiles([sub_fits[j].inlier_points(p) if isinstance(sub_fits[j], CircleFit) else p
                               for j, p in enumerate(sub.profiles)])
    say(f"joint refinement over {sum(len(p) for p in clean.profiles)} points"
        + (f" and {int(np.count_nonzero(clean.kinds != KIND_PROFILE))} centre observations" if clean.has_centres else ""))
    if ts.alternatives:
        # starts that fit nearly alike through the nominal poses: the joint model decides
        def cost(r: RefineResult, scale: float) -> float:
            return cost_at(clean, r, noise, opt.fit_radius, scale, **robot_effects, time_effects=time_effects)

        ts, ref = settle_alternative_starts(clean, ts, refit, cost, say)
    else:
        ref = refit(clean, ts)
    linear = None if ts.diagnostics.get("start") == "linear" else linear_start_beside(sub, ts, opt)
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
    else:
        clean, ref = trim_stray_points(clean, ref, noise, opt, flags, budget, refit, batch=time_effects is not None,
                                       recording=time_effects is not None)
        clean, ref = reject_inconsistent_shots(clean, ref, opt, flags, budget, refit, batch=time_effects is not None)
        reweighed = None if reweigh is None else reweigh(clean, ref, noise)
        if reweighed is not None or every_point is not None:
            noise = reweighed or noise
            if every_point is not None:
                clean = _every_point(every_point, clean, ref, noise, opt)
                say(f"joint refinement over every point of the profiles kept ({sum(len(p) for p in clean.profiles)})")
            timing = {} if time_effects is None else {"time_effects": with_start(time_effects, ref.timing)}
            ref = refine(clean, ref.R, ref.t, ref.centre, noise, opt.fit_radius,
                         opt.estimate_pose_noise and reweighed is None, **robot_effects, **timing, progress=told)

    compared = None
    if linear is not None and not absurd:
        def cost(r: RefineResult, scale: float) -> float:
            return cost_at(clean, r, noise, opt.fit_radius, scale, **robot_effects, time_effects=time_effects)

        ref, compared = beside_the_linear_start(clean, ts, ref, linear, refit, cost, say)
    if not (clean.kinds == KIND_PROFILE).any() and opt.point_noise_mm is None:
        # no profile shows the sensor's point noise: the centres' per-axis noise stands in
        # for it (in the expected residual and the point-error budget)
        noise = replace(noise, point_noise_mm=_typical_centre_sd(clean, ref))
    n_point_rejected = sum(original_points.get(int(i), 0) - len(p) for i, p in zip(clean.obs_index, clean.profiles))
    orientations = len(clean.station_labels)
    result = _result(dataset, clean, ts, ref, flags, n_point_rejected, orientations, noise, opt)
    if grouped:
        orientation_diagnostics = {**orientation_diagnostics, "single_row_labels_grouped": grouped}
    added = {"station_orientation": orientation_diagnostics, "start": start_diagnostics(ts, ref, compared)}
    if start_notes:
        robot = result.robot_error
        choice = "; ".join([*start_notes, *([robot.model_choice] if robot.model_choice else [])])
        result = result.model_copy(update={"robot_error": robot.model_copy(update={"model_choice": choice})})
    if opt.nominal_transform is None and (clean.kinds == KIND_CIRCLE).all():
        added["mirror_twin"] = {"excluded": False, "text": CIRCLE_TWIN}
    result = result.model_copy(update={"diagnostics": result.diagnostics.model_copy(update=added)})
    return Solution(result, clean, ts, ref, fits, extras={"kinds": {o.index: o.kind for o in dataset.observations}})


def _station_start(problem: Problem, fits: dict, flags: list[ObservationFlag], opt, hint: str, say, time_effects):
    """The two-step start of station data (:func:`.screening.two_step_without_gross_outliers`;
    a recording's from a subsample, :func:`_recording_start`): (start, the problem of the
    shots used, their fits, the rejection budget). :class:`DegenerateDataError` when the
    stations cannot give it."""
    require_usable_stations(problem, fits, flags, opt, hint)
    say("two-step solution (rotation from translations, translation from orientations)")
    budget = RejectionBudget(int(opt.max_rejected_profile_fraction * len(fits)))
    # a recording's poses are read at each profile's time, not paired with it: no shot
    # is mis-paired, and the profiles near the sphere's rim, whose centres the two-step
    # sees poorly, would pass for such
    if time_effects is None:
        ts, sub, sub_fits = two_step_without_gross_outliers(problem, fits, flags, opt, hint, budget)
    else:
        ts, sub, sub_fits = _recording_start(problem, fits, flags, opt, hint)
    return ts, sub, sub_fits, budget


def _any_pose_start(problem: Problem, opt, table_flags: list[ObservationFlag], say, cause: DegenerateDataError,
                    orientation_diagnostics: dict, robot_effects: dict, kinematics, joints_known: bool):
    """The start from any orientations (:mod:`.any_poses`) of every row of ``problem``
    (before the orientation screening: no row is left out as turned) but those
    ``table_flags`` name, when the two-step cannot start (``cause``). Returns what :func:`_solve` goes on with: the start, the
    problem of the rows used (stations regrouped by orientation), their fits, the
    rejection budget, the flags, the orientation diagnostics, the robot error effects
    (without station offsets when no two rows share an orientation) and what the result
    says of them. When it cannot start either, :class:`DegenerateDataError` gives both
    causes."""
    flags = list(table_flags)
    out = {f.index for f in table_flags}
    problem = problem.subset(~np.isin(problem.obs_index, list(out))) if out else problem
    fits = _fit_shots(problem, opt, flags, say)
    used = np.array(sorted(fits), dtype=int)
    sub = problem.subset(np.isin(np.arange(problem.n_profiles), used))
    sub_fits = {j: fits[int(i)] for j, i in enumerate(used)}
    budget = RejectionBudget(int(opt.max_rejected_profile_fraction * len(fits)), stations=False)
    try:
        start, keep = linear_start_of_rows(sub, sub_fits, flags, budget, opt.nominal_transform)
    except DegenerateDataError as exc:
        raise DegenerateDataError(f"{cause}. Nor can the start from any orientations solve it: {exc}") from None
    if not keep.all():
        sub_fits = {j: sub_fits[int(i)] for j, i in enumerate(np.flatnonzero(keep))}
        sub = sub.subset(keep)
    say(f"the rows are not stations of pure translations ({cause}): the start from any orientations, linear in the "
        f"sphere centres of {int(keep.sum())} rows, is used")
    sub, split, largest = orientation_stations(sub, orientation_diagnostics["tolerance_deg"])
    notes = [f"station {label}: its rows are at {n} orientations, not one station of pure translations: grouped by "
             "orientation" for label, n in split.items()]
    effects, robot_notes = dict(robot_effects), []
    if largest < 2 and effects["station_effects"].enabled:
        note, use_kinematic = robot_error_without_stations(opt.robot_error_model,
                                                           kinematics is not None and joints_known)
        effects["station_effects"] = replace(effects["station_effects"], enabled=False, common_only=not use_kinematic)
        if use_kinematic and effects["kinematic_effects"] is None:
            effects["kinematic_effects"] = kinematic_effects(opt, kinematics.chain)
        robot_notes.append(note)
    for note in notes + robot_notes:
        say(note)
    diagnostics = {**{k: orientation_diagnostics[k] for k in ("tolerance_deg", "tolerance_derived",
                                                             "rotation_noise_seen_deg")},
                   "orientation_groups": len(sub.station_labels), "largest_orientation_group": largest,
                   "split_by_orientation": split, "notes": notes + robot_notes}
    return as_start(start), sub, sub_fits, budget, flags, diagnostics, effects, robot_notes


#: A recording's fit is screened on a thinned copy of its points when it has more than
#: this many (every k-th point of each profile, k the smallest that brings them under it),
#: then refitted once on every point.
SCREENING_POINTS = 3_000_000


def _thinning(problem: Problem) -> int:
    """Every how many points of each profile a recording's screening takes (1: all)."""
    n = sum(len(p) for p in problem.profiles)
    return max(1, int(np.ceil(n / SCREENING_POINTS)))


def _every_point(full: Problem, screened: Problem, ref: RefineResult, noise: NoiseAssumptions, opt) -> Problem:
    """The shots the screening kept (``screened``, thinned) with every point of their
    profiles as measured (``full``), less the points beyond the stray limit of the
    screened fit (``ref``): as :func:`.screening.trim_stray_points` judges them."""
    row = {int(o): j for j, o in enumerate(full.obs_index)}
    rows = np.array([row[int(o)] for o in screened.obs_index])
    points = [full.profiles[j] for j in rows]
    C = ref.predicted
    rho = np.sqrt(np.maximum(ref.radius**2 - C[:, 0] ** 2, 0.0))
    res = [np.linalg.norm(p - C[i, 1:], axis=1) - rho[i] for i, p in enumerate(points)]
    limit = opt.point_outlier_k * max(1.4826 * median(np.abs(np.concatenate(ref.residuals))), noise.point_noise_mm)
    kept = []
    for i, (p, e) in enumerate(zip(points, res)):
        inside = np.abs(e) <= limit
        kept.append(p if screened.kinds[i] != KIND_PROFILE or inside.all() else p[inside])  # (no copy of a clean one)
    return screened.with_profiles(kept)


#: A recording's two-step start uses at most this many profiles per station, evenly
#: spread in time: it is a start, and its sphere fit over every point of thousands of
#: profiles (per side-of-plane combination) would cost more than the joint fit.
RECORDING_START_PROFILES = 96


def _recording_start(problem: Problem, fits: dict, flags: list[ObservationFlag], opt, hint: str):
    """The two-step start of a recording from a subsample of its profiles, and the
    problem and fits of every profile with a fit (all go to the joint refinement)."""
    used = np.array(sorted(fits))
    pick = spread_per_station(used, problem.station_of, RECORDING_START_PROFILES)
    ts, _, _ = two_step_without_gross_outliers(problem, {int(i): fits[int(i)] for i in pick}, flags, opt, hint,
                                               RejectionBudget(0))
    sub = problem.subset(np.isin(np.arange(problem.n_profiles), used))
    return ts, sub, {j: fits[int(i)] for j, i in enumerate(used)}


def _fit_shots(problem: Problem, opt, flags: list[ObservationFlag], say) -> dict[int, CircleFit | CentreShot]:
    """A circle fitted to each profile that shows the sphere, the others left out and
    flagged (:func:`.screening.unusable_profile_reason`); each centre observation as the
    two-step takes it. Keyed by row of ``problem``."""
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
        reason = unusable_profile_reason(pts, circles.get(i), opt, problem.radius_mm)
        if reason is not None:
            flags.append(flag_shot(problem, i, reason))
            continue
        fits[i] = circles[i]
    return fits


def _noise_assumptions(opt, sub_fits: dict, orientation_diagnostics: dict, say) -> NoiseAssumptions:
    """The noise the refinement assumes: the point noise given, else the circle fits'
    pooled one; the orientation read noise the stations show where it is more than
    :data:`ROTATION_NOISE_SEEN_FACTOR` times the assumed one."""
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
    # assumed 10 times too small, the station scales run off and take the translation with them)
    rotation_noise_deg = opt.pose_rotation_noise_deg
    seen = float(orientation_diagnostics.get("rotation_noise_seen_deg", 0.0))
    if opt.estimate_pose_noise and seen > ROTATION_NOISE_SEEN_FACTOR * rotation_noise_deg:
        say(f"the orientation readings scatter by {seen:.4f} deg per axis within the stations, more than the "
            f"assumed pose_rotation_noise_deg = {rotation_noise_deg:g}: {seen:.4f} deg is used")
        rotation_noise_deg = seen
    return NoiseAssumptions(max(sigma, 1e-7), opt.pose_translation_noise_mm, rotation_noise_deg)


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
        point_error_nominal_arm_k2_mm=nominal_arm_point_error_k2_mm(clean, ref, budget),
        dominant=max(parts, key=parts.get),
        station_prediction=station_prediction_summary(clean, ref),
    )


def _result(dataset, clean, ts, ref, flags, n_point_rejected, orientations, noise, opt) -> CalibrationResult:
    # the transform's and sphere's block (the identified geometric parameters' spreads go to
    # robot_error.kinematic_parameters): result.covariance is that block, as readers check
    n_geo = 10 if opt.fit_radius else 9
    linear = ts.diagnostics.get("start") == "linear"
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
        method=("closed-form linear start from the sphere centres at any orientations" if linear else
                "two-step (Ren, Yin and Zhu 2012) start") + ", then joint refinement over all points "
        "(generalised least squares with robot pose noise, stray points and inconsistent profiles rejected)"
        + (" and centre observations, each with its covariance" if clean.has_centres else ""),
        **({} if linear else {"two_step_transform": Pose.from_rt(ts.R, ts.t)}),
        diagnostics=ResultDiagnostics(
            orientations=orientations,
            **({} if linear else {
                "two_step": {k: v for k, v in ts.diagnostics.items() if k != "obs_index"},
                "two_step_vs_refined": {"rotation_deg": geo.rotation_angle_deg(ts.R, ref.R),
                                        "translation_mm": float(np.linalg.norm(ts.t - ref.t))}}),
            station_consistency=station_consistency(clean, ts, ref),
            refinement={
                "iterations": ref.iterations,
                "converged": ref.converged,
                "information_condition_number": ref.diagnostics["information_condition_number"],
                "profile_variance_factor": ref.diagnostics["profile_variance_factor"],
            },
            noise={
                "point_noise_mm": noise.point_noise_mm,
                "pose_translation_noise_mm": noise.pose_translation_noise_mm * np.sqrt(ref.pose_noise_scale),
                "pose_rotation_noise_deg": noise.pose_rotation_noise_deg * np.sqrt(ref.pose_noise_scale),
                "pose_noise_estimated": opt.estimate_pose_noise,
                **({"centre_noise_mm": ref.centre_noise_mm,
                    "centre_noise_within_stations_mm": within_station_noise(clean)} if centre_res is not None else {}),
            },
        ),
        provenance={"dataset": dataset.provenance.get("source", "unknown")},
    )

