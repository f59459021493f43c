"""``spherecal calibrate`` with ``[acquisition] mode = "on_the_fly"``: plan sweeps at each
station, check every sweep as any move is checked, confirm, take the sweeps with both
devices streaming into the stream-form journal (``--resume`` continues at the next sweep
not finished), then solve the recording with its clock relation and write the result,
exports and report as stop-and-go does (docs/on-the-fly.md, "Live acquisition")."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np

from spherecal.app.cell import make_cell
from spherecal.app.outputs import RESULT_NAME, STREAM_JOURNAL_NAME, check_output_folder, written_files
from spherecal.app.plan_checks import ON_THE_FLY_SPEEDS, check_plan, check_plan_solvable, confirm_motion, plan_digest
from spherecal.app.plugin_host import open_devices
from spherecal.app.provenance import (CALIBRATION_OPTIONS_KEY, check_same_devices, check_same_settings, traceability,
                                      with_clock_truth)
from spherecal.app.solving import Outcome, calibration_options, solve_and_write
from spherecal.core.errors import ConfigError, InputError
from spherecal.core.models import Dataset
from spherecal.core.streams import POSES_ASSUMED_KEY
from spherecal.devices.contract import device_identity
from spherecal.devices.pose_streaming import pose_stream_assumption
from spherecal.estimation.on_the_fly import solve_recording
from spherecal.io.stream_writer import RecordingWriter
from spherecal.io.streams import read_recording, reopen_recording
from spherecal.motion.acquisition import Target
from spherecal.motion.kinematic_plan import uses_planner
from spherecal.motion.on_the_fly import (OnTheFlyReport, PlannedSweep, SweepJournal, acquire_sweeps, check_streaming,
                                         plan_sweeps, sweep_targets)

#: The finished sweeps of an on-the-fly calibration, beside its journal (STREAM_JOURNAL_NAME).
SWEEPS_NAME = "journal.sweeps.jsonl"
#: Simulated time left between an interrupted run's last stamp and a resumed run's start, s.
RESUME_GAP_S = 1.0


def calibrate_on_the_fly(run, outcome: Outcome, *, dry_run: bool, resume: bool, yes: bool, ask, report: bool,
                         force: bool, operator: str | None) -> Outcome:
    """The on-the-fly calibration of ``run`` (a :class:`spherecal.app.calibrate._Calibration`);
    see the module's docstring. A dry run checks the plan (with the devices opened, the
    robot's own limits and that both stream) and moves nothing."""
    sweeps, targets, of_sweep = _planned(run)
    if dry_run:
        _check_dry_run(run, sweeps, targets)
        return outcome
    journal, sweeps_path = run.out / STREAM_JOURNAL_NAME, run.out / SWEEPS_NAME
    if journal.exists() and not resume:
        raise InputError(f"{journal} already holds an acquisition: run with --resume to continue it, or choose another "
                         "output_dir (nothing is ever overwritten)")
    if not journal.exists():
        check_output_folder(run.out, "calibrate", "give a new folder (--out or output_dir)", run.exports)
    cell = make_cell(run.cfg, run.arm, run.fov)
    acq = run.cfg.acquisition
    if cell is None:
        confirm_motion("calibrate", f"{len(sweeps)} sweeps on the fly in {len({s.station for s in sweeps})} stations "
                       f"(plan above), at most {max(max(s.speed_mm_s for s in sweeps), acq.approach_speed_mm_s):g} "
                       "mm/s", yes, ask, run.log)
    run.out.mkdir(parents=True, exist_ok=True)
    digest = plan_digest(targets)
    done: set[int] = set()
    previous: dict | None = None
    if resume and journal.exists():
        done, previous = _resumed(journal, sweeps_path, digest, cell, run.log)
    taken = _take(run, sweeps, targets, of_sweep, cell, journal, sweeps_path, digest, done, previous)
    if taken.sweeps:
        # a resumed run's figures are the whole journal's, the sweeps of the runs before included
        whole = OnTheFlyReport.of_journal(SweepJournal.finished(sweeps_path), taken.simulated_time) if done else taken
        this_run = (f"; this run took {len(taken.sweeps)} of them, {taken.profiles} profiles in "
                    f"{taken.robot_time_s:.1f} s" if done else "")
        run.log(f"acquisition: {whole.robot_time_line()} on the fly ({len(whole.sweeps)} sweeps{this_run})")
        run.log(whole.losses_line())
        outcome.acquisition = {"profiles": whole.profiles, "robot_time_s": whole.robot_time_s,
                               "profiles_per_minute": 60.0 * whole.profiles / max(whole.robot_time_s, 1e-9),
                               "simulated": whole.simulated_time, "mode": "on_the_fly", "sweeps": len(whole.sweeps),
                               "sweeps_this_run": len(taken.sweeps),
                               "pose_samples_lost": sum(s.pose_lost for s in whole.sweeps),
                               "frames_lost": sum(s.frames_lost for s in whole.sweeps)}
    outcome.files["journal"] = journal
    return _solved(run, journal, outcome, report=report, force=force, operator=operator)


def _planned(run) -> tuple[list[PlannedSweep], list[Target], dict[int, list[int]]]:
    """The sweeps, shown and checked against the configured limits before anything moves."""
    cfg, acq, log = run.cfg, run.cfg.acquisition, run.log
    if uses_planner(acq, cfg.calibration):
        raise ConfigError("[acquisition] mode = \"on_the_fly\" sweeps the stations listed in acquisition.sweep.tilts_deg; "
                          "the kinematic planner's stations ([acquisition.kinematic_plan], identify_kinematics) are "
                          "taken stop-and-go: give tilts_deg, or mode = \"stop_and_go\"")
    sweeps = plan_sweeps(acq, cfg.mounting, cfg.nominal_transform, cfg.sphere)
    targets, of_sweep = sweep_targets(sweeps, acq.approach_speed_mm_s)
    stations = list(dict.fromkeys(s.station for s in sweeps))
    otf = acq.on_the_fly
    log(f"plan: {len(sweeps)} sweeps on the fly in {len(stations)} stations ({len(otf.directions_in_sensor)} "
        f"directions x {len(otf.speeds_mm_s)} speeds ({', '.join(f'{v:g}' for v in otf.speeds_mm_s)} mm/s) x forth "
        f"and back), {sum(s.length_mm for s in sweeps):.0f} mm of sweeps; every sweep checked at "
        f"{len(targets)} points; sweeps numbered 0 to {len(sweeps) - 1}, as in the journal")
    check_plan(targets, acq, "on-the-fly plan", setup=(cfg.mounting, cfg.nominal_transform), keep_out=run.keep_out,
               log=log, speed_keys=ON_THE_FLY_SPEEDS)
    check_plan_solvable([Target(s.index, s.station, s.start, True, s.speed_mm_s) for s in sweeps])
    return sweeps, targets, of_sweep


def _check_dry_run(run, sweeps: list[PlannedSweep], targets: list[Target]) -> None:
    """The plan against the robot's own limits, and both devices' streaming, nothing moved."""
    cfg = run.cfg
    run.log("dry run: on-the-fly plan checked against acquisition.workspace and speeds; nothing moved")
    cell = make_cell(cfg, run.arm, run.fov)
    with open_devices(run.loaded, run.host, cell, run.log) as (robot, sensor):
        check_streaming(robot, sensor, cfg.robot["type"], cfg.sensor["type"])
        check_plan(targets, cfg.acquisition, "on-the-fly plan", robot=robot, setup=(cfg.mounting, cfg.nominal_transform),
                   keep_out=run.keep_out, log=run.log, speed_keys=ON_THE_FLY_SPEEDS)
    run.log(f"dry run: {len(sweeps)} sweeps checked against the robot's own limits too; both devices stream")


def _resumed(journal: Path, sweeps_path: Path, digest: str, cell, log) -> tuple[set[int], dict]:
    """The finished sweeps of an interrupted run and its journal's provenance; InputError
    when it was taken with another plan. A simulated world resumes after the journal's
    last stamps (its clocks went on while the run stood)."""
    with open(journal, "rb") as fh:
        header = _header(fh.readline(), journal)
    provenance = header.get("provenance") or {}
    if provenance.get("plan_digest") != digest:
        raise InputError(f"{journal} was taken with another plan ({provenance.get('plan_digest')}, now {digest}): the "
                         "configuration's acquisition, nominal transform or mode changed since; resume with the "
                         "configuration it was taken with, or start a new run in another output_dir")
    done = set(SweepJournal.finished(sweeps_path))
    log(f"resuming {journal}: {len(done)} sweep(s) finished, continuing at the next")
    if cell is not None:
        _continue_simulated_time(journal, cell, provenance)
    return done, provenance


def _header(line: bytes, journal: Path) -> dict:
    import json

    try:
        header = json.loads(line)
    except ValueError:
        header = None
    if not isinstance(header, dict):
        raise InputError(f"{journal}: its first line is not a stream recording's header; start a new run in another "
                         "output_dir")
    return header


def _continue_simulated_time(journal: Path, cell, provenance: dict) -> None:
    """Move the resumed simulated world's clock past the journal's last stamps (mapped to
    true time by the clocks the journal names), and stand the arm where the journal's last
    pose sample has it (a real arm stays where the interrupted run left it: a controller
    started at its home instead may reach the next sweep in another configuration, with
    another geometric error, than the station's sweeps before)."""
    clocks = provenance.get("simulated_clocks")
    if not isinstance(clocks, dict):
        return
    # reopened first: a line the interruption cut is dropped from the file (said once), so
    # that reading it next does not say so again
    writer = reopen_recording(journal)
    last_pose, last_profile = writer._last_pose_t, writer._last_profile_t
    writer.close()
    taken = read_recording(journal)
    if taken.poses.joints_deg is not None and taken.poses.n:
        cell.arm_start_joints_deg = np.array(taken.poses.joints_deg[-1], dtype=float)
    ends = [0.0]
    for stamp, key in ((last_pose, "robot"), (last_profile, "sensor")):
        if stamp is not None:
            c = clocks[key]
            ends.append(((stamp - c["epoch_s"]) - c["offset_s"]) / c["rate"])
    cell.clock.advance_to(max(ends) + RESUME_GAP_S)


def _journal_provenance(run, digest: str, cell) -> dict:
    """The journal's provenance: the plan, the configuration, the estimator's settings
    (``solve`` of the journal starts from them), the device types and, in a simulated run,
    the truth (the transform, the sphere and the two stream clocks)."""
    cfg = run.cfg
    provenance = {"source": "spherecal calibrate on the fly", "plan_digest": digest, "config": str(run.loaded.path),
                  "robot": cfg.robot["type"], "sensor": cfg.sensor["type"], "simulated": cell is not None,
                  CALIBRATION_OPTIONS_KEY: calibration_options(cfg).model_dump(mode="json")}
    if cell is not None:
        from spherecal.sim.live import clock_truth

        provenance.update(true_transform_name=cell.transform_name, true_transform=cell.true_transform.model_dump(),
                          true_sphere_centre_mm=cell.sphere_centre_mm.tolist(), simulation_seed=cfg.simulation.seed,
                          simulated_clocks=clock_truth(cell))
    return provenance


def _take(run, sweeps, targets, of_sweep, cell, journal: Path, sweeps_path: Path, digest: str, done: set[int],
          previous: dict | None) -> OnTheFlyReport:
    """The devices opened, both checked to stream, the plan checked against the robot
    once more (from where the arm stands), the sweeps taken into the journal."""
    cfg, acq, log = run.cfg, run.cfg.acquisition, run.log
    done_targets = {i for k in done for i in of_sweep.get(k, [])}
    with open_devices(run.loaded, run.host, cell, log) as (robot, sensor):
        check_streaming(robot, sensor, cfg.robot["type"], cfg.sensor["type"])
        check_plan(targets, acq, "on-the-fly plan", robot=robot, done=done_targets,
                   setup=(cfg.mounting, cfg.nominal_transform), keep_out=run.keep_out, log=log,
                   speed_keys=ON_THE_FLY_SPEEDS)
        provenance = _journal_provenance(run, digest, cell)
        provenance.update(robot_identity=device_identity(robot), sensor_identity=device_identity(sensor))
        assumed = pose_stream_assumption(robot)
        if assumed is not None:  # poses computed, not measured: the result must say what they assume
            provenance[POSES_ASSUMED_KEY] = assumed
        if previous is not None:
            check_same_devices(previous, provenance, journal, log)
            check_same_settings(previous, provenance, journal, log)
            writer = reopen_recording(journal, fsync=True)
        else:
            writer = RecordingWriter(journal, mounting=cfg.mounting, sphere_radius_mm=cfg.sphere.radius_mm,
                                     clocks={"robot": f"{cfg.robot['type']} controller",
                                             "sensor": f"{cfg.sensor['type']} sensor"},
                                     sweeps=[s.info for s in sweeps], provenance=provenance, fsync=True)
        with writer:
            return acquire_sweeps(robot, sensor, sweeps, SweepJournal(writer, sweeps_path), acq, done, log,
                                  clock=cell.clock if cell is not None else None)


def _solved(run, journal: Path, outcome: Outcome, *, report: bool, force: bool, operator: str | None) -> Outcome:
    """The journal read as a recording, solved with its clock relation, graded and written."""
    cfg, log = run.cfg, run.log
    recording = read_recording(journal)
    header = Dataset(mounting=recording.mounting, sphere_radius_mm=recording.sphere_radius_mm,
                     provenance=with_clock_truth(recording))
    options = calibration_options(cfg)
    arm = run.arm if recording.poses.joints_deg is not None else None

    def solver():
        return solve_recording(recording, options, kinematics=arm, progress=log)

    def as_mounting(mounting: str):
        return solve_recording(replace(recording, mounting=mounting), options, kinematics=arm).result

    solution, outcome.verdict, outcome.exports_written = solve_and_write(
        header, options, run.out, run.exports, None, log, report=report, force=force, kinematics=arm,
        provenance=traceability(header, journal, run.loaded, operator), report_settings=cfg.report, solver=solver,
        recheck=as_mounting)
    run.host.calibration_finished(result=solution.result, dataset=header, out_dir=run.out,
                                  exports_written=outcome.exports_written, robot_type=cfg.robot["type"],
                                  sensor_type=cfg.sensor["type"])
    outcome.solution, outcome.dataset = solution, header
    outcome.files.update(written_files(run.out))
    outcome.files["journal"] = journal
    return outcome


__all__ = ["RESULT_NAME", "STREAM_JOURNAL_NAME", "SWEEPS_NAME", "calibrate_on_the_fly"]
