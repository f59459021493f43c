"""Pytest fixtures and checks for authors of robot and sensor plugins.

This module is a pytest plugin, registered under the ``pytest11`` entry point
``spherecal``: in any environment where spherecal is installed its fixtures are available
to every test without an import. (So it imports nothing heavy at module level, and every
fixture name starts with ``spherecal_``.)

Fixtures
--------
``spherecal_cell``
    A seeded :func:`spherecal.plugins.standard_cell`, eye-in-hand by default. Choose the
    mounting (or more) by indirect parametrisation::

        @pytest.mark.parametrize("spherecal_cell", ["eye_in_hand", "eye_to_hand"], indirect=True)

    A parameter may also be a dict of :func:`standard_cell` arguments
    (``{"mounting": "eye_to_hand", "seed": 3}``). The cell is laid out for an IRB
    2400-class arm; for another arm give its kinematics (``{"arm": kinematics}``, e.g.
    ``host.arm_kinematics({"type": "urdf", ...})``: the sphere, or the eye-to-hand
    sensor, where that arm reaches the default plan) or its size (``{"reach_mm": 900.0,
    "shoulder_mm": (0, 0, 90)}``). The dict may also set the cell's truth and sensor:
    ``sphere_centre_mm`` (mm; base in eye-in-hand, flange in eye-to-hand),
    ``true_transform`` (a :class:`~spherecal.plugins.Pose`) and ``fov`` (your sensor's
    :class:`~spherecal.plugins.SensorFieldOfView`, e.g.
    ``host.registry.sensor_type(name).field_of_view``; without it, that of the only
    installed, else the only built-in, sensor type that declares one,
    :func:`default_field_of_view`); or the parameter is a whole
    :class:`~spherecal.plugins.SimulatedCell` (also ``{"cell": cell}``), used as it is. Either
    dict may carry ``plan``, the cell's own :class:`~spherecal.plugins.SweepPlan` (e.g. a
    configuration's ``[acquisition.sweep]``, or one your arm reaches):
    ``spherecal_stations`` and the harnesses use its stations.
    To use one cell in every test of a plugin, override the fixture in the plugin's own
    ``conftest.py`` (a fixture of the same name there wins; docs/plugins.md), and pass
    its ``request`` on (``make_cell({...}, request)``) so that a test's parameter still
    chooses the mounting: a test whose parameter asks for a mounting its cell does not
    have fails, saying so.
``spherecal_host``
    A fresh :class:`spherecal.plugins.PluginHost` (built-ins and installed plugins).
``spherecal_context``
    A :class:`spherecal.plugins.DeviceContext` whose ``cell`` is ``spherecal_cell``: pass it
    to ``host.create_robot`` / ``host.create_sensor`` to get the simulated devices.
``spherecal_stations``
    Planned flange targets for the cell, ``[(label, [base_from_flange, ...]), ...]``, from
    :func:`spherecal.plugins.plan_stations` with the cell's true transform, of the cell's
    plan (``plan`` above) or the default one (:func:`planned_stations`).
``spherecal_robot_harness`` / ``spherecal_sensor_harness``
    :class:`RobotHarness` / :class:`SensorHarness` bound to the cell and stations:
    ``spherecal_robot_harness.check(robot)`` checks that a robot honours the
    :class:`~spherecal.plugins.Robot` protocol against the cell (moves land where
    commanded, reported poses agree within the cell's noise, limits are enforced,
    ``close()`` twice is fine); ``spherecal_sensor_harness.check(sensor)`` that profiles
    match the cell's ideal profile within the noise and that an empty view gives None.
    Built by hand, a harness takes ``stations`` or ``plan`` (a
    :class:`~spherecal.plugins.SweepPlan`, planned on the cell):
    ``RobotHarness(cell, plan=loaded.config.acquisition.sweep)``.

:func:`acquire_dataset` runs a complete acquisition with a robot and a sensor.
"""

from __future__ import annotations

import weakref
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, Callable

import pytest

if TYPE_CHECKING:  # pragma: no cover
    import numpy as np

    from spherecal.devices.contract import DeviceContext, Robot, Sensor, SensorFieldOfView
    from spherecal.core.models import Dataset, Pose
    from spherecal.motion.planning import SweepPlan
    from spherecal.plugins.host import PluginHost
    from spherecal.sim import SimulatedCell



# ---------------------------------------------------------------------------------------
# Helpers
# ---------------------------------------------------------------------------------------
def pose_error(a: "Pose", b: "Pose") -> tuple[float, float]:
    """(translation distance in mm, rotation angle in degrees) between two poses."""
    import numpy as np

    dt = float(np.linalg.norm(a.translation - b.translation))
    # |R_a - R_b|_F = 2 sqrt(2) sin(angle / 2): accurate for small angles, unlike arccos.
    chord = float(np.linalg.norm(a.rotation_matrix - b.rotation_matrix)) / (2.0 * np.sqrt(2.0))
    angle = float(np.degrees(2.0 * np.arcsin(min(chord, 1.0))))
    return dt, angle


def acquire_dataset(
    robot: "Robot",
    sensor: "Sensor",
    stations,
    mounting: str,
    sphere_radius_mm: float,
    speed_mm_s: float = 50.0,
    host: "PluginHost | None" = None,
    provenance: dict | None = None,
) -> "Dataset":
    """Acquire one observation per planned flange target.

    For each target ``base_from_flange`` (quaternion (w, x, y, z), mm): move there with
    ``robot.move_linear``, read the pose the robot reports (``read_flange_pose``) and its
    joints (``read_joints_deg``), take a profile (``sensor.read_profile``); shots without a
    profile are skipped. With ``host``, calls the ``spherecal_observation_taken`` and
    ``spherecal_acquisition_finished`` hooks."""
    from spherecal.core.models import Dataset, Observation

    observations = []
    for label, targets in stations:
        for target in targets:
            robot.move_linear(target, speed_mm_s)
            reported = robot.read_flange_pose()
            joints = robot.read_joints_deg()
            profile = sensor.read_profile()
            if profile is None:
                continue
            obs = Observation(
                index=len(observations),
                station=label,
                base_from_flange=reported,
                joints_deg=None if joints is None else tuple(float(j) for j in joints),
                profile=profile,
            )
            observations.append(obs)
            if host is not None:
                host.observation_taken(observation=obs)
    dataset = Dataset(
        mounting=mounting,
        sphere_radius_mm=sphere_radius_mm,
        observations=observations,
        provenance=dict(provenance or {}),
    )
    if host is not None:
        host.acquisition_finished(dataset=dataset)
    return dataset


def planned_stations(cell: "SimulatedCell", plan: "SweepPlan | None" = None):
    """Flange targets ``[(label, [base_from_flange, ...]), ...]`` of ``plan`` on ``cell``
    (:func:`spherecal.plugins.plan_stations` with the cell's truth, fitted to its field
    of view); without ``plan``, the one given to ``spherecal_cell`` with the cell
    (:func:`make_cell`), else the default :class:`~spherecal.plugins.SweepPlan`."""
    from spherecal.motion.planning import SweepPlan, plan_stations

    if plan is None:
        plan = _CELL_PLANS.get(cell)
    if plan is not None and not isinstance(plan, SweepPlan):
        raise TypeError(f"plan must be a spherecal.plugins.SweepPlan, got {type(plan).__name__}")
    return plan_stations(cell.mounting, cell.true_transform, cell.sphere_centre_mm, cell.sphere_radius_mm, plan,
                         field_of_view=cell.fov)


def _stations_or_plan(cell, stations, plan, who: str):
    if stations is not None and plan is not None:
        raise TypeError(f"{who}: give stations or plan (its stations are planned on the cell), not both")
    return stations if stations is not None else planned_stations(cell, plan)


def _first_targets(stations, per_station: int) -> list[tuple[str, "Pose"]]:
    out = []
    for label, poses in stations:
        step = max(1, len(poses) // per_station)
        out.extend((label, p) for p in poses[::step][:per_station])
    return out


# ---------------------------------------------------------------------------------------
# Harnesses
# ---------------------------------------------------------------------------------------
@dataclass
class RobotReport:
    """What :meth:`RobotHarness.check` measured."""

    n_moves: int
    max_move_error_mm: float
    max_move_error_deg: float
    max_report_error_mm: float
    max_report_error_deg: float
    max_kinematics_error_mm: float | None = None


#: What the robot harness allows, on top of the cell's pose noise, between the forward
#: kinematics of the joints a robot reports and the commanded pose, mm: joints carried
#: with 4 decimals in degrees move a flange 1 m out by up to about 2 um per joint.
JOINT_ROUNDING_MM = 0.01


@dataclass
class RobotHarness:
    """Checks a robot object against the simulated cell it was created on.

    It moves through ``stations`` (``[(label, [base_from_flange, ...]), ...]``), or, when
    they are not given, through the stations of ``plan`` (a
    :class:`~spherecal.plugins.SweepPlan`: the cell's own plan, e.g. a configuration's
    ``[acquisition.sweep]`` or one your arm reaches) planned on the cell
    (:func:`planned_stations`; without either, the plan given to ``spherecal_cell``, else
    the default plan). A TypeError for both."""

    cell: "SimulatedCell"
    stations: Any = None
    per_station: int = 3
    speed_mm_s: float = 50.0
    #: How close a move must land: 1 um and 0.001 deg allow for a controller protocol that
    #: carries positions with 3 decimals in mm and quaternions with 6 decimals.
    move_tolerance_mm: float = 1e-3
    move_tolerance_deg: float = 1e-3
    plan: "SweepPlan | None" = None

    def __post_init__(self) -> None:
        self.stations = _stations_or_plan(self.cell, self.stations, self.plan, type(self).__name__)

    def check(
        self,
        robot: "Robot",
        *,
        flange_pose_from_joints: Callable[[Any], "Pose"] | None = None,
        kinematics_tolerance_mm: float | None = None,
        report_tolerance_mm: float | None = None,
        report_tolerance_deg: float | None = None,
        check_close: bool = True,
    ) -> RobotReport:
        """Assert that ``robot`` honours the Robot protocol on ``self.cell``.

        - it is a :class:`spherecal.plugins.Robot`;
        - after ``move_linear(target, speed)`` the cell's flange is at the target (within
          ``move_tolerance_mm`` / ``_deg``): the move landed where commanded;
        - ``read_flange_pose()`` agrees with the target within ``report_tolerance_mm`` /
          ``_deg`` (default: six standard deviations of the cell's pose noise, plus 1 um
          and 1e-4 deg for rounding; give more for a protocol that carries poses with
          fewer decimals);
        - ``read_joints_deg()`` is None or one finite number per joint; with
          ``flange_pose_from_joints`` (joints_deg -> base_from_flange), the pose computed
          from them agrees with the target within ``kinematics_tolerance_mm`` (default:
          the reported-pose bound, six standard deviations of the cell's pose noise, plus
          :data:`JOINT_ROUNDING_MM` for joints a protocol carries rounded);
        - a non-positive speed is refused with a :class:`~spherecal.plugins.SpherecalError`
          before the robot moves;
        - ``close()`` can be called twice (when ``check_close``; the robot is closed after).

        Returns a :class:`RobotReport`; raises AssertionError naming the target at fault."""
        import numpy as np

        from spherecal.devices.contract import Robot
        from spherecal.core.errors import SpherecalError

        assert isinstance(robot, Robot), (
            f"{type(robot).__name__} is not a spherecal.plugins.Robot: it needs read_flange_pose, "
            f"read_joints_deg, move_linear and close"
        )
        noise = self.cell.noise
        tol_report_mm = (6 * noise.pose_translation_noise_mm * np.sqrt(3) + 1e-3 if report_tolerance_mm is None
                         else float(report_tolerance_mm))
        tol_report_deg = (6 * noise.pose_rotation_noise_deg * np.sqrt(3) + 1e-4 if report_tolerance_deg is None
                          else float(report_tolerance_deg))
        if kinematics_tolerance_mm is None:
            kinematics_tolerance_mm = 6 * noise.pose_translation_noise_mm * np.sqrt(3) + JOINT_ROUNDING_MM
        report = RobotReport(0, 0.0, 0.0, 0.0, 0.0)
        kin_errors = []
        for label, target in _first_targets(self.stations, self.per_station):
            robot.move_linear(target, self.speed_mm_s)
            where = f"station {label}, target {target.translation_mm} mm / {target.quaternion_wxyz} (wxyz)"
            dt, da = pose_error(self.cell.current_base_from_flange, target)
            assert dt <= self.move_tolerance_mm and da <= self.move_tolerance_deg, (
                f"move_linear did not land where commanded ({where}): the cell's flange is "
                f"{dt:.6f} mm and {da:.6f} deg away"
            )
            reported = robot.read_flange_pose()
            rt, ra = pose_error(reported, target)
            assert rt <= tol_report_mm and ra <= tol_report_deg, (
                f"read_flange_pose() is {rt:.3g} mm / {ra:.3g} deg from the commanded pose ({where}); "
                f"allowed {tol_report_mm:.3g} mm / {tol_report_deg:.3g} deg (the cell's pose noise and rounding, "
                "or check(report_tolerance_mm=, report_tolerance_deg=)). Is the pose base_from_flange, in mm, "
                "quaternion (w, x, y, z)?"
            )
            joints = robot.read_joints_deg()
            if joints is not None:
                j = np.asarray(joints, dtype=float)
                assert j.ndim == 1 and 1 <= j.size <= 7 and np.all(np.isfinite(j)), (
                    f"read_joints_deg() must return None or one finite angle in degrees per joint (six for a "
                    f"six-axis arm), got {joints!r}"
                )
                if flange_pose_from_joints is not None:
                    kt, _ = pose_error(flange_pose_from_joints(j), target)
                    kin_errors.append(kt)
                    assert kt <= kinematics_tolerance_mm, (
                        f"forward kinematics of read_joints_deg() = {j.tolist()} is {kt:.3g} mm from the "
                        f"commanded pose ({where}); allowed {kinematics_tolerance_mm:.3g} mm (the cell's pose "
                        f"noise and joint rounding, or check(kinematics_tolerance_mm=))"
                    )
            report.n_moves += 1
            report.max_move_error_mm = max(report.max_move_error_mm, dt)
            report.max_move_error_deg = max(report.max_move_error_deg, da)
            report.max_report_error_mm = max(report.max_report_error_mm, rt)
            report.max_report_error_deg = max(report.max_report_error_deg, ra)
        assert report.n_moves > 0, "no stations to check (empty plan)"
        if kin_errors:
            report.max_kinematics_error_mm = max(kin_errors)

        before = self.cell.current_base_from_flange
        first = _first_targets(self.stations, 1)[-1][1]
        try:
            robot.move_linear(first, 0.0)
        except SpherecalError:
            pass
        else:
            raise AssertionError("move_linear(target, speed_mm_s=0.0) was accepted; a robot must refuse a "
                                 "non-positive speed with a spherecal error before moving")
        assert self.cell.current_base_from_flange is before, (
            "move_linear with a refused speed moved the flange anyway; check limits before moving"
        )
        if check_close:
            robot.close()
            robot.close()
        return report


@dataclass
class SensorReport:
    """What :meth:`SensorHarness.check` measured."""

    n_profiles: int
    max_distance_mm: float
    rms_distance_mm: float
    min_coverage: float


@dataclass
class SensorHarness:
    """Checks a sensor object against the simulated cell it was created on.

    The harness puts the flange at planned poses itself (``cell.move_flange_to``), so a
    sensor can be tested without a robot."""

    cell: "SimulatedCell"
    stations: Any = None
    per_station: int = 3
    min_coverage: float = 0.8
    max_outlier_fraction: float = 0.0
    extra_tolerance_mm: float = 0.005
    #: As :class:`RobotHarness`: the plan whose stations to use when ``stations`` is not given.
    plan: "SweepPlan | None" = None

    def __post_init__(self) -> None:
        self.stations = _stations_or_plan(self.cell, self.stations, self.plan, type(self).__name__)

    def check(self, sensor: "Sensor", *, check_close: bool = True) -> SensorReport:
        """Assert that ``sensor`` honours the Sensor protocol on ``self.cell``.

        - it is a :class:`spherecal.plugins.Sensor`;
        - at each checked pose, ``read_profile()`` returns a :class:`~spherecal.plugins.Profile`
          whose points (y, z in mm, sensor frame) lie on the circle where the laser plane
          cuts the sphere, within six standard deviations of the cell's point noise plus
          ``extra_tolerance_mm`` (a share ``max_outlier_fraction`` may lie further off);
        - the points cover at least ``min_coverage`` of the y-range of the ideal profile
          (a sensor that drops most points, or mirrors y, fails here);
        - with the sphere out of the laser plane, ``read_profile()`` returns None;
        - ``close()`` can be called twice (when ``check_close``).

        Returns a :class:`SensorReport`; raises AssertionError naming the pose at fault."""
        import numpy as np

        from spherecal.devices.contract import Sensor
        from spherecal.core.models import Pose, Profile

        assert isinstance(sensor, Sensor), (
            f"{type(sensor).__name__} is not a spherecal.plugins.Sensor: it needs read_profile and close"
        )
        cell = self.cell
        tol = 6 * cell.noise.point_noise_mm + self.extra_tolerance_mm
        n_profiles, worst, sq, n_pts, coverage = 0, 0.0, 0.0, 0, 1.0
        for label, pose in _first_targets(self.stations, self.per_station):
            cell.move_flange_to(pose)
            ideal = cell.ideal_profile(pose)
            profile = sensor.read_profile()
            where = f"station {label}, flange at {pose.translation_mm} mm"
            if len(ideal) == 0:
                assert profile is None, f"read_profile() returned points where the sensor sees nothing ({where})"
                continue
            assert isinstance(profile, Profile), (
                f"read_profile() returned {type(profile).__name__} ({where}); expected a spherecal.plugins.Profile"
            )
            c = cell.sphere_centre_in_sensor(pose)
            rho = np.sqrt(cell.sphere_radius_mm**2 - c[0] ** 2)
            pts = profile.points_mm
            d = np.abs(np.hypot(pts[:, 0] - c[1], pts[:, 1] - c[2]) - rho)
            off = d > tol
            assert off.mean() <= self.max_outlier_fraction, (
                f"{int(off.sum())} of {len(d)} profile points are more than {tol:.4f} mm off the sphere "
                f"(worst {d.max():.4f} mm) ({where}). Are the points (y, z) in mm in the sensor frame, "
                f"z positive towards the sensor?"
            )
            span = np.ptp(ideal[:, 0])
            covered = float(np.ptp(pts[:, 0]) / span) if span > 0 else 1.0
            overlap = min(pts[:, 0].max(), ideal[:, 0].max()) - max(pts[:, 0].min(), ideal[:, 0].min())
            covered = min(covered, float(overlap / span) if span > 0 else 1.0)
            assert covered >= self.min_coverage, (
                f"the profile covers {covered:.0%} of the visible arc's y-range "
                f"[{ideal[:, 0].min():.2f}, {ideal[:, 0].max():.2f}] mm; expected at least "
                f"{self.min_coverage:.0%} ({where})"
            )
            n_profiles += 1
            inl = d[~off]
            worst = max(worst, float(inl.max()) if inl.size else 0.0)
            sq += float((inl**2).sum())
            n_pts += int(inl.size)
            coverage = min(coverage, covered)
        assert n_profiles > 0, "no pose in the plan showed the sphere; nothing was checked"

        # Out of view: slide the sphere off the laser plane along the sensor's x.
        label, pose = _first_targets(self.stations, 1)[0]
        shift_sensor = np.array([3.0 * cell.sphere_radius_mm, 0.0, 0.0])
        if cell.mounting == "eye_in_hand":
            base_from_sensor = pose @ cell.true_transform
            away = Pose.from_rt(pose.rotation_matrix, pose.translation + base_from_sensor.rotation_matrix @ shift_sensor)
        else:
            away = Pose.from_rt(pose.rotation_matrix,
                                pose.translation + cell.true_transform.rotation_matrix @ shift_sensor)
        cell.move_flange_to(away)
        assert len(cell.ideal_profile(away)) == 0  # the harness's own premise
        empty = sensor.read_profile()
        assert empty is None, (
            f"read_profile() returned {type(empty).__name__} with the sphere out of view; it must return None"
        )
        if check_close:
            sensor.close()
            sensor.close()
        rms = float(np.sqrt(sq / n_pts)) if n_pts else 0.0
        return SensorReport(n_profiles, worst, rms, coverage)


# ---------------------------------------------------------------------------------------
# Fixtures
# ---------------------------------------------------------------------------------------
#: Keys of a ``spherecal_cell`` parameter besides :func:`spherecal.plugins.standard_cell`'s.
CELL_PARAMETERS = ("cell", "sphere_centre_mm", "true_transform", "fov", "plan")

#: The plan given with a cell (``make_cell``'s ``plan`` key), for :func:`planned_stations`.
_CELL_PLANS: "weakref.WeakKeyDictionary[SimulatedCell, SweepPlan]" = weakref.WeakKeyDictionary()


def default_field_of_view() -> "SensorFieldOfView":
    """The field of view a ``spherecal_cell`` measures with when its parameter gives no
    ``fov``, read through a :class:`~spherecal.plugins.PluginHost` as a run reads
    it: that of the only installed sensor type that declares one; with several (yours
    beside a built-in one, say), that of the only built-in sensor type that declares one,
    so that installing a sensor plugin does not change the cells of other tests. A
    TypeError naming them asks for ``fov`` when neither settles it. A sensor plugin's
    tests give their own (``{"fov": ...}``, or a ``spherecal_cell`` of their own)."""
    from spherecal.plugins.host import PluginHost

    def declared(host) -> dict:
        return {n: t.field_of_view for n, t in host.registry.sensors.items() if t.field_of_view is not None}

    installed = declared(PluginHost())
    if len(installed) == 1:
        return next(iter(installed.values()))
    builtin = declared(PluginHost(autoload=False))
    if len(builtin) == 1:
        return next(iter(builtin.values()))
    raise TypeError(
        "spherecal_cell: give the cell's field of view ({'fov': host.registry.sensor_type(name).field_of_view}): "
        f"installed sensor types that declare one: {', '.join(sorted(installed)) or 'none'}"
    )


def make_cell(param: Any = "eye_in_hand", request: "pytest.FixtureRequest | None" = None) -> "SimulatedCell":
    """The cell of a ``spherecal_cell`` parameter (module docstring): a mounting name, a
    :class:`~spherecal.plugins.SimulatedCell` (used as it is), or a dict of
    :func:`~spherecal.plugins.standard_cell` arguments (``seed`` defaults to 0) with any of
    ``sphere_centre_mm`` (the true sphere centre, base in eye-in-hand, flange in
    eye-to-hand, mm), ``true_transform`` (a :class:`~spherecal.plugins.Pose`:
    ``flange_from_sensor`` in eye-in-hand, ``base_from_sensor`` in eye-to-hand), ``fov``
    (a :class:`~spherecal.plugins.SensorFieldOfView`, your sensor's; default
    :func:`default_field_of_view`) or ``cell`` (a whole cell, alone), and ``plan`` (a
    :class:`~spherecal.plugins.SweepPlan`, the cell's own plan: ``spherecal_stations``
    and the harnesses plan with it, :func:`planned_stations`). A key that is none of these
    is a TypeError naming it.

    ``request``: the fixture request of an override of ``spherecal_cell``. The test's
    parameter (``@pytest.mark.parametrize("spherecal_cell", [...], indirect=True)``), when
    it has one, goes over ``param``: a mounting name sets ``mounting``, a dict's keys
    replace ``param``'s, a whole cell is used as it is. An override that leaves the
    request out and returns a cell of another mounting than the test's parameter fails
    the test (:func:`check_cell_parameter`)."""
    import inspect

    import numpy as np

    from spherecal.core.models import Pose
    from spherecal.motion.planning import SweepPlan
    from spherecal.sim import SimulatedCell, standard_cell

    given = _test_parameter(request)
    if given is not _NO_PARAMETER:
        param = _merged(param, given, SimulatedCell)
    if isinstance(param, SimulatedCell):
        return param
    if not isinstance(param, dict):
        return standard_cell(param, seed=0, fov=default_field_of_view())
    kwargs = dict(param)
    plan = kwargs.pop("plan", None)
    if plan is not None and not isinstance(plan, SweepPlan):
        raise TypeError(f"spherecal_cell: plan must be a spherecal.plugins.SweepPlan, got {type(plan).__name__}")
    if "cell" in kwargs:
        if len(kwargs) > 1 or not isinstance(kwargs["cell"], SimulatedCell):
            raise TypeError("spherecal_cell: 'cell' takes a spherecal.plugins.SimulatedCell and no other key (but "
                            f"'plan'), got {sorted(param)}")
        return _with_plan(kwargs["cell"], plan)
    known = set(inspect.signature(standard_cell).parameters) | set(CELL_PARAMETERS)
    unknown = sorted(set(kwargs) - known)
    if unknown:
        raise TypeError(f"spherecal_cell: unknown parameter(s) {unknown}; known: {sorted(known)}")
    centre = kwargs.pop("sphere_centre_mm", None)
    true = kwargs.pop("true_transform", None)
    if true is not None and not isinstance(true, Pose):
        raise TypeError(f"spherecal_cell: true_transform must be a spherecal.plugins.Pose, got {type(true).__name__}")
    kwargs.setdefault("seed", 0)
    if kwargs.get("fov") is None:
        kwargs["fov"] = default_field_of_view()
    cell = standard_cell(**kwargs)
    if true is not None:
        cell.true_transform = true
    if centre is not None:
        cell.sphere_centre_mm = np.asarray(centre, dtype=float).reshape(3)
    return _with_plan(cell, plan)


_NO_PARAMETER = object()


def _test_parameter(request) -> Any:
    """The test's own ``spherecal_cell`` parameter, or :data:`_NO_PARAMETER`."""
    callspec = getattr(getattr(request, "node", None), "callspec", None)
    params = getattr(callspec, "params", {}) if callspec is not None else {}
    return params.get("spherecal_cell", _NO_PARAMETER)


def _merged(default: Any, given: Any, cell_class: type) -> Any:
    """A test's parameter over an override's own cell parameters."""
    if isinstance(given, cell_class) or isinstance(default, cell_class) or (isinstance(given, dict) and "cell" in given):
        return given
    base = dict(default) if isinstance(default, dict) else {"mounting": default}
    return {**base, **(given if isinstance(given, dict) else {"mounting": given})}


def _intended_mounting(given: Any) -> str | None:
    if isinstance(given, str):
        return given
    if isinstance(given, dict):
        cell = given.get("cell")
        return given.get("mounting", getattr(cell, "mounting", None))
    return getattr(given, "mounting", None)


def check_cell_parameter(request, cell: "SimulatedCell") -> "SimulatedCell":
    """``cell``, after checking it is of the mounting the test's ``spherecal_cell``
    parameter asks for. An override of ``spherecal_cell`` that ignores its ``request``
    would otherwise run every eye-to-hand case on its own eye-in-hand cell and pass: the
    test fails instead, saying how to pass the parameter on (:func:`make_cell`)."""
    given = _test_parameter(request)
    if given is _NO_PARAMETER:
        return cell
    wanted = _intended_mounting(given)
    have = getattr(cell, "mounting", None)
    if wanted is not None and have is not None and wanted != have:
        pytest.fail(
            f"spherecal_cell: the test asks for an {wanted} cell ({given!r}) but the spherecal_cell fixture gave an "
            f"{have} one: an override of spherecal_cell in a conftest.py ignores the test's parameter. Take "
            "'request' in the override and pass it on: make_cell({...your cell's parameters...}, request) "
            "(docs/plugins.md, 'Overriding a fixture')",
            pytrace=False,
        )
    return cell


def _with_plan(cell: "SimulatedCell", plan: "SweepPlan | None") -> "SimulatedCell":
    if plan is not None:
        _CELL_PLANS[cell] = plan
    return cell


@pytest.fixture
def spherecal_cell(request) -> "SimulatedCell":
    """A seeded standard cell (default eye-in-hand, seed 0); parametrise indirectly with a
    mounting name, a whole :class:`~spherecal.plugins.SimulatedCell`, or a dict of
    ``standard_cell`` arguments plus ``sphere_centre_mm``, ``true_transform`` and ``fov``
    (:func:`make_cell`). Override it in your own ``conftest.py`` for a cell of your own
    in every test (docs/plugins.md)."""
    return make_cell("eye_in_hand", request)


@pytest.fixture(autouse=True)
def _spherecal_cell_parameter_honoured(request):
    """Fails a test whose ``spherecal_cell`` parameter the fixture (an override of it)
    did not honour (:func:`check_cell_parameter`); does nothing for other tests."""
    if _test_parameter(request) is not _NO_PARAMETER and "spherecal_cell" in request.fixturenames:
        check_cell_parameter(request, request.getfixturevalue("spherecal_cell"))


@pytest.fixture
def spherecal_host() -> "PluginHost":
    """A fresh plugin host: built-ins plus installed third-party plugins (unless
    ``SPHERECAL_DISABLE_PLUGIN_AUTOLOAD`` is set)."""
    from spherecal.plugins.host import PluginHost

    return PluginHost()


@pytest.fixture
def spherecal_context(spherecal_cell) -> "DeviceContext":
    """A device context on ``spherecal_cell``: factories return simulated devices."""
    from spherecal.devices.contract import DeviceContext

    messages: list[str] = []
    return DeviceContext(cell=spherecal_cell, log=messages.append, extras={"log_messages": messages})


@pytest.fixture
def spherecal_stations(spherecal_cell):
    """Planned flange targets ``[(label, [base_from_flange, ...]), ...]`` for the cell: of
    the plan given with it (``{"plan": SweepPlan(...)}``), else the default plan
    (:func:`planned_stations`)."""
    return planned_stations(spherecal_cell)


@pytest.fixture
def spherecal_robot_harness(spherecal_cell, spherecal_stations) -> RobotHarness:
    """A :class:`RobotHarness` on the cell and its planned stations."""
    return RobotHarness(spherecal_cell, spherecal_stations)


@pytest.fixture
def spherecal_sensor_harness(spherecal_cell, spherecal_stations) -> SensorHarness:
    """A :class:`SensorHarness` on the cell and its planned stations."""
    return SensorHarness(spherecal_cell, spherecal_stations)
