"""The pytest plugin for plugin authors: fixtures and the robot/sensor harnesses.

The harnesses must pass honest simulated devices and fail broken ones with a message
that says what is wrong."""

from __future__ import annotations

import numpy as np
import pytest

from spherecal.core.errors import DeviceError
from spherecal.core.models import Pose, Profile
from spherecal.motion.planning import SweepPlan
from spherecal.plugins.testing import RobotHarness, SensorHarness, acquire_dataset, pose_error
from reference_sensor import reference_fov


class CellRobot:
    """An honest robot on the cell; subclasses break one thing each."""

    def __init__(self, cell):
        self.cell = cell

    def move_linear(self, base_from_flange, speed_mm_s):
        if speed_mm_s <= 0:
            raise DeviceError(f"speed_mm_s = {speed_mm_s} must be positive")
        self.cell.move_flange_to(base_from_flange)

    def read_flange_pose(self):
        return self.cell.report_pose(self.cell.current_base_from_flange)

    def read_joints_deg(self):
        return None

    def close(self):
        pass


class OffsetRobot(CellRobot):
    def move_linear(self, base_from_flange, speed_mm_s):
        super().move_linear(Pose.from_rt(base_from_flange.rotation_matrix, base_from_flange.translation + [1, 0, 0]),
                            speed_mm_s)


class XyzwRobot(CellRobot):
    """Reports the quaternion in SciPy's (x, y, z, w) order: a classic."""

    def read_flange_pose(self):
        p = super().read_flange_pose()
        w, x, y, z = p.quaternion_wxyz
        return Pose(translation_mm=p.translation_mm, quaternion_wxyz=(x, y, z, w))


class Reckless(CellRobot):
    def move_linear(self, base_from_flange, speed_mm_s):
        self.cell.move_flange_to(base_from_flange)


class CellSensor:
    def __init__(self, cell, transform=None):
        self.cell = cell
        self.transform = transform or (lambda pts: pts)

    def read_profile(self):
        pts = self.cell.measure_profile()
        if len(pts) == 0:
            return None
        return Profile.from_points(self.transform(pts))

    def close(self):
        pass


def test_cell_fixture_defaults_to_eye_in_hand_and_is_seeded(spherecal_cell):
    from spherecal.sim import standard_cell

    assert spherecal_cell.mounting == "eye_in_hand"
    again = standard_cell("eye_in_hand", seed=0, fov=reference_fov())
    assert np.array_equal(spherecal_cell.rng.normal(size=3), again.rng.normal(size=3))


@pytest.mark.parametrize("spherecal_cell", ["eye_to_hand", {"mounting": "eye_to_hand", "seed": 7}], indirect=True)
def test_cell_fixture_is_parametrisable(spherecal_cell, spherecal_stations, spherecal_context):
    assert spherecal_cell.mounting == "eye_to_hand"
    assert spherecal_context.cell is spherecal_cell
    assert [label for label, _ in spherecal_stations] == ["S1", "S2", "S3", "S4"]
    # the planned targets put the sphere in view
    pose = spherecal_stations[0][1][0]
    assert len(spherecal_cell.ideal_profile(pose)) > 100


def test_host_fixture_is_fresh_each_time(spherecal_host):
    from spherecal.plugins.host import PluginHost

    assert isinstance(spherecal_host, PluginHost)
    assert spherecal_host.registry is not PluginHost(load_entry_points=False).registry


@pytest.mark.parametrize("spherecal_cell", ["eye_in_hand", "eye_to_hand"], indirect=True)
def test_robot_harness_passes_an_honest_robot(spherecal_cell, spherecal_robot_harness):
    report = spherecal_robot_harness.check(CellRobot(spherecal_cell))
    assert report.n_moves == 12
    assert report.max_move_error_mm == 0.0
    assert 0 < report.max_report_error_mm < 0.2  # the cell's pose noise, 0.02 mm per axis


@pytest.mark.parametrize(
    "robot_class, message",
    [
        (OffsetRobot, r"move_linear did not land where commanded \(station S1.*1\.000000 mm"),
        (XyzwRobot, r"read_flange_pose\(\) is .* deg from the commanded pose.*quaternion \(w, x, y, z\)\?"),
        (Reckless, r"speed_mm_s=0\.0\) was accepted"),
    ],
)
def test_robot_harness_catches_broken_robots(spherecal_cell, spherecal_robot_harness, robot_class, message):
    with pytest.raises(AssertionError, match=message):
        spherecal_robot_harness.check(robot_class(spherecal_cell))


class RoundingRobot(CellRobot):
    """Reports the exact pose with its translation rounded to 0.01 mm (a protocol with two
    decimals), on a noise-free cell."""

    def read_flange_pose(self):
        from spherecal.core.models import Pose

        p = self.cell.current_base_from_flange
        return Pose(translation_mm=tuple(np.round(p.translation_mm, 2)), quaternion_wxyz=p.quaternion_wxyz)


def test_robot_harness_report_tolerance_can_be_given_and_its_message_keeps_the_margin():
    """A protocol's rounding beyond the default bound: the message shows both figures to
    three significant digits (not rounded to the same number), and a tolerance given to
    check() lets the robot pass."""
    from spherecal.plugins.testing import RobotHarness, make_cell
    from spherecal.sim import NoiseModel

    cell = make_cell({"mounting": "eye_in_hand", "noise": NoiseModel(pose_translation_noise_mm=0.0,
                                                                     pose_rotation_noise_deg=0.0)})
    with pytest.raises(AssertionError, match=r"read_flange_pose\(\) is 0\.00[0-9]+ mm .*allowed 0\.001 mm") as info:
        RobotHarness(cell).check(RoundingRobot(cell))
    assert "report_tolerance_mm=" in str(info.value)
    report = RobotHarness(cell).check(RoundingRobot(cell), report_tolerance_mm=0.01)
    assert 0.001 < report.max_report_error_mm <= 0.01


def test_robot_harness_checks_kinematics_when_given(spherecal_cell, spherecal_robot_harness):
    class JointRobot(CellRobot):
        def read_joints_deg(self):
            return np.zeros(6)

    fk_right = lambda joints: spherecal_cell.current_base_from_flange  # noqa: E731
    report = spherecal_robot_harness.check(JointRobot(spherecal_cell), flange_pose_from_joints=fk_right)
    assert report.max_kinematics_error_mm == 0.0
    with pytest.raises(AssertionError, match=r"forward kinematics of read_joints_deg\(\) = \[0\.0, .*mm from"):
        RobotHarness(spherecal_cell, spherecal_robot_harness.stations).check(
            JointRobot(spherecal_cell), flange_pose_from_joints=lambda joints: Pose.identity())


@pytest.mark.parametrize("spherecal_cell", ["eye_in_hand", "eye_to_hand"], indirect=True)
def test_sensor_harness_passes_an_honest_sensor(spherecal_cell, spherecal_sensor_harness):
    report = spherecal_sensor_harness.check(CellSensor(spherecal_cell))
    assert report.n_profiles == 12
    assert 0.005 < report.rms_distance_mm < 0.02  # the cell's point noise, 0.01 mm
    assert report.min_coverage > 0.95


@pytest.mark.parametrize(
    "transform, message",
    [
        (lambda p: p * [-1, 1], r"profile points are more than .* off the sphere"),  # y mirrored
        (lambda p: p * [1, -1], r"off the sphere.*z positive towards the sensor"),  # z flipped
        (lambda p: p / 1000.0, r"off the sphere"),  # metres
        (lambda p: p[: len(p) // 3], r"the profile covers 3\d% of the visible arc"),  # drops points
    ],
)
def test_sensor_harness_catches_broken_sensors(spherecal_cell, spherecal_sensor_harness, transform, message):
    with pytest.raises(AssertionError, match=message):
        spherecal_sensor_harness.check(CellSensor(spherecal_cell, transform))


def test_sensor_harness_wants_none_when_nothing_is_seen(spherecal_cell, spherecal_stations):
    class Stubborn(CellSensor):
        def read_profile(self):
            return super().read_profile() or Profile.from_points([[0.0, 0.0]])

    with pytest.raises(AssertionError, match=r"read_profile\(\) returned Profile with the sphere out of view"):
        SensorHarness(spherecal_cell, spherecal_stations).check(Stubborn(spherecal_cell))


def test_acquire_dataset_takes_one_observation_per_target(spherecal_cell, spherecal_stations):
    from spherecal.plugins.host import PluginHost

    seen, finished = [], []
    plugin = type("P", (), {
        "spherecal_observation_taken": staticmethod(lambda observation: seen.append(observation.index)),
        "spherecal_acquisition_finished": staticmethod(lambda dataset: finished.append(len(dataset.observations))),
    })()
    host = PluginHost(plugins=[("listener", plugin)], load_entry_points=False)
    dataset = acquire_dataset(CellRobot(spherecal_cell), CellSensor(spherecal_cell), spherecal_stations,
                              spherecal_cell.mounting, spherecal_cell.sphere_radius_mm, host=host)
    n_targets = sum(len(poses) for _, poses in spherecal_stations)
    assert len(dataset.observations) == n_targets == 40
    assert seen == list(range(40)) and finished == [40]
    last_target = spherecal_stations[-1][1][-1]
    assert pose_error(dataset.observations[-1].base_from_flange, last_target)[0] < 0.2


def test_pose_error_is_exact_for_small_and_large_angles():
    from spherecal.core.geometry import matrix_from_rotvec

    a = Pose.from_rt(matrix_from_rotvec([0.3, -0.2, 0.1]), [1.0, 2.0, 3.0])
    for angle_deg in (1e-7, 0.01, 90.0, 179.0):
        b = Pose.from_rt(matrix_from_rotvec(np.radians([0.0, 0.0, angle_deg])) @ a.rotation_matrix, [1.0, 2.0, 7.0])
        dt, da = pose_error(a, b)
        assert dt == pytest.approx(4.0)
        assert da == pytest.approx(angle_deg, rel=1e-6, abs=1e-9)
    assert pose_error(a, a) == (0.0, 0.0)


def _builtin_missing(module: str) -> bool:
    import importlib.util

    return importlib.util.find_spec(module) is None


@pytest.mark.skipif(_builtin_missing("spherecal.robots.abb_irb2400.plugin"), reason="abb_irb2400 plugin not written yet")
def test_builtin_robot_passes_the_robot_harness(spherecal_host, spherecal_context, spherecal_cell, spherecal_stations):
    section = {"type": "abb_irb2400"}
    robot = spherecal_host.create_robot(section, spherecal_context)
    try:
        report = RobotHarness(spherecal_cell, spherecal_stations, per_station=2).check(
            robot, flange_pose_from_joints=spherecal_host.robot_kinematics(section))
    finally:
        robot.close()
    assert report.max_kinematics_error_mm is not None


@pytest.mark.skipif(_builtin_missing("spherecal.sensors.nxsensor_i.plugin"), reason="nxsensor_i plugin not written yet")
def test_builtin_sensor_passes_the_sensor_harness(spherecal_host, spherecal_context, spherecal_sensor_harness):
    sensor = spherecal_host.create_sensor({"type": "nxsensor_i"}, spherecal_context)
    report = spherecal_sensor_harness.check(sensor)
    assert report.n_profiles == 12


# --- the cell as a plugin author sets it up -----------------------------------------------
OWN_TRUTH = Pose.from_rt(np.eye(3), [10.0, -5.0, 120.0])


@pytest.mark.parametrize("spherecal_cell", [
    {"sphere_centre_mm": (900.0, -100.0, 300.0), "true_transform": OWN_TRUTH, "seed": 4},
], indirect=True)
def test_cell_fixture_takes_the_sphere_and_the_true_transform(spherecal_cell, spherecal_stations):
    assert np.array_equal(spherecal_cell.sphere_centre_mm, [900.0, -100.0, 300.0])
    assert spherecal_cell.true_transform is OWN_TRUTH and spherecal_cell.seed == 4
    # the stations are planned around that truth: mid-sweep, the sphere's centre is where the plan
    # puts it in the sensor frame (the sweep's point plus the station's offset), to rounding
    from spherecal.motion.planning import SweepPlan, sphere_centres_in_sensor, with_standoff

    plan = with_standoff(SweepPlan(), spherecal_cell.fov)
    planned = sphere_centres_in_sensor(plan, spherecal_cell.sphere_radius_mm)
    for k, (_, poses) in enumerate(spherecal_stations):
        dy, dz = plan.station_offsets_mm[k % len(plan.station_offsets_mm)]
        mid = len(poses) // 2
        assert np.allclose(spherecal_cell.sphere_centre_in_sensor(poses[mid]), planned[mid] + [0.0, dy, dz],
                           atol=1e-9)


def _small_fov():
    from spherecal.devices.contract import SensorFieldOfView

    return SensorFieldOfView(z_near_mm=15.0, z_far_mm=-15.0, width_near_mm=18.0, width_far_mm=26.0, n_columns=200)


#: a sphere whose visible half fits the 30 mm range with the plan's wander and offsets sized to it
@pytest.mark.parametrize("spherecal_cell", [{"fov": _small_fov(), "sphere_radius_mm": 6.35}], indirect=True)
def test_cell_fixture_takes_the_sensors_field_of_view(spherecal_cell, spherecal_stations, spherecal_sensor_harness):
    assert spherecal_cell.fov == _small_fov()
    # planned in that range: the reference station (no offset) sweeps the sphere's centre at its middle
    # (0 mm); an honest sensor passes on it
    report = spherecal_sensor_harness.check(CellSensor(spherecal_cell))
    assert report.n_profiles > 0
    _, poses = spherecal_stations[0]
    pts = spherecal_cell.ideal_profile(poses[len(poses) // 2])
    assert len(pts) and pts[:, 1].min() >= -15.0 and pts[:, 1].max() <= 15.0
    assert spherecal_cell.sphere_centre_in_sensor(poses[len(poses) // 2])[2] == pytest.approx(0.0, abs=4.0 + 1e-9)


_WHOLE = None


def _whole_cell():
    global _WHOLE
    if _WHOLE is None:
        from spherecal.sim import NoiseModel, SimulatedCell

        _WHOLE = SimulatedCell("eye_in_hand", OWN_TRUTH, (1000.0, 0.0, 350.0), 12.7,
                               noise=NoiseModel(pose_translation_noise_mm=0.0), seed=9, fov=reference_fov())
    return _WHOLE


@pytest.mark.parametrize("spherecal_cell", [_whole_cell(), {"cell": _whole_cell()}], indirect=True)
def test_cell_fixture_takes_a_whole_cell(spherecal_cell):
    assert spherecal_cell is _whole_cell()


@pytest.mark.parametrize("param, message", [
    ({"sphere_centre": (1, 2, 3)}, r"unknown parameter\(s\) \['sphere_centre'\]; known: .*'sphere_centre_mm'"),
    ({"cell": "eye_in_hand"}, "'cell' takes a spherecal.plugins.SimulatedCell and no other key"),
    ({"true_transform": [1, 2, 3]}, "true_transform must be a spherecal.plugins.Pose, got list"),
])
def test_cell_fixture_parameters_are_checked(param, message):
    from spherecal.plugins.testing import make_cell

    with pytest.raises(TypeError, match=message):
        make_cell(param)


class NoisyJointRobot(CellRobot):
    """Reports joints whose forward kinematics (below) lands 0.05 mm off the flange: a
    real controller's joints carry the arm's pose noise."""

    def read_joints_deg(self):
        return np.zeros(6)


def _fk_off_by(cell, mm):
    return lambda joints: Pose.from_rt(cell.current_base_from_flange.rotation_matrix,
                                       cell.current_base_from_flange.translation + [mm, 0.0, 0.0])


@pytest.mark.parametrize("spherecal_cell", [{"noise": None}], indirect=True)
def test_robot_harness_kinematics_tolerance_follows_the_pose_noise(spherecal_cell, spherecal_stations):
    from spherecal.plugins.testing import JOINT_ROUNDING_MM
    from spherecal.sim import NoiseModel

    # the default cell's pose noise, 0.02 mm per axis: 0.05 mm is within 6 sigma
    report = RobotHarness(spherecal_cell, spherecal_stations).check(
        NoisyJointRobot(spherecal_cell), flange_pose_from_joints=_fk_off_by(spherecal_cell, 0.05))
    assert report.max_kinematics_error_mm == pytest.approx(0.05, abs=1e-9)
    # a cell without pose noise allows only the joints' rounding
    quiet = make_quiet(spherecal_cell, NoiseModel(pose_translation_noise_mm=0.0))
    stations = _stations(quiet)
    with pytest.raises(AssertionError, match=rf"0\.05 mm from the commanded pose .*allowed "
                                             rf"{JOINT_ROUNDING_MM:.3g} mm \(the cell's pose noise"):
        RobotHarness(quiet, stations).check(NoisyJointRobot(quiet), flange_pose_from_joints=_fk_off_by(quiet, 0.05))
    RobotHarness(quiet, stations).check(NoisyJointRobot(quiet), flange_pose_from_joints=_fk_off_by(quiet, 0.005))


def make_quiet(cell, noise):
    from spherecal.sim import standard_cell

    return standard_cell(cell.mounting, seed=0, noise=noise, fov=reference_fov())


def _stations(cell):
    from spherecal.motion.planning import plan_stations

    return plan_stations(cell.mounting, cell.true_transform, cell.sphere_centre_mm, cell.sphere_radius_mm,
                         field_of_view=cell.fov)


@pytest.mark.slow
def test_a_plugins_conftest_overrides_the_cell_fixture(tmp_path):
    """The documented way to give every test of a plugin its own cell: a fixture of the
    same name in the plugin's conftest.py; the other fixtures then use it."""
    import subprocess
    import sys

    (tmp_path / "conftest.py").write_text('''
import pytest
from spherecal.plugins.testing import make_cell


@pytest.fixture
def spherecal_cell():
    return make_cell({"mounting": "eye_to_hand", "seed": 11, "sphere_centre_mm": (1.0, 2.0, 140.0)})
''')
    (tmp_path / "test_own_cell.py").write_text('''
def test_my_cell(spherecal_cell, spherecal_stations, spherecal_context):
    assert spherecal_cell.mounting == "eye_to_hand" and spherecal_cell.seed == 11
    assert list(spherecal_cell.sphere_centre_mm) == [1.0, 2.0, 140.0]
    assert spherecal_context.cell is spherecal_cell and len(spherecal_stations) == 4
''')
    run = subprocess.run([sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider", str(tmp_path)],
                         capture_output=True, text=True, cwd=tmp_path)
    assert run.returncode == 0 and "1 passed" in run.stdout, run.stdout + run.stderr


def _run_pytest(folder) -> "subprocess.CompletedProcess":
    import subprocess
    import sys

    return subprocess.run([sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider", str(folder)],
                          capture_output=True, text=True, cwd=folder)


#: A plugin's tests of both mountings, as docs/plugins.md parametrises them.
BOTH_MOUNTINGS_TEST = '''
import pytest


@pytest.mark.parametrize("spherecal_cell", ["eye_in_hand", "eye_to_hand"], indirect=True)
def test_mounting(spherecal_cell, spherecal_stations, spherecal_context, request):
    assert spherecal_cell.mounting == request.node.callspec.params["spherecal_cell"]
    assert spherecal_context.cell is spherecal_cell and len(spherecal_stations) == 4
'''


def _documented_override() -> str:
    """The conftest.py of docs/plugins.md ("Overriding a fixture"), as written there, for
    the built-in sensor type instead of the page's made-up one."""
    from pathlib import Path

    page = (Path(__file__).resolve().parents[2] / "docs" / "plugins.md").read_text()
    start = page.index("# tests/conftest.py of your plugin")
    code = page[start:page.index("```", start)]
    assert "make_cell(" in code and "request" in code
    return code.replace('"acme_profiler"', '"nxsensor_i"')


@pytest.mark.slow
def test_the_documented_override_runs_each_mounting_it_is_asked_for(tmp_path):
    """The override of docs/plugins.md, copied from the page, with the documented
    parametrisation over both mountings: each case gets a cell of its own mounting."""
    (tmp_path / "conftest.py").write_text(_documented_override())
    (tmp_path / "test_both.py").write_text(BOTH_MOUNTINGS_TEST)
    run = _run_pytest(tmp_path)
    assert run.returncode == 0 and "2 passed" in run.stdout, run.stdout + run.stderr


@pytest.mark.slow
def test_an_override_that_drops_the_mounting_fails_the_test_saying_so(tmp_path):
    """An override that ignores the test's parameter would run the eye-to-hand case on
    its own eye-in-hand cell and pass: that case fails at its set-up (an error), naming
    the cause and the fix; the eye-in-hand case, which it does serve, passes."""
    (tmp_path / "conftest.py").write_text('''
import pytest
from spherecal.plugins.testing import make_cell


@pytest.fixture
def spherecal_cell():
    return make_cell({"mounting": "eye_in_hand", "seed": 4})
''')
    (tmp_path / "test_both.py").write_text(BOTH_MOUNTINGS_TEST)
    run = _run_pytest(tmp_path)
    assert run.returncode == 1 and "1 passed, 1 error" in run.stdout, run.stdout + run.stderr
    assert "asks for an eye_to_hand cell" in run.stdout and "ignores the test's parameter" in run.stdout
    assert "make_cell({...your cell's parameters...}, request)" in run.stdout


def test_make_cell_puts_the_tests_parameter_over_the_overrides(spherecal_cell):
    """make_cell(defaults, request): a mounting name replaces the mounting, a dict's keys
    replace the defaults', the rest of the defaults stay."""
    from types import SimpleNamespace

    from spherecal.plugins.testing import make_cell

    def request_with(param):
        return SimpleNamespace(node=SimpleNamespace(callspec=SimpleNamespace(params={"spherecal_cell": param})))

    defaults = {"mounting": "eye_in_hand", "seed": 7}
    assert make_cell(defaults).mounting == "eye_in_hand"
    cell = make_cell(defaults, request_with("eye_to_hand"))
    assert (cell.mounting, cell.seed) == ("eye_to_hand", 7)
    cell = make_cell(defaults, request_with({"seed": 9}))
    assert (cell.mounting, cell.seed) == ("eye_in_hand", 9)
    assert make_cell(defaults, request_with(spherecal_cell)) is spherecal_cell
    assert make_cell(defaults, SimpleNamespace(node=SimpleNamespace())).seed == 7  # an unparametrised test


#: A plan of a cell's own, unlike the default one: two stations of five shots, the second tilted 20 deg about x.
OWN_PLAN_KW = {"profiles_per_station": 5, "tilts_deg": [(0.0, 0.0, 0.0), (20.0, 0.0, 0.0)],
               "station_offsets_mm": [(0.0, 0.0), (4.0, -6.0)]}
OWN_PLAN = SweepPlan(**OWN_PLAN_KW)


class RecordingRobot(CellRobot):
    """An honest robot that remembers where it was sent."""

    def __init__(self, cell):
        super().__init__(cell)
        self.targets = []

    def move_linear(self, base_from_flange, speed_mm_s):
        super().move_linear(base_from_flange, speed_mm_s)
        self.targets.append(base_from_flange)


def _expected_stations(cell, plan):
    from spherecal.motion.planning import plan_stations

    return plan_stations(cell.mounting, cell.true_transform, cell.sphere_centre_mm, cell.sphere_radius_mm, plan,
                         field_of_view=cell.fov)


def _same(a, b) -> bool:
    return [label for label, _ in a] == [label for label, _ in b] and all(
        np.allclose(p.as_matrix(), q.as_matrix(), atol=1e-12) for (_, s), (_, t) in zip(a, b) for p, q in zip(s, t))


def test_robot_harness_takes_the_cells_plan():
    from spherecal.motion.planning import SweepPlan
    from spherecal.sim import standard_cell

    cell = standard_cell("eye_to_hand", seed=4, fov=reference_fov())
    plan = SweepPlan(**OWN_PLAN_KW)
    harness = RobotHarness(cell, plan=plan)
    assert _same(harness.stations, _expected_stations(cell, plan))
    assert not _same(harness.stations, _expected_stations(cell, SweepPlan()))  # not the default plan
    robot = RecordingRobot(cell)
    report = harness.check(robot)
    assert report.n_moves == 2 * 3  # three shots of each of the plan's two stations
    planned = [p for _, poses in harness.stations for p in poses]
    for target in robot.targets[:-1]:  # the last one is the refused zero-speed move's
        assert any(np.array_equal(target.as_matrix(), p.as_matrix()) for p in planned)
    # the sensor harness takes one too; stations and a plan together are refused
    assert _same(SensorHarness(cell, plan=plan).stations, harness.stations)
    with pytest.raises(TypeError, match=r"RobotHarness: give stations or plan .*not both"):
        RobotHarness(cell, harness.stations, plan=plan)
    with pytest.raises(TypeError, match=r"plan must be a spherecal.plugins.SweepPlan, got dict"):
        RobotHarness(cell, plan=OWN_PLAN_KW)


@pytest.mark.parametrize("spherecal_cell", [{"mounting": "eye_in_hand", "plan": OWN_PLAN}], indirect=True)
def test_cell_fixture_takes_the_cells_plan(spherecal_cell, spherecal_stations, spherecal_robot_harness,
                                          spherecal_sensor_harness):
    from spherecal.plugins.testing import make_cell

    assert _same(spherecal_stations, _expected_stations(spherecal_cell, OWN_PLAN))
    assert spherecal_robot_harness.stations is spherecal_stations
    assert spherecal_robot_harness.check(CellRobot(spherecal_cell)).n_moves == 6
    assert spherecal_sensor_harness.check(CellSensor(spherecal_cell)).n_profiles > 0
    # a whole cell takes one too, and a plan that is not a SweepPlan is refused
    whole = make_cell({"cell": _whole_cell(), "plan": OWN_PLAN})
    assert whole is _whole_cell() and _same(RobotHarness(whole).stations, _expected_stations(whole, OWN_PLAN))
    with pytest.raises(TypeError, match=r"spherecal_cell: plan must be a spherecal.plugins.SweepPlan, got dict"):
        make_cell({"plan": OWN_PLAN_KW})


def test_the_default_field_of_view_is_the_only_declared_or_the_built_in_one(monkeypatch):
    from pydantic import BaseModel, ConfigDict

    import spherecal.plugins.host as host_module
    from spherecal.devices.contract import SensorFieldOfView, SensorType
    from spherecal.plugins import hookimpl
    from spherecal.plugins.testing import default_field_of_view, make_cell

    assert default_field_of_view() == reference_fov()  # here: the built-in nxSensor-I, the only one
    acme_fov = SensorFieldOfView(z_near_mm=10.0, z_far_mm=-10.0, width_near_mm=8.0, width_far_mm=12.0)

    class AcmeConfig(BaseModel):
        model_config = ConfigDict(extra="forbid", frozen=True)

    class Acme:
        @staticmethod
        @hookimpl
        def spherecal_register_devices(registry):
            registry.add_sensor(SensorType(name="acme", config_model=AcmeConfig, factory=lambda c, ctx: None,
                                           field_of_view=acme_fov))

    real = host_module.PluginHost
    # a sensor plugin installed beside the built-in one: the built-in one still
    monkeypatch.setattr(host_module, "PluginHost", lambda autoload=None: real(
        plugins=[("acme", Acme)] if autoload is not False else [], autoload=autoload))
    assert default_field_of_view() == reference_fov()
    assert make_cell("eye_to_hand").fov == reference_fov()
    # two that nothing tells apart: the test must say
    monkeypatch.setattr(host_module, "PluginHost", lambda autoload=None: real(plugins=[("acme", Acme)],
                                                                               autoload=autoload))
    with pytest.raises(TypeError, match=r"spherecal_cell: give the cell's field of view .*installed sensor types "
                                        r"that declare one: acme, nxsensor_i"):
        make_cell("eye_in_hand")
    assert make_cell({"fov": acme_fov}).fov == acme_fov
