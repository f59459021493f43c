"""``spherecal validate`` measuring as the scan does when it scans on the fly
(:func:`spherecal.app.scan_on_the_fly.scan_mode`): each validation sweep (the sphere's
views, the ball bar's balls, the flat) is one continuous pass at the scan's speed and
rate, both devices streaming, every profile given the pose at its exposure by the
calibration's clock relation, and the acceptance figures computed from those profiles and
poses as from stop-and-go shots (docs/on-the-fly.md, "Validating on the fly")."""

from __future__ import annotations

from dataclasses import dataclass
from datetime import datetime, timezone
from pathlib import Path
from typing import Callable

import numpy as np

from spherecal.app.plan_checks import ON_THE_FLY_SPEEDS, SCAN_SPEEDS
from spherecal.app.scan_on_the_fly import clock_relation
from spherecal.core.clock import ClockRelation
from spherecal.core.models import Observation, Profile
from spherecal.core.streams import SweepInfo
from spherecal.motion.acquisition import Target
from spherecal.motion.on_the_fly import PlannedSweep, sweep_targets
from spherecal.motion.scan_on_the_fly import PassCollector, scan_on_the_fly
from spherecal.motion.validation import Measured, Sweep

__all__ = ["OnTheFlyValidation", "validation_passes", "plan_on_the_fly", "measure_on_the_fly",
           "solve_calibration_recording"]


def validation_passes(sweeps: list[Sweep], speed_mm_s: float) -> list[PlannedSweep]:
    """Each validation sweep as one straight pass from its first target to its last at
    ``speed_mm_s``."""
    passes = []
    for k, sw in enumerate(sweeps):
        start, end = sw.targets[0].pose, sw.targets[-1].pose
        d = end.translation - start.translation
        info = SweepInfo(station=f"{sw.label}-{sw.kind}", speed_mm_s=float(speed_mm_s),
                         direction=tuple(float(c) for c in d / max(float(np.linalg.norm(d)), 1e-12)))
        passes.append(PlannedSweep(k, f"{sw.label}-{sw.kind}", start, end, float(speed_mm_s), info, False))
    return passes


@dataclass(frozen=True)
class OnTheFlyValidation:
    """The validation's passes on the fly (:func:`plan_on_the_fly`): the passes, the
    targets the plan check takes along them, their speed (mm/s), the clock relation
    their profiles are mapped with, and where their speeds are configured (for
    :func:`spherecal.app.plan_checks.check_plan`)."""

    passes: list[PlannedSweep]
    targets: list[Target]
    speed_mm_s: float
    relation: ClockRelation
    speed_keys: tuple[str, str]

    def describe(self) -> str:
        """``4 passes on the fly at 100 mm/s``."""
        return f"{len(self.passes)} passes on the fly at {self.speed_mm_s:g} mm/s"


def plan_on_the_fly(cfg, sweeps: list[Sweep], result, source: str, log: Callable[[str], None]) -> OnTheFlyValidation:
    """The passes of the validation ``sweeps`` (the scan's speed, else the calibration's
    slowest sweep) and their clock relation (the calibration's, or the scan's given
    ``clock_offset_ms``), before anything opens: InputError when there is none."""
    sc, acq = cfg.scan, cfg.acquisition
    speed = sc.speed_mm_s if sc is not None else min(acq.on_the_fly.speeds_mm_s)
    relation = clock_relation(sc.clock_offset_ms if sc is not None else None, result, source, log)
    passes = validation_passes(sweeps, speed)
    targets, _ = sweep_targets(passes, acq.approach_speed_mm_s)
    return OnTheFlyValidation(passes, targets, float(speed), relation,
                              SCAN_SPEEDS if sc is not None else ON_THE_FLY_SPEEDS)


def measure_on_the_fly(cfg, robot, sensor, sweeps: list[Sweep], plan: OnTheFlyValidation, writer,
                       log: Callable[[str], None], clock=None) -> list[Measured]:
    """Take every validation sweep on the fly as ``plan`` says (the module's docstring; the
    plan checked and both devices checked to stream by the caller) and give each its
    mapped profiles with their poses; every mapped profile goes to the validation's
    journal ``writer`` with its pose. The pass rules of
    :func:`spherecal.motion.scan_on_the_fly.scan_on_the_fly` hold (nothing mapped outside
    the pose samples; a fault stops the run)."""
    sc, acq, passes = cfg.scan, cfg.acquisition, plan.passes
    log(f"validating on the fly: {len(passes)} passes at {plan.speed_mm_s:g} mm/s, mapped with "
        f"{plan.relation.source}")
    collector = PassCollector(plan.relation, sc.max_timing_error_mm if sc is not None else 0.1)
    report = scan_on_the_fly(robot, sensor, passes, collector, acq, log, clock=clock,
                             rate_hz=sc.rate_hz if sc is not None else None)
    log(f"validation on the fly: {report.robot_time_line()}")
    measured = []
    for p, sw in zip(passes, sweeps):
        poses, profiles = collector.poses.get(p.index, []), collector.profiles.get(p.index, [])
        for pose, pts in zip(poses, profiles):
            writer.append(Observation(index=writer.next_index, station=p.station, timestamp=datetime.now(timezone.utc),
                                      base_from_flange=pose, profile=Profile.from_points(pts)))
        measured.append(Measured(sw, list(poses), list(profiles)))
    return measured


def solve_calibration_recording(journal: Path, options, arm):
    """The on-the-fly calibration's journal (a stream recording) solved again as
    ``calibrate`` solved it (its clock relation; ``arm``, the robot's kinematics, used when
    the recording has joints), for the report's figures of the calibration."""
    from spherecal.estimation.on_the_fly import solve_recording
    from spherecal.io.streams import read_recording

    recording = read_recording(journal)
    return solve_recording(recording, options, kinematics=arm if recording.poses.joints_deg is not None else None)
