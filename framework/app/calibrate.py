"""``spherecal calibrate``: plan, check, acquire into the journal (or replay a recorded
dataset), solve, and write the result, exports and report."""

from __future__ import annotations

import warnings
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

import numpy as np

from spherecal.app import plugin_host
from spherecal.app.cell import configured_for_sensor, make_cell
from spherecal.app.outputs import JOURNAL_NAME, RESULT_NAME, check_output_folder, written_files
from spherecal.app.plan_checks import (CALIBRATION_KEEP_OUT_FIX, check_identification_from_here, check_plan,
                                       check_plan_solvable, confirm_motion, keep_out_for, plan_digest, step_prompt)
from spherecal.app.plugin_host import export_plan, in_file, open_devices, robot_arm
from spherecal.app.provenance import (CALIBRATION_OPTIONS_KEY, check_same_devices, check_same_settings,
                                      traceability)
from spherecal.app.solving import Outcome, calibration_options, solve_and_write
from spherecal.config import LoadedConfig, RunConfig
from spherecal.core.errors import ConfigError, InputError
from spherecal.core.models import Dataset
from spherecal.devices.contract import SensorFieldOfView, device_identity
from spherecal.io import dataset as dataio
from spherecal.io.exporters import ExportPlan
from spherecal.io.runlog import progress_log
from spherecal.motion.acquisition import (Progress, SensorBlindError, acquire, acquire_manual, describe_plan,
                                         plan_targets)
from spherecal.estimation.options import station_rotation_tolerance_deg
from spherecal.motion.keep_out import KeepOut
from spherecal.motion.kinematic_plan import check_plan_identifies_kinematics, plan_kinematic_stations, uses_planner

_LOG = progress_log("run")  # the default ``log``: logger spherecal.run


@dataclass
class _Calibration:
    """What every step of one calibration run uses: the configuration fitted to the
    sensor, the output folder, the run's plugin host and what it built."""

    loaded: LoadedConfig
    out: Path
    host: object
    fov: SensorFieldOfView | None
    fk: Callable | None
    arm: object | None
    exports: ExportPlan
    log: Callable[[str], None]
    #: the sensor's body against the sphere before any motion (None: no body, or nothing moves)
    keep_out: KeepOut | None = None

    @property
    def cfg(self) -> RunConfig:
        return self.loaded.config


@dataclass
class _Plan:
    """The shots to take (none in manual mode: the operator jogs), the kinematic
    planner's stations when it planned them, and what the plan identifies of the arm."""

    manual: bool
    targets: list = field(default_factory=list)
    planned: object | None = None
    identification: str = ""


@dataclass
class _Resumed:
    """A journal taken before: its dataset, the targets it holds and the next station's number."""

    previous: Dataset | None = None
    done: set[int] = field(default_factory=set)
    first_station: int = 1


def run_calibrate(
    loaded: LoadedConfig,
    *,
    dry_run: bool = False,
    resume: bool = False,
    manual: bool = False,
    out_dir: Path | None = None,
    log: Callable[[str], None] = _LOG,
    ask: Callable[[str], str] = input,
    progress_stream=None,
    report: bool = True,
    force: bool = False,
    yes: bool = False,
    operator: str | None = None,
    step: bool = False,
) -> Outcome:
    """``spherecal calibrate``: plan, check, acquire into the journal (or replay a
    recorded dataset), solve, write the result, exports and report. A RED result's
    ``result.json`` and exports are written only with ``force`` (its report always).
    ``operator`` (``--operator``) overrides the configuration's ``[report] operator``.
    ``step``: ``ask`` before each station (:func:`~spherecal.app.plan_checks.step_prompt`);
    an answer other than yes stops the run, the journal kept."""
    run = _prepare(loaded, Path(out_dir) if out_dir is not None else loaded.output_dir, log)
    outcome = Outcome()
    if resume and (run.out / RESULT_NAME).exists():
        outcome.finished = True  # (the command says so, once)
        return outcome
    if run.cfg.replay is None and not manual and run.cfg.acquisition.mode == "on_the_fly":
        from spherecal.app.calibrate_on_the_fly import calibrate_on_the_fly

        if step:
            raise ConfigError("--step asks before each station of a stop-and-go plan; [acquisition] mode = "
                              "\"on_the_fly\" does not stop between sweeps: leave out --step (the plan is shown and "
                              "confirmed before the first motion); nothing was opened or moved")

        return calibrate_on_the_fly(run, outcome, dry_run=dry_run, resume=resume, yes=yes, ask=ask, report=report,
                                    force=force, operator=operator)
    if run.cfg.replay is not None:
        source = run.loaded.resolve(run.cfg.replay)
        dataset = _replayed(run, source, dry_run)
    else:
        dataset = _acquired(run, outcome, dry_run=dry_run, resume=resume, manual=manual, yes=yes, ask=ask,
                            progress_stream=progress_stream, step=step)
        source = outcome.files.get("journal")
    if dataset is None:  # a dry run
        return outcome
    return _solved(run, dataset, source, outcome, report=report, force=force, operator=operator)


def _prepare(loaded: LoadedConfig, out: Path, log: Callable[[str], None]) -> _Calibration:
    """The run's plugin host and what it builds, every setting checked before anything moves."""
    host = plugin_host.make_host()
    loaded, fov = configured_for_sensor(loaded, host)
    cfg = loaded.config
    fk = in_file(loaded, host.robot_kinematics, cfg.robot, base_dir=loaded.path.parent)
    arm = robot_arm(loaded, host)
    in_file(loaded, host.validate_sensor_config, cfg.sensor["type"], cfg.sensor, base_dir=loaded.path.parent)
    keep_out = None
    if cfg.replay is None and cfg.acquisition.mode != "manual":
        keep_out = in_file(loaded, keep_out_for, cfg, host, cfg.nominal_transform.pose(), CALIBRATION_KEEP_OUT_FIX, log,
                           fov)
    return _Calibration(loaded, out, host, fov, fk, arm, export_plan(loaded, host, log), log, keep_out)


def _replayed(run: _Calibration, path: Path, dry_run: bool) -> Dataset | None:
    """The recorded dataset the configuration replays (``replay``); None on a dry run."""
    if not dry_run:
        check_output_folder(run.out, "calibrate", "give a new folder (--out or output_dir)", run.exports)
    run.log(f"replaying {path}")
    dataset = dataio.read_dataset(path)
    if dataset.mounting != run.cfg.mounting:
        raise InputError(f"{path}: dataset is {dataset.mounting} but the configuration says {run.cfg.mounting}")
    if dry_run:
        run.log(f"dry run: {len(dataset.observations)} observations would be solved")
        return None
    return dataset


def _acquired(run: _Calibration, outcome: Outcome, *, dry_run: bool, resume: bool, manual: bool, yes: bool,
              ask: Callable[[str], str], progress_stream, step: bool = False) -> Dataset | None:
    """The shots taken into the run's journal (continued with ``resume``); None on a dry
    run, which checks the plan against the configured limits and the robot's."""
    acq = run.cfg.acquisition
    plan = _planned(run, manual or acq.mode == "manual")
    if dry_run:
        _check_dry_run(run, plan)
        return None
    journal = run.out / JOURNAL_NAME
    if journal.exists() and not resume:
        raise InputError(
            f"{journal} already holds an acquisition: run with --resume to continue it, "
            "or choose another output_dir (nothing is ever overwritten)"
        )
    if not journal.exists():
        check_output_folder(run.out, "calibrate", "give a new folder (--out or output_dir)", run.exports)
    cell = make_cell(run.cfg, run.arm, run.fov)
    if not plan.manual and cell is None:
        confirm_motion("calibrate", f"{len(plan.targets)} shots in {len(set(t.station for t in plan.targets))} "
                       f"stations (plan above), at most {acq.max_speed_mm_s:g} mm/s"
                       + (f"; {plan.identification}" if plan.identification else ""), yes, ask, run.log)
    run.out.mkdir(parents=True, exist_ok=True)
    digest = "manual" if plan.manual else plan_digest(plan.targets)
    resumed = _resumed(journal, digest, run.log) if resume and journal.exists() else _Resumed()
    if cell is not None and resumed.previous is not None:
        # a real arm stays where the interrupted run left it; a simulated controller started at
        # its home instead could reach the station's next shot in the other wrist solution
        # (joints 4-6 -116.5/-13.7/124.3 -> 62.4/13.9/-54.5 seen), with another geometric error
        taken = [o.joints_deg for o in resumed.previous.observations if o.joints_deg is not None]
        if taken:
            cell.arm_start_joints_deg = np.array(taken[-1], dtype=float)
    rep = _take(run, plan, cell, journal, _journal_provenance(run, digest, cell), resumed, ask, progress_stream,
                step_prompt(ask) if step else None)
    outcome.notes.extend(rep.skipped)
    for s in rep.skipped:
        run.log(f"skipped {s}")
    if rep.taken and rep.robot_time_s > 0:
        run.log(f"acquisition: {rep.robot_time_line()}")
        outcome.acquisition = {"profiles": rep.taken, "robot_time_s": rep.robot_time_s,
                               "profiles_per_minute": 60.0 * rep.taken / rep.robot_time_s,
                               "simulated": rep.simulated_time}
    dataset = dataio.read_dataset(journal)
    run.host.acquisition_finished(dataset=dataset, robot_type=run.cfg.robot["type"],
                                  sensor_type=run.cfg.sensor["type"])
    outcome.files["journal"] = journal
    return dataset


def _planned(run: _Calibration, manual: bool) -> _Plan:
    """The plan (none in manual mode), shown and checked against the configured limits,
    the stations' orientations and, with ``identify_kinematics``, what it identifies."""
    plan = _Plan(manual)
    if manual:
        return plan
    cfg, log = run.cfg, run.log
    if uses_planner(cfg.acquisition, cfg.calibration):
        plan.planned = plan_kinematic_stations(cfg.acquisition, cfg.calibration, cfg.mounting, cfg.nominal_transform,
                                               cfg.sphere, run.arm, robot_type=cfg.robot.get("type"))
        log(plan.planned.summary())
        plan.targets = plan_targets(cfg.acquisition, cfg.mounting, cfg.nominal_transform, cfg.sphere,
                                    plan.planned.sweep)
    else:
        plan.targets = plan_targets(cfg.acquisition, cfg.mounting, cfg.nominal_transform, cfg.sphere)
    log(f"plan: {len(plan.targets)} shots in {len(set(t.station for t in plan.targets))} stations")
    log(describe_plan(plan.targets))
    check_plan(plan.targets, cfg.acquisition, "plan", setup=(cfg.mounting, cfg.nominal_transform),
               keep_out=run.keep_out, log=log)
    check_plan_solvable(plan.targets)
    if cfg.calibration.identify_kinematics:
        plan.identification = check_plan_identifies_kinematics(
            plan.targets, cfg.acquisition, cfg.calibration, cfg.mounting, cfg.nominal_transform, cfg.sphere, run.arm,
            plan.planned, robot_type=cfg.robot.get("type"))
        log(plan.identification)
    return plan


def _check_dry_run(run: _Calibration, plan: _Plan) -> None:
    """A dry run: the plan checked against the robot's own limits too (devices opened,
    nothing moved)."""
    run.log("dry run: plan checked against acquisition.workspace and speeds; nothing moved")
    if plan.manual:
        return
    cell = make_cell(run.cfg, run.arm, run.fov)
    with open_devices(run.loaded, run.host, cell, run.log) as (robot, _sensor):
        check_plan(plan.targets, run.cfg.acquisition, "plan", robot=robot,
                   setup=(run.cfg.mounting, run.cfg.nominal_transform), keep_out=run.keep_out, log=run.log)
        check_identification_from_here(robot, plan.targets, run.cfg, run.arm, plan.planned, run.log)
    run.log("plan checked against the robot's own limits too")


def _resumed(journal: Path, digest: str, log: Callable[[str], None]) -> _Resumed:
    """The journal to continue; InputError when it was taken with another plan."""
    previous = dataio.read_dataset(journal)
    taken_with = previous.provenance.get("plan_digest")
    if taken_with != digest:
        raise InputError(
            f"{journal} was taken with another plan ({taken_with}, now {digest}): the configuration's "
            "acquisition, nominal transform or mode changed since; resume with the configuration it was "
            "taken with, or start a new run in another output_dir"
        )
    done = {o.target for o in previous.observations if o.target is not None}
    labels = [o.station for o in previous.observations if o.station[1:].isdigit()]
    first_station = 1 + max((int(lb[1:]) for lb in labels), default=0)
    log(f"resuming {journal}: {len(previous.observations)} observations already taken")
    return _Resumed(previous, done, first_station)


def _journal_provenance(run: _Calibration, digest: str, cell) -> dict:
    """The journal's provenance: the plan, configuration, device types, the estimator's
    settings (``solve`` of the journal starts from them) and, for a simulated cell, its
    truth."""
    cfg = run.cfg
    provenance = {
        "source": "spherecal calibrate",
        "plan_digest": digest,
        "config": str(run.loaded.path),
        "robot": cfg.robot["type"],
        "sensor": cfg.sensor["type"],
        "simulated": cell is not None,
        CALIBRATION_OPTIONS_KEY: calibration_options(cfg).model_dump(mode="json"),
    }
    if run.fov is not None:  # the sensor's field of view: screening names profiles it clipped
        provenance["fov"] = run.fov.model_dump()
    if cell is not None:
        provenance.update(
            true_transform_name=cell.transform_name,
            true_transform=cell.true_transform.model_dump(),
            true_sphere_centre_mm=cell.sphere_centre_mm.tolist(),
            simulation_seed=cfg.simulation.seed,
        )
    return provenance


def _take(run: _Calibration, plan: _Plan, cell, journal: Path, provenance: dict, resumed: _Resumed,
          ask: Callable[[str], str], progress_stream, before_station=None):
    """The acquisition itself, into ``journal``: the devices opened, the plan checked
    against the robot once more, the shots taken (or captured as the operator jogs);
    ``before_station``: the step mode's question before each station."""
    cfg, acq, log = run.cfg, run.cfg.acquisition, run.log
    with open_devices(run.loaded, run.host, cell, log) as (robot, sensor):
        if not plan.manual:
            check_plan(plan.targets, acq, "plan", robot=robot, done=resumed.done,
                       setup=(cfg.mounting, cfg.nominal_transform), keep_out=run.keep_out, log=log)
            check_identification_from_here(robot, plan.targets, cfg, run.arm, plan.planned, log)
        provenance.update(robot_identity=device_identity(robot), sensor_identity=device_identity(sensor))
        if resumed.previous is not None:
            check_same_devices(resumed.previous.provenance, provenance, journal, log)
            check_same_settings(resumed.previous.provenance, provenance, journal, log)
        with warnings.catch_warnings():
            if resumed.previous is not None:  # _resumed read the journal and said what it dropped of it
                warnings.simplefilter("ignore", dataio.TruncatedFileWarning)
            writer = dataio.DatasetWriter(journal, mounting=cfg.mounting, sphere_radius_mm=cfg.sphere.radius_mm,
                                          provenance=provenance, resume=journal.exists(), fsync=True)
        with writer:
            kinds = {"robot_type": cfg.robot["type"], "sensor_type": cfg.sensor["type"]}
            notify = lambda obs: run.host.observation_taken(observation=obs, **kinds)  # noqa: E731
            if plan.manual:
                return acquire_manual(robot, sensor, writer, acq, ask=ask, log=log, on_observation=notify,
                                      rotation_tolerance_deg=station_rotation_tolerance_deg(cfg.calibration),
                                      first_station=resumed.first_station)
            try:
                return acquire(robot, sensor, plan.targets, writer, acq, resumed.done, notify, log,
                               Progress(len(plan.targets), progress_stream),
                               taken=resumed.previous.observations if resumed.done else (),
                               min_points=cfg.calibration.min_points_per_profile, before_station=before_station,
                               clock=cell.clock if cell is not None else None)
            except SensorBlindError as exc:
                q = ", ".join(f"{v:g}" for v in cfg.nominal_transform.quaternion_wxyz)
                raise SensorBlindError(f"{exc}. This configuration: mounting = \"{cfg.mounting}\", "
                                       f"[nominal_transform] quaternion_wxyz = [{q}]") from None


def _solved(run: _Calibration, dataset: Dataset, source: Path, outcome: Outcome, *, report: bool, force: bool,
            operator: str | None) -> Outcome:
    """The dataset solved, graded and written; the plugins told."""
    cfg = run.cfg
    trace = traceability(dataset, source, run.loaded, operator)
    solution, outcome.verdict, outcome.exports_written = solve_and_write(
        dataset, calibration_options(cfg), run.out, run.exports, run.fk, run.log, report=report, force=force,
        kinematics=run.arm, provenance=trace, report_settings=cfg.report)
    run.host.calibration_finished(result=solution.result, dataset=dataset, out_dir=run.out,
                                  exports_written=outcome.exports_written, robot_type=cfg.robot["type"],
                                  sensor_type=cfg.sensor["type"])
    outcome.solution, outcome.dataset = solution, dataset
    outcome.files.update(written_files(run.out))
    return outcome
