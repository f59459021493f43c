"""Planning real motion: the stations of a calibration sweep (pure-translation sweeps across
the sphere at several orientations), as flange targets.

The calibration (:mod:`spherecal.motion.acquisition`), validation (:mod:`spherecal.motion.validation`),
scan (:mod:`spherecal.motion.scanning`) and the kinematic planner (:mod:`spherecal.motion.kinematic_plan`) plan
with it from a nominal transform (the configuration's) and a rough sphere position; the
simulated acquisition (:mod:`spherecal.sim`) plans with the cell's true transform.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from spherecal.config import SweepPlan
from spherecal.core import geometry as geo
from spherecal.core.errors import ConfigError
from spherecal.core.models import MountingMode, Pose

if TYPE_CHECKING:
    from spherecal.config import OnTheFlyPlan  # pragma: no cover
    from spherecal.devices.contract import SensorFieldOfView

#: Flange pointing down (tool0 z along -z of base), as in a typical scanning cell: the
#: reference orientation of a plan's stations. 180 deg
#: about base y, written out as ``geo.matrix_from_rotvec(np.radians([0.0, 180.0, 0.0]))``
#: gives it to the last bit (sin(pi) in double precision is 1.2246e-16), so that importing
#: the planner needs no SciPy.
FLANGE_DOWN = np.array([[-1.0, 0.0, 1.2246467991473532e-16], [0.0, 1.0, 0.0], [-1.2246467991473532e-16, 0.0, -1.0]])


#: The default stations' places in the field of view, (y, z) in percent: y of the line's
#: width at the sweep's standoff, z of the measuring range, from the standoff. For a 100
#: mm range with a line 40 mm wide at the standoff (a sensor measuring -60..+40 mm,
#: standoff -20 mm) they are (0, 0), (10, -25), (-10, 18) and (0, -30) mm; a sensor with a
#: 25 mm or a 400 mm range gets a quarter or four times that. Percent of a length, so
#: that ``length * p / 100`` is exact for such round lengths.
STATION_OFFSETS_PERCENT = ((0, 0), (25, -25), (-25, 18), (0, -30))

#: The default y/z wander within a sweep, percent of the measuring range (4 mm in 100 mm).
LATERAL_AMPLITUDE_PERCENT = 4

_NEEDS = {
    "standoff_z_mm": "sensor-frame z of the sphere centre, mm",
    "station_offsets_mm": "(y, z) shift of each station's sweep in the sensor frame, mm",
    "lateral_amplitude_mm": "y/z wander within a sweep, mm",
}


#: Where the range allows, a sweep puts the sphere where its diameter spans this share of
#: the line's width: the rims inside the line with room for the stations' offsets, the
#: line narrow enough that many of its points fall on the sphere.
SPHERE_SHARE_OF_LINE = 0.8


def sphere_standoff_z_mm(field_of_view: "SensorFieldOfView", sphere_radius_mm: float | None = None) -> float:
    """z of the sphere centre in a calibration sweep (mm): the sensor's own
    ``standoff_z_mm`` when it declares one; else, given the sphere's radius, the z where
    the sphere's diameter spans :data:`SPHERE_SHARE_OF_LINE` of the line's width, kept
    within the range so that every station's section stays in it (the stations' z offsets
    and twice the wander below the centre, above the sphere's top); else the middle of
    the range. A sphere too large for the range with those offsets gets the middle of
    what is left."""
    fov = field_of_view
    if fov.standoff_z_mm is not None or sphere_radius_mm is None:
        return float(fov.sweep_standoff_z_mm)
    r, depth = float(sphere_radius_mm), fov.z_near_mm - fov.z_far_mm
    below = -min(z for _, z in STATION_OFFSETS_PERCENT) + 2 * LATERAL_AMPLITUDE_PERCENT
    above = max(z for _, z in STATION_OFFSETS_PERCENT) + 2 * LATERAL_AMPLITUDE_PERCENT
    lowest, highest = fov.z_far_mm + below * depth / 100, fov.z_near_mm - r - above * depth / 100
    if lowest > highest:
        return float((lowest + highest) / 2)
    width = 2.0 * r / SPHERE_SHARE_OF_LINE  # the line's width wanted: it grows linearly away from the sensor
    z = fov.z_near_mm - (width - fov.width_near_mm) * depth / (fov.width_far_mm - fov.width_near_mm)
    return float(min(max(z, lowest), highest))


def with_standoff(plan: SweepPlan, field_of_view: "SensorFieldOfView | None",
                  sphere_radius_mm: float | None = None) -> SweepPlan:
    """``plan`` fitted to the sensor: the settings it leaves to the sensor set from
    ``field_of_view``, each only where the plan does not give its own: the standoff
    (:func:`sphere_standoff_z_mm`: the sensor's own, else sized for a sphere of
    ``sphere_radius_mm``, else the middle of the range), the stations'
    offsets (:data:`STATION_OFFSETS_PERCENT` of the line's width at the standoff and of
    the measuring range) and the wander (:data:`LATERAL_AMPLITUDE_PERCENT` of the range).
    :class:`ConfigError` naming the first setting missing when there is no field of view
    to take it from (a sensor type that declares none); a plan that gives all three is
    returned as it is."""
    missing = [name for name in _NEEDS if getattr(plan, name) is None]
    if not missing:
        return plan
    if field_of_view is None:
        name = missing[0]
        raise ConfigError(f"acquisition.sweep.{name}: not set, and the sensor type declares no field of view "
                          f"to take it from; set it ({_NEEDS[name]})")
    standoff = plan.standoff_z_mm if plan.standoff_z_mm is not None else sphere_standoff_z_mm(field_of_view,
                                                                                               sphere_radius_mm)
    update = {"standoff_z_mm": standoff}
    if plan.station_offsets_mm is None:
        update["station_offsets_mm"] = [offset_in_field_of_view_mm(field_of_view, standoff, p)
                                        for p in STATION_OFFSETS_PERCENT]
    if plan.lateral_amplitude_mm is None:
        update["lateral_amplitude_mm"] = (field_of_view.z_near_mm - field_of_view.z_far_mm) * LATERAL_AMPLITUDE_PERCENT / 100
    return plan.model_copy(update=update)


def offset_in_field_of_view_mm(field_of_view: "SensorFieldOfView", standoff_z_mm: float,
                               percent) -> tuple[float, float]:
    """A (y, z) shift in the sensor frame, mm, given as shares of ``field_of_view`` in
    ``percent``: y of the line's width at ``standoff_z_mm``, z of the measuring range."""
    y, z = percent
    width_mm = field_of_view.width_at_mm(standoff_z_mm)
    return width_mm * y / 100, (field_of_view.z_near_mm - field_of_view.z_far_mm) * z / 100


def site_offset_mm(offset_mm, offset_percent, field_of_view: "SensorFieldOfView | None", standoff_z_mm: float,
                   where: str) -> tuple[float, float]:
    """The (y, z) shift of a validation or scan sweep, mm: ``offset_mm`` when given, else
    ``offset_percent`` of the field of view (:func:`offset_in_field_of_view_mm`).
    :class:`ConfigError` naming ``where`` when a share is given and there is no field of view."""
    if offset_mm is not None:
        return tuple(float(v) for v in offset_mm)
    if not any(offset_percent):
        return 0.0, 0.0
    if field_of_view is None:
        raise ConfigError(f"{where}.offset_mm: not set, and the sensor type declares no field of view to size "
                          f"offset_percent {tuple(offset_percent)} in; set it ((y, z) shift of the sweep, mm)")
    return offset_in_field_of_view_mm(field_of_view, standoff_z_mm, offset_percent)


def sphere_centres_in_sensor(plan: SweepPlan, radius_mm: float) -> np.ndarray:
    """(n, 3) planned sensor-frame positions of the sphere centre along one sweep, mm
    (``plan`` with its standoff set, :func:`with_standoff`)."""
    if plan.standoff_z_mm is None or plan.lateral_amplitude_mm is None:
        raise ConfigError("acquisition.sweep: the plan is not fitted to the sensor (no standoff or wander; "
                          "with_standoff sets them from the sensor's field of view)")
    n = plan.profiles_per_station
    s = np.linspace(-1.0, 1.0, n)
    phase = np.linspace(0.0, 2 * np.pi, n, endpoint=False)
    a = plan.lateral_amplitude_mm
    return np.column_stack(
        [s * plan.sweep_fraction * radius_mm, a * np.sin(phase), plan.standoff_z_mm + a * np.cos(phase)]
    )


def sweep_ends_in_sensor_mm(plan: SweepPlan, otf: "OnTheFlyPlan", radius_mm: float, station_index: int,
                            direction_in_sensor) -> np.ndarray:
    """(2, 3) mm: where the sphere centre lies in the sensor frame at the two ends of an
    on-the-fly sweep at station ``station_index`` of ``plan``, along ``direction_in_sensor``:
    centred on the station's crossing point (``station_offsets_mm`` at ``standoff_z_mm``),
    ``crossing_fraction`` radii of the sensor's x each way at full speed, with room for the
    speed ramps at ``acceleration_mm_s2`` beyond. The live plan and the simulated
    recording's plan both take their sweeps from here."""
    dy, dz = plan.station_offsets_mm[station_index % len(plan.station_offsets_mm)]
    c0 = np.array([0.0, dy, plan.standoff_z_mm + dz])
    d = np.asarray(direction_in_sensor, dtype=float)
    v_max = max(otf.speeds_mm_s)
    half = otf.crossing_fraction * radius_mm / abs(d[0]) + v_max * v_max / (2 * otf.acceleration_mm_s2)
    return np.array([c0 - half * d, c0 + half * d])


def station_flange_poses(
    mounting: MountingMode,
    nominal_transform: Pose,
    sphere_centre_mm,
    radius_mm: float,
    plan: SweepPlan,
    tilts_deg,
    offsets_mm,
    reference_flange_rotation=None,
) -> tuple[np.ndarray, np.ndarray]:
    """Flange targets ``base_from_flange`` of stations with the rotation vectors
    ``tilts_deg`` (K, 3) and field-of-view shifts ``offsets_mm`` (K, 2), the sweep's other
    settings from ``plan``: rotations (K, n, 3, 3) and translations (K, n, 3), mm, n =
    ``plan.profiles_per_station``. Arguments as :func:`plan_stations`."""
    R_ref = FLANGE_DOWN if reference_flange_rotation is None else geo.check_rotation_matrix(reference_flange_rotation)
    centre = np.asarray(sphere_centre_mm, dtype=float)
    tilts = np.atleast_2d(np.asarray(tilts_deg, dtype=float))
    offsets = np.atleast_2d(np.asarray(offsets_mm, dtype=float))
    poses = _station_poses(mounting, nominal_transform, centre, radius_mm, plan, tilts, offsets, R_ref)
    R = np.array([[p.rotation_matrix for p in station] for station in poses]).reshape(len(tilts), -1, 3, 3)
    t = np.array([[p.translation for p in station] for station in poses]).reshape(len(tilts), -1, 3)
    return R, t


def _station_poses(mounting, X: Pose, centre: np.ndarray, radius_mm: float, plan: SweepPlan, tilts: np.ndarray,
                   offsets: np.ndarray, R_ref: np.ndarray) -> list[list[Pose]]:
    """The flange poses of :func:`station_flange_poses`, station by station, composed pose
    by pose as :class:`Pose` does it, so that the simulated datasets are bit for bit those
    the reference results were solved from (tests/estimation/test_profiles_unchanged.py)."""
    X_inv = X.inverse()
    cs0 = sphere_centres_in_sensor(plan, radius_mm)
    out = []
    for tilt, (dy, dz) in zip(tilts, offsets):
        Rt = geo.matrix_from_rotvec(np.radians(tilt))
        station = []
        for c_s in cs0 + [0.0, dy, dz]:
            if mounting == "eye_in_hand":
                # base_from_sensor puts the sphere centre at c_s; base_from_flange = base_from_sensor X^-1
                R_bs = R_ref @ X.rotation_matrix @ Rt
                station.append(Pose.from_rt(R_bs, centre - R_bs @ c_s) @ X_inv)
            else:
                # the sphere centre, on the flange, at X c_s in base
                R_bf = Rt @ R_ref
                station.append(Pose.from_rt(R_bf, X.apply(c_s) - R_bf @ centre))
        out.append(station)
    return out


def plan_stations(
    mounting: MountingMode,
    nominal_transform: Pose,
    sphere_centre_mm,
    radius_mm: float,
    plan: SweepPlan | None = None,
    reference_flange_rotation=None,
    field_of_view: "SensorFieldOfView | None" = None,
) -> list[tuple[str, list[Pose]]]:
    """Flange targets ``base_from_flange`` per station: ``[(label, [pose, ...]), ...]``.

    ``nominal_transform`` is flange_from_sensor (eye-in-hand) or base_from_sensor
    (eye-to-hand); ``sphere_centre_mm`` is in base (eye-in-hand) or flange (eye-to-hand).
    ``reference_flange_rotation`` (3x3, base_from_flange) defaults to flange pointing down.
    Station k is tilted by ``plan.tilts_deg[k]`` (about the sensor's axes, eye-in-hand, or
    the base's, eye-to-hand) and shifted by ``plan.station_offsets_mm`` (cycled). A plan
    without ``standoff_z_mm`` takes the sensor's, from ``field_of_view`` (:func:`with_standoff`,
    for a sphere of ``radius_mm``)."""
    plan = with_standoff(plan or SweepPlan(), field_of_view, radius_mm)
    offsets = [plan.station_offsets_mm[k % len(plan.station_offsets_mm)] for k in range(len(plan.tilts_deg))]
    R_ref = FLANGE_DOWN if reference_flange_rotation is None else geo.check_rotation_matrix(reference_flange_rotation)
    poses = _station_poses(mounting, nominal_transform, np.asarray(sphere_centre_mm, dtype=float), radius_mm, plan,
                           np.atleast_2d(np.asarray(plan.tilts_deg, dtype=float)), np.asarray(offsets, dtype=float),
                           R_ref)
    return [(f"S{k + 1}", station) for k, station in enumerate(poses)]
