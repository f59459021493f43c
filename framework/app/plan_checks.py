"""Checks of a motion plan before anything moves, and the operator's confirmation of the
motion on real hardware."""

from __future__ import annotations

import hashlib
import re
from typing import Callable

import numpy as np

from spherecal.core.errors import ConfigError, InputError, SpherecalError
from spherecal.core.keep_out import KeepOutGeometry
from spherecal.io.runlog import Notice
from spherecal.motion.acquisition import PlanProblem, check_first_move, target_problems
from spherecal.motion.keep_out import KeepOut, check_keep_out, keep_out_message
from spherecal.motion.kinematic_plan import check_plan_identifies_kinematics


def plan_digest(targets) -> str:
    """A short fingerprint of a plan (every target's station, pose and speed), stored in
    the journal so that --resume can refuse a journal taken with another plan."""
    h = hashlib.sha256()
    for t in targets:
        h.update(f"{t.index}|{t.station}|{t.speed_mm_s:.6f}|".encode())
        h.update(np.round(np.concatenate([t.pose.translation_mm, t.pose.quaternion_wxyz]), 6).tobytes())
    return h.hexdigest()[:16]


#: Farther than this from the flange, a sensor (eye_in_hand) or a sphere on its stylus
#: (eye_to_hand) is not mounted on the arm (mm).
FAR_FROM_FLANGE_MM = 500.0
#: ... when no target of the plan can be taken: farther than this, the offset on the arm
#: reads like a position in base (a stylus or a sensor bracket is shorter), mm.
FAR_FROM_FLANGE_IF_NOTHING_FITS_MM = 300.0
#: Nearer than this to the robot's base origin, a sphere (eye_in_hand) or a sensor
#: (eye_to_hand) would sit inside the robot's foot (mm).
NEAR_BASE_MM = 300.0


def mounting_hint(mounting, nominal, acq, nothing_fits: bool = False) -> str | None:
    """The configuration's geometry read in ``mounting``'s frames, when it is not a cell's;
    None when it looks like a cell. The thing on the arm (the sensor eye-in-hand, the
    sphere eye-to-hand) far from the flange and the fixed one near the robot's base: the
    other mounting. The thing on the arm far from the flange alone (beyond
    :data:`FAR_FROM_FLANGE_MM`, or :data:`FAR_FROM_FLANGE_IF_NOTHING_FITS_MM` when
    ``nothing_fits``: no target of the plan passed its checks): its offset, which is in the
    flange frame, given in base."""
    on_arm, fixed = ((np.asarray(nominal.translation_mm, float), np.asarray(acq.sphere_centre_mm, float))
                     if mounting == "eye_in_hand" else
                     (np.asarray(acq.sphere_centre_mm, float), np.asarray(nominal.translation_mm, float)))
    arm_name, fixed_name = ("sensor", "sphere") if mounting == "eye_in_hand" else ("sphere", "sensor")
    arm_key, fixed_key = (("[nominal_transform] translation_mm", "acquisition.sphere_centre_mm")
                          if mounting == "eye_in_hand" else
                          ("acquisition.sphere_centre_mm", "[nominal_transform] translation_mm"))
    far_mm = FAR_FROM_FLANGE_IF_NOTHING_FITS_MM if nothing_fits else FAR_FROM_FLANGE_MM
    far, near = np.linalg.norm(on_arm) > far_mm, np.linalg.norm(fixed) < NEAR_BASE_MM
    if far and not near:
        what = ("flange_from_sensor, the sensor's origin and axes in the flange frame" if mounting == "eye_in_hand"
                else "the sphere's centre in the flange frame (where the stylus holds it)")
        values = ", ".join(f"{v:g}" for v in on_arm)
        return (f"{arm_key} = [{values}] puts the {arm_name} {np.linalg.norm(on_arm) / 1000:.2f} m from the flange: "
                f"for mounting = \"{mounting}\" it is {what}, and this looks like a position in base; give it in "
                "the flange frame")
    odd = []
    if far:
        odd.append(f"the {arm_name} {np.linalg.norm(on_arm) / 1000:.2f} m from the flange ({arm_key}, "
                   "in the flange frame)")
    if near:
        odd.append(f"the {fixed_name} {np.linalg.norm(fixed):.0f} mm from the robot's base origin ({fixed_key}, "
                   "in base)")
    if not odd:
        return None
    other = "eye_to_hand" if mounting == "eye_in_hand" else "eye_in_hand"
    return (f"mounting = \"{mounting}\" puts {' and '.join(odd)}: is the mounting right? ({other} reads the "
            f"sphere's centre in {'the flange frame' if other == 'eye_to_hand' else 'base'} and the nominal "
            f"transform as {'base_from_sensor' if other == 'eye_to_hand' else 'flange_from_sensor'})")


#: Where the speeds of a plan's targets come from: the move to a station's (or sweep's)
#: first target, and the moves after it. A stop-and-go plan's; see :func:`check_plan`.
STOP_AND_GO_SPEEDS = ("[acquisition] approach_speed_mm_s", "[acquisition] speed_mm_s")
#: ... an on-the-fly calibration's sweeps.
ON_THE_FLY_SPEEDS = ("[acquisition] approach_speed_mm_s", "[acquisition.on_the_fly] speeds_mm_s")
#: ... a scan's passes.
SCAN_SPEEDS = ("[acquisition] approach_speed_mm_s", "[scan] speed_mm_s")
#: Targets named per group of a refusal (:func:`grouped_problems`).
EXAMPLES_PER_REASON = 3


def grouped_problems(problems: list[PlanProblem], speed_keys: tuple[str, str] = STOP_AND_GO_SPEEDS) -> list[str]:
    """The lines of a refusal: each distinct reason once (reasons that differ only in their
    measures, numbers with a decimal point such as each target's position, are one; a
    whole number, such as a joint's, tells reasons apart), with how many targets and stations
    (sweeps, on the fly) have it and the first few of those, each the first target of its
    station or sweep; a speed beyond a limit names the keys that change it
    (``speed_keys``: where the approach's and the other moves' speeds are set). A reason
    of one target is its line alone."""
    groups: dict[tuple, list[PlanProblem]] = {}
    for p in problems:
        key = (re.sub(r"-?\d+\.\d+(e[-+]?\d+)?", "#", p.reason), p.speed_limit,
               p.target.speed_mm_s if p.speed_limit else None)
        groups.setdefault(key, []).append(p)
    lines = []
    for group in groups.values():
        first = group[0]
        line = str(first)
        if len(group) > 1:
            by_label = list({p.target.station: p for p in reversed(group)}.values())[::-1]  # first of each
            unit = "sweep" if all(", sweep " in p.target.station for p in group) else "station"
            names = ", ".join(p.name for p in by_label[:EXAMPLES_PER_REASON])
            more = ", ..." if len(by_label) > EXAMPLES_PER_REASON else ""
            same = all(p.reason == first.reason and not p.at for p in group)
            reason = first.reason if same else (f"the first at {first.at} mm {first.reason}" if first.at
                                                else f"the first: {first.reason}")
            line = (f"{len(group)} targets in {len(by_label)} {unit}{'s' if len(by_label) != 1 else ''} "
                    f"({names}{more}): {reason}")
        if first.speed_limit is not None:
            line += speed_fix(group, speed_keys)
        lines.append(line)
    return lines


def speed_fix(group: list[PlanProblem], speed_keys: tuple[str, str]) -> str:
    """What to change when the targets of ``group`` (all at one speed) exceed the speed
    limit they name: that limit, or the keys their speed comes from."""
    speed = group[0].target.speed_mm_s
    approach, moves = speed_keys
    keys = list(dict.fromkeys(approach if p.target.first_of_station else moves for p in group))
    return (f"; to take them, raise {group[0].speed_limit} to at least {speed:g} mm/s, or lower the speed set in "
            f"{' and '.join(keys)}")


def check_plan(targets, acq, what: str = "plan", robot=None, done: set[int] = frozenset(), setup=None,
               keep_out: KeepOut | None = None, log: Callable[[str], None] | None = None,
               speed_keys: tuple[str, str] = STOP_AND_GO_SPEEDS) -> None:
    """Raise before any motion when a target breaks the configured limits (or, with
    ``robot``, the robot plugin's own limits, and the first move, from wherever the arm
    stands to the first target not in ``done``, breaks either), each distinct reason once
    (:func:`grouped_problems`; ``speed_keys`` where the plan's speeds are set). ``setup``:
    (mounting, nominal transform), to name a likely wrong mounting or frame once, before
    the list. ``keep_out``: then the targets not in ``done`` and the moves between them (with
    ``robot``, the first move from where the arm stands too) keep the sensor's body away
    from the sphere and its stand, else InputError naming each target or move, the gap
    found and what to change; ``log`` hears the closest approach when they do."""
    found = target_problems(targets, acq, robot)
    problems = grouped_problems(found, speed_keys)
    todo = [t for t in targets if t.index not in done]
    if robot is not None and todo:
        problems += check_first_move(robot, todo[0], acq)
    if problems:
        limits = "the robot's limits" if robot is not None else "the limits"
        nothing_fits = len({p.target.index for p in found}) == len(targets)
        hint = mounting_hint(setup[0], setup[1], acq, nothing_fits) if setup is not None else None
        head = f"the {what} breaks {limits}; nothing was moved"
        raise InputError(head + (f". {hint}" if hint else "") + ":\n  " + "\n  ".join(problems))
    if keep_out is not None and todo:
        start = robot.read_flange_pose() if robot is not None else None
        finding = check_keep_out(todo, keep_out, start)
        if finding.problems:
            raise InputError(keep_out_message(what, finding, keep_out))
        if log is not None:
            log(finding.summary(keep_out))


#: What to change when a calibration plan comes too near the sphere: at a target, and on a
#: move between targets.
CALIBRATION_KEEP_OUT_FIX = (
    "put the sphere farther from the sensor (a lower acquisition.sweep.standoff_z_mm: the sensor's z points towards "
    "the sensor; or lower z in station_offsets_mm), and check [nominal_transform] and acquisition.sphere_centre_mm",
    "smaller tilts between consecutive stations or another order of them (acquisition.sweep.tilts_deg; with the "
    "kinematic planner a lower [acquisition.kinematic_plan] max_tilt_deg)")

#: ... of a validation plan.
VALIDATION_KEEP_OUT_FIX = (
    "put that site farther from the sensor (a lower z in its offset_mm, [validation] sphere_positions, "
    "ball_bar.positions, flat.positions), or the artefact away from the sphere",
    "other tilts of consecutive sites (their tilt_deg), or the artefacts away from the sphere")
#: ... of a scan plan.
SCAN_KEEP_OUT_FIX = (
    "a lower scan.standoff_z_mm (the object farther from the sensor), or scan.object_centre_mm away from the sphere",
    "scan.object_centre_mm away from the sphere, or another scan.site")


def keep_out_for(cfg, host, transform, fixes: tuple[str, str], log: Callable[[str], None],
                 field_of_view=None) -> KeepOut | None:
    """The run's keep-out check: the sensor's body (``[keep_out.sensor_body]``, else the
    sensor type's declared one) at ``transform`` (the sensor's pose the plan was made
    with: the nominal one, or the calibration's) against the sphere at
    ``acquisition.sphere_centre_mm`` with its stand, as ``[keep_out]`` says; ``fixes``:
    what to change at a target and on a move. None, said as a warning, when there is no
    body to check; None without ``[acquisition]`` (no sphere position). ConfigError when
    the body reaches into the sensor's own measuring range (``field_of_view``)."""
    ko, acq = cfg.keep_out, cfg.acquisition
    if acq is None:
        return None
    sensor_type = cfg.sensor["type"]
    if ko.sensor_body is not None:
        body, source = ko.sensor_body, "[keep_out.sensor_body]"
    else:
        body, source = host.registry.sensor_type(sensor_type).body, f"declared by sensor type {sensor_type!r}"
    if body is None:
        log(Notice(f"warning: sensor type {sensor_type!r} declares no body and [keep_out.sensor_body] is not given: "
                   "the sensor's body is not checked against the sphere and its stand before motion; give the "
                   "housing's box in the sensor frame (docs/configuration.md, [keep_out])"))
        return None
    if field_of_view is not None and body.overlap_with_range(field_of_view):
        raise ConfigError(f"{source}: the box {list(body.min_mm)}..{list(body.max_mm)} mm reaches into the sensor's "
                          f"own measuring range (z {field_of_view.z_far_mm:g}..{field_of_view.z_near_mm:g} mm on the "
                          "laser plane x = 0): the sensor looks towards -z, so its housing lies at z above "
                          f"z_near_mm = {field_of_view.z_near_mm:g}")
    geometry = KeepOutGeometry(cfg.mounting, transform, body, tuple(acq.sphere_centre_mm), cfg.sphere.radius_mm,
                               ko.stand_radius_mm, ko.stand_length_mm)
    return KeepOut(geometry, ko.clearance_mm, source, *fixes)


def check_identification_from_here(robot, targets, cfg, arm, planned, log: Callable[[str], None]) -> None:
    """With ``identify_kinematics``, once the robot is connected: the plan check again,
    with the joints the arm will take from where it stands (the check before connecting
    started from the arm's home; an arm that starts in another wrist or elbow configuration keeps
    it, and sees the arm's geometry from other joints). Raises before anything moves when
    the plan no longer identifies the arm from here."""
    if not cfg.calibration.identify_kinematics or arm is None:
        return
    start = robot.read_joints_deg()
    if start is None:
        return
    try:
        log("from the arm's joints now: " + check_plan_identifies_kinematics(
            targets, cfg.acquisition, cfg.calibration, cfg.mounting, cfg.nominal_transform, cfg.sphere, arm,
            planned, start_joints_deg=start))
    except SpherecalError as exc:
        raise InputError(f"from where the arm stands now (joints {np.round(np.asarray(start, float), 1).tolist()} deg): "
                         f"{exc}") from exc


def check_plan_solvable(targets) -> None:
    """Raise InputError (before anything moves) when the plan's stations can never
    determine the transform: the translation needs changes of orientation about at
    least two different axes, so at least three stations."""
    first: dict[str, np.ndarray] = {}
    for t in targets:
        first.setdefault(t.station, t.pose.rotation_matrix)
    Rs = list(first.values())
    hint = ("add stations tilted by 20-45 deg about two different axes (acquisition.sweep.tilts_deg); nothing "
            "was moved")
    if len(Rs) < 3:
        raise InputError(f"the plan has {len(Rs)} station(s): the translation cannot be determined from fewer than "
                         f"three orientations; {hint}")
    M = np.vstack([R - Rs[0] for R in Rs[1:]])
    sv = np.linalg.svd(M, compute_uv=False)
    if sv[-1] < 0.05:
        raise InputError("the plan's stations are tilted about one axis only: the translation along it cannot be "
                         f"determined; {hint}")


class MotionNotConfirmed(ConfigError):
    """The operator did not confirm the motion (or could not: no input and no --yes)."""


def confirm_motion(command: str, plan: str, yes: bool, ask: Callable[[str], str], log: Callable[[str], None]) -> None:
    """Before the first motion on real hardware: the plan summary and a typed 'yes', or
    ``yes`` (``--yes``). Raises :class:`MotionNotConfirmed` otherwise; nothing has been
    opened or moved then."""
    if yes:
        log(f"{command}: motion confirmed with --yes: {plan}")
        return
    log(Notice(f"{command} is about to move the real robot: {plan}. Keep the cell clear and a hand on the "
               "enabling device or the emergency stop."))  # shown with -q too: it is what 'yes' confirms
    try:
        answer = ask("Type 'yes' to start the motion (anything else stops): ")
    except (EOFError, OSError):
        raise MotionNotConfirmed(f"{command} would move the robot and nobody confirmed it (no input): run it at a "
                                 "terminal and type 'yes', or give --yes; nothing was moved") from None
    if answer.strip().lower() != "yes":
        raise MotionNotConfirmed(f"{command}: motion not confirmed (answer {answer.strip()[:20]!r}); nothing was moved")


class StoppedAtStep(KeyboardInterrupt):
    """The operator stopped the run at a step prompt (``--step``): an interruption like
    Ctrl-C (exit 130), the journal keeps every shot taken, ``--resume`` continues."""


def step_prompt(ask: Callable[[str], str]) -> Callable[[str, list], None]:
    """Step mode: before each station, the station, its shots and where its first one is,
    and a typed answer. ``y`` goes on; anything else (``n``, ``q``, an empty line, no
    input) raises :class:`StoppedAtStep` before the station's first move."""

    def before(station: str, targets: list) -> None:
        x, y, z = targets[0].pose.translation_mm
        prompt = (f"station {station}: {len(targets)} shot{'s' if len(targets) != 1 else ''} from flange "
                  f"({x:.1f}, {y:.1f}, {z:.1f}) mm in base; go? [y/N/q] ")
        try:
            answer = ask(prompt)
        except (EOFError, OSError):
            answer = "(no input)"
        if answer.strip().lower() in ("y", "yes"):
            return
        raise StoppedAtStep(f"stopped before station {station} (--step, answered {answer.strip()[:20]!r}); nothing "
                            "more was moved")

    return before
