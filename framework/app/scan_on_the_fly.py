"""``spherecal scan`` on the fly (``[scan] mode``, or ``[acquisition] mode = "on_the_fly"``):
the scan plan's passes as continuous sweeps, checked as any move is, both devices
streaming, every profile mapped through the pose at its exposure by the calibration's
clock relation and streamed into the PLY pass by pass (docs/on-the-fly.md, "Scanning on
the fly")."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Callable

from spherecal.app.calibrate_on_the_fly import RESUME_GAP_S
from spherecal.app.cell import make_cell
from spherecal.app.outputs import STREAM_JOURNAL_NAME
from spherecal.app.plan_checks import SCAN_SPEEDS, SCAN_KEEP_OUT_FIX, check_plan, confirm_motion, keep_out_for
from spherecal.app.plugin_host import in_file, open_devices, robot_arm
from spherecal.config import LoadedConfig
from spherecal.core.clock import ClockRelation
from spherecal.core.errors import ConfigError, DatasetFileError, InputError
from spherecal.core.models import SPHERE_FRAME
from spherecal.io.ply import PlyWriter
from spherecal.io.runlog import Notice
from spherecal.motion.on_the_fly import check_streaming, sweep_targets
from spherecal.motion.scan_on_the_fly import PassMapper, ScanOnTheFlyReport, plan_passes, scan_on_the_fly
from spherecal.motion.scanning import plan_scan

#: The journal of an on-the-fly scan's passes, beside its PLY: ``<ply>.passes.jsonl``.
PASSES_SUFFIX = ".passes.jsonl"


def scan_mode(cfg) -> str:
    """``[scan] mode``, or by default ``on_the_fly`` when ``[acquisition] mode`` is."""
    if cfg.scan is not None and cfg.scan.mode is not None:
        return cfg.scan.mode
    acq = cfg.acquisition
    return "on_the_fly" if acq is not None and acq.mode == "on_the_fly" else "stop_and_go"


def clock_relation(given_offset_ms: float | None, result, result_path: Path,
                   log: Callable[[str], None]) -> ClockRelation:
    """The clock relation profiles are mapped with: the calibration's ``timing``, or the
    offset ``[scan] clock_offset_ms`` gives (``given_offset_ms``) for a calibration
    without one (said loudly). InputError naming why when there is neither; ConfigError
    when both."""
    timing = result.timing if result is not None else None
    if timing is not None:
        if given_offset_ms is not None:
            raise ConfigError(f"scan.clock_offset_ms: {result_path} has its own clock relation (estimated with the "
                              "transform, with its uncertainty); remove clock_offset_ms")
        relation = ClockRelation.from_timing(timing, f"the calibration's timing in {result_path}")
        if timing.poses_assumed:
            log(Notice(f"note: the calibration's poses were computed, not measured: {timing.poses_assumed}"))
        return relation
    if given_offset_ms is None:
        raise InputError(
            f"{result_path} holds no clock relation (no 'timing': a stop-and-go calibration): the time between the "
            "sensor's stamps and the robot's is unknown, so no profile taken on the fly can be given the pose it was "
            "taken at; nothing was moved. Calibrate on the fly ([acquisition] mode = \"on_the_fly\"), scan "
            "stop-and-go ([scan] mode = \"stop_and_go\"), or, only when the offset is known (both devices stamping "
            "one synchronised clock), give it as [scan] clock_offset_ms")
    offset = float(given_offset_ms)
    log(Notice(f"WARNING: scanning on the fly with a clock offset GIVEN in [scan] clock_offset_ms = {offset:g} ms, not "
               "estimated: no drift, no uncertainty; any error in it moves every point along its pass by speed x "
               "error, and nothing in the scan can see it"))
    return ClockRelation(offset * 1e-3, 0.0, 0.0, None, None, 0.0,
                         f"[scan] clock_offset_ms = {offset:g} ms, GIVEN, not estimated")


@dataclass
class OnTheFlyScan:
    """What :func:`run_scan_on_the_fly` hands back to ``run_scan``: the passes' report, the
    pass journal and the clock relation used."""

    report: ScanOnTheFlyReport
    journal: Path
    relation: ClockRelation


def run_scan_on_the_fly(loaded: LoadedConfig, host, fov, out: Path, result_path: Path, result, ply_path: Path,
                        log: Callable[[str], None], yes: bool, ask: Callable[[str], str]) -> OnTheFlyScan:
    """Plan, check, confirm and take the passes (the module's docstring). Refuses, before
    anything moves, a calibration without a clock relation (:func:`clock_relation`), a
    pass that breaks a limit, and devices that cannot stream."""
    cfg = loaded.config
    sc, acq = cfg.scan, cfg.acquisition
    relation = clock_relation(sc.clock_offset_ms, result, result_path, log)
    passes = plan_passes(plan_scan(sc, acq, cfg.mounting, result.transform, fov), sc.speed_mm_s)
    targets, _ = sweep_targets(passes, acq.approach_speed_mm_s)
    log(f"plan: {len(passes)} passes on the fly at {sc.speed_mm_s:g} mm/s, {sum(p.length_mm for p in passes):.0f} mm; "
        f"every pass checked at {len(targets)} points")
    keep_out = in_file(loaded, keep_out_for, cfg, host, result.transform, SCAN_KEEP_OUT_FIX, log, fov)
    check_plan(targets, acq, "scan plan", keep_out=keep_out, log=log, speed_keys=SCAN_SPEEDS)
    journal = ply_path.with_name(ply_path.name + PASSES_SUFFIX)
    for path in (ply_path, journal):
        if path.exists():
            raise InputError(f"{path} exists; remove it or set [scan] ply to another name (nothing is overwritten)")
    cell = make_cell(cfg, robot_arm(loaded, host), fov)
    if cell is None:
        confirm_motion("scan", f"{len(passes)} passes on the fly at {sc.speed_mm_s:g} mm/s", yes, ask, log)
    else:
        _after_the_calibration(out, cell)
    out.mkdir(parents=True, exist_ok=True)
    log(f"scan: on the fly into {ply_path}, mapped with {relation.source}")
    frame = SPHERE_FRAME[cfg.mounting]
    comments = (f"spherecal scan on the fly, {result.transform_name} from {result_path}",
                f"clock relation: {relation.source}")
    with open_devices(loaded, host, cell, log) as (robot, sensor):
        check_streaming(robot, sensor, cfg.robot["type"], cfg.sensor["type"])
        check_plan(targets, acq, "scan plan", robot=robot, keep_out=keep_out, log=log, speed_keys=SCAN_SPEEDS)
        with PlyWriter(ply_path, format=sc.format, with_profile=True, frame=frame, comments=comments) as writer:
            mapper = PassMapper(result.transform, cfg.mounting, relation, writer, journal, sc.max_timing_error_mm)
            report = scan_on_the_fly(robot, sensor, passes, mapper, acq, log,
                                     clock=cell.clock if cell is not None else None, rate_hz=sc.rate_hz)
    return OnTheFlyScan(report, journal, relation)


def _after_the_calibration(out: Path, cell) -> None:
    """A simulated scan starts after the on-the-fly calibration in ``out`` ended (its
    journal's last stamps, mapped to true time by the simulated clocks it names), on the
    clocks that calibration ran on, so that the clock relation is used as far from its
    reference stamp as a real scan's would be. Nothing is written to that journal."""
    from spherecal.io.streams import read_recording

    journal = out / STREAM_JOURNAL_NAME
    if not journal.is_file():
        return
    try:
        recording = read_recording(journal)
    except (InputError, DatasetFileError):
        return
    clocks = recording.provenance.get("simulated_clocks")
    if not isinstance(clocks, dict):
        return
    ends = [cell.clock.now_s]
    for stamps, key in ((recording.poses.t_robot_s, "robot"), (recording.profiles.t_sensor_s, "sensor")):
        if len(stamps):
            c = clocks[key]
            ends.append(((float(stamps[-1]) - c["epoch_s"]) - c["offset_s"]) / c["rate"])
    cell.clock.advance_to(max(ends) + RESUME_GAP_S)
