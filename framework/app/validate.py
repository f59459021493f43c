"""``spherecal validate``: the acceptance test of a calibration, at views other than the
calibration's, against the maximum permissible errors."""

from __future__ import annotations

import json
from dataclasses import replace
from datetime import datetime, timezone
from pathlib import Path
from typing import Callable

import numpy as np

from spherecal.app import plugin_host
from spherecal.app.cell import configured_for_sensor, make_cell
from spherecal.app.outputs import STREAM_JOURNAL_NAME, calibrated_setup, calibrated_urdf_in, journal_of
from spherecal.app.plan_checks import (STOP_AND_GO_SPEEDS, VALIDATION_KEEP_OUT_FIX, check_plan, confirm_motion,
                                      keep_out_for)
from spherecal.app.plugin_host import export_plan, in_file, open_devices, robot_arm
from spherecal.io.files import sha256_of
from spherecal.app.scan_on_the_fly import scan_mode
from spherecal.app.solving import calibration_options
from spherecal.app.validate_on_the_fly import measure_on_the_fly, plan_on_the_fly, solve_calibration_recording
from spherecal.config import LoadedConfig
from spherecal.core.errors import ConfigError
from spherecal.core.metrology import ShotNoise
from spherecal.core.models import TRANSFORM_NAME, Observation
from spherecal.estimation import solve
from spherecal.io import dataset as dataio
from spherecal.io import files as safeio
from spherecal.io.runlog import progress_log
from spherecal.motion.acquisition import Progress
from spherecal.motion.on_the_fly import check_streaming
from spherecal.motion.validation import evaluate, measure, plan_validation, position_rows
from spherecal.motion.planning import sphere_standoff_z_mm
from spherecal.report.assess import Verdict, verdict
from spherecal.report.html import write_report_version
from spherecal.report.validation_advice import validation_verdict

_LOG = progress_log("run")  # the default ``log``: logger spherecal.run


def run_validate(loaded: LoadedConfig, *, out_dir: Path | None = None, log: Callable[[str], None] = _LOG,
                 progress_stream=None, report: bool = True, yes: bool = False, ask: Callable[[str], str] = input,
                 transform=None, host=None):
    """``spherecal validate``: scan the artefacts at new views with the calibrated
    system, compute the acceptance figures, compare with the MPEs. ``transform`` (a
    :class:`~spherecal.report.compare.TransformEstimate`): validate that transform, one spherecal
    did not compute (the controller's current tool or work object, a pose file), instead
    of the calibration's ``result.json``; the report is then left alone. ``host``: the
    run's plugin host (default: made here).

    Writes the figures to ``validation-<time>.json`` (and ``validation.json``, the latest)
    and, with ``report``, a new version of the calibration's report (``report-<n>.html``:
    ``report.html`` and ``result.json`` stay as the calibration wrote them); the outcome
    names both (``figures_path``, ``report_path``)."""
    host = host if host is not None else plugin_host.make_host()
    loaded, fov = configured_for_sensor(loaded, host)
    cfg = loaded.config
    out, result_path, result, X, source = _transform_to_validate(loaded, out_dir, transform, log)
    sweeps = plan_validation(cfg.validation, cfg.acquisition, cfg.mounting, X, cfg.sphere, fov, cfg.sensor["type"])
    # on the fly, the passes alone are checked and said: what moves
    on_the_fly = plan_on_the_fly(cfg, sweeps, result, source, log) if scan_mode(cfg) == "on_the_fly" else None
    if on_the_fly is None:
        targets = [t for s in sweeps for t in s.targets]
        plan, what, speed_keys = f"{len(sweeps)} sweeps, {len(targets)} shots", "validation plan", STOP_AND_GO_SPEEDS
        log(f"validating {source}: {plan}")
    else:
        targets, plan = on_the_fly.targets, on_the_fly.describe()
        what, speed_keys = "validation plan (on the fly)", on_the_fly.speed_keys
        log(f"validating {source}: {plan}, one per validation sweep; every pass checked at "
            f"{len(targets)} points")
    keep_out = in_file(loaded, keep_out_for, cfg, host, X, VALIDATION_KEEP_OUT_FIX, log, fov)
    check_plan(targets, cfg.acquisition, what, keep_out=keep_out, log=log, speed_keys=speed_keys)
    exports = export_plan(loaded, host)  # for the report's notes; a bad [export] stops before any motion
    cell = make_cell(cfg, robot_arm(loaded, host), fov)
    if cell is None:
        confirm_motion("validate", plan, yes, ask, log)
    out.mkdir(parents=True, exist_ok=True)
    started = datetime.now(timezone.utc)
    stamp = started.strftime("%Y%m%dT%H%M%S%fZ")
    journal = out / f"validation-{stamp}.jsonl"  # one journal per validation run; none is overwritten
    with open_devices(loaded, host, cell, log) as (robot, sensor):
        if on_the_fly is not None:
            check_streaming(robot, sensor, cfg.robot["type"], cfg.sensor["type"])
        check_plan(targets, cfg.acquisition, what, robot=robot, keep_out=keep_out, log=log, speed_keys=speed_keys)
        with dataio.DatasetWriter(journal, mounting=cfg.mounting, sphere_radius_mm=cfg.sphere.radius_mm,
                                  provenance={"source": "spherecal validate", "result": source,
                                              "transform": X.model_dump()},
                                  fsync=True) as writer:

            def record(sweep, target, pose, profile):
                writer.append(Observation(index=writer.next_index, station=f"{sweep.label}-{sweep.kind}",
                                          timestamp=datetime.now(timezone.utc), base_from_flange=pose,
                                          profile=profile, target=target.index))

            if on_the_fly is not None:
                measured = measure_on_the_fly(cfg, robot, sensor, sweeps, on_the_fly, writer, log,
                                              clock=cell.clock if cell is not None else None)
            else:
                measured = measure(robot, sensor, sweeps, cfg.acquisition, log,
                                   Progress(len(targets), progress_stream), record)
    outcome = evaluate(cfg.validation, cfg.mounting, X, cfg.sphere, measured, shot_noise(cfg, result))
    if fov is not None:
        outcome.line_width_mm = float(fov.width_at_mm(sphere_standoff_z_mm(fov, cfg.sphere.radius_mm)))
    own = verdict(result) if result is not None else Verdict(
        "green", "A transform spherecal did not compute: only its validation is graded.")
    outcome.verdict, outcome.cause = validation_verdict(own, outcome.table(), result)
    outcome.transform, outcome.transform_name, outcome.transform_source = X, TRANSFORM_NAME[cfg.mounting], source
    outcome.figures_path = _write_validation(outcome, out, stamp, journal, transform is not None)
    calib_journal = journal_of(out)  # stop-and-go's or on the fly's
    if report and transform is None and calib_journal.exists():
        # the report shows the calibration's residuals: only when that calibration is the one validated
        added = (f"the validation run at {started.isoformat(timespec='seconds')} ({outcome.figures_path.name}, its "
                 f"shots in {journal.name}): {'passed' if outcome.passed else 'FAILED'}; the verdict, the validation "
                 "tables and the sign-off are this version's.")
        outcome.report_path = _report_version(loaded, host, outcome, result, result_path, out, exports, added, log)
    return outcome


def shot_noise(cfg, result) -> ShotNoise:
    """The noise the validation's points carry, as the calibration found it
    (``result.diagnostics.noise``: the sensor's point noise, the robot's pose noise per
    shot), or as the configuration's ``[calibration]`` states it for a transform
    spherecal did not compute (a point noise it leaves to the data: none; it is a small
    share of P_S's uncertainty beside the robot's)."""
    found = (result.diagnostics.noise or {}) if result is not None else {}
    cal = cfg.calibration

    def pick(key: str, stated) -> float:
        value = found.get(key)
        return float(value if value is not None else stated if stated is not None else 0.0)

    return ShotNoise(point_noise_mm=pick("point_noise_mm", cal.point_noise_mm),
                     shot_translation_noise_mm=pick("pose_translation_noise_mm", cal.pose_translation_noise_mm),
                     shot_rotation_noise_deg=pick("pose_rotation_noise_deg", cal.pose_rotation_noise_deg))


def _transform_to_validate(loaded: LoadedConfig, out_dir: Path | None, transform, log: Callable[[str], None]):
    """The output folder, the calibration's result (path and result; None for a given
    transform), the transform to validate and where it comes from."""
    cfg = loaded.config
    missing = "no [validation] section: say what to validate against which MPEs"
    if transform is None:
        out, result_path, result = calibrated_setup(loaded, cfg.validation, missing, "validation", out_dir)
        return out, result_path, result, result.transform, str(result_path)
    out, result_path, result = calibrated_setup(loaded, cfg.validation, missing, "validation", out_dir,
                                                read_result=False)
    expected = TRANSFORM_NAME[cfg.mounting]
    if transform.transform_name not in (None, expected):
        raise ConfigError(f"{transform.source} is {transform.transform_name}, but {loaded.path} calibrates "
                          f"{expected} ({cfg.mounting}): validate a transform of the configuration's mounting")
    if transform.note:
        log(f"note: {transform.note}")
    return out, result_path, result, transform.pose, transform.source


def _write_validation(outcome, out: Path, stamp: str, journal: Path, transform_given: bool) -> Path:
    """``validation-<stamp>.json`` and ``validation.json`` (the latest run, for scripts;
    ``cause``: the likely cause of a failure and its remedy when named, for ``scan``).
    Returns the first."""
    X = outcome.transform
    text = json.dumps({"passed": outcome.passed, "result": outcome.transform_source, "transform": X.model_dump(),
                       "transform_given": transform_given, "journal": journal.name,
                       "verdict": {"level": outcome.verdict.level, "headline": outcome.verdict.headline},
                       "cause": outcome.cause.as_dict() if outcome.cause is not None else None,
                       "figures": outcome.table(), "positions": position_rows(outcome),
                       "report": outcome.report.model_dump(), "centres_mm": outcome.centres_mm},
                      indent=2, default=float)
    path = out / f"validation-{stamp}.json"
    safeio.write_text(path, text)
    safeio.write_text(out / "validation.json", text)  # the latest run, for scripts
    return path


def _report_version(loaded: LoadedConfig, host, outcome, result, result_path: Path, out: Path, exports, added: str,
                    log: Callable[[str], None]) -> Path | None:
    """A new version of the calibration's report in ``out`` with the validation's figures
    (``report-<n>.html``, saying which version it supersedes and that it adds ``added``),
    when solving the calibration's journal there again gives the transform validated;
    else None, and the log says why not. The calibration's ``report.html`` is never
    rewritten."""
    cfg = loaded.config
    calib_journal = journal_of(out)
    X = outcome.transform
    if calib_journal.name == STREAM_JOURNAL_NAME:
        solution = solve_calibration_recording(calib_journal, calibration_options(cfg), robot_arm(loaded, host))
    else:
        solution = solve(dataio.read_dataset(calib_journal), calibration_options(cfg),
                         host.robot_kinematics(cfg.robot, base_dir=loaded.path.parent),
                         kinematics=robot_arm(loaded, host))
    if np.allclose(solution.result.transform.as_matrix(), X.as_matrix(), atol=1e-6):
        # the result as written (its provenance: the calibration's identity and hashes)
        solution = replace(solution, result=result)
        return write_report_version(solution, out, added, validation=outcome.table(),
                                    validation_positions=position_rows(outcome), verdict_override=outcome.verdict,
                                    notes=exports.notes(solution.result), point_distance_mm=cfg.report.point_distance_mm,
                                    calibrated_urdf=calibrated_urdf_in(out))
    log(f"no new version of the report: {not_the_calibration(result, result_path, calib_journal, loaded)}")
    return None


def not_the_calibration(result, result_path: Path, journal: Path, loaded: LoadedConfig) -> str:
    """Why ``result`` and the calibration of ``journal`` solved again with ``loaded``'s
    settings differ: another dataset, or the same one under a configuration that changed
    since (its robot model, the calibration settings), from the result's provenance."""
    prov = (result.provenance or {}) if result is not None else {}
    taken = prov.get("dataset_sha256")
    if taken is None or taken != sha256_of(journal):
        return f"{result_path} is not the calibration of {journal}"
    cfg_then = prov.get("configuration_sha256")
    changed = (f"{loaded.path} is not the configuration it was calibrated with ({prov.get('configuration_file')})"
               + " (its robot model or [calibration] settings)" if cfg_then != sha256_of(loaded.path)
               else "the configuration is the one it was calibrated with, so a file it names (a robot model) or "
                    "spherecal changed since")
    return (f"{result_path} is the calibration of {journal}, but solving that journal again with this configuration "
            f"gives another transform: {changed}; the validation itself used the result as written")
