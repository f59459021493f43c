"""``spherecal solve``: calibrate a recorded dataset, without devices; the robot's
kinematics from its plugin when the dataset needs them."""

from __future__ import annotations

from pathlib import Path
from typing import Callable

import numpy as np

from spherecal.app import plugin_host
from spherecal.app.outputs import check_output_folder
from spherecal.app.provenance import provenance_type, recorded_options, traceability
from spherecal.app.solving import Outcome, solve_and_write
from spherecal.core.errors import ConfigError, InputError, SpherecalError
from spherecal.core.models import Dataset
from spherecal.io.runlog import logger, progress_log
from spherecal.io.transform_text import parse_xyz_quat

_LOG = progress_log("run")  # the default ``log``: logger spherecal.run


def default_out(dataset_path: str | Path) -> Path:
    """The output folder of a solve not given one: ``<dataset>.calibration`` next to it."""
    return Path(dataset_path).with_suffix("").with_suffix(".calibration")


def run_solve(dataset: Dataset, dataset_path: Path, out: Path, *, nominal: str | None = None,
              robot_type: str | None = None, robot_config: Path | None = None, pose_from: str = "reported",
              fit_radius: bool | None = None, station_rotation_tolerance_deg: float | None = None,
              identify_kinematics: bool | None = None, robot_error_model: str | None = None, overwrite: bool = False,
              report: bool = True, force: bool = False, operator: str | None = None,
              log: Callable[[str], None] = _LOG) -> Outcome:
    """``spherecal solve`` of ``dataset`` (read from ``dataset_path``) into ``out``, with
    the command's options (docs/cli.md). ``nominal``: the rough transform as
    ``x,y,z,qw,qx,qy,qz``. The estimator's settings are those the dataset's provenance
    holds (a journal of ``calibrate``: its run's, :func:`~spherecal.app.provenance.recorded_options`),
    else the defaults; each option given (not None) replaces its own. Refuses to replace
    a result in ``out`` unless ``overwrite``."""
    if not dataset.observations:
        raise InputError(f"{dataset_path}: the dataset holds no observations (only its header): nothing to solve")
    nominal_pose = parse_xyz_quat(nominal, "--nominal") if nominal is not None else None
    host = plugin_host.make_host()
    fk, dataset, arm = solve_kinematics(dataset, robot_type, robot_config, pose_from, host=host)
    robot_type = solve_robot_type(dataset, robot_type, robot_config)
    sensor_type = provenance_type(dataset, "sensor")
    exports = host.export_plan(None, dataset.mounting, robot_type)
    given = {"nominal_transform": nominal_pose, "fit_radius": fit_radius,
             "station_rotation_tolerance_deg": station_rotation_tolerance_deg,
             "identify_kinematics": identify_kinematics, "robot_error_model": robot_error_model}
    options = recorded_options(dataset.provenance, dataset_path, log, flags=tuple(given), what="dataset",
                               **{k: v for k, v in given.items() if v is not None})
    if options.identify_kinematics and arm is None:
        raise ConfigError("--identify-kinematics needs the robot's kinematics: give --robot TYPE (a type whose "
                          "plugin describes its arm; `spherecal plugins` lists them) and joints_deg in every "
                          "observation")
    logger("run").debug("options: %s", options.model_dump_json(exclude={"nominal_transform"}))
    if not overwrite:
        check_output_folder(out, "solve", "give a new folder with --out, or --overwrite to replace its result, "
                            "exports and report", exports)
    solution, graded, written = solve_and_write(dataset, options, out, exports, fk, log=log, report=report,
                                                force=force, kinematics=arm,
                                                provenance=traceability(dataset, dataset_path, operator=operator))
    host.calibration_finished(result=solution.result, dataset=dataset, out_dir=out, exports_written=written,
                              robot_type=robot_type, sensor_type=sensor_type)
    return Outcome(solution=solution, verdict=graded, exports_written=written, dataset=dataset)


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
    # (the file loader and its TOML parser load with --robot-config only: the one part of
    # a solve that reads a configuration file, tests/cli/test_startup_imports.py)
    from spherecal.config.load import read_toml

    data = read_toml(path, "robot configuration")
    section = data.get("robot", data)
    if not isinstance(section, dict):
        raise ConfigError(f"{path}: robot: expected a table of robot settings")
    return dict(section)


def solve_kinematics(
    dataset: Dataset,
    robot_type: str | None,
    robot_config: Path | None,
    pose_from: str,
    host,
) -> tuple[Callable | None, Dataset, object | None]:
    """Forward kinematics for ``spherecal solve``, the dataset to solve, and the robot's
    :class:`~spherecal.core.kinematics.ArmKinematics` when its plugin describes the arm (for
    the kinematic robot error model; None otherwise). ``host``: the run's plugin host.

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
        dataset = _poses_from_joints(dataset, fk)
    return fk, dataset, host.arm_kinematics({"type": name, **section}, path=path, base_dir=base_dir)


def _poses_from_joints(dataset: Dataset, fk) -> Dataset:
    """``dataset`` with every flange pose computed from its joints (``--pose-from joints``)."""
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
    return dataset.model_copy(update={"observations": obs})


def _provenance_arm(name: str | None, dataset: Dataset, host):
    """The arm kinematics of the robot type the dataset's provenance names, when the
    observations carry joints and that type is installed with default settings; else None
    (the estimator then models the robot's error per station)."""
    if name is None or any(o.joints_deg is None for o in dataset.observations):
        return None
    try:
        return host.arm_kinematics({"type": name})
    except SpherecalError:
        return None
