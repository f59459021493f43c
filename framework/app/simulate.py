"""``spherecal simulate``: a dataset from the simulated cell, the standard one or the one
a configuration describes; stop-and-go observations or an on-the-fly recording."""

from __future__ import annotations

import os
from dataclasses import replace
from pathlib import Path

from spherecal.app import plugin_host
from spherecal.app.cell import configured_for_sensor, make_cell
from spherecal.app.plugin_host import robot_arm
from spherecal.app.provenance import CALIBRATION_OPTIONS_KEY
from spherecal.app.solving import calibration_options
from spherecal.config import PoseStreamSettings, StreamSimSettings, load_config
from spherecal.core.errors import ConfigError, InputError
from spherecal.core.models import Dataset
from spherecal.core.streams import Recording
from spherecal.devices.contract import SensorFieldOfView
from spherecal.io import dataset as dataio
from spherecal.io.streams import write_recording
from spherecal.motion.kinematic_plan import plan_kinematic_stations, uses_planner
from spherecal.sim import NoiseModel, SimulatedCell, SweepPlan, simulate_dataset, simulate_recording, standard_cell


def configured_cell(config: str | Path, seed: int | None = None) -> tuple[SimulatedCell, SweepPlan, dict]:
    """The cell and plan of a configuration: its ``[simulation]`` cell (or, without one,
    the standard cell measuring with the configured sensor's field of view, seeded with
    ``seed``), the plan calibrate would take (the kinematic planner's stations, or
    ``[acquisition.sweep]``), and what the data's provenance says of the run as
    calibrate's journal does: the robot and sensor types, the configuration, and the
    estimator's settings (``solve`` of the file starts from them)."""
    host = plugin_host.make_host()
    loaded, fov = configured_for_sensor(load_config(config), host)  # the standoffs the sensor sets, as a run
    cfg = loaded.config
    arm = robot_arm(loaded, host)
    cell = make_cell(cfg, arm, field_of_view=fov)
    if cell is None:  # no [simulation]: the standard cell, measuring with the configured sensor's field of view
        if fov is None:
            raise ConfigError(f"{loaded.path}: sensor.type {cfg.sensor['type']!r} declares no field of view to "
                              "simulate; give it whole in [simulation.fov]")
        cell = standard_cell(cfg.mounting, seed=seed or 0, fov=fov)
    elif seed is not None:
        raise ConfigError(f"--seed {seed}: {loaded.path} has a [simulation] section, whose seed is used; "
                          "change simulation.seed there")
    if arm is not None and cell.arm is None:
        cell.attach_arm(arm)  # as the simulated controller does: the joints of every shot are recorded
    if uses_planner(cfg.acquisition, cfg.calibration):  # the kinematic planner's stations, as calibrate plans them
        plan = plan_kinematic_stations(cfg.acquisition, cfg.calibration, cfg.mounting, cfg.nominal_transform,
                                       cfg.sphere, arm, robot_type=cfg.robot.get("type")).sweep
    else:
        plan = cfg.acquisition.sweep if cfg.acquisition else SweepPlan()
    provenance = {"config": str(loaded.path), "robot": cfg.robot.get("type"), "sensor": cfg.sensor.get("type"),
                  CALIBRATION_OPTIONS_KEY: calibration_options(cfg).model_dump(mode="json")}
    return cell, plan, provenance


def standard_cell_for(sensor: str | None, mounting: str, seed: int, profiles: int, point_noise_mm: float,
                      pose_noise_mm: float, stray_fraction: float) -> tuple[SimulatedCell, SweepPlan]:
    """The standard cell measuring with the field of view of sensor type ``sensor``
    (:func:`simulated_sensor_fov`), with the given noise, and a plan of ``profiles`` per station."""
    noise = NoiseModel(
        point_noise_mm=point_noise_mm,
        pose_translation_noise_mm=pose_noise_mm,
        stray_profile_fraction=stray_fraction,
    )
    cell = standard_cell(mounting, seed=seed, noise=noise, fov=simulated_sensor_fov(sensor, plugin_host.make_host()))
    return cell, SweepPlan(profiles_per_station=profiles)


def simulated_sensor_fov(name: str | None, host) -> SensorFieldOfView:
    """The field of view ``spherecal simulate`` measures with: that of the sensor type
    registered as ``name`` (``--sensor``), or, without one, of the only installed sensor
    type that declares one. :class:`ConfigError` naming ``--sensor`` (with the known
    types) for an unknown name, a type that declares none, or a choice to make."""
    sensors = host.registry.sensors
    with_fov = sorted(n for n, t in sensors.items() if t.field_of_view is not None)
    if name is None:
        if len(with_fov) == 1:
            return sensors[with_fov[0]].field_of_view
        raise ConfigError("--sensor: give the sensor type to simulate (installed sensor types with a field of view: "
                          f"{', '.join(with_fov) or 'none'})")
    if name not in sensors:
        raise ConfigError(f"--sensor {name}: unknown sensor type; installed sensor types: "
                          f"{', '.join(sorted(sensors)) or 'none'} (list them with `spherecal plugins`)")
    fov = sensors[name].field_of_view
    if fov is None:
        raise ConfigError(f"--sensor {name}: sensor type {name!r} declares no field of view to simulate; simulate it "
                          "from a configuration that gives one in [simulation.fov] (--config)")
    return fov


def write_simulated(cell: SimulatedCell, plan: SweepPlan, out: str | Path, force: bool = False,
                    provenance: dict | None = None) -> Dataset:
    """The dataset ``cell`` gives for ``plan``, ``provenance`` added to its own, written
    to ``out`` (replacing a file there only with ``force``)."""
    if not force and os.path.lexists(out):
        raise InputError(f"{out} already exists; give --force to replace it, or another file name")
    ds = simulate_dataset(cell, plan)
    if provenance:
        ds = ds.model_copy(update={"provenance": {**ds.provenance, **provenance}})
    dataio.write_dataset(out, ds, overwrite=force)
    return ds


def stream_settings_for(cell: SimulatedCell) -> StreamSimSettings:
    """The on-the-fly simulation's settings for ``cell``: the defaults, with the cell's
    pose noise (its standard deviations) as the pose stream's smooth repeatability noise."""
    n = cell.noise
    return StreamSimSettings(pose=PoseStreamSettings(translation_noise_mm=n.pose_translation_noise_mm,
                                                     rotation_noise_deg=n.pose_rotation_noise_deg))


def write_simulated_recording(cell: SimulatedCell, stations: SweepPlan, out: str | Path, force: bool = False,
                              settings: StreamSimSettings | None = None, provenance: dict | None = None) -> Recording:
    """The on-the-fly recording ``cell`` gives at the stations of ``stations`` (the
    default sweeps, :class:`~spherecal.config.OnTheFlyPlan`; ``settings`` default
    :func:`stream_settings_for`), ``provenance`` added to its own, written to ``out`` in
    the stream form (replacing a file there only with ``force``)."""
    if not force and os.path.lexists(out):
        raise InputError(f"{out} already exists; give --force to replace it, or another file name")
    rec = simulate_recording(cell, settings=settings or stream_settings_for(cell), stations=stations)
    if provenance:
        rec = replace(rec, provenance={**rec.provenance, **provenance})
    write_recording(out, rec, overwrite=force)
    return rec
