"""Scanning with the calibrated system: sweep an object, map every profile through the
calibrated transform into the frame the object is fixed in (base in eye-in-hand, flange
in eye-to-hand) and stream the points to a PLY file, profile by profile, so memory stays
bounded however long the scan."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

import numpy as np

from spherecal.core import geometry as geo
from spherecal.io.runlog import progress_log
from spherecal.motion.acquisition import Progress, Target, WallClock, move_and_shoot, robot_time_line, targets_from_poses
from spherecal.config import AcquisitionConfig, ScanConfig
from spherecal.core.errors import ConfigError
from spherecal.core.mapping import frame_from_sensor_stack, map_profile_list
from spherecal.core.models import SPHERE_FRAME, MountingMode, Pose
from spherecal.io.ply import PlyWriter
from spherecal.motion.planning import SweepPlan, plan_stations, site_offset_mm

_LOG = progress_log("scan")  # the default ``log``: logger spherecal.scan


def plan_scan(sc: ScanConfig, acq: AcquisitionConfig, mounting: MountingMode, X: Pose,
              field_of_view=None) -> list[Target]:
    """Parallel pure-translation passes over ``[scan] object_centre_mm``, with the
    calibrated transform ``X`` and the reference orientation and approach speed of
    ``acq``; a site's ``offset_percent`` is sized to ``field_of_view`` (the sensor's)."""
    R_ref = geo.matrix_from_quat_wxyz(acq.reference_flange_quaternion_wxyz)
    if sc.standoff_z_mm is None:
        raise ConfigError("scan.standoff_z_mm: not set, and the sensor type declares no field of view to take it "
                          "from; set it (sensor-frame z of the object's surface at the centre, mm)")
    n = int(round(sc.length_mm / sc.step_mm)) + 1
    targets: list[Target] = []
    offset = site_offset_mm(sc.site.offset_mm, sc.site.offset_percent, field_of_view, sc.standoff_z_mm, "scan.site")
    for j in range(sc.passes):
        dy = offset[0] + (j - (sc.passes - 1) / 2) * sc.pass_spacing_mm
        plan = SweepPlan(profiles_per_station=max(n, 4), sweep_fraction=0.5, lateral_amplitude_mm=0.0,
                         standoff_z_mm=sc.standoff_z_mm, station_offsets_mm=[(dy, offset[1])],
                         tilts_deg=[sc.site.tilt_deg])
        (_, poses), = plan_stations(mounting, X, sc.object_centre_mm, sc.length_mm, plan, R_ref)
        targets += targets_from_poses(poses, f"pass{j + 1}", len(targets), acq.approach_speed_mm_s, sc.speed_mm_s)
    return targets


@dataclass
class ScanSummary:
    profiles: int = 0
    points: int = 0
    empty_profiles: int = 0
    #: Why the calibration the points were mapped with is doubtful (its latest validation
    #: failed), or None.
    calibration_doubt: str | None = None
    #: What to do about it: the remedy of the cause its validation named, or None.
    calibration_remedy: str | None = None
    #: How long the scan took on its clock (moves, settles, shots), s, and whether that
    #: is simulated robot time (a simulated cell's clock) or the wall clock.
    robot_time_s: float = 0.0
    simulated_time: bool = False
    #: "stop_and_go" or "on_the_fly"; on the fly, the profiles streamed (``profiles``:
    #: those mapped), those not mapped by reason
    #: (:data:`spherecal.motion.scan_on_the_fly.UNMAPPED_REASONS`) and the pass journal.
    mode: str = "stop_and_go"
    streamed: int = 0
    unmapped: dict[str, int] = field(default_factory=dict)
    passes_journal: Path | None = None

    def robot_time_line(self) -> str:
        """How fast the profiles were taken (:func:`~spherecal.motion.acquisition.robot_time_line`)."""
        return robot_time_line(self.profiles + self.empty_profiles, self.robot_time_s, self.simulated_time)

    def unmapped_line(self) -> str:
        """The profiles not mapped, by reason, or that none was left out."""
        from spherecal.motion.scan_on_the_fly import UNMAPPED_REASONS

        if not self.unmapped:
            return "every profile that saw something was mapped"
        parts = ", ".join(f"{n} {UNMAPPED_REASONS.get(k, k)}" for k, n in self.unmapped.items())
        return f"{sum(self.unmapped.values())} profiles not mapped (never given a guessed pose): {parts}"


def scan(robot, sensor, targets: list[Target], X: Pose, acq: AcquisitionConfig, mounting: MountingMode,
         writer: PlyWriter, log: Callable[[str], None] = _LOG, progress: Progress | None = None,
         clock=None) -> ScanSummary:
    """Take every target (with the pose checks and retries of ``acq``) and append its
    points, mapped through ``X`` into the frame the object is fixed in, to ``writer``
    straight away. ``clock`` (default the wall clock; a simulated run's ``cell.clock``)
    times the waits and the scan's ``robot_time_s``."""
    frame = SPHERE_FRAME[mounting]
    clock = clock if clock is not None else WallClock()
    summary = ScanSummary(simulated_time=bool(getattr(clock, "simulated", False)))
    progress = progress or Progress(len(targets))
    started = clock.now_s
    for n, t in enumerate(targets, start=1):
        pose, _j, profile, _ = move_and_shoot(robot, sensor, t, acq, log, clock.wait)
        summary.robot_time_s = clock.now_s - started
        if profile is None:
            summary.empty_profiles += 1
        else:
            R, tt = frame_from_sensor_stack(mounting, pose.rotation_matrix[None], pose.translation[None], X, frame)
            pts, _ = map_profile_list(R, tt, [profile.points_mm])
            writer.write(pts, profile=np.full(len(pts), t.index, dtype=np.uint32))
            summary.profiles += 1
            summary.points += len(pts)
        progress.update(n, t.station)
    return summary
