"""On-the-fly acquisition: continuous sweeps at each station, the robot streaming its
pose and the sensor its profiles, each on its own clock (docs/on-the-fly.md, "Live
acquisition").

Planning (:func:`plan_sweeps`): at each station of the stop-and-go plan (its flange
orientation, and where in the field of view the sphere crosses the laser plane), straight
MoveL sweeps that carry the laser plane through the sphere, forth and back, at every speed
and along every direction of ``[acquisition.on_the_fly]`` (:class:`~spherecal.config.OnTheFlyPlan`),
planned from the nominal transform and the rough sphere centre. What they identify of the
clocks' relation is in docs/on-the-fly.md ("Identifiability").

Checking (:func:`sweep_targets`): every sweep becomes targets for the plan check every
move gets (:func:`spherecal.app.plan_checks.check_plan`): its start (reached at the
approach speed), points every :data:`SWEEP_CHECK_STEP_MM` along it and its end (at the
sweep's speed), so the workspace, the speeds, the reach along the path (the robot's
``check_target``, each point solved from the one before) and the keep-out check cover the
whole sweep. A sweep does not turn the flange, so its speed at the sensor is its speed.

Acquiring (:func:`acquire_sweeps`): per sweep, a stop-and-go move to its start, both
streams started, MoveL at the sweep's speed, both streams stopped, and the sweep's poses
and profiles appended to the stream-form journal (:class:`SweepJournal`, flushed and
fsync'ed per sweep, one line per finished sweep beside it with its counts). A stream that
fails during a sweep ends that sweep's data (what came before the fault is written; the
solve maps no profile outside the pose stream's samples) and stops the run after the move
(:class:`SweepStreamError`, naming the stream, the sweep and the counts).
"""

from __future__ import annotations

import json
import os
from dataclasses import dataclass, field, fields
from pathlib import Path
from typing import Callable

import numpy as np

from spherecal.config import AcquisitionConfig, SphereConfig, TransformConfig
from spherecal.core import geometry as geo
from spherecal.core.errors import DeviceError, InputError
from spherecal.core.models import MountingMode, Pose
from spherecal.core.streams import PoseStream, ProfileStream, SweepInfo
from spherecal.devices.contract import ProfileStreamError, ProfileStreamingSensor
from spherecal.devices.pose_streaming import PoseStreamError, PoseStreamingRobot
from spherecal.io.runlog import progress_log
from spherecal.io.stream_writer import RecordingWriter
from spherecal.motion.acquisition import Target, WallClock, robot_time_line
from spherecal.motion.planning import SweepPlan, plan_stations, sweep_ends_in_sensor_mm

__all__ = ["PlannedSweep", "SweepJournal", "SweepStreamError", "OnTheFlyReport", "acquire_sweeps",
           "check_streaming", "plan_sweeps", "sweep_streams", "sweep_targets"]

_LOG = progress_log("acquisition")

#: Spacing of the points checked along a sweep (reach, workspace, keep-out), mm.
SWEEP_CHECK_STEP_MM = 10.0
#: The pose stream must end with the arm at the sweep's end (the move returns in
#: position, and the stream is stopped after it): a last sample farther than this from
#: the end means the stream stopped before the move did, mm and deg.
STREAM_END_TOLERANCE_MM = 0.25
STREAM_END_TOLERANCE_DEG = 0.05
#: Where a plugin author reads how to stream (named in the refusal of a device that cannot).
ROBOT_STREAMING_GUIDE = 'docs/writing-a-robot-plugin.md, "Streaming the pose while the arm moves"'
SENSOR_STREAMING_GUIDE = 'docs/writing-a-sensor-plugin.md, "Streaming profiles"'


@dataclass(frozen=True)
class PlannedSweep:
    """One sweep: ``index`` into the recording's sweeps, its ``station``, the flange's
    ``start`` and ``end`` (``base_from_flange``, mm; one orientation), its speed at the
    tool point (mm/s) and ``info`` (the recording's :class:`SweepInfo`: station, speed,
    direction in base). ``back``: the return pass of a forth-and-back pair."""

    index: int
    station: str
    start: Pose
    end: Pose
    speed_mm_s: float
    info: SweepInfo
    back: bool

    @property
    def length_mm(self) -> float:
        return float(np.linalg.norm(self.end.translation - self.start.translation))

    @property
    def name(self) -> str:
        """``sweep 17 (station S3, back at 50 mm/s)``: the sweep's index, counted from 0 as
        in the journal (the profiles' ``sweep``, ``journal.sweeps.jsonl``)."""
        return (f"sweep {self.index} (station {self.station}, {'back' if self.back else 'forth'} at "
                f"{self.speed_mm_s:g} mm/s)")


def _flange_translation_mm(mounting: MountingMode, X: Pose, sphere_centre_mm, R_bf: np.ndarray,
                           centre_in_sensor_mm: np.ndarray) -> np.ndarray:
    """The flange translation (base, mm) that, with the flange rotation ``R_bf``, puts the
    sphere centre at ``centre_in_sensor_mm`` (..., 3) in the sensor frame, by the nominal
    transform ``X`` and the rough sphere centre."""
    R_x, t_x = X.rotation_matrix, X.translation
    c = np.asarray(centre_in_sensor_mm, dtype=float)
    sphere = np.asarray(sphere_centre_mm, dtype=float)
    if mounting == "eye_in_hand":  # base_from_sensor = base_from_flange X maps c to the sphere centre
        return sphere - c @ (R_bf @ R_x).T - R_bf @ t_x
    return c @ R_x.T + t_x - R_bf @ sphere  # the sphere on the flange, at X c in base


def plan_sweeps(acq: AcquisitionConfig, mounting: MountingMode, nominal: TransformConfig, sphere: SphereConfig,
                sweep: SweepPlan | None = None) -> list[PlannedSweep]:
    """The sweeps of ``acq.on_the_fly`` at the stations of ``acq.sweep`` (or ``sweep``),
    in order: per station, per direction, per speed, forth then back (the module's
    docstring). Each sweep crosses ``crossing_fraction`` radii of the sensor's x at full
    speed, with room for the ramps at ``acceleration_mm_s2`` beyond."""
    plan, otf = sweep or acq.sweep, acq.on_the_fly
    X = nominal.pose()
    R_ref = geo.matrix_from_quat_wxyz(acq.reference_flange_quaternion_wxyz)
    stations = plan_stations(mounting, X, acq.sphere_centre_mm, sphere.radius_mm, plan, R_ref)
    if otf.stations is not None:
        stations = stations[:otf.stations]
    sweeps: list[PlannedSweep] = []
    for k, (label, poses) in enumerate(stations):
        R_k = poses[0].rotation_matrix
        for d in otf.directions_in_sensor:
            ends = _flange_translation_mm(mounting, X, acq.sphere_centre_mm, R_k,
                                          sweep_ends_in_sensor_mm(plan, otf, sphere.radius_mm, k, d))
            direction = (ends[1] - ends[0]) / np.linalg.norm(ends[1] - ends[0])
            for v in otf.speeds_mm_s:
                for start, end, sign in ((ends[0], ends[1], 1.0), (ends[1], ends[0], -1.0)):
                    info = SweepInfo(station=label, speed_mm_s=float(v),
                                     direction=tuple(float(c) for c in sign * direction))
                    sweeps.append(PlannedSweep(len(sweeps), label, Pose.from_rt(R_k, start), Pose.from_rt(R_k, end),
                                               float(v), info, sign < 0))
    return sweeps


def sweep_targets(sweeps: list[PlannedSweep], approach_speed_mm_s: float) -> tuple[list[Target], dict[int, list[int]]]:
    """The sweeps as targets for the plan check (the module's docstring), and each
    sweep's target indices. A sweep that starts where the one before ends has no start
    target of its own. Targets are named ``station S1, sweep 3`` in the check's messages
    (the sweep's index, as in the journal)."""
    targets: list[Target] = []
    of_sweep: dict[int, list[int]] = {}
    previous: PlannedSweep | None = None
    for s in sweeps:
        label = f"{s.station}, sweep {s.index}"
        mine = of_sweep.setdefault(s.index, [])
        joined = previous is not None and np.allclose(previous.end.translation, s.start.translation, atol=1e-9) and \
            np.allclose(previous.end.rotation_matrix, s.start.rotation_matrix, atol=1e-12)
        if not joined:
            mine.append(len(targets))
            targets.append(Target(len(targets), label, s.start, True, approach_speed_mm_s))
        n = max(1, int(np.ceil(s.length_mm / SWEEP_CHECK_STEP_MM)))
        for u in np.arange(1, n + 1) / n:
            t = (1 - u) * s.start.translation + u * s.end.translation
            mine.append(len(targets))
            targets.append(Target(len(targets), label, Pose.from_rt(s.start.rotation_matrix, t), False, s.speed_mm_s))
        previous = s
    return targets, of_sweep


def check_streaming(robot, sensor, robot_type: str, sensor_type: str) -> None:
    """Refuse (InputError, before anything moves) a robot or a sensor that cannot stream,
    naming which and what to configure. A robot configured not to stream says what to
    configure when asked to start (the :class:`PoseStreamingRobot` contract): it is asked,
    which moves nothing."""
    problems = []
    if not isinstance(robot, PoseStreamingRobot):
        problems.append(f"robot type {robot_type!r} does not stream its pose (its plugin does not implement "
                        f"PoseStreamingRobot: {ROBOT_STREAMING_GUIDE}); use a robot type that does, or "
                        "mode = \"stop_and_go\"")
    elif not robot.can_stream_poses():
        try:
            robot.start_pose_stream()
        except DeviceError as exc:
            problems.append(f"robot type {robot_type!r} is not configured to stream its pose: {exc}")
        else:
            robot.stop_pose_stream()
            problems.append(f"robot type {robot_type!r} says it is not configured to stream its pose "
                            "(can_stream_poses() is False); configure its stream")
    if not isinstance(sensor, ProfileStreamingSensor):
        problems.append(f"sensor type {sensor_type!r} does not stream profiles (its plugin does not implement "
                        f"ProfileStreamingSensor: {SENSOR_STREAMING_GUIDE}); use a sensor type that does, or "
                        "mode = \"stop_and_go\"")
    if problems:
        raise InputError("[acquisition] mode = \"on_the_fly\" needs a robot that streams its pose and a sensor that "
                         "streams profiles; nothing was moved:\n  " + "\n  ".join(problems))


class SweepStreamError(DeviceError):
    """A stream failed during a sweep: the sweep's data ended at the fault (what came
    before it is in the journal) and the run stopped after the move. ``sweep`` the
    :class:`PlannedSweep`, ``stream`` ``"pose"`` or ``"profile"``, ``taken`` its
    :class:`SweepTaken`."""

    def __init__(self, message: str, sweep: PlannedSweep, stream: str, taken: "SweepTaken"):
        super().__init__(message)
        self.sweep, self.stream, self.taken = sweep, stream, taken


@dataclass
class SweepTaken:
    """What one sweep put into the journal: pose samples and profiles written, and the
    streams' counts (lost, late), the robot time it took (s, on the run's clock) and the
    fault that ended it, if one did."""

    sweep: int
    station: str
    pose_samples: int = 0
    pose_lost: int = 0
    pose_late: int = 0
    profiles: int = 0
    frames_lost: int = 0
    frames_late: int = 0
    robot_time_s: float = 0.0
    fault: str | None = None

    def text(self) -> str:
        return (f"{self.pose_samples} pose samples ({self.pose_lost} lost, {self.pose_late} late), {self.profiles} "
                f"profiles ({self.frames_lost} frames lost, {self.frames_late} late)")


@dataclass
class OnTheFlyReport:
    """What an on-the-fly acquisition took: the sweeps (:class:`SweepTaken`, this run's),
    the robot time from the first move to the last sweep's end on the run's clock, and
    whether it is simulated time."""

    sweeps: list[SweepTaken] = field(default_factory=list)
    robot_time_s: float = 0.0
    simulated_time: bool = False

    @classmethod
    def of_journal(cls, finished: dict[int, dict], simulated_time: bool) -> "OnTheFlyReport":
        """What the journal's finished sweeps took, over every run that added to it
        (``finished``: :meth:`SweepJournal.finished`): their counts, and the sum of their
        robot times (each from the end of the sweep before, its move to the start included)."""
        names = {f.name for f in fields(SweepTaken)}
        sweeps = [SweepTaken(**{k: v for k, v in row.items() if k in names}) for _, row in sorted(finished.items())]
        return cls(sweeps, float(sum(s.robot_time_s for s in sweeps)), simulated_time)

    @property
    def profiles(self) -> int:
        return sum(s.profiles for s in self.sweeps)

    def robot_time_line(self) -> str:
        return robot_time_line(self.profiles, self.robot_time_s, self.simulated_time)

    def losses_line(self) -> str:
        lost_p = sum(s.pose_lost for s in self.sweeps)
        lost_f = sum(s.frames_lost for s in self.sweeps)
        late_f = sum(s.frames_late for s in self.sweeps)
        hit = [f"{s.sweep}" for s in self.sweeps if s.pose_lost or s.frames_lost]
        where = f" (in sweeps {', '.join(hit)})" if hit else ""
        return (f"streams: {lost_p} pose samples lost, {lost_f} profile frames lost and {late_f} exposed late over "
                f"{len(self.sweeps)} sweeps{where}")


class SweepJournal:
    """The journal of an on-the-fly acquisition: the stream-form recording (a
    :class:`~spherecal.io.stream_writer.RecordingWriter`, new or reopened to append) and,
    beside it, one JSON line per finished sweep (``sweeps_path``) with its counts, written
    after the sweep's poses and profiles are on the disk. A sweep without its line is not
    finished: ``--resume`` takes it again (what it wrote before stays: poses and profiles
    at their own stamps)."""

    def __init__(self, writer: RecordingWriter, sweeps_path: Path, fsync: bool = True):
        self.writer = writer
        self.sweeps_path = Path(sweeps_path)
        self.fsync = fsync

    def add(self, sweep: PlannedSweep, poses: PoseStream | None, profiles: ProfileStream | None,
            taken: SweepTaken) -> None:
        """The sweep's poses, then its profiles (labelled with the sweep), then its line."""
        if poses is not None and poses.n:
            self.writer.add_poses(poses.t_robot_s, poses.t_mm, poses.quaternion_wxyz, poses.joints_deg, poses.seq)
        if profiles is not None and profiles.n:
            frame = profiles.frame if profiles.frame is not None else None
            self.writer.add_profiles(profiles.t_sensor_s, profiles.points_yz_mm, profiles.start, frame=frame,
                                     sweep=np.full(profiles.n, sweep.index, dtype=np.int64))
        if taken.fault is not None:
            return  # an unfinished sweep has no line: a resumed run takes it again
        line = json.dumps({"sweep": sweep.index, "station": sweep.station, "speed_mm_s": sweep.speed_mm_s,
                           **{k: v for k, v in vars(taken).items() if k not in ("sweep", "station", "fault")}})
        with open(self.sweeps_path, "a", encoding="utf-8") as fh:
            fh.write(line + "\n")
            fh.flush()
            if self.fsync:
                os.fsync(fh.fileno())

    @staticmethod
    def finished(sweeps_path: Path) -> dict[int, dict]:
        """The finished sweeps' lines by sweep index (a cut last line, from a kill while
        writing it, is not finished)."""
        done: dict[int, dict] = {}
        if not Path(sweeps_path).is_file():
            return done
        for raw in Path(sweeps_path).read_text(encoding="utf-8").splitlines():
            try:
                row = json.loads(raw)
            except ValueError:
                continue
            if isinstance(row, dict) and isinstance(row.get("sweep"), int):
                done[row["sweep"]] = row
        return done


def _stream_end_problem(poses: PoseStream | None, sweep: PlannedSweep) -> str | None:
    """Why the pose stream does not cover the move (its last sample is not at the sweep's
    end), or None."""
    if poses is None or poses.n == 0:
        return "no pose sample came"
    d = float(np.linalg.norm(poses.t_mm[-1] - sweep.end.translation))
    ang = geo.rotation_angle_deg(poses.R[-1], sweep.end.rotation_matrix)
    if d <= STREAM_END_TOLERANCE_MM and ang <= STREAM_END_TOLERANCE_DEG:
        return None
    return (f"its last sample shows the flange {d:.2f} mm and {ang:.3f} deg from the sweep's end, where the move "
            f"stopped: the stream ended before the move did (a stall)")


def sweep_streams(robot, sensor, sweep: PlannedSweep, rate_hz: float | None):
    """Both streams around the sweep's MoveL: (poses, profiles, faults), ``faults`` a list
    of (which stream, why).
    A stream that fails keeps what came before its fault; the other is stopped and kept.
    An error of the move itself is raised after both streams are stopped."""
    sensor.start_profile_stream(rate_hz)
    try:
        robot.start_pose_stream()
    except BaseException:
        try:
            sensor.stop_profile_stream()
        except DeviceError:
            pass
        raise
    moved: BaseException | None = None
    try:
        robot.move_linear(sweep.end, sweep.speed_mm_s)
    except BaseException as exc:  # stop both streams first; the move's error follows
        moved = exc
    faults: list[tuple[str, str]] = []
    try:
        poses = robot.stop_pose_stream()
    except PoseStreamError as exc:
        poses = exc.stream
        faults.append(("pose", f"{exc} ({exc.counts.text()})"))
    try:
        profiles = sensor.stop_profile_stream()
    except ProfileStreamError as exc:
        profiles = exc.taken
        faults.append(("profile", str(exc)))
    if moved is not None:
        raise moved
    if not faults and (problem := _stream_end_problem(poses, sweep)) is not None:
        faults.append(("pose", problem))
    return poses, profiles, faults


def acquire_sweeps(robot, sensor, sweeps: list[PlannedSweep], journal: SweepJournal, acq: AcquisitionConfig,
                   done: set[int] = frozenset(), log: Callable[[str], None] = _LOG, clock=None,
                   rate_hz: float | None = None) -> OnTheFlyReport:
    """Take every sweep not in ``done``, in order (the module's docstring): a stop-and-go
    move to its start (none when the arm ends the sweep before there), both streams on,
    MoveL at its speed, both streams off, the sweep into ``journal``. ``clock`` (default
    the wall clock; a simulated run's ``cell.clock``) gives the robot time. Raises
    :class:`SweepStreamError` after a sweep whose stream failed (its data written up to
    the fault, the sweep not marked finished)."""
    clock = clock if clock is not None else WallClock()
    report = OnTheFlyReport(simulated_time=bool(getattr(clock, "simulated", False)))
    todo = [s for s in sweeps if s.index not in done]
    at: Pose | None = None  # where the last sweep left the arm (planned)
    started = clock.now_s
    for s in todo:
        began = clock.now_s
        if at is None or not (np.allclose(at.translation, s.start.translation, atol=1e-9)
                              and np.allclose(at.rotation_matrix, s.start.rotation_matrix, atol=1e-12)):
            robot.move_linear(s.start, acq.approach_speed_mm_s)
            if acq.settle_s:
                clock.wait(acq.settle_s)
        try:
            poses, profiles, faults = sweep_streams(robot, sensor, s, rate_hz)
        except KeyboardInterrupt:  # Ctrl-C: the devices' own lines may follow; say which sweep it cut
            log(f"{s.name}: interrupted; none of its data is written (--resume takes it again)")
            raise
        at = s.end
        pc = robot.pose_stream_counts()
        fc = getattr(sensor, "profile_stream_counts", None)
        taken = SweepTaken(s.index, s.station, pose_samples=0 if poses is None else poses.n, pose_lost=pc.lost,
                           pose_late=pc.late, profiles=0 if profiles is None else profiles.n,
                           frames_lost=getattr(fc, "lost", 0), frames_late=getattr(fc, "late", 0),
                           robot_time_s=clock.now_s - began,
                           fault="; ".join(f"the {which} stream failed during the sweep: {why}"
                                           for which, why in faults) or None)
        journal.add(s, poses, profiles, taken)
        report.sweeps.append(taken)
        report.robot_time_s = clock.now_s - started
        log(f"{s.name}: {taken.text()}")
        if faults:
            which = faults[0][0]
            raise SweepStreamError(
                f"{s.name}: {taken.fault}. The sweep's data ends at the "
                f"fault ({taken.text()} written; no profile is mapped outside the pose stream's samples); the run "
                "stopped after the move, the journal kept: --resume takes this sweep again", s, which, taken)
    return report
