"""``spherecal scan``: sweep an object with the calibrated system and stream its points
to a PLY file."""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

import numpy as np

from spherecal.app import plugin_host
from spherecal.app.cell import configured_for_sensor, make_cell
from spherecal.app.outputs import calibrated_setup
from spherecal.app.plan_checks import SCAN_SPEEDS, SCAN_KEEP_OUT_FIX, check_plan, confirm_motion, keep_out_for
from spherecal.app.plugin_host import in_file, open_devices, robot_arm
from spherecal.config import LoadedConfig
from spherecal.core.errors import ConfigError, InputError
from spherecal.core.models import SPHERE_FRAME, Pose
from spherecal.io.files import check_writable_target, is_inside
from spherecal.io.ply import PlyWriter
from spherecal.io.runlog import Notice, progress_log
from spherecal.motion.acquisition import Progress
from spherecal.app.scan_on_the_fly import run_scan_on_the_fly, scan_mode
from spherecal.motion.scanning import ScanSummary, plan_scan, scan

_LOG = progress_log("run")  # the default ``log``: logger spherecal.run


def run_scan(loaded: LoadedConfig, *, out_dir: Path | None = None, log: Callable[[str], None] = _LOG,
             progress_stream=None, yes: bool = False, ask: Callable[[str], str] = input):
    """``spherecal scan``: sweep the object, stream its points to a PLY file."""
    host = plugin_host.make_host()
    loaded, fov = configured_for_sensor(loaded, host)
    cfg = loaded.config
    if cfg.scan is not None:  # where the PLY goes, before anything else
        ply_path = _ply_path(loaded, out_dir)
    out, result_path, result = calibrated_setup(loaded, cfg.scan, "no [scan] section: say what to scan", "scanning",
                                                out_dir)
    doubt = failed_validation(out, result)
    if doubt:  # said before anything moves, and again by the exit code
        log(Notice(f"warning: {doubt.text}; {doubt.carried} (scanning all the same)"))
    if scan_mode(cfg) == "on_the_fly":
        return ply_path, _on_the_fly(loaded, host, fov, out, result_path, result, ply_path, doubt, log, yes, ask)
    targets = plan_scan(cfg.scan, cfg.acquisition, cfg.mounting, result.transform, fov)
    keep_out = in_file(loaded, keep_out_for, cfg, host, result.transform, SCAN_KEEP_OUT_FIX, log, fov)
    check_plan(targets, cfg.acquisition, "scan plan", keep_out=keep_out, log=log, speed_keys=SCAN_SPEEDS)
    if ply_path.exists():
        raise InputError(f"{ply_path} exists; remove it or set [scan] ply to another name (nothing is overwritten)")
    cell = make_cell(cfg, robot_arm(loaded, host), fov)
    if cell is None:
        confirm_motion("scan", f"{len(targets)} profiles", yes, ask, log)
    out.mkdir(parents=True, exist_ok=True)
    log(f"scan: {len(targets)} profiles into {ply_path}")
    frame = SPHERE_FRAME[cfg.mounting]
    with open_devices(loaded, host, cell, log) as (robot, sensor):
        check_plan(targets, cfg.acquisition, "scan plan", robot=robot, keep_out=keep_out, log=log,
                   speed_keys=SCAN_SPEEDS)
        with PlyWriter(ply_path, format=cfg.scan.format, with_profile=True, frame=frame,
                       comments=(f"spherecal scan, {result.transform_name} from {result_path}",)) as writer:
            summary = scan(robot, sensor, targets, result.transform, cfg.acquisition, cfg.mounting, writer, log,
                           Progress(len(targets), progress_stream), clock=cell.clock if cell is not None else None)
    log(f"scan: {summary.points} points from {summary.profiles} profiles ({summary.empty_profiles} empty) in "
        f"{frame} frame")
    if summary.robot_time_s > 0:
        log(f"scan: {summary.robot_time_line()}")
    if doubt:
        summary.calibration_doubt, summary.calibration_remedy = doubt.text, doubt.remedy
    return ply_path, summary


def _on_the_fly(loaded, host, fov, out, result_path, result, ply_path, doubt, log, yes, ask) -> "ScanSummary":
    """The scan on the fly (:mod:`spherecal.app.scan_on_the_fly`), said as the stop-and-go
    scan says it, with the profiles not mapped and why."""
    done = run_scan_on_the_fly(loaded, host, fov, out, result_path, result, ply_path, log, yes, ask)
    rep = done.report
    empty = sum(p.empty for p in rep.passes)
    summary = ScanSummary(profiles=rep.mapped, points=rep.points, empty_profiles=empty, robot_time_s=rep.robot_time_s,
                          simulated_time=rep.simulated_time, mode="on_the_fly", unmapped=rep.unmapped(),
                          streamed=rep.profiles, passes_journal=done.journal)
    log(f"scan: {summary.points} points from {summary.profiles} profiles mapped ({empty} saw nothing) of "
        f"{rep.profiles} streamed in {len(rep.passes)} passes, {SPHERE_FRAME[loaded.config.mounting]} frame")
    log(f"scan: {summary.unmapped_line()}")
    if rep.robot_time_s > 0:
        log(f"scan: {rep.robot_time_line()} on the fly")
    if doubt:
        summary.calibration_doubt, summary.calibration_remedy = doubt.text, doubt.remedy
    return summary


def _ply_path(loaded: LoadedConfig, out_dir: Path | None) -> Path:
    """Where ``[scan] ply`` goes: in the output folder unless the configuration says
    otherwise on purpose; never through a link."""
    cfg = loaded.config
    out = Path(out_dir) if out_dir is not None else loaded.output_dir
    given = Path(cfg.scan.ply).expanduser()
    ply_path = given if given.is_absolute() else out / given
    check_writable_target(ply_path)  # a link is named as a link, wherever it points
    if not cfg.scan.ply_outside_output_dir and (given.is_absolute() or not is_inside(ply_path, out)):
        raise ConfigError(f"{loaded.path}: scan.ply = {cfg.scan.ply!r} lies outside the output folder {out}: "
                          "give a file name in it, or set scan.ply_outside_output_dir = true to write there "
                          "on purpose")
    check_writable_target(ply_path)
    return ply_path


@dataclass(frozen=True)
class FailedValidation:
    """The latest validation of a calibration failed: what failed (``text``), what the
    scan's points carry of it (``carried``) and what to do (``remedy``)."""

    text: str
    carried: str
    remedy: str


#: What to do about a failed validation whose cause was not named.
UNNAMED_REMEDY = "re-calibrate, or validate again once the cause is fixed"


def failed_validation(out: Path, result) -> FailedValidation | None:
    """What is wrong when the latest validation in ``out`` (``validation.json``) is of
    ``result``'s transform and failed, with the likely cause and its remedy when the
    validation named them (the robot's own error, which no new calibration of the sensor
    removes: ``cause`` in validation.json); None when it passed, is of another transform,
    or there is none."""
    path = out / "validation.json"
    try:
        latest = json.loads(path.read_text())
        validated = Pose.model_validate(latest["transform"])
    except (OSError, ValueError, KeyError, TypeError):
        return None
    if latest.get("passed", True) or not np.allclose(validated.as_matrix(), result.transform.as_matrix(), atol=1e-9):
        return None
    failed = [name for name, row in (latest.get("figures") or {}).items() if not row.get("passed", True)]
    text = f"this calibration failed its latest validation ({path}: {', '.join(failed) or 'a figure'} beyond its MPE)"
    cause = latest.get("cause")
    if not isinstance(cause, dict) or not all(isinstance(cause.get(k), str) for k in ("cause", "remedy")):
        return FailedValidation(text, "the scan's points carry that error", UNNAMED_REMEDY)
    expected = cause.get("expected_point_error_k2_mm")
    size = f"up to about {expected:.3f} mm (k = 2) " if isinstance(expected, (int, float)) else ""
    carried = (f"the scan's points carry the robot's error: {size}in where they lie (absolute), much less in the "
               "shape within one pass (relative)")
    return FailedValidation(f"{text}; likely cause: {cause['cause']}", carried, cause["remedy"])
