"""The application layer: configuration -> plugin host -> devices -> acquisition ->
estimation -> files. The CLI calls these functions; they take every file name and
stream they use as arguments (no hidden I/O)."""

from __future__ import annotations

import contextlib
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import TYPE_CHECKING, Callable, Iterator

import numpy as np
from pydantic import ValidationError

from spherecal.io import dataset as dataio
from spherecal.io.runlog import Notice, progress_log
from spherecal.core.errors import ConfigError, FitBreakdownError, InputError, SpherecalError
from spherecal.estimation import CalibrationOptions, Solution, solve
from spherecal.estimation.options import station_rotation_tolerance_deg
from spherecal.core.models import Dataset, Pose
from spherecal.core.models import SPHERE_FRAME, TRANSFORM_NAME
from spherecal.report.assess import Verdict

if TYPE_CHECKING:
    from spherecal.config import LoadedConfig, ReportConfig, RunConfig
    from spherecal.devices.contract import SensorFieldOfView
    from spherecal.sim import SimulatedCell

# The acquisition, the configuration file's models, the planners, the devices and the
# simulated world are imported by the functions that use them: `spherecal solve` (a
# dataset file, no configuration, no devices) does not load them.

_LOG = progress_log("run")  # the default ``log``: logger spherecal.run
JOURNAL_NAME = "journal.jsonl"
RESULT_NAME = "result.json"
#: The identified robot model written next to the result (:func:`write_calibrated_urdf`).
CALIBRATED_URDF_NAME = "robot_calibrated.urdf"
#: What a calibration writes into its folder besides its exporters' files (an
#: :class:`~spherecal.io.exporters.ExportPlan` gives theirs).
OUTPUT_PATTERNS = (RESULT_NAME, "report.html", "report_*.png", CALIBRATED_URDF_NAME)


def existing_outputs(out: Path, patterns: tuple[str, ...] = ()) -> list[Path]:
    """The files in ``out`` that writing a calibration there would replace (links too):
    :data:`OUTPUT_PATTERNS` and the exporters' ``patterns``."""
    if not out.is_dir():
        return []
    found = {p for pattern in (*OUTPUT_PATTERNS, *patterns) for p in out.glob(pattern)}
    return sorted(found)


def check_output_folder(out: Path, what: str, how: str, exports=None) -> None:
    """Refuse (InputError naming the file) to write a calibration into ``out`` when that
    would replace a file already there: ``what`` is the command, ``how`` how to proceed,
    ``exports`` the run's :class:`~spherecal.io.exporters.ExportPlan` (its files count too)."""
    if out.exists() and not out.is_dir():
        raise InputError(f"{out} is not a folder: give an output folder")
    check_output_targets(out, exports)  # a planted link is named as a link, before anything else
    found = existing_outputs(out, exports.file_patterns() if exports is not None else ())
    journal = out / JOURNAL_NAME
    if found:
        kind = "a calibration run" if journal.exists() else "a result"
        raise InputError(f"{found[0]} exists: {out} already holds {kind}, and {what} would replace it "
                         f"(nothing is overwritten silently); {how}")


def check_output_targets(out: Path, exports=None) -> None:
    """Refuse (InputError naming it) before anything is written into ``out`` when a file
    a calibration would write there exists as a symbolic link or as anything but a
    regular file: the run then writes nothing at all, instead of stopping half-way at the
    first link (:func:`spherecal.io.files.check_writable_target`)."""
    from spherecal.io.files import check_writable_target

    for path in existing_outputs(out, exports.file_patterns() if exports is not None else ()):
        check_writable_target(path)


def sensor_field_of_view(cfg: RunConfig, host) -> SensorFieldOfView | None:
    """The field of view of the run's sensor: its sensor type's declared one
    (:attr:`spherecal.devices.contract.SensorType.field_of_view`), with the fields the
    configuration's ``[simulation.fov]`` gives over it in a simulated run. None when the
    sensor type declares none and the configuration does not give it whole.
    :class:`ConfigError` naming ``simulation.fov`` when the two together are not a field
    of view."""
    from spherecal.devices.contract import SensorFieldOfView

    declared = host.registry.sensor_type(cfg.sensor["type"]).field_of_view
    given = cfg.simulation.fov.model_dump(exclude_none=True) if cfg.simulation and cfg.simulation.fov else {}
    if not given:
        return declared
    fields = {**(declared.model_dump() if declared is not None else {}), **given}
    try:
        return SensorFieldOfView.model_validate(fields)
    except ValidationError as exc:
        whose = (f"sensor type {cfg.sensor['type']!r} declares no field of view" if declared is None
                 else f"over sensor type {cfg.sensor['type']!r}'s field of view")
        problems = "; ".join(f"{'.'.join(str(p) for p in e['loc']) or 'fov'}: {e['msg']}" for e in exc.errors())
        raise ConfigError(f"simulation.fov ({whose}): {problems}") from None


def for_sensor(cfg: RunConfig, field_of_view: SensorFieldOfView | None) -> RunConfig:
    """``cfg`` with the settings it leaves to the sensor set from ``field_of_view``: the
    calibration sweep's (``[acquisition.sweep]`` ``standoff_z_mm``, the sensor's
    ``sweep_standoff_z_mm``; ``station_offsets_mm`` and ``lateral_amplitude_mm``, sized
    to the field of view: :func:`spherecal.motion.planning.with_standoff`) and the scan's
    (``[scan] standoff_z_mm``, the middle of the measuring range). Unchanged without a
    field of view (the planner then asks for them)."""
    if field_of_view is None:
        return cfg
    from spherecal.motion.planning import with_standoff

    update = {}
    acq = cfg.acquisition
    if acq is not None:
        sweep = with_standoff(acq.sweep, field_of_view)
        if sweep is not acq.sweep:
            update["acquisition"] = acq.model_copy(update={"sweep": sweep})
    if cfg.scan is not None and cfg.scan.standoff_z_mm is None:
        update["scan"] = cfg.scan.model_copy(update={"standoff_z_mm": float(field_of_view.middle_z_mm)})
    return cfg.model_copy(update=update) if update else cfg


def configured_for_sensor(loaded: LoadedConfig, host) -> tuple[LoadedConfig, SensorFieldOfView | None]:
    """The configuration with the standoffs it leaves to the sensor set
    (:func:`for_sensor`), and the sensor's field of view (:func:`sensor_field_of_view`)."""
    from spherecal.config import LoadedConfig

    fov = sensor_field_of_view(loaded.config, host)
    return LoadedConfig(for_sensor(loaded.config, fov), loaded.path), fov


def make_cell(cfg: RunConfig, arm=None, field_of_view: SensorFieldOfView | None = None) -> SimulatedCell | None:
    """The simulated cell of a simulated run, or None for hardware. ``arm`` (the robot
    type's :class:`~spherecal.core.kinematics.ArmKinematics`, when it describes its arm) lays
    the standard cell out for the arm's reach (:func:`spherecal.sim.standard_cell`); the
    configuration's ``[simulation] sphere_centre_mm`` and ``true_transform`` override it.
    An arm with a calibrated model (kinematics that keep their ``nominal`` one) is laid out
    as its nominal arm: giving the robot its calibrated model must not move the world.
    ``field_of_view`` is the simulated sensor's (default: :func:`sensor_field_of_view` with
    the installed plugins); :class:`ConfigError` naming ``simulation.fov`` when there is none."""
    from spherecal.sim import BallBar, CarDoorPanel, FlatPlate, standard_cell

    sim = cfg.simulation
    if sim is None:
        return None
    if field_of_view is None:
        field_of_view = sensor_field_of_view(cfg, make_host())
    if field_of_view is None:
        raise ConfigError(f"simulation.fov: sensor type {cfg.sensor['type']!r} declares no field of view; give "
                          "z_near_mm, z_far_mm, width_near_mm and width_far_mm in [simulation.fov]")
    cell = standard_cell(cfg.mounting, seed=sim.seed, noise=sim.noise, fov=field_of_view,
                         sphere_radius_mm=cfg.sphere.radius_mm,
                         arm=getattr(arm, "nominal", arm))
    cell.arm = None  # laid out for the arm; the simulated controller attaches its own (nominal) arm
    cell.noise_per_pose = True  # a resumed run reproduces an uninterrupted one
    cell.robot_error = sim.robot_error  # the simulated controller gives its arm this error
    if sim.true_transform is not None:
        cell.true_transform = sim.true_transform.pose()
    if sim.sphere_centre_mm is not None:
        cell.sphere_centre_mm = np.asarray(sim.sphere_centre_mm, dtype=float)
    frame = SPHERE_FRAME[cfg.mounting]
    v = cfg.validation
    if v is not None and v.ball_bar is not None:
        bb = v.ball_bar
        a, b = np.asarray(bb.centre_a_mm, float), np.asarray(bb.centre_b_mm, float)
        true = sim.ball_bar_true_distance_mm or bb.certified_distance_mm
        b = a + (b - a) / np.linalg.norm(b - a) * true  # the simulated bar has its true length
        cell.add_object(BallBar(a, b, bb.ball_radius_mm, frame=frame, certified_distance_mm=bb.certified_distance_mm))
    if v is not None and v.flat is not None:
        f = v.flat
        cell.add_object(FlatPlate(Pose.from_abb(f.centre_mm, f.quaternion_wxyz), f.length_mm, f.width_mm, frame=frame))
    if sim.scan_object != "none":
        if cfg.scan is None:
            raise ConfigError("simulation.scan_object needs a [scan] section (its object_centre_mm places the object)")
        at = Pose.from_abb(cfg.scan.object_centre_mm, (1.0, 0.0, 0.0, 0.0))
        if sim.scan_object == "flat_plate":
            cell.add_object(FlatPlate(at, 300.0, 200.0, frame=frame, name="scan_plate"))
        else:
            cell.add_object(CarDoorPanel(at, frame=frame))
    return cell


def make_host(enable: list[str] | None = None):
    from spherecal.plugins.host import PluginHost

    return PluginHost(enable=enable) if enable else PluginHost()


def export_plan(loaded: LoadedConfig, host, log: Callable[[str], None] | None = None):
    """The exporters of a configured run (``[export]``), checked before anything moves;
    ``log`` hears which exporters were left out and why."""
    cfg = loaded.config
    plan = _in_file(loaded, host.export_plan, cfg.export, cfg.mounting, cfg.robot["type"])
    if log is not None:
        for why in plan.left_out.values():
            log(f"export: {why}")
    return plan


def _in_file(loaded: LoadedConfig, fn, *args, **kwargs):
    try:
        return fn(*args, **kwargs)
    except ConfigError as exc:
        raise ConfigError(f"{loaded.path}: {exc}") from None


def robot_arm(loaded: LoadedConfig, host):
    """The configured robot's arm kinematics (None when its type does not describe it);
    relative paths in the robot section resolve against the configuration's folder."""
    return _in_file(loaded, host.arm_kinematics, loaded.config.robot, base_dir=loaded.path.parent)


def tool_point_mm(cfg: RunConfig) -> tuple[float, float, float] | None:
    """The point on the flange whose speed the moves limit (flange frame, mm): the
    sensor's origin from the nominal transform (eye-in-hand), the rough sphere centre
    (eye-to-hand)."""
    if cfg.mounting == "eye_in_hand":
        return tuple(cfg.nominal_transform.translation_mm)
    return tuple(cfg.acquisition.sphere_centre_mm) if cfg.acquisition is not None else None


@contextlib.contextmanager
def open_devices(loaded: LoadedConfig, host, cell: SimulatedCell | None, log: Callable[[str], None]) -> Iterator:
    """Robot and sensor from the configuration, closed on the way out whatever happens."""
    from spherecal.devices.contract import DeviceContext

    cfg = loaded.config
    context = DeviceContext(cell=cell, log=log, tool_point_mm=tool_point_mm(cfg))
    robot = _in_file(loaded, host.create_robot, cfg.robot, context, base_dir=loaded.path.parent)
    try:
        sensor = _in_file(loaded, host.create_sensor, cfg.sensor, context)
    except BaseException:
        robot.close()
        raise
    try:
        yield robot, sensor
    finally:
        with contextlib.suppress(Exception):
            sensor.close()
        robot.close()


def plan_digest(targets) -> str:
    """A short fingerprint of a plan (every target's station, pose and speed), stored in
    the journal so that --resume can refuse a journal taken with another plan."""
    import hashlib

    h = hashlib.sha256()
    for t in targets:
        h.update(f"{t.index}|{t.station}|{t.speed_mm_s:.6f}|".encode())
        h.update(np.round(np.concatenate([t.pose.translation_mm, t.pose.quaternion_wxyz]), 6).tobytes())
    return h.hexdigest()[:16]


def _check_plan(targets, acq, what: str = "plan", robot=None, done: set[int] = frozenset()) -> None:
    """Raise before any motion when a target breaks the configured limits (or, with
    ``robot``, the robot plugin's own limits, and the first move, from wherever the arm
    stands to the first target not in ``done``, breaks either)."""
    from spherecal.motion.acquisition import check_first_move, check_targets

    problems = check_targets(targets, acq, robot)
    todo = [t for t in targets if t.index not in done]
    if robot is not None and todo:
        problems += check_first_move(robot, todo[0], acq)
    if problems:
        limits = "the robot's limits" if robot is not None else "the limits"
        raise InputError(f"the {what} breaks {limits}; nothing was moved:\n  " + "\n  ".join(problems))


def _check_identification_from_here(robot, targets, cfg, arm, planned, log) -> None:
    """With ``identify_kinematics``, once the robot is connected: the plan check again,
    with the joints the arm will take from where it stands (the check before connecting
    assumed zero joints; an arm that starts in another wrist or elbow configuration keeps
    it, and sees the arm's geometry from other joints). Raises before anything moves when
    the plan no longer identifies the arm from here."""
    from spherecal.motion.kinematic_plan import check_plan_identifies_kinematics

    if not cfg.calibration.identify_kinematics or arm is None:
        return
    start = robot.read_joints_deg()
    if start is None:
        return
    try:
        log("from the arm's joints now: " + check_plan_identifies_kinematics(
            targets, cfg.acquisition, cfg.calibration, cfg.mounting, cfg.nominal_transform, cfg.sphere, arm,
            planned, start_joints_deg=start))
    except SpherecalError as exc:
        raise InputError(f"from where the arm stands now (joints {np.round(np.asarray(start, float), 1).tolist()} deg): "
                         f"{exc}") from exc


def check_plan_solvable(targets) -> None:
    """Raise InputError (before anything moves) when the plan's stations can never
    determine the transform: the translation needs changes of orientation about at
    least two different axes, so at least three stations."""
    first: dict[str, np.ndarray] = {}
    for t in targets:
        first.setdefault(t.station, t.pose.rotation_matrix)
    Rs = list(first.values())
    hint = ("add stations tilted by 20-45 deg about two different axes (acquisition.sweep.tilts_deg); nothing "
            "was moved")
    if len(Rs) < 3:
        raise InputError(f"the plan has {len(Rs)} station(s): the translation cannot be determined from fewer than "
                         f"three orientations; {hint}")
    M = np.vstack([R - Rs[0] for R in Rs[1:]])
    sv = np.linalg.svd(M, compute_uv=False)
    if sv[-1] < 0.05:
        raise InputError("the plan's stations are tilted about one axis only: the translation along it cannot be "
                         f"determined; {hint}")


class MotionNotConfirmed(ConfigError):
    """The operator did not confirm the motion (or could not: no input and no --yes)."""


def confirm_motion(command: str, plan: str, yes: bool, ask: Callable[[str], str], log: Callable[[str], None]) -> None:
    """Before the first motion on real hardware: the plan summary and a typed 'yes', or
    ``yes`` (``--yes``). Raises :class:`MotionNotConfirmed` otherwise; nothing has been
    opened or moved then."""
    if yes:
        log(f"{command}: motion confirmed with --yes: {plan}")
        return
    log(Notice(f"{command} is about to move the real robot: {plan}. Keep the cell clear and a hand on the "
               "enabling device or the emergency stop."))  # shown with -q too: it is what 'yes' confirms
    try:
        answer = ask("Type 'yes' to start the motion (anything else stops): ")
    except (EOFError, OSError):
        raise MotionNotConfirmed(f"{command} would move the robot and nobody confirmed it (no input): run it at a "
                                 "terminal and type 'yes', or give --yes; nothing was moved") from None
    if answer.strip().lower() != "yes":
        raise MotionNotConfirmed(f"{command}: motion not confirmed (answer {answer.strip()[:20]!r}); nothing was moved")


@dataclass
class Outcome:
    """What a calibrate/solve run produced."""

    solution: Solution | None = None
    files: dict[str, Path] = field(default_factory=dict)
    notes: list[str] = field(default_factory=list)
    verdict: "Verdict | None" = None
    #: False when the result is RED and was not written (no ``force``)
    exports_written: bool = False
    #: ``--resume`` found a finished run (its result.json): nothing was done
    finished: bool = False


def calibration_options(cfg: RunConfig) -> CalibrationOptions:
    return cfg.calibration.model_copy(update={"nominal_transform": cfg.nominal_transform.pose()})


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
) -> Outcome:
    """``spherecal calibrate``: plan, check, acquire into the journal (or replay a
    recorded dataset), solve, write the result, exports and report. A RED result's
    ``result.json`` and exports are written only with ``force`` (its report always).
    ``operator`` (``--operator``) overrides the configuration's ``[report] operator``."""
    from spherecal.motion.acquisition import Progress, acquire, acquire_manual, describe_plan, plan_targets
    from spherecal.devices.contract import device_identity
    from spherecal.motion.kinematic_plan import check_plan_identifies_kinematics, plan_kinematic_stations, uses_planner

    out = Path(out_dir) if out_dir is not None else loaded.output_dir
    host = make_host()
    loaded, fov = configured_for_sensor(loaded, host)
    cfg = loaded.config
    fk = _in_file(loaded, host.robot_kinematics, cfg.robot, base_dir=loaded.path.parent)
    arm = robot_arm(loaded, host)
    _in_file(loaded, host.validate_sensor_config, cfg.sensor["type"], cfg.sensor)
    exports = export_plan(loaded, host, log)
    outcome = Outcome()

    if resume and (out / RESULT_NAME).exists():
        outcome.finished = True  # (the command says so, once)
        return outcome
    if cfg.replay is not None:
        path = loaded.resolve(cfg.replay)
        if not dry_run:
            check_output_folder(out, "calibrate", "give a new folder (--out or output_dir)", exports)
        log(f"replaying {path}")
        dataset = dataio.read_dataset(path)
        if dataset.mounting != cfg.mounting:
            raise InputError(f"{path}: dataset is {dataset.mounting} but the configuration says {cfg.mounting}")
        if dry_run:
            log(f"dry run: {len(dataset.observations)} observations would be solved")
            return outcome
    else:
        acq = cfg.acquisition
        manual = manual or acq.mode == "manual"
        journal = out / JOURNAL_NAME
        targets, identification, planned = [], "", None
        if not manual and uses_planner(cfg.acquisition, cfg.calibration):
            planned = plan_kinematic_stations(cfg.acquisition, cfg.calibration, cfg.mounting, cfg.nominal_transform,
                                              cfg.sphere, arm, robot_type=cfg.robot.get("type"))
            log(planned.summary())
            targets = plan_targets(cfg.acquisition, cfg.mounting, cfg.nominal_transform, cfg.sphere, planned.sweep)
        elif not manual:
            targets = plan_targets(cfg.acquisition, cfg.mounting, cfg.nominal_transform, cfg.sphere)
        if not manual:
            log(f"plan: {len(targets)} shots in {len(set(t.station for t in targets))} stations")
            log(describe_plan(targets))
            _check_plan(targets, acq, "plan")
            check_plan_solvable(targets)
            if cfg.calibration.identify_kinematics:
                identification = check_plan_identifies_kinematics(
                    targets, cfg.acquisition, cfg.calibration, cfg.mounting, cfg.nominal_transform, cfg.sphere, arm,
                    planned, robot_type=cfg.robot.get("type"))
                log(identification)
        if dry_run:
            log("dry run: plan checked against acquisition.workspace and speeds; nothing moved")
            if not manual:
                cell = make_cell(cfg, arm, fov)
                with open_devices(loaded, host, cell, log) as (robot, _sensor):
                    _check_plan(targets, acq, "plan", robot=robot)
                    _check_identification_from_here(robot, targets, cfg, arm, planned, log)
                log("plan checked against the robot's own limits too")
            return outcome
        if journal.exists() and not resume:
            raise InputError(
                f"{journal} already holds an acquisition: run with --resume to continue it, "
                "or choose another output_dir (nothing is ever overwritten)"
            )
        if not journal.exists():
            check_output_folder(out, "calibrate", "give a new folder (--out or output_dir)", exports)
        cell = make_cell(cfg, arm, fov)
        if not manual and cell is None:
            confirm_motion("calibrate", f"{len(targets)} shots in {len(set(t.station for t in targets))} stations "
                           f"(plan above), at most {acq.max_speed_mm_s:g} mm/s"
                           + (f"; {identification}" if identification else ""), yes, ask, log)
        out.mkdir(parents=True, exist_ok=True)
        done: set[int] = set()
        digest = "manual" if manual else plan_digest(targets)
        first_station = 1
        if resume and journal.exists():
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
        provenance = {
            "source": "spherecal calibrate",
            "plan_digest": digest,
            "config": str(loaded.path),
            "robot": cfg.robot["type"],
            "sensor": cfg.sensor["type"],
            "simulated": cell is not None,
        }
        if cell is not None:
            provenance.update(
                true_transform_name=cell.transform_name,
                true_transform=cell.true_transform.model_dump(),
                true_sphere_centre_mm=cell.sphere_centre_mm.tolist(),
                simulation_seed=cfg.simulation.seed,
            )
        with open_devices(loaded, host, cell, log) as (robot, sensor):
            if not manual:
                _check_plan(targets, acq, "plan", robot=robot, done=done)
                _check_identification_from_here(robot, targets, cfg, arm, planned, log)
            provenance.update(robot_identity=device_identity(robot), sensor_identity=device_identity(sensor))
            if resume and journal.exists():
                _check_same_devices(previous.provenance, provenance, journal, log)
            with dataio.DatasetWriter(
                journal, mounting=cfg.mounting, sphere_radius_mm=cfg.sphere.radius_mm,
                provenance=provenance, resume=journal.exists(), fsync=True,
            ) as writer:
                kinds = {"robot_type": cfg.robot["type"], "sensor_type": cfg.sensor["type"]}
                notify = lambda obs: host.observation_taken(observation=obs, **kinds)  # noqa: E731
                if manual:
                    rep = acquire_manual(robot, sensor, writer, acq, ask=ask, log=log, on_observation=notify,
                                         rotation_tolerance_deg=station_rotation_tolerance_deg(cfg.calibration),
                                         first_station=first_station)
                else:
                    rep = acquire(robot, sensor, targets, writer, acq, done, notify, log,
                                  Progress(len(targets), progress_stream),
                                  taken=previous.observations if done else ())
        outcome.notes.extend(rep.skipped)
        for s in rep.skipped:
            log(f"skipped {s}")
        dataset = dataio.read_dataset(journal)
        host.acquisition_finished(dataset=dataset, robot_type=cfg.robot["type"], sensor_type=cfg.sensor["type"])
        outcome.files["journal"] = journal

    trace = traceability(dataset, path if cfg.replay is not None else outcome.files["journal"], loaded, operator)
    solution, outcome.verdict, outcome.exports_written = solve_and_write(
        dataset, calibration_options(cfg), out, fk, log, report=report, force=force, kinematics=arm, exports=exports,
        provenance=trace, report_settings=cfg.report)
    host.calibration_finished(result=solution.result, dataset=dataset, out_dir=out,
                              exports_written=outcome.exports_written, robot_type=cfg.robot["type"],
                              sensor_type=cfg.sensor["type"])
    outcome.solution = solution
    outcome.files.update(written_files(out))
    return outcome


def written_files(out: Path) -> dict[str, Path]:
    return {p.name: p for p in sorted(out.iterdir()) if p.is_file()} if out.exists() else {}


def provenance_type(dataset: Dataset, kind: str = "robot") -> str | None:
    """The robot (or, with ``kind="sensor"``, sensor) type a dataset's provenance names
    (``"robot": "abb_irb2400"`` as ``spherecal calibrate`` writes it, or ``"robot":
    {"type": ...}``), or None."""
    robot = dataset.provenance.get(kind)
    if isinstance(robot, dict):
        robot = robot.get("type")
    return robot if isinstance(robot, str) and robot else None


def solve_robot_type(dataset: Dataset, robot_type: str | None = None, robot_config: Path | None = None) -> str | None:
    """The robot type of a ``spherecal solve``: ``robot_type`` (``--robot``), else the
    ``type`` of ``robot_config``, else the one the dataset's provenance names; None when
    nothing says (then every exporter for the mounting runs)."""
    if robot_type:
        return robot_type
    if robot_config is not None:
        given = read_robot_section(robot_config).get("type")
        if isinstance(given, str) and given:
            return given
    return provenance_type(dataset)


def read_robot_section(path: Path) -> dict:
    """A robot section from a TOML file: its ``[robot]`` table (a spherecal configuration)
    or, without one, the whole file (the plugin's settings, ``type`` optional)."""
    from spherecal.config import read_toml

    data = read_toml(path, "robot configuration")
    section = data.get("robot", data)
    if not isinstance(section, dict):
        raise ConfigError(f"{path}: robot: expected a table of robot settings")
    return dict(section)


def solve_kinematics(
    dataset: Dataset,
    robot_type: str | None = None,
    robot_config: Path | None = None,
    pose_from: str = "reported",
    host=None,
) -> tuple[Callable | None, Dataset, object | None]:
    """Forward kinematics for ``spherecal solve``, the dataset to solve, and the robot's
    :class:`~spherecal.core.kinematics.ArmKinematics` when its plugin describes the arm (for
    the kinematic robot error model; None otherwise).

    The robot type is ``robot_type`` (``--robot``), else the ``type`` in ``robot_config``
    (``--robot-config``), else the one the dataset's provenance names; its settings are
    those of ``robot_config`` or the plugin's defaults. An explicitly named type is always
    checked (an unknown one is a :class:`ConfigError` naming the installed ones); the
    provenance's only when kinematics is needed. ``pose_from``: ``"reported"`` uses each
    observation's ``base_from_flange`` and kinematics only for observations without one;
    ``"joints"`` computes every flange pose from ``joints_deg``."""
    if pose_from not in ("reported", "joints"):
        raise ConfigError(f"--pose-from: expected 'reported' or 'joints', got {pose_from!r}")
    section = read_robot_section(robot_config) if robot_config is not None else {}
    given = section.pop("type", None)
    if robot_type is not None and given is not None and given != robot_type:
        raise ConfigError(f"--robot {robot_type} but {robot_config} says type = {given!r}: give one robot type")
    name, where = (robot_type, "--robot") if robot_type else (given, f"{robot_config}: robot.type")
    needed = pose_from == "joints" or any(o.base_from_flange is None for o in dataset.observations)
    if name is None:
        name, where = provenance_type(dataset), "the dataset's provenance robot"
        if name is None or not needed:
            if pose_from == "joints":
                raise ConfigError("--pose-from joints needs the robot's kinematics: give --robot TYPE "
                                  "(`spherecal plugins` lists the robot types)")
            return None, dataset, _provenance_arm(name, dataset, host)
    host = host or make_host()
    host.registry.robot_type(name, path=where)
    path = f"{robot_config}: robot" if robot_config is not None else "robot"
    base_dir = Path(robot_config).resolve().parent if robot_config is not None else None
    fk = host.robot_kinematics({"type": name, **section}, path=path, base_dir=base_dir)
    if fk is None:
        if needed:
            raise ConfigError(f"{where}: robot type '{name}' has no forward kinematics; observations need "
                              "base_from_flange, or a robot type whose plugin computes poses from joints")
        return None, dataset, None
    if pose_from == "joints":
        obs = []
        for o in dataset.observations:
            if o.joints_deg is None:
                raise InputError(f"observation {o.index} (station {o.station}) has no joints_deg: "
                                 "--pose-from joints needs joint readings in every observation")
            try:
                pose = fk(np.asarray(o.joints_deg, dtype=float))
            except SpherecalError as exc:
                raise InputError(f"observation {o.index} (station {o.station}): joints_deg: {exc}") from None
            obs.append(o.model_copy(update={"base_from_flange": pose}))
        dataset = dataset.model_copy(update={"observations": obs})
    return fk, dataset, host.arm_kinematics({"type": name, **section}, path=path, base_dir=base_dir)


def _provenance_arm(name: str | None, dataset: Dataset, host):
    """The arm kinematics of the robot type the dataset's provenance names, when the
    observations carry joints and that type is installed with default settings; else None
    (the estimator then models the robot's error per station)."""
    if name is None or any(o.joints_deg is None for o in dataset.observations):
        return None
    host = host or make_host()
    try:
        return host.arm_kinematics({"type": name})
    except SpherecalError:
        return None


def solve_and_write(
    dataset: Dataset,
    options: CalibrationOptions,
    out: Path,
    fk=None,
    log: Callable[[str], None] = _LOG,
    report: bool = True,
    force: bool = False,
    kinematics=None,
    exports=None,
    provenance: dict | None = None,
    report_settings: ReportConfig | None = None,
) -> tuple[Solution, "Verdict", bool]:
    """Solve ``dataset``, grade the result (:func:`assess_solution`) and write
    ``result.json``, the exports and the HTML report in ``out``. A RED result's
    ``result.json`` and exports are written only with ``force``; its report is written
    (it says why). Returns the solution, its verdict and whether the result and exports
    were written. ``kinematics``: the robot's arm model, for the kinematic robot error
    model. ``exports``: the run's :class:`~spherecal.io.exporters.ExportPlan` (None: every
    installed exporter for the mounting, with default settings); ``provenance``: the
    result's (:func:`traceability`); ``report_settings``: the configuration's ``[report]``."""
    from spherecal.io.exporters import write_exports

    if exports is None:
        exports = make_host().export_plan(None, dataset.mounting, None)
    check_output_targets(out, exports)  # a planted link: refuse before solving, write nothing
    try:
        solution = solve(dataset, options, fk, progress=log, kinematics=kinematics)
    except FitBreakdownError as exc:
        cause = _breakdown_cause(dataset, options, fk, log, kinematics)
        if cause is None:
            raise
        raise FitBreakdownError(f"{cause}. ({exc})") from None
    if provenance is not None:
        solution = replace(solution, result=solution.result.model_copy(update={"provenance": provenance}))
    graded = assess_solution(solution, dataset, options, fk, log, kinematics=kinematics)
    out.mkdir(parents=True, exist_ok=True)
    written = graded.level != "red" or force
    # the verdict travels with the result: a RED one written with --force says so in result.json
    solution = replace(solution, result=solution.result.model_copy(update={"diagnostics": {
        **solution.result.diagnostics,
        "verdict": {"level": graded.level, "headline": graded.headline, "written_with_force": graded.level == "red"}}}))
    if written:
        write_exports(solution.result, out, exports, overwrite=True)  # result.json among them; derived files only
        urdf = write_calibrated_urdf(solution, kinematics, out)
        if urdf is not None:
            log(f"calibrated robot model: {urdf}")
    if report:
        try:
            from spherecal.report.html import write_report
        except ImportError:  # pragma: no cover
            write_report = None
        if write_report is not None:
            chosen = {} if report_settings is None else {"point_distance_mm": report_settings.point_distance_mm}
            write_report(solution, out, verdict_override=graded, notes=exports.notes(solution.result), **chosen)
    return solution, graded, written


def sha256_of(path: Path) -> str:
    """SHA-256 of a file's bytes, hex."""
    import hashlib

    h = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


def traceability(dataset: Dataset, dataset_path: Path | None, loaded: LoadedConfig | None = None,
                 operator: str | None = None) -> dict:
    """The result's provenance (docs/results.md, "Identity and traceability"): what was
    calibrated (cell, robot and sensor types with what the devices said they are, the
    sphere and its certificate), by whom, when, with which software, and the SHA-256 of
    the dataset and of the configuration it was calibrated from."""
    from datetime import datetime, timezone

    from spherecal import __version__

    prov = dataset.provenance
    cfg = loaded.config if loaded is not None else None
    settings = cfg.report if cfg is not None else None  # (its [report]: operator, cell)

    def device(kind: str) -> dict:
        given = prov.get(kind)
        kind_type = given.get("type") if isinstance(given, dict) else given
        if kind_type is None and cfg is not None:
            kind_type = getattr(cfg, kind).get("type")
        found = prov.get(f"{kind}_identity")
        return {"type": kind_type, **(found if isinstance(found, dict) else {})}

    sphere = {"radius_mm": dataset.sphere_radius_mm}
    if cfg is not None:
        sphere.update(radius_uncertainty_mm_k2=cfg.sphere.radius_uncertainty_mm, certificate=cfg.sphere.certificate)
    return {
        "dataset": prov.get("source", "unknown"),
        "dataset_file": None if dataset_path is None else str(dataset_path),
        "dataset_sha256": None if dataset_path is None else sha256_of(dataset_path),
        "configuration_file": None if loaded is None else str(loaded.path),
        "configuration_sha256": None if loaded is None else sha256_of(loaded.path),
        "software": f"spherecal {__version__}",
        "calibrated_at": datetime.now(timezone.utc).isoformat(timespec="seconds"),
        "operator": operator or (settings.operator if settings is not None else None),
        "cell": settings.cell if settings is not None else None,
        "robot": device("robot"),
        "sensor": device("sensor"),
        "sphere": sphere,
        "simulated": prov.get("simulated"),
    }


def _check_same_devices(before: dict, now: dict, journal: Path, log: Callable[[str], None]) -> None:
    """On --resume: say so when the robot or sensor now connected is not the one the
    journal was started with (a swapped unit changes the transform)."""
    for kind in ("robot", "sensor"):
        was, is_ = before.get(f"{kind}_identity") or {}, now.get(f"{kind}_identity") or {}
        if was.get("serial_number") and is_.get("serial_number") and was["serial_number"] != is_["serial_number"]:
            log(f"warning: {journal} was started with {kind} serial number {was['serial_number']}, now "
                f"{is_['serial_number']} is connected: the journal's provenance keeps the first; if the unit was "
                "swapped, start a new run")




def write_calibrated_urdf(solution: Solution, kinematics, out: Path) -> Path | None:
    """With identified kinematic parameters, the robot with its identified geometry as a
    URDF (metres, joints in the model's convention): the nominal chain with the identified
    errors applied and the others left at zero. Joint and link names are the arm's when
    its kinematics name them (``joint_names``, ``base_link``, ``flange_link``: a robot
    described by its URDF reads the file back with the same settings), else ``joint_1``
    ... with ``base_link`` and ``tool0``. None when nothing was identified."""
    ref = solution.refined
    ke = ref.diagnostics.get("kinematic_effects")
    if kinematics is None or not ke or not any(ke["identified"]):
        return None
    from spherecal.io import files as safeio
    from spherecal.io.exporters import red_warning
    from spherecal.core.kinematics import chain_with_errors
    from spherecal.core.urdf import chain_to_urdf

    kappa = np.where(ke["identified"], ref.kinematic_errors, 0.0)
    limits = getattr(kinematics, "model_joint_limits_rad", None)
    n_id = sum(ke["identified"])
    text = chain_to_urdf(
        chain_with_errors(kinematics.chain, kappa), "spherecal_calibrated_robot",
        joint_names=getattr(kinematics, "joint_names", None),
        base_link=getattr(kinematics, "base_link", "base_link"),
        flange_link=getattr(kinematics, "flange_link", "tool0"),
        joint_limits_rad=limits() if callable(limits) else None,
        warning=red_warning(solution.result) or None,
        comment=f"Identified by spherecal from {solution.problem.n_profiles} profiles: {n_id} of "
                f"{len(ke['identified'])} geometric parameters (result.json, robot_error.kinematic_parameters); "
                "joint zero offsets are folded into the joint origins.",
    )
    path = out / CALIBRATED_URDF_NAME
    safeio.write_text(path, text)
    return path


def _breakdown_cause(dataset: Dataset, options: CalibrationOptions, fk, log, kinematics,
                     what: str = "the fit broke down") -> str | None:
    """When the fit of ``dataset`` broke down or is absurd (``what``): the dataset read
    another way that fits, if one does (one solve each, only then): the quaternions read
    (x, y, z, w) instead of (w, x, y, z), the other mounting. The sentence naming it, or
    None."""
    from spherecal.report.assess import absurd_ratio, is_absurd

    def fits(ds: Dataset):
        res = _solved_other_way(ds, options, fk, kinematics)
        return None if res is None or is_absurd(res) else res

    if all(o.base_from_flange is not None for o in dataset.observations):
        log(f"{what}: trying the quaternions as (x, y, z, w)")
        alt = fits(_quaternions_read_xyzw(dataset))
        if alt is not None:
            return ("the poses' quaternions are probably written (x, y, z, w): read that way the same data fit, with "
                    f"residual RMS {alt.residuals.rms_mm:.4f} mm ({absurd_ratio(alt):.2f} x the expected). spherecal "
                    "reads base_from_flange quaternions w first, as ABB writes them (docs/conventions.md); convert "
                    "them, or export them w first")
    other = _other_mounting(dataset.mounting)
    log(f"{what}: checking whether the data are {other} data")
    alt = fits(dataset.model_copy(update={"mounting": other}))
    if alt is not None:
        return (f"the dataset's mounting is probably wrong: it says {dataset.mounting}, but solved as {other} the "
                f"same data fit with residual RMS {alt.residuals.rms_mm:.4f} mm ({absurd_ratio(alt):.2f} x the "
                "expected). Check the sensor's mounting and the 'mounting' of the configuration or dataset")
    return _station_quaternions_xyzw(dataset, options, fk, log, kinematics, what,
                                     lambda res: not is_absurd(res))


def _solved_other_way(dataset: Dataset, options: CalibrationOptions, fk, kinematics):
    """The result of ``dataset`` (read another way than given), without the nominal
    transform (it was given for the data as first read); None when it cannot be solved."""
    try:
        return solve(dataset, options.model_copy(update={"nominal_transform": None}), fk,
                     kinematics=kinematics).result
    except SpherecalError:
        return None


def _quaternions_read_xyzw(dataset: Dataset, station: str | None = None) -> Dataset:
    """``dataset`` with its poses' quaternions (or one station's) taken as written
    (x, y, z, w): the w-first reading of a pose written scalar last, undone."""
    return dataset.model_copy(update={"observations": [
        o.model_copy(update={"base_from_flange": Pose(
            translation_mm=o.base_from_flange.translation_mm,
            quaternion_wxyz=np.roll(np.asarray(o.base_from_flange.quaternion_wxyz, float), 1))})
        if station is None or o.station == station else o for o in dataset.observations]})


def _station_quaternions_xyzw(dataset: Dataset, options: CalibrationOptions, fk, log, kinematics, what: str,
                              good: Callable) -> str | None:
    """The station whose quaternions, read (x, y, z, w), make the result ``good`` (one
    solve a station, only for a result that failed): a station's poses exported by
    another tool. The sentence naming it, or None."""
    if any(o.base_from_flange is None for o in dataset.observations):
        return None
    labels = list(dict.fromkeys(o.station for o in dataset.observations))
    log(f"{what}: trying each station's quaternions as (x, y, z, w)")
    for label in labels:
        alt = _solved_other_way(_quaternions_read_xyzw(dataset, label), options, fk, kinematics)
        if alt is not None and good(alt):
            return (f"station {label}'s quaternions are probably written (x, y, z, w): read that way the stations fit "
                    f"together (residual RMS {alt.residuals.rms_mm:.4f} mm). spherecal reads base_from_flange "
                    "quaternions w first, as ABB writes them (docs/conventions.md): convert that station's poses")
    return None


def _other_mounting(mounting: str) -> str:
    return "eye_to_hand" if mounting == "eye_in_hand" else "eye_in_hand"


def assess_solution(solution: Solution, dataset: Dataset, options: CalibrationOptions, fk=None,
                    log: Callable[[str], None] = _LOG, kinematics=None) -> "Verdict":
    """The verdict of ``solution`` (:func:`spherecal.report.assess.verdict`); for a RED
    one, the likely cause named where the data can tell it:

    - an absurd solution (residuals many times the noise) solved again with the other
      mounting: when that fits, the dataset's mounting label is wrong;
    - residuals above the expected with the certified radius: solved again with the
      radius fitted; when the data prefer another radius, it is named.

    Each check costs one more solve, and only for a RED result. ``kinematics`` (the arm's,
    as given to :func:`solve`) is passed to every such solve: without it a solve that
    identifies the arm's geometry or uses the kinematic error model refuses to run, and
    the check would say nothing."""
    from spherecal.report.assess import Thresholds, absurd_ratio, expected_rms_mm, is_absurd, verdict

    th = Thresholds()
    v = verdict(solution.result, th)
    if v.level != "red":
        return v
    result = solution.result
    ratio = result.residuals.rms_mm / expected_rms_mm(result, th)
    causes: list[str] = []
    absurd = is_absurd(result, th)
    if absurd:
        cause = _breakdown_cause(dataset, options, fk, log, kinematics,
                                 f"the result is absurd ({absurd_ratio(result, th):.3g} x the expected)")
        if cause is not None:
            causes.append(cause)
    if not causes and not result.radius_fitted and ratio > th.residual_ratio_amber:
        log("residuals above the expected: checking which sphere radius the data prefer")
        try:
            alt = solve(dataset, options.model_copy(update={"fit_radius": True}), fk, kinematics=kinematics).result
        except SpherecalError:
            alt = None
        if alt is not None and alt.std_sphere_radius_mm is not None:
            given, fitted = result.sphere_radius_mm, alt.sphere_radius_mm
            if abs(fitted - given) > max(5 * alt.std_sphere_radius_mm, 0.01) and alt.residuals.rms_mm < 0.7 * result.residuals.rms_mm:
                causes.append(
                    f"the sphere radius is probably wrong: the data prefer {fitted:.3f} mm (1-sigma "
                    f"{alt.std_sphere_radius_mm:.3f} mm; residual RMS then {alt.residuals.rms_mm:.4f} mm) but "
                    f"{given:g} mm was given. Check the certificate (radius in mm, not the diameter)"
                )
    re = result.robot_error
    if not causes and re is not None and len(dataset.observations) and re.station_translation_mm > 0.1:
        causes.extend(_odd_station(solution, dataset, options, fk, log, th, kinematics))
        if not causes and not absurd:  # (an absurd result has had its stations read the other way already)
            spread = re.station_translation_mm
            cause = _station_quaternions_xyzw(
                dataset, options, fk, log, kinematics, f"the stations disagree by {spread:.3f} mm",
                lambda alt: verdict(alt, th).level != "red" and alt.robot_error is not None
                and alt.robot_error.station_translation_mm < spread / 3)
            if cause is not None:
                causes.append(cause)
    if causes:
        v.reasons.extend(("red", "likely cause: " + c) for c in causes)
        v.headline = f"{v.headline} Likely cause: {causes[0].split(':')[0]}."
    return v


def _odd_station(solution: Solution, dataset: Dataset, options: CalibrationOptions, fk, log, th,
                 kinematics=None) -> list[str]:
    """The station whose leaving out makes the others agree, when there is one: each
    station left out in turn (one solve each)."""
    from spherecal.report.assess import verdict

    result = solution.result
    labels = list(solution.problem.station_labels)
    if len(labels) < 4:
        return []
    log(f"the stations disagree by {result.robot_error.station_translation_mm:.3f} mm: leaving each out in turn")
    best = None
    for label in labels:
        keep = [o for o in dataset.observations if o.station != label]
        try:
            alt = solve(dataset.model_copy(update={"observations": keep}), options, fk, kinematics=kinematics).result
        except SpherecalError:
            continue
        spread = alt.robot_error.station_translation_mm if alt.robot_error is not None else 0.0
        if best is None or spread < best[1]:
            best = (label, spread, verdict(alt, th).level)
    if best is None or best[2] == "red" or best[1] > result.robot_error.station_translation_mm / 3:
        return []
    return [f"station {best[0]} disagrees with the others: without it they agree to {best[1]:.3f} mm (with it "
            f"{result.robot_error.station_translation_mm:.3f} mm). Its profiles or poses are offset (the sensor or "
            "the sphere moved, another tool or work object, a pose read in another frame): re-acquire that station"]


def summary(solution: Solution, graded: "Verdict | None" = None) -> str:
    """The result in a few lines: both directions, xyz + ABB quaternion, uncertainties,
    and the verdict (``graded``, else computed from the result), with the reasons for a
    RED one."""
    r = solution.result
    X = r.transform
    inv = X.inverse()
    a, b = r.transform_name.split("_from_")
    q = ", ".join(f"{v:.8f}" for v in X.quaternion_wxyz)
    t = ", ".join(f"{v:.4f}" for v in X.translation_mm)
    lines = [
        f"{r.transform_name} (maps points in {b} to {a}):",
        f"  translation_mm  = [{t}]",
        f"  quaternion_wxyz = [{q}]",
        f"  std: rotation {', '.join(f'{v:.4f}' for v in r.std_rotation_deg)} deg about {a} x, y, z; "
        f"translation {', '.join(f'{v:.4f}' for v in r.std_translation_mm)} mm",
        f"  expanded U (k = 2): rotation {', '.join(f'{2 * v:.4f}' for v in r.std_rotation_deg)} deg; "
        f"translation {', '.join(f'{2 * v:.4f}' for v in r.std_translation_mm)} mm",
        f"{b}_from_{a}: translation_mm = [{', '.join(f'{v:.4f}' for v in inv.translation_mm)}], "
        f"quaternion_wxyz = [{', '.join(f'{v:.8f}' for v in inv.quaternion_wxyz)}]",
        f"residuals: RMS {r.residuals.rms_mm:.4f} mm over {r.residuals.n_points_used} points of "
        f"{r.residuals.n_profiles_used} profiles; {r.residuals.n_points_rejected} stray points rejected"
        + (f"; {r.residuals.n_centres_used} centre observations, their residuals {r.residuals.centre_rms_mm:.4f} mm "
           f"RMS (3-D), {r.residuals.centre_max_mm:.4f} mm at most" if r.residuals.n_centres_used else ""),
    ]
    re = r.robot_error
    if re is not None:
        from spherecal.estimation.pipeline import POINT_ERROR_PARTS

        rot = ", ".join(f"{v:.4f}" for v in re.std_rotation_deg_robot_frame)
        trans = ", ".join(f"{v:.4f}" for v in re.std_translation_mm_robot_frame)
        rot2 = ", ".join(f"{2 * v:.4f}" for v in re.std_rotation_deg_robot_frame)
        trans2 = ", ".join(f"{2 * v:.4f}" for v in re.std_translation_mm_robot_frame)
        if re.kinematic_parameters is not None:
            n_seen = sum(p.identifiable for p in re.kinematic_parameters)
            n_cal = sum(p.identified for p in re.kinematic_parameters)
            how = (f"{n_cal} of its {len(re.kinematic_parameters)} geometric parameters identified" if n_cal else
                   f"{n_seen} of its {len(re.kinematic_parameters)} geometric parameters seen by the data, all "
                   f"marginalised (prior spread x {re.kinematic_prior_scale:.2f})")
            lines.append(f"robot error: the arm's geometry (kinematic model), {how}")
            if re.model_choice is not None:
                lines.append(f"  {re.model_choice}")
            lines.append(f"  std relative to the robot's own frame: rotation {rot} deg; translation {trans} mm (the "
                         "std above adds the geometric errors no data from one sphere location can see)")
        elif re.model_choice is not None:
            lines.append(f"robot error: {re.model_choice}")
            lines.append(f"  std relative to the robot's own frame: rotation {rot} deg; translation {trans} mm (the "
                         "std above adds the geometric errors no data from one sphere location can see)")
        else:
            lines.append(
                f"  std relative to the robot's own frame: rotation {rot} deg; translation {trans} mm (the std above "
                f"adds the robot's assumed accuracy {re.common_translation_mm:g} mm, {re.common_rotation_deg:g} deg "
                "per axis)"
            )
        lines.append(f"  expanded U (k = 2) relative to the robot's own frame: rotation {rot2} deg; translation "
                     f"{trans2} mm")
        if re.kinematic_parameters is not None and any(p.identified for p in re.kinematic_parameters):
            lines.append(
                f"a point measured at a new pose through the calibrated model ({CALIBRATED_URDF_NAME}): expected "
                f"error {re.point_error_k2_mm:.3f} mm (k = 2), mostly from {POINT_ERROR_PARTS.get(re.dominant, re.dominant)}"
            )
        else:
            lines.append(
                f"a point measured at a new pose: expected error {re.point_error_k2_mm:.3f} mm (k = 2), mostly from "
                f"{POINT_ERROR_PARTS.get(re.dominant, re.dominant)}; the robot's error differs between stations by "
                f"{re.station_translation_mm:.3f} mm and {re.station_rotation_deg:.4f} deg per axis"
            )
    for f in r.flagged:
        lines.append(f"flagged observation {f.index} (station {f.station}): {f.reason}")
    from spherecal.report.assess import advice, verdict

    graded = graded or verdict(r)
    lines.append(format_verdict(graded))
    if graded.level in ("red", "amber"):  # what to do, as the report gives it (its headline points here)
        todo = [a for a in advice(r) if a.level in ("red", "amber")]
        lines.extend(f"  advice: {a.title}: {a.text}" for a in todo[:4])
        if len(todo) > 4:
            lines.append(f"  advice: {len(todo) - 4} more in the report")
    return "\n".join(lines)


def format_verdict(v: "Verdict") -> str:
    """The verdict as the terminal prints it (the report shows the same): its level and
    headline, and the reasons for a red or amber one (what is red first)."""
    lines = [f"verdict: {v.level.upper()}: {v.headline}"]
    if v.level in ("red", "amber"):
        for level in ("red", "amber"):
            lines.extend(f"  {level}: {text}" for lvl, text in v.reasons if lvl == level)
    return "\n".join(lines)


def truth_check(solution: Solution, dataset: Dataset) -> str | None:
    """For simulated data: the error against the cell's true transform."""
    prov = dataset.provenance
    if "true_transform" not in prov:
        return None
    from spherecal.core import geometry as geo

    true = Pose.model_validate(prov["true_transform"])
    X = solution.result.transform
    rot = geo.rotation_angle_deg(true.rotation_matrix, X.rotation_matrix)
    dt = float(np.linalg.norm(true.translation - X.translation))
    return f"simulated truth: error {rot:.4f} deg, {dt:.4f} mm"


def _result_for(loaded: LoadedConfig, section, out: Path):
    cfg = loaded.config
    path = loaded.resolve(section.result) if section.result else out / RESULT_NAME
    result = dataio.read_result(path)
    if result.mounting != cfg.mounting:
        raise InputError(f"{path}: the result is {result.mounting} but the configuration says {cfg.mounting}")
    return path, result


def _calibrated_setup(loaded: LoadedConfig, section, missing: str, moving: str, out_dir: Path | None,
                      read_result: bool = True):
    """What validate and scan both need first: their section, the acquisition settings,
    the output folder and the calibration result in it (``(out, None, None)`` without
    ``read_result``)."""
    cfg = loaded.config
    if section is None:
        raise ConfigError(f"{loaded.path}: {missing}")
    if cfg.acquisition is None:
        raise ConfigError(f"{loaded.path}: {moving} moves the robot: it needs [acquisition] (speeds, workspace)")
    out = Path(out_dir) if out_dir is not None else loaded.output_dir
    return (out, *_result_for(loaded, section, out)) if read_result else (out, None, None)


def run_validate(loaded: LoadedConfig, *, out_dir: Path | None = None, log: Callable[[str], None] = _LOG,
                 progress_stream=None, report: bool = True, yes: bool = False, ask: Callable[[str], str] = input,
                 transform=None):
    """``spherecal validate``: scan the artefacts at new views with the calibrated
    system, compute the acceptance figures, compare with the MPEs. ``transform`` (a
    :class:`~spherecal.report.compare.TransformEstimate`): validate that transform, one spherecal
    did not compute (the controller's current tool or work object, a pose file), instead
    of the calibration's ``result.json``; the report is then left alone."""
    from spherecal.motion.acquisition import Progress
    from spherecal.motion.validation import evaluate, measure, plan_validation

    host = make_host()
    loaded, fov = configured_for_sensor(loaded, host)
    cfg = loaded.config
    missing = "no [validation] section: say what to validate against which MPEs"
    if transform is None:
        out, result_path, result = _calibrated_setup(loaded, cfg.validation, missing, "validation", out_dir)
        X, source = result.transform, str(result_path)
    else:
        out, result_path, result = _calibrated_setup(loaded, cfg.validation, missing, "validation", out_dir,
                                                     read_result=False)
        expected = TRANSFORM_NAME[cfg.mounting]
        if transform.transform_name not in (None, expected):
            raise ConfigError(f"{transform.source} is {transform.transform_name}, but {loaded.path} calibrates "
                              f"{expected} ({cfg.mounting}): validate a transform of the configuration's mounting")
        X, source = transform.pose, transform.source
        if transform.note:
            log(f"note: {transform.note}")
    sweeps = plan_validation(cfg.validation, cfg.acquisition, cfg.mounting, X, cfg.sphere, fov, cfg.sensor["type"])
    targets = [t for s in sweeps for t in s.targets]
    log(f"validating {source}: {len(sweeps)} sweeps, {len(targets)} shots")
    _check_plan(targets, cfg.acquisition, "validation plan")
    exports = export_plan(loaded, host)  # for the report's notes; a bad [export] stops before any motion
    cell = make_cell(cfg, robot_arm(loaded, host), fov)
    if cell is None:
        confirm_motion("validate", f"{len(sweeps)} sweeps, {len(targets)} shots", yes, ask, log)
    out.mkdir(parents=True, exist_ok=True)
    from datetime import datetime, timezone

    stamp = datetime.now(timezone.utc).strftime("%Y%m%dT%H%M%S%fZ")
    journal = out / f"validation-{stamp}.jsonl"  # one journal per validation run; none is overwritten
    with open_devices(loaded, host, cell, log) as (robot, sensor):
        _check_plan(targets, cfg.acquisition, "validation plan", robot=robot)
        with dataio.DatasetWriter(journal, mounting=cfg.mounting, sphere_radius_mm=cfg.sphere.radius_mm,
                                  provenance={"source": "spherecal validate", "result": source,
                                              "transform": X.model_dump()},
                                  fsync=True) as writer:
            from spherecal.core.models import Observation

            def record(sweep, target, pose, profile):
                writer.append(Observation(index=writer.next_index, station=f"{sweep.label}-{sweep.kind}",
                                          timestamp=datetime.now(timezone.utc), base_from_flange=pose,
                                          profile=profile, target=target.index))

            measured = measure(robot, sensor, sweeps, cfg.acquisition, log, Progress(len(targets), progress_stream),
                               record)
    outcome = evaluate(cfg.validation, cfg.mounting, X, cfg.sphere, measured)
    from spherecal.report.assess import Verdict, verdict, with_validation
    from spherecal.motion.validation import position_rows

    own = verdict(result) if result is not None else Verdict(
        "green", "A transform spherecal did not compute: only its validation is graded.")
    outcome.verdict = with_validation(own, outcome.table())
    outcome.transform, outcome.transform_name, outcome.transform_source = X, TRANSFORM_NAME[cfg.mounting], source
    import json

    text = json.dumps({"passed": outcome.passed, "result": source, "transform": X.model_dump(),
                       "transform_given": transform is not None, "journal": journal.name,
                       "verdict": {"level": outcome.verdict.level, "headline": outcome.verdict.headline},
                       "figures": outcome.table(), "positions": position_rows(outcome),
                       "report": outcome.report.model_dump(), "centres_mm": outcome.centres_mm},
                      indent=2, default=float)
    from spherecal.io import files as safeio

    safeio.write_text(out / f"validation-{stamp}.json", text)
    safeio.write_text(out / "validation.json", text)  # the latest run, for scripts
    calib_journal = out / JOURNAL_NAME
    if report and transform is None and calib_journal.exists():
        # the report shows the calibration's residuals: only when that calibration is the one validated
        solution = solve(dataio.read_dataset(calib_journal), calibration_options(cfg),
                         host.robot_kinematics(cfg.robot, base_dir=loaded.path.parent), kinematics=robot_arm(loaded, host))
        if np.allclose(solution.result.transform.as_matrix(), X.as_matrix(), atol=1e-6):
            from spherecal.report.html import write_report

            # the result as written (its provenance: the calibration's identity and hashes)
            solution = replace(solution, result=result)
            write_report(solution, out, validation=outcome.table(), validation_positions=position_rows(outcome),
                         verdict_override=outcome.verdict, notes=exports.notes(solution.result),
                         point_distance_mm=cfg.report.point_distance_mm)
        else:
            log(f"report.html not updated: {_not_the_calibration(result, result_path, calib_journal, loaded)}")
    return outcome


def _not_the_calibration(result, result_path: Path, journal: Path, loaded: LoadedConfig) -> str:
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


def run_scan(loaded: LoadedConfig, *, out_dir: Path | None = None, log: Callable[[str], None] = _LOG,
             progress_stream=None, yes: bool = False, ask: Callable[[str], str] = input):
    """``spherecal scan``: sweep the object, stream its points to a PLY file."""
    from spherecal.motion.acquisition import Progress
    from spherecal.io.ply import PlyWriter
    from spherecal.motion.scanning import plan_scan, scan

    host = make_host()
    loaded, fov = configured_for_sensor(loaded, host)
    cfg = loaded.config
    if cfg.scan is not None:  # where the PLY goes, before anything else
        out = Path(out_dir) if out_dir is not None else loaded.output_dir
        given = Path(cfg.scan.ply).expanduser()
        ply_path = given if given.is_absolute() else out / given
        from spherecal.io.files import check_writable_target, is_inside

        check_writable_target(ply_path)  # a link is named as a link, wherever it points
        if not cfg.scan.ply_outside_output_dir and (given.is_absolute() or not is_inside(ply_path, out)):
            raise ConfigError(f"{loaded.path}: scan.ply = {cfg.scan.ply!r} lies outside the output folder {out}: "
                              "give a file name in it, or set scan.ply_outside_output_dir = true to write there "
                              "on purpose")
        check_writable_target(ply_path)
    out, result_path, result = _calibrated_setup(loaded, cfg.scan, "no [scan] section: say what to scan", "scanning",
                                                 out_dir)
    doubt = failed_validation(out, result)
    if doubt:  # said before anything moves, and again by the exit code
        log(Notice(f"warning: {doubt}; the scan's points carry that error (scanning all the same)"))
    targets = plan_scan(cfg.scan, cfg.acquisition, cfg.mounting, result.transform, fov)
    _check_plan(targets, cfg.acquisition, "scan plan")
    if ply_path.exists():
        raise InputError(f"{ply_path} exists; remove it or set [scan] ply to another name (nothing is overwritten)")
    cell = make_cell(cfg, robot_arm(loaded, host), fov)
    if cell is None:
        confirm_motion("scan", f"{len(targets)} profiles", yes, ask, log)
    out.mkdir(parents=True, exist_ok=True)
    log(f"scan: {len(targets)} profiles into {ply_path}")
    frame = SPHERE_FRAME[cfg.mounting]
    with open_devices(loaded, host, cell, log) as (robot, sensor):
        _check_plan(targets, cfg.acquisition, "scan plan", robot=robot)
        with PlyWriter(ply_path, format=cfg.scan.format, with_profile=True, frame=frame,
                       comments=(f"spherecal scan, {result.transform_name} from {result_path}",)) as writer:
            summary = scan(robot, sensor, targets, result.transform, cfg.acquisition, cfg.mounting, writer, log,
                              Progress(len(targets), progress_stream))
    log(f"scan: {summary.points} points from {summary.profiles} profiles ({summary.empty_profiles} empty) in {frame} frame")
    summary.calibration_doubt = doubt
    return ply_path, summary


def failed_validation(out: Path, result) -> str | None:
    """What is wrong when the latest validation in ``out`` (``validation.json``) is of
    ``result``'s transform and failed; None when it passed, is of another transform, or
    there is none."""
    import json

    path = out / "validation.json"
    try:
        latest = json.loads(path.read_text())
        validated = Pose.model_validate(latest["transform"])
    except (OSError, ValueError, KeyError, TypeError):
        return None
    if latest.get("passed", True) or not np.allclose(validated.as_matrix(), result.transform.as_matrix(), atol=1e-9):
        return None
    failed = [name for name, row in (latest.get("figures") or {}).items() if not row.get("passed", True)]
    return (f"this calibration failed its latest validation ({path}: {', '.join(failed) or 'a figure'} beyond "
            "its MPE)")
