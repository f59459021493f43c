"""Scanning on the fly: continuous passes over the scan region, the robot streaming its
pose and the sensor its profiles, every profile mapped through the flange pose at its
exposure (docs/on-the-fly.md, "Scanning on the fly").

Planning (:func:`plan_passes`): the stop-and-go scan plan's passes
(:func:`spherecal.motion.scanning.plan_scan`), each made one straight MoveL from its first
target to its last at ``[scan] speed_mm_s``, every other pass run backwards so that a pass
starts where the one before ended, beside it. They are checked as calibrate's sweeps are
(:func:`spherecal.motion.on_the_fly.sweep_targets`: the start, points every 10 mm and the
end through the plan check).

Mapping (:func:`map_pass`): a profile stamped ``t_sensor`` (sensor clock) was exposed at
robot time ``t_robot`` by the calibration's :class:`~spherecal.core.clock.ClockRelation`;
its flange pose is the pose stream's there (:meth:`spherecal.core.streams.PoseStream.at`:
between the two samples around it, never across a gap). A profile is **not mapped** (it is
counted, with its reason, :data:`UNMAPPED_REASONS`) when its exposure lies before the pose
stream's first sample, after its last, or in a gap; when its stamp is off the frame grid
of the pass (:func:`off_frame_grid`: the sensor's clock stepped, so its stamp no longer
says when it was exposed); or when there is no pose stream at all. A pass whose clock
relation is too uncertain for its speed (``max_timing_error_mm``) is not mapped at all.

Acquiring (:func:`scan_on_the_fly`): per pass, a stop-and-go move to its start (none when
the pass before ended there), both streams on, MoveL at the pass's speed, both off; the
pass's mapped points go to the PLY and one line with its counts to the pass journal
(``scan.passes.jsonl``), flushed and fsync'ed, before the next pass moves. A stream that
fails during a pass ends it (what is bracketed by the samples before the fault is mapped)
and stops the scan after the move (:class:`ScanStreamError`).
"""

from __future__ import annotations

import json
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

import numpy as np

from spherecal.config import AcquisitionConfig
from spherecal.core.clock import ClockRelation
from spherecal.core.errors import DeviceError
from spherecal.core.mapping import frame_from_sensor_stack, map_profile_list
from spherecal.core.models import SPHERE_FRAME, MountingMode, Pose
from spherecal.core.streams import PoseStream, ProfileStream, SweepInfo
from spherecal.io.runlog import progress_log
from spherecal.motion.acquisition import Target, WallClock, robot_time_line
from spherecal.motion.on_the_fly import PlannedSweep, sweep_streams

__all__ = ["ClockRelationLost", "GRID_TOLERANCE_PERIODS", "LATE_RUN_FRAMES", "UNMAPPED_REASONS", "PassCollector", "PassMapper", "PassMapping", "PassTaken",
           "ScanOnTheFlyReport", "ScanStreamError", "TimingTooUncertain", "map_pass", "off_frame_grid",
           "plan_passes", "scan_on_the_fly"]

_LOG = progress_log("scan")

#: A stamp further than this many frame periods from the pass's frame grid is off it.
GRID_TOLERANCE_PERIODS = 0.1
#: Frames off the grid that come back to it within this many frames were exposed late
#: (a slipped trigger: their stamps say when) and are mapped; a longer run, or one that
#: does not come back before the pass ends, is a step of the sensor's clock.
LATE_RUN_FRAMES = 8
#: Why a profile was not mapped, in words (keys as in the pass journal).
UNMAPPED_REASONS = {
    "before": "exposed before the pose stream's first sample",
    "after": "exposed after the pose stream's last sample (or its fault)",
    "gap": "exposed in a gap of the pose stream",
    "off_grid": "stamped off the pass's frame grid (the sensor's clock stepped)",
    "no_poses": "no pose stream came",
    "timing": "the clock relation too uncertain at the pass's speed (max_timing_error_mm)",
}


def plan_passes(targets: list[Target], speed_mm_s: float) -> list[PlannedSweep]:
    """The passes of a stop-and-go scan plan (its targets grouped by pass) as straight
    sweeps at ``speed_mm_s`` from each pass's first target to its last, every other one
    backwards (the module's docstring)."""
    passes: list[PlannedSweep] = []
    for j, label in enumerate(dict.fromkeys(t.station for t in targets)):
        mine = [t for t in targets if t.station == label]
        first, last = mine[0].pose, mine[-1].pose
        back = j % 2 == 1
        start, end = (last, first) if back else (first, last)
        d = end.translation - start.translation
        info = SweepInfo(station=label, speed_mm_s=float(speed_mm_s),
                         direction=tuple(float(c) for c in d / max(float(np.linalg.norm(d)), 1e-12)))
        passes.append(PlannedSweep(j, label, start, end, float(speed_mm_s), info, back))
    return passes


def pass_name(p: PlannedSweep) -> str:
    return f"pass {p.index + 1} ({'back' if p.back else 'forth'} at {p.speed_mm_s:g} mm/s)"


def off_frame_grid(t_sensor_s: np.ndarray, frame: np.ndarray | None,
                   tolerance_periods: float = GRID_TOLERANCE_PERIODS,
                   late_run_frames: int = LATE_RUN_FRAMES) -> np.ndarray:
    """Which profiles of one stream are stamped off its frame grid (bool (m,)).

    The sensor exposes frame k at its first frame's time plus k periods of its own clock
    and stamps it by that clock, so within one stream each stamp step is the frame
    counter's step times the period (lost frames keep it). A step away from that by more
    than ``tolerance_periods`` periods starts a run off the grid of the stream's first
    frame: a run that comes back within ``late_run_frames`` frames is frames exposed late
    (their stamps say when: kept); one that does not, or that the stream ends in, is a
    step of the sensor's clock, and every profile from its start on is off the grid.
    Without frame counters (None), nothing can be told: all False."""
    t = np.asarray(t_sensor_s, dtype=float)
    m = len(t)
    off = np.zeros(m, dtype=bool)
    if frame is None or m < 2:
        return off
    df = np.diff(np.asarray(frame, dtype=np.int64)).astype(float)
    dt = np.diff(t)
    good = df > 0
    if not np.any(good):
        return off
    period = float(np.median(dt[good] / df[good]))
    tol = tolerance_periods * period
    step = dt - df * period
    step[np.abs(step) <= tol] = 0.0  # jitter within the tolerance does not add up
    drift_from_grid = np.concatenate([[0.0], np.cumsum(step)])
    away = np.abs(drift_from_grid) > tol
    j = 1
    while j < m:
        if not away[j]:
            j += 1
            continue
        k = j
        while k < m and away[k]:
            k += 1
        if k < m and k - j <= late_run_frames:
            j = k  # back on the grid: exposed late, stamped when
            continue
        off[j:] = True  # the clock stepped: nothing after it is on the time line the relation knows
        break
    return off


@dataclass
class PassMapping:
    """What :func:`map_pass` made of one pass: per profile ``reason`` ("" mapped, "empty"
    (nothing seen), or a key of :data:`UNMAPPED_REASONS`), ``t_robot_s`` the robot time
    of each exposure, the mapped profiles' indices ``mapped`` (into the pass's profile
    stream) with their flange poses ``R`` (n, 3, 3) and ``t_mm`` (n, 3)
    (``base_from_flange``), and ``timing_error_mm`` the largest position error the clock
    relation's uncertainty gives a mapped profile (k = 2, at the flange's speed; None:
    not known)."""

    reason: np.ndarray
    t_robot_s: np.ndarray
    mapped: np.ndarray
    R: np.ndarray
    t_mm: np.ndarray
    timing_error_mm: float | None

    def counts(self) -> dict[str, int]:
        keys, n = np.unique(self.reason[self.reason != ""], return_counts=True)
        return {str(k): int(c) for k, c in zip(keys, n)}


def map_pass(poses: PoseStream | None, profiles: ProfileStream, relation: ClockRelation) -> PassMapping:
    """The pose of every profile of one pass (the module's docstring): interpolated in the
    pose stream at the robot time of its exposure, or the reason it has none."""
    m = profiles.n
    t_robot = relation.robot_time(profiles.t_sensor_s)
    reason = np.full(m, "", dtype=object)
    R, t_mm = np.zeros((m, 3, 3)), np.zeros((m, 3))
    speed = np.zeros(m)
    if poses is None:
        reason[:] = "no_poses"
    elif m:
        at = poses.at(t_robot)
        R, t_mm, speed = at.R, at.t, np.linalg.norm(at.v_mm_s, axis=1)
        ts = poses.t_robot_s
        reason[~at.ok] = "gap"
        reason[t_robot < ts[0]] = "before"
        reason[t_robot > ts[-1]] = "after"
    grid = off_frame_grid(profiles.t_sensor_s, profiles.frame)
    reason[(reason == "") & grid] = "off_grid"
    reason[(reason == "") & (profiles.counts == 0)] = "empty"
    mapped = np.flatnonzero(reason == "")
    err = None
    std = relation.std_s(profiles.t_sensor_s[mapped]) if len(mapped) else None
    if std is not None:
        err = float(np.max(2.0 * std * speed[mapped]))
    return PassMapping(reason.astype(str), t_robot, mapped, R[mapped], t_mm[mapped], err)


@dataclass
class PassTaken:
    """One pass: its streams' counts (pose samples received and lost, profiles received,
    frames lost and late), what was mapped (profiles, points, empty ones) and why the rest
    was not (``unmapped``: reason -> count), the clock relation's position error on it
    (k = 2, mm; None: not known), its robot time (s, with the move to its start) and the
    time both streams ran (``streaming_s``), and the fault that ended it."""

    index: int
    label: str
    speed_mm_s: float
    pose_samples: int = 0
    pose_lost: int = 0
    profiles: int = 0
    frames_lost: int = 0
    frames_late: int = 0
    mapped: int = 0
    points: int = 0
    empty: int = 0
    unmapped: dict[str, int] = field(default_factory=dict)
    timing_error_k2_mm: float | None = None
    robot_time_s: float = 0.0
    streaming_s: float = 0.0
    fault: str | None = None

    def text(self) -> str:
        left = ", ".join(f"{n} {UNMAPPED_REASONS[k]}" for k, n in self.unmapped.items()) or "none"
        timing = "" if self.timing_error_k2_mm is None else f"; clock relation {self.timing_error_k2_mm:.4f} mm (k = 2)"
        return (f"{self.profiles} profiles ({self.frames_lost} frames lost, {self.frames_late} late), "
                f"{self.pose_samples} pose samples ({self.pose_lost} lost): {self.mapped} mapped ({self.points} "
                f"points), {self.empty} saw nothing; not mapped: {left}{timing}")


class TimingTooUncertain(DeviceError):
    """A pass's clock relation is too uncertain for its speed: nothing of it was mapped."""


class ClockRelationLost(DeviceError):
    """The clock relation no longer holds: the sensor's clock stepped during a pass (the
    profiles after the step are not mapped; a later pass's stamps would all be off), or
    most of a pass's profiles fall outside its pose stream, which ran over the same move
    (a clock restarted, wrapped or stepped since the calibration)."""


#: More than this share of a pass's profiles outside its pose stream's samples means the
#: clock relation does not hold (both streams run over the same move).
LOST_RELATION_SHARE = 0.5


class ScanStreamError(DeviceError):
    """A stream failed during a pass: the pass's profiles bracketed by pose samples before
    the fault are in the PLY, the scan stopped after the move. ``taken`` the pass's
    :class:`PassTaken`, ``stream`` ``"pose"`` or ``"profile"``."""

    def __init__(self, message: str, taken: PassTaken, stream: str):
        super().__init__(message)
        self.taken, self.stream = taken, stream


class PassMapper:
    """Maps each pass (:func:`map_pass`) through the calibrated ``X`` into the frame the
    object is fixed in, appends its points to ``writer`` (a PLY writer, each point with
    the scan-wide index of its profile) and one JSON line with its :class:`PassTaken` to
    ``journal_path`` (flushed and fsync'ed): a kill loses no finished pass."""

    def __init__(self, X: Pose, mounting: MountingMode, relation: ClockRelation, writer, journal_path: Path,
                 max_timing_error_mm: float, fsync: bool = True):
        self.X, self.mounting, self.relation, self.writer = X, mounting, relation, writer
        self.journal_path = Path(journal_path) if journal_path is not None else None
        self.max_timing_error_mm, self.fsync = max_timing_error_mm, fsync
        self.next_profile = 0

    def add(self, p: PlannedSweep, poses: PoseStream | None, profiles: ProfileStream | None,
            taken: PassTaken) -> PassMapping | None:
        if profiles is not None and profiles.n:
            mapping = map_pass(poses, profiles, self.relation)
            taken.timing_error_k2_mm = mapping.timing_error_mm
            counts = mapping.counts()
            taken.empty = counts.pop("empty", 0)
            too_uncertain = mapping.timing_error_mm is not None and mapping.timing_error_mm > self.max_timing_error_mm
            if too_uncertain:
                counts = {**counts, "timing": len(mapping.mapped)}
            else:
                self._write(mapping, profiles, taken)
            taken.unmapped = counts
            self.next_profile += profiles.n
        else:
            mapping = None
        self._journal(taken)
        return mapping

    def _write(self, mapping: PassMapping, profiles: ProfileStream, taken: PassTaken) -> None:
        if not len(mapping.mapped):
            return
        frame = SPHERE_FRAME[self.mounting]
        R, t = frame_from_sensor_stack(self.mounting, mapping.R, mapping.t_mm, self.X, frame)
        pts, shot = map_profile_list(R, t, [profiles.profile(int(j)) for j in mapping.mapped])
        self.writer.write(pts, profile=(self.next_profile + mapping.mapped[shot]).astype(np.uint32))
        taken.mapped, taken.points = len(mapping.mapped), len(pts)

    def _journal(self, taken: PassTaken) -> None:
        with open(self.journal_path, "a", encoding="utf-8") as fh:
            fh.write(json.dumps(vars(taken)) + "\n")
            fh.flush()
            if self.fsync:
                os.fsync(fh.fileno())


class PassCollector(PassMapper):
    """A :class:`PassMapper` that keeps each pass's mapped profiles (``poses[index]``:
    ``base_from_flange`` per profile, ``profiles[index]``: its (y, z) points) instead of
    writing them: for validation on the fly, whose figures are computed from the
    sweeps' profiles and poses. Nothing is written (``journal_path`` None)."""

    def __init__(self, relation: ClockRelation, max_timing_error_mm: float):
        super().__init__(Pose.identity(), "eye_in_hand", relation, None, None, max_timing_error_mm)
        self.poses: dict[int, list[Pose]] = {}
        self.profiles: dict[int, list[np.ndarray]] = {}
        self._pass: int | None = None

    def add(self, p: PlannedSweep, poses, profiles, taken: PassTaken):
        self._pass = p.index
        self.poses.setdefault(p.index, [])
        self.profiles.setdefault(p.index, [])
        return super().add(p, poses, profiles, taken)

    def _write(self, mapping: PassMapping, profiles: ProfileStream, taken: PassTaken) -> None:
        for k, j in enumerate(mapping.mapped):
            self.poses[self._pass].append(Pose.from_rt(mapping.R[k], mapping.t_mm[k]))
            self.profiles[self._pass].append(profiles.profile(int(j)))
        taken.mapped, taken.points = len(mapping.mapped), int(profiles.counts[mapping.mapped].sum())

    def _journal(self, taken: PassTaken) -> None:
        return None


@dataclass
class ScanOnTheFlyReport:
    """The passes taken (:class:`PassTaken`), the robot time from the first move to the
    last pass's end on the run's clock, and whether it is simulated time."""

    passes: list[PassTaken] = field(default_factory=list)
    robot_time_s: float = 0.0
    simulated_time: bool = False

    @property
    def profiles(self) -> int:
        return sum(p.profiles for p in self.passes)

    @property
    def mapped(self) -> int:
        return sum(p.mapped for p in self.passes)

    @property
    def points(self) -> int:
        return sum(p.points for p in self.passes)

    @property
    def streaming_s(self) -> float:
        return sum(p.streaming_s for p in self.passes)

    def unmapped(self) -> dict[str, int]:
        total: dict[str, int] = {}
        for p in self.passes:
            for k, n in p.unmapped.items():
                total[k] = total.get(k, 0) + n
        return total

    def robot_time_line(self) -> str:
        per_s = self.profiles / self.robot_time_s if self.robot_time_s > 0 else float("nan")
        streaming = self.profiles / self.streaming_s if self.streaming_s > 0 else float("nan")
        return (f"{robot_time_line(self.profiles, self.robot_time_s, self.simulated_time)} ({per_s:.1f} a second; "
                f"{streaming:.1f} a second while streaming, {self.streaming_s:.1f} s)")


def scan_on_the_fly(robot, sensor, passes: list[PlannedSweep], mapper: PassMapper, acq: AcquisitionConfig,
                    log: Callable[[str], None] = _LOG, clock=None, rate_hz: float | None = None) -> ScanOnTheFlyReport:
    """Take every pass (the module's docstring), mapping each into the PLY before the
    next moves. Raises :class:`ScanStreamError` after a pass whose stream failed,
    :class:`ClockRelationLost` after one whose profiles mostly fall outside its pose
    stream, and :class:`TimingTooUncertain` after one the clock relation cannot map at its
    speed."""
    clock = clock if clock is not None else WallClock()
    report = ScanOnTheFlyReport(simulated_time=bool(getattr(clock, "simulated", False)))
    at: Pose | None = None
    started = clock.now_s
    for p in passes:
        began = clock.now_s
        if at is None or not (np.allclose(at.translation, p.start.translation, atol=1e-9)
                              and np.allclose(at.rotation_matrix, p.start.rotation_matrix, atol=1e-12)):
            robot.move_linear(p.start, acq.approach_speed_mm_s)
            if acq.settle_s:
                clock.wait(acq.settle_s)
        streaming = clock.now_s
        poses, profiles, faults = sweep_streams(robot, sensor, p, rate_hz)
        streaming = clock.now_s - streaming
        at = p.end
        pc = robot.pose_stream_counts()
        fc = getattr(sensor, "profile_stream_counts", None)
        taken = PassTaken(p.index, p.station, p.speed_mm_s, pose_samples=0 if poses is None else poses.n,
                          pose_lost=pc.lost, profiles=0 if profiles is None else profiles.n,
                          frames_lost=getattr(fc, "lost", 0), frames_late=getattr(fc, "late", 0),
                          robot_time_s=clock.now_s - began, streaming_s=streaming,
                          fault="; ".join(f"the {which} stream failed during the pass: {why}"
                                          for which, why in faults) or None)
        mapper.add(p, poses, profiles, taken)
        report.passes.append(taken)
        report.robot_time_s = clock.now_s - started
        log(f"{pass_name(p)}: {taken.text()}")
        if faults:
            raise ScanStreamError(
                f"{pass_name(p)}: {taken.fault}. The pass ends at the fault: {taken.mapped} profiles bracketed by pose "
                f"samples before it are in the PLY, none after it is mapped; the scan stopped after the move",
                taken, faults[0][0])
        if taken.unmapped.get("off_grid"):
            raise ClockRelationLost(
                f"{pass_name(p)}: the sensor's clock stepped during the pass: {taken.unmapped['off_grid']} profiles "
                "stamped after the step are off the pass's frame grid and were not mapped; the clock relation "
                f"({mapper.relation.source}) no longer holds for the sensor's stamps, so the scan stopped after the "
                "pass. Calibrate on the fly again")
        outside = taken.unmapped.get("before", 0) + taken.unmapped.get("after", 0)
        if taken.profiles >= 10 and outside > LOST_RELATION_SHARE * taken.profiles:
            raise ClockRelationLost(
                f"{pass_name(p)}: {outside} of its {taken.profiles} profiles fall outside its pose stream's samples, "
                f"though both streams ran over the same move: the clock relation ({mapper.relation.source}) does not "
                "hold for these clocks (one was restarted, wrapped or stepped since the calibration). None of them was "
                "mapped; the scan stopped. Calibrate on the fly again with the devices as they are now")
        if "timing" in taken.unmapped:
            raise TimingTooUncertain(
                f"{pass_name(p)}: the clock relation ({mapper.relation.source}) gives its profiles up to "
                f"{taken.timing_error_k2_mm:.3f} mm of position error (k = 2, at the flange's speed), beyond "
                f"[scan] max_timing_error_mm = {mapper.max_timing_error_mm:g}: nothing of the pass was mapped and "
                "the scan stopped. The relation's uncertainty grows with the time since the calibration (its drift's): "
                "calibrate on the fly again, scan slower, or accept more error (max_timing_error_mm)")
    return report
