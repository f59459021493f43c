"""The run's cell from the configuration: the sensor's field of view, the standoffs it
sets, and the simulated cell of a simulated run."""

from __future__ import annotations

import numpy as np
from pydantic import ValidationError

from spherecal.config import LoadedConfig, RunConfig
from spherecal.core.errors import ConfigError
from spherecal.core.models import SPHERE_FRAME, Pose
from spherecal.devices.contract import SensorFieldOfView
from spherecal.motion.planning import with_standoff
from spherecal.sim import BallBar, CarDoorPanel, FlatPlate, SimulatedCell, standard_cell
from spherecal.sim.live import add_repeatability


def sensor_field_of_view(cfg: RunConfig, host) -> SensorFieldOfView | None:
    """The field of view of the run's sensor: its sensor type's declared one
    (:attr:`spherecal.devices.contract.SensorType.field_of_view`), with the fields the
    configuration's ``[simulation.fov]`` gives over it in a simulated run. None when the
    sensor type declares none and the configuration does not give it whole.
    :class:`ConfigError` naming ``simulation.fov`` when the two together are not a field
    of view."""
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
    update = {}
    acq = cfg.acquisition
    if acq is not None:
        sweep = with_standoff(acq.sweep, field_of_view, cfg.sphere.radius_mm)
        if sweep is not acq.sweep:
            update["acquisition"] = acq.model_copy(update={"sweep": sweep})
    if cfg.scan is not None and cfg.scan.standoff_z_mm is None:
        update["scan"] = cfg.scan.model_copy(update={"standoff_z_mm": float(field_of_view.middle_z_mm)})
    return cfg.model_copy(update=update) if update else cfg


def configured_for_sensor(loaded: LoadedConfig, host) -> tuple[LoadedConfig, SensorFieldOfView | None]:
    """The configuration with the standoffs it leaves to the sensor set
    (:func:`for_sensor`), and the sensor's field of view (:func:`sensor_field_of_view`)."""
    fov = sensor_field_of_view(loaded.config, host)
    return LoadedConfig(for_sensor(loaded.config, fov), loaded.path), fov


def make_cell(cfg: RunConfig, arm=None, field_of_view: SensorFieldOfView | None = None) -> SimulatedCell | None:
    """The simulated cell of a simulated run, or None for hardware. ``arm`` (the robot
    type's :class:`~spherecal.core.kinematics.ArmKinematics`, when it describes its arm) lays
    the standard cell out for the arm's reach (:func:`spherecal.sim.standard_cell`); the
    configuration's ``[simulation] sphere_centre_mm`` and ``true_transform`` override it.
    An arm with a calibrated model (kinematics that keep their ``nominal`` one) is laid out
    as its nominal arm: giving the robot its calibrated model must not move the world.
    ``field_of_view`` is the simulated sensor's (:func:`sensor_field_of_view`);
    :class:`ConfigError` naming ``simulation.fov`` when there is none."""
    sim = cfg.simulation
    if sim is None:
        return None
    if field_of_view is None:
        raise ConfigError(f"simulation.fov: sensor type {cfg.sensor['type']!r} declares no field of view; give "
                          "z_near_mm, z_far_mm, width_near_mm and width_far_mm in [simulation.fov]")
    cell = standard_cell(cfg.mounting, seed=sim.seed, noise=sim.noise, fov=field_of_view,
                         sphere_radius_mm=cfg.sphere.radius_mm,
                         arm=getattr(arm, "nominal", arm))
    cell.arm = None  # laid out for the arm; the simulated controller attaches its own (nominal) arm
    cell.noise_per_pose = True  # a resumed run reproduces an uninterrupted one
    cell.robot_error = sim.robot_error  # the simulated controller gives its arm this error
    add_repeatability(cell)  # the arm's path error along a move, which streams see
    if sim.true_transform is not None:
        cell.true_transform = sim.true_transform.pose()
    if sim.sphere_centre_mm is not None:
        cell.sphere_centre_mm = np.asarray(sim.sphere_centre_mm, dtype=float)
    _add_objects(cell, cfg)
    return cell


def _add_objects(cell: SimulatedCell, cfg: RunConfig) -> None:
    """The configuration's artefacts in the simulated cell: the validation's ball bar and
    flat, and the object ``[simulation] scan_object`` places at the scan's centre."""
    sim = cfg.simulation
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
        cell.add_object(FlatPlate(Pose.from_xyz_quat_wxyz(f.centre_mm, f.quaternion_wxyz), f.length_mm, f.width_mm, frame=frame))
    if sim.scan_object != "none":
        if cfg.scan is None:
            raise ConfigError("simulation.scan_object needs a [scan] section (its object_centre_mm places the object)")
        at = Pose.from_xyz_quat_wxyz(cfg.scan.object_centre_mm, (1.0, 0.0, 0.0, 0.0))
        if sim.scan_object == "flat_plate":
            cell.add_object(FlatPlate(at, 300.0, 200.0, frame=frame, name="scan_plate"))
        else:
            cell.add_object(CarDoorPanel(at, frame=frame))
