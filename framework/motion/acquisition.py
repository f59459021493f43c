"""Acquisition: plan the stations, check every target before any motion, then move,
read, and append each observation to the journal the moment it is taken.

Devices are reached only through the :class:`spherecal.devices.contract.Robot` and
:class:`spherecal.devices.contract.Sensor` interfaces; the journal is a
:class:`spherecal.io.dataset.DatasetWriter` (one flushed, fsync'ed line per observation), so
a run killed at any point loses nothing already taken and resumes where it stopped.
"""

from __future__ import annotations

import sys
import time
from dataclasses import dataclass, field
from datetime import datetime, timezone
from typing import Callable, Sequence, TextIO

import numpy as np

from spherecal.core import geometry as geo
from spherecal.io.runlog import progress_log
from spherecal.config import AcquisitionConfig, SphereConfig, TransformConfig
from spherecal.io.dataset import DatasetWriter
from spherecal.core.errors import DeviceError, InputError, SpherecalError
from spherecal.core.models import MountingMode, Observation, Pose, Profile
from spherecal.motion.planning import SweepPlan, plan_stations

_LOG = progress_log("acquisition")  # the default ``log``: logger spherecal.acquisition


@dataclass(frozen=True)
class Target:
    """One planned shot: flange pose ``base_from_flange`` (mm) in a station, and the
    speed of the linear move that reaches it (mm/s)."""

    index: int
    station: str
    pose: Pose
    first_of_station: bool
    speed_mm_s: float


def targets_from_poses(poses: list[Pose], station: str, first_index: int, approach_mm_s: float, speed_mm_s: float) -> list[Target]:
    """Targets of one pure-translation sweep: the first reached at the approach speed."""
    return [
        Target(first_index + k, station, p, k == 0, approach_mm_s if k == 0 else speed_mm_s)
        for k, p in enumerate(poses)
    ]


def plan_targets(acq: AcquisitionConfig | None, mounting: MountingMode, nominal: TransformConfig,
                 sphere: SphereConfig, sweep: SweepPlan | None = None) -> list[Target]:
    """The planned shots of ``acq``, in order, from the nominal transform (the
    configuration's ``[nominal_transform]``) and the rough sphere position; ``sweep``
    replaces ``acquisition.sweep`` (the kinematic planner's stations,
    :mod:`spherecal.motion.kinematic_plan`)."""
    if acq is None:
        raise InputError("no [acquisition] section: nothing to plan")
    R_ref = geo.matrix_from_quat_wxyz(acq.reference_flange_quaternion_wxyz)
    stations = plan_stations(
        mounting, nominal.pose(), acq.sphere_centre_mm, sphere.radius_mm, sweep or acq.sweep, R_ref
    )
    targets: list[Target] = []
    for label, poses in stations:
        targets += targets_from_poses(poses, label, len(targets), acq.approach_speed_mm_s, acq.speed_mm_s)
    return targets


@dataclass(frozen=True)
class PlanProblem:
    """What is wrong with one target of a plan (:func:`target_problems`): ``reason`` in the
    check's words, ``at`` the target's flange position when the reason does not give it
    (``"[x, y, z]"``, mm), ``speed_limit`` the configuration key of the speed limit the
    target's speed exceeds, when that is the problem (else None)."""

    target: Target
    reason: str
    at: str = ""
    speed_limit: str | None = None

    @property
    def name(self) -> str:
        return f"target {self.target.index} (station {self.target.station})"

    def __str__(self) -> str:
        return f"{self.name} at {self.at} mm {self.reason}" if self.at else f"{self.name}: {self.reason}"


def target_problems(targets: list[Target], acq: AcquisitionConfig, robot=None) -> list[PlanProblem]:
    """Every problem with the plan, before anything moves: the workspace box, the speeds,
    and the robot plugin's own check (``robot.check_target``) where it has one. A target
    the robot refuses at a speed its own ``check_speed`` refuses is a speed problem of
    ``[robot] max_speed_mm_s``."""
    problems = []
    check = getattr(robot, "check_target", None) if robot is not None else None
    check_speed = getattr(robot, "check_speed", None) if robot is not None else None
    too_fast: dict[float, bool] = {}  # the robot's verdict on each speed of the plan

    def refused_speed(speed_mm_s: float) -> bool:
        if check_speed is None:
            return False
        if speed_mm_s not in too_fast:
            try:
                check_speed(speed_mm_s)
                too_fast[speed_mm_s] = False
            except SpherecalError:
                too_fast[speed_mm_s] = True
        return too_fast[speed_mm_s]

    for t in targets:
        if t.speed_mm_s > acq.max_speed_mm_s:
            problems.append(PlanProblem(t, f"speed {t.speed_mm_s} mm/s exceeds acquisition.max_speed_mm_s = "
                                           f"{acq.max_speed_mm_s}", speed_limit="[acquisition] max_speed_mm_s"))
        if not acq.workspace.contains(t.pose.translation):
            problems.append(PlanProblem(
                t, f"is outside acquisition.workspace {list(acq.workspace.min_mm)}..{list(acq.workspace.max_mm)}",
                at=str(np.round(t.pose.translation, 1).tolist())))
        if check is not None:
            try:
                check(t.pose, t.speed_mm_s)
            except SpherecalError as exc:
                problems.append(PlanProblem(t, str(exc), speed_limit="[robot] max_speed_mm_s"
                                            if refused_speed(t.speed_mm_s) else None))
    return problems


def check_targets(targets: list[Target], acq: AcquisitionConfig, robot=None) -> list[str]:
    """Every problem with the plan (:func:`target_problems`), one line per target at fault."""
    return [str(p) for p in target_problems(targets, acq, robot)]


def check_first_move(robot, target: Target, acq: AcquisitionConfig) -> list[str]:
    """Every problem with the move from wherever the arm stands now to ``target``, the
    first of a run (or of a resumed run), before anything moves.

    Every other move runs between two planned targets, both checked by
    :func:`check_targets` against ``acquisition.workspace``, so its straight path stays
    in that box (a box is convex). The first starts where the arm happens to be: the
    arm's pose now must be in the box too (else the problem says how much of the path
    would leave it), and the robot plugin checks the move itself (``robot.check_move``,
    where it has one: its limits from the arm's actual joints along the path, as it
    checks every move before sending it)."""
    problems = []
    start = robot.read_flange_pose()
    box = acq.workspace
    outside = box.fraction_outside(start.translation, target.pose.translation)
    if not box.contains(start.translation):
        problems.append(
            f"the arm stands at {np.round(start.translation, 1).tolist()} mm, outside acquisition.workspace "
            f"{list(box.min_mm)}..{list(box.max_mm)}: the straight move to the first target {target.index} (station "
            f"{target.station}) would run outside it for {outside:.0%} of the way. Jog the arm into the workspace, "
            "near the first target, and start again"
        )
    check = getattr(robot, "check_move", None)
    if check is not None:
        try:
            check(target.pose, target.speed_mm_s)
        except SpherecalError as exc:
            problems.append(f"the first move, from where the arm stands to target {target.index} (station "
                            f"{target.station}): {exc}")
    return problems


def describe_plan(targets: list[Target]) -> str:
    """A table of the stations: orientation, number of shots and the extent of the sweep."""
    lines = [f"{'station':8s} {'shots':>5s}  {'flange quaternion (w, x, y, z), base':38s} "
             f"{'first target (mm, base)':>28s}"]
    for label in dict.fromkeys(t.station for t in targets):
        ts = [t for t in targets if t.station == label]
        q = ", ".join(f"{v:+.4f}" for v in ts[0].pose.quaternion_wxyz)
        p = ", ".join(f"{v:.1f}" for v in ts[0].pose.translation_mm)
        lines.append(f"{label:8s} {len(ts):5d}  {q:38s} {p:>28s}")
    return "\n".join(lines)


class Progress:
    """A progress bar with an estimate of the time left, on a terminal; plain lines
    otherwise (every tenth step)."""

    def __init__(self, total: int, stream: TextIO | None = None, width: int = 30):
        self.total = max(total, 1)
        self.stream = stream or sys.stderr
        self.width = width
        self.start = time.monotonic()
        self.done = 0
        self.tty = hasattr(self.stream, "isatty") and self.stream.isatty()

    def update(self, done: int, note: str = "") -> None:
        self.done = done
        elapsed = time.monotonic() - self.start
        left = elapsed / done * (self.total - done) if done else float("nan")
        eta = "--:--" if not np.isfinite(left) else f"{int(left // 60):02d}:{int(left % 60):02d}"
        filled = int(self.width * done / self.total)
        bar = "#" * filled + "." * (self.width - filled)
        text = f"[{bar}] {done}/{self.total} {note} eta {eta}"
        if self.tty:
            self.stream.write("\r" + text.ljust(79))
            if done >= self.total:
                self.stream.write("\n")
        elif done == self.total or done % max(self.total // 10, 1) == 0:
            self.stream.write(text + "\n")
        self.stream.flush()

    def end_line(self) -> None:
        """End the bar's line on a terminal (before a question), so that the question
        starts a line of its own."""
        if self.tty and 0 < self.done < self.total:
            self.stream.write("\n")
            self.stream.flush()


class WallClock:
    """Real time: the clock of an acquisition on real devices, for its waits and for how
    long it took. A simulated run passes the simulated cell's clock instead
    (:class:`spherecal.sim.timeline.SimClock`: the same ``now_s``, ``wait`` and
    ``simulated``), so that its waits take simulated time and its duration is robot time."""

    simulated = False

    @property
    def now_s(self) -> float:
        return time.monotonic()

    def wait(self, seconds: float) -> None:
        time.sleep(seconds)


def robot_time_line(profiles: int, robot_time_s: float, simulated: bool) -> str:
    """``"40 profiles in 38.2 s of robot time (simulated), 62.8 profiles a minute"``: how
    fast an acquisition took its profiles (moves, settles and shots), in the clock's time."""
    rate = 60.0 * profiles / robot_time_s if robot_time_s > 0 else float("nan")
    clock = "simulated robot time" if simulated else "robot time (wall clock)"
    return f"{profiles} profiles in {robot_time_s:.1f} s of {clock}, {rate:.1f} profiles a minute"


@dataclass
class AcquisitionReport:
    taken: int = 0
    skipped: list[str] = field(default_factory=list)
    retakes: int = 0
    #: How long the acquisition took on its clock, s: every move, settle and shot from the
    #: first move to the last shot (on a wall clock, the operator's answers in step mode
    #: too; a simulated clock does not run while the operator thinks).
    robot_time_s: float = 0.0
    #: Whether ``robot_time_s`` is simulated time (a simulated cell's clock).
    simulated_time: bool = False

    def robot_time_line(self) -> str:
        """How fast the shots were taken (:func:`robot_time_line`)."""
        return robot_time_line(self.taken, self.robot_time_s, self.simulated_time)


def _poses_agree(a: Pose, b: Pose, acq: AcquisitionConfig) -> tuple[bool, float, float]:
    d = float(np.linalg.norm(a.translation - b.translation))
    ang = geo.rotation_angle_deg(a.rotation_matrix, b.rotation_matrix)
    return d <= acq.pose_agreement_mm and ang <= acq.pose_agreement_deg, d, ang


def _read_joints(robot) -> np.ndarray | None:
    try:
        return robot.read_joints_deg()
    except (NotImplementedError, AttributeError):
        return None


def take_shot(robot, sensor, acq: AcquisitionConfig, log: Callable[[str], None],
              wait: Callable[[float], None] = time.sleep) -> tuple[Pose, np.ndarray | None, Profile | None, int]:
    """Read pose, joints, profile, pose; re-take while the two poses disagree (after
    ``wait(acq.settle_s)``). Returns (pose, joints, profile or None, re-takes)."""
    for attempt in range(acq.retries_per_target + 1):
        before = robot.read_flange_pose()
        joints = _read_joints(robot)
        profile = sensor.read_profile()
        after = robot.read_flange_pose()
        ok, d, ang = _poses_agree(before, after, acq)
        if ok:
            return before, joints, profile, attempt
        log(f"  poses before and after the profile differ by {d:.3f} mm / {ang:.3f} deg: robot not settled; re-taking")
        if acq.settle_s:
            wait(acq.settle_s)
    raise DeviceError(
        f"the robot pose kept changing while the profile was taken ({acq.retries_per_target + 1} tries, "
        f"last difference {d:.3f} mm / {ang:.3f} deg): is the robot in position? Raise acquisition.settle_s"
    )


def move_and_shoot(robot, sensor, target: Target, acq: AcquisitionConfig, log: Callable[[str], None],
                   wait: Callable[[float], None] = time.sleep):
    """Move to ``target``, let the robot settle (``wait(acq.settle_s)``: real time, or a
    simulated clock's), take the shot (see :func:`take_shot`)."""
    robot.move_linear(target.pose, target.speed_mm_s)
    if acq.settle_s:
        wait(acq.settle_s)
    return take_shot(robot, sensor, acq, log, wait)


#: Largest change of any joint between two shots of one station (deg): a station's sweep
#: is a few short linear moves, so more means the arm reached the shot in another
#: configuration (a wrist or elbow flipped), with another robot error.
STATION_JOINT_JUMP_DEG = 90.0


def configuration_change(joints_deg, before_deg) -> str | None:
    """``"joint 4 moved 180.0 deg, joint 6 179.9 deg"`` when a joint of ``joints_deg`` is
    more than :data:`STATION_JOINT_JUMP_DEG` from ``before_deg`` (the angle's shortest
    way round), else None."""
    d = np.abs((np.asarray(joints_deg, float) - np.asarray(before_deg, float) + 180.0) % 360.0 - 180.0)
    jumped = np.flatnonzero(d > STATION_JOINT_JUMP_DEG)
    if not len(jumped):
        return None
    return ", ".join(f"joint {k + 1} {'moved ' if i == 0 else ''}{d[k]:.1f} deg" for i, k in enumerate(jumped))


#: Shots in a row that see nothing (no profile, or fewer points than a profile needs)
#: before the acquisition stops: the plan puts the line across the sphere on every
#: target, and the example plans see it on all of them (196 points or more), so a run of
#: blind shots means the plan and the cell disagree.
BLIND_SHOTS_IN_A_ROW = 3


class SensorBlindError(DeviceError):
    """The sensor saw nothing on several planned targets in a row: the acquisition stopped,
    the shots taken are in the journal."""


def _blind_stop(blind: list[tuple[Target, int]], min_points: int, done: int, total: int, acq: AcquisitionConfig,
                taken: int) -> SensorBlindError:
    """The stop after ``blind`` (target, points seen) in a row, naming the likely causes."""
    seen = ", ".join(f"{t.index} ({t.station}): {n} points" for t, n in blind)
    return SensorBlindError(
        f"the sensor saw nothing on {len(blind)} targets in a row where the plan puts the laser line across the "
        f"sphere (target {seen}; a profile needs {min_points}): the acquisition stopped after {done} of {total} "
        f"targets; the {taken} shots taken this run are kept in the journal. Likely causes: the nominal transform "
        "([nominal_transform] quaternion_wxyz is (w, x, y, z), w first: one written (x, y, z, w) turns the sensor "
        f"away), the sphere's position (acquisition.sphere_centre_mm = {list(acq.sphere_centre_mm)}), the mounting "
        "(eye_in_hand or eye_to_hand). A fixed configuration is a new plan: start it in a new output "
        "folder; --resume continues this plan only, after a fix of the cell itself (the sphere moved back, the "
        "sensor's cable or window)"
    )


def acquire(
    robot,
    sensor,
    targets: list[Target],
    writer: DatasetWriter,
    acq: AcquisitionConfig,
    done_targets: set[int] = frozenset(),
    on_observation: Callable[[Observation], None] | None = None,
    log: Callable[[str], None] = _LOG,
    progress: Progress | None = None,
    taken: Sequence[Observation] = (),
    min_points: int = 20,
    before_station: Callable[[str, list[Target]], None] | None = None,
    clock=None,
) -> AcquisitionReport:
    """Take every target not in ``done_targets``; each observation goes to the journal
    (flushed, fsync'ed by the writer) before the next move. ``before_station(station,
    targets)`` is called before the first move to each station with the station's targets
    still to take (step mode: it may ask the operator, and stop the run by raising; the
    journal keeps what was taken). ``taken``: the journal's
    observations of a resumed run. A shot whose joints show the arm in another
    configuration than the station's shot before it (:func:`configuration_change`; on a
    resume the arm comes from elsewhere and may take the other wrist solution) is kept
    and said as a warning: its robot error is not its station's. Raises
    :class:`SensorBlindError` after :data:`BLIND_SHOTS_IN_A_ROW` targets in a row see no
    profile or fewer than ``min_points`` points (those taken stay in the journal).
    ``clock`` (default :class:`WallClock`; a simulated run's ``cell.clock``) times the
    waits and gives ``robot_time_s``, the time from the first move to the last shot."""
    clock = clock if clock is not None else WallClock()
    report = AcquisitionReport(simulated_time=bool(getattr(clock, "simulated", False)))
    blind: list[tuple[Target, int]] = []
    todo = [t for t in targets if t.index not in done_targets]
    progress = progress or Progress(len(targets))
    progress.update(len(targets) - len(todo), "resumed" if done_targets else "")
    station_joints = {o.station: o.joints_deg for o in taken if o.joints_deg is not None}
    started = clock.now_s
    for k, t in enumerate(todo):
        n = len(targets) - len(todo) + 1 + k
        if before_station is not None and (k == 0 or todo[k - 1].station != t.station):
            progress.end_line()
            before_station(t.station, [u for u in todo[k:] if u.station == t.station])
        pose, joints, profile, retakes = move_and_shoot(robot, sensor, t, acq, log, clock.wait)
        report.robot_time_s = clock.now_s - started
        before = station_joints.get(t.station)
        if joints is not None and before is not None and (change := configuration_change(joints, before)):
            log(f"warning: target {t.index} (station {t.station}) was reached with the arm in another "
                f"configuration than the station's shot before it ({change}; now "
                f"{np.round(np.asarray(joints, float), 1).tolist()} deg): its robot error is not the station's. "
                "The shot is kept; for shots like the others, jog the arm back to the station's configuration "
                "and take the station again in a new run")
        if joints is not None:
            station_joints[t.station] = joints
        report.retakes += retakes
        if profile is None:
            report.skipped.append(f"target {t.index} (station {t.station}): the sensor saw nothing (sphere out of view?)")
        else:
            obs = Observation(
                index=writer.next_index,
                station=t.station,
                timestamp=datetime.now(timezone.utc),
                base_from_flange=pose,
                joints_deg=None if joints is None else tuple(float(v) for v in joints),
                profile=profile,
                target=t.index,
            )
            writer.append(obs)
            report.taken += 1
            if on_observation is not None:
                on_observation(obs)
        progress.update(n, t.station)
        seen = 0 if profile is None else len(profile)
        blind = blind + [(t, seen)] if seen < min_points else []
        if len(blind) >= BLIND_SHOTS_IN_A_ROW:
            raise _blind_stop(blind, min_points, n, len(targets), acq, report.taken)
    return report


def acquire_manual(
    robot,
    sensor,
    writer: DatasetWriter,
    acq: AcquisitionConfig,
    ask: Callable[[str], str] = input,
    log: Callable[[str], None] = _LOG,
    on_observation: Callable[[Observation], None] | None = None,
    rotation_tolerance_deg: float = 0.05,
    first_station: int = 1,
) -> AcquisitionReport:
    """The operator jogs the robot; each Enter captures a shot. Commands: Enter =
    capture, ``s`` = start a new station (new orientation), ``q`` = finish.
    Within a station only translations are allowed: a capture whose orientation differs
    from the station's first by more than ``rotation_tolerance_deg`` (the estimator's
    station tolerance) is refused with a message. Stations are labelled M1, M2, ...
    from ``first_station`` (a resumed session continues the numbering)."""
    report = AcquisitionReport()
    station_no = first_station
    first: Pose | None = None
    log("Manual acquisition: jog the robot so that the laser line crosses the sphere.\n"
        "  Enter: capture   s: new station (new orientation)   q: finish")
    while True:
        label = f"M{station_no}"
        try:
            cmd = ask(f"[{label}, {report.taken} taken] > ").strip().lower()
        except EOFError:
            cmd = "q"
        if cmd == "q":
            return report
        if cmd == "s":
            station_no += 1
            first = None
            continue
        if cmd:
            log(f"  unknown command {cmd!r}: Enter, s or q")
            continue
        pose, joints, profile, retakes = take_shot(robot, sensor, acq, log)
        report.retakes += retakes
        if first is not None:
            ang = geo.rotation_angle_deg(first.rotation_matrix, pose.rotation_matrix)
            if ang > rotation_tolerance_deg:
                log(f"  refused: orientation differs from the station's first shot by {ang:.3f} deg; "
                    "within a station jog by translations only, or press s to start a new station")
                continue
        if profile is None:
            log("  refused: the sensor saw nothing; move the line onto the sphere")
            report.skipped.append(f"{label}: empty profile")
            continue
        first = first or pose
        obs = Observation(
            index=writer.next_index, station=label, timestamp=datetime.now(timezone.utc), base_from_flange=pose,
            joints_deg=None if joints is None else tuple(float(v) for v in joints), profile=profile,
        )
        writer.append(obs)
        report.taken += 1
        log(f"  captured shot {obs.index}: {len(profile)} points")
        if on_observation is not None:
            on_observation(obs)
