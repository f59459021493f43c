"""Exports of a calibration result: every export parsed back and checked against the
result it came from, in both mounting modes."""

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from spherecal.io.dataset import read_result
from spherecal.core.errors import InputError
from spherecal.estimation import solve
from spherecal.io.exporters import write_exports
from spherecal.plugins.host import PluginHost
from spherecal.report import export as ex
from spherecal.sim import SweepPlan, simulate_dataset, standard_cell
from reference_sensor import reference_fov

MM_TOL = 0.5 * 10 ** -ex.MM_DECIMALS + 1e-12
Q_TOL = 0.5 * 10 ** -ex.QUAT_DECIMALS + 1e-15


@pytest.fixture(scope="module")
def results():
    plan = SweepPlan(profiles_per_station=6)
    return {m: solve(simulate_dataset(standard_cell(m, seed=4, fov=reference_fov()),
                                      plan)).result for m in ("eye_in_hand", "eye_to_hand")}


@pytest.fixture
def result(results, mounting):
    return results[mounting]


def _R_from_wxyz(q):
    """Independent of spherecal.core.geometry: SciPy wants (x, y, z, w)."""
    w, x, y, z = q
    return Rotation.from_quat([x, y, z, w]).as_matrix()


# --- 4x4 ----------------------------------------------------------------------------------------
def test_matrix_text_holds_both_directions(result):
    text = ex.matrix_text(result)
    mats = ex.read_matrix_text(text)
    name = result.transform_name
    inv = ex.inverse_name(name)
    assert set(mats) == {name, inv}
    T = result.transform.as_matrix()
    np.testing.assert_allclose(mats[name], T, atol=1e-9)
    np.testing.assert_allclose(mats[inv], np.linalg.inv(T), atol=1e-9)
    # rounding the rotation to 1e-10 moves a point 1 m away by 1e-7 mm
    np.testing.assert_allclose(mats[name] @ mats[inv], np.eye(4), atol=1e-6)
    assert "p_A = T_A_from_B @ p_B" in text and "millimetres" in text and result.mounting in text
    # the header's uncertainty sentence carries the result's own numbers
    assert f"{result.std_rotation_deg[0]:.4f}" in text and f"{result.std_translation_mm[2]:.4f}" in text


def test_matrix_text_names_are_as_the_mounting_says(results):
    assert set(ex.read_matrix_text(ex.matrix_text(results["eye_in_hand"]))) == {"flange_from_sensor", "sensor_from_flange"}
    assert set(ex.read_matrix_text(ex.matrix_text(results["eye_to_hand"]))) == {"base_from_sensor", "sensor_from_base"}


def test_matrix_reader_rejects_a_short_block():
    bad = "[flange_from_sensor]\n1 0 0 0\n0 1 0 0\n0 0 1 0\n[x_from_y]\n"
    with pytest.raises(InputError, match=r"block \[flange_from_sensor\] has 3 rows, expected 4"):
        ex.read_matrix_text(bad)
    with pytest.raises(InputError, match="last row of .* must be 0 0 0 1"):
        ex.read_matrix_text("[a_from_b]\n1 0 0 0\n0 1 0 0\n0 0 1 0\n0 0 1 1\n")


# --- xyz + quaternion ------------------------------------------------------------------------------
def test_xyz_quaternion_line_round_trip(result):
    text = ex.xyz_quaternion_text(result)
    name, xyz, q = ex.read_xyz_quaternion(text)
    assert name == result.transform_name
    np.testing.assert_allclose(xyz, result.transform.translation_mm, atol=MM_TOL)
    np.testing.assert_allclose(q, result.transform.quaternion_wxyz, atol=Q_TOL)
    assert q[0] >= 0 and "(w, x, y, z), scalar FIRST" in text
    np.testing.assert_allclose(_R_from_wxyz(q), result.transform.rotation_matrix, atol=1e-7)


# --- ROS ------------------------------------------------------------------------------------------------
def _check_ros(d, r, parent, child):
    assert d["frame_id"] == parent and d["child_frame_id"] == child
    # metres: 1000 x smaller than the mm result, to the printed 7 decimals
    np.testing.assert_allclose(d["xyz_m"] * 1000.0, r.transform.translation_mm, atol=0.5e-7 * 1000 + 1e-9)
    w, x, y, z = r.transform.quaternion_wxyz
    np.testing.assert_allclose(d["quaternion_xyzw"], [x, y, z, w], atol=Q_TOL)
    # (x, y, z, w) is what SciPy (like ROS) reads: the rotation must come out right
    np.testing.assert_allclose(Rotation.from_quat(d["quaternion_xyzw"]).as_matrix(), r.transform.rotation_matrix,
                               atol=1e-7)


def test_ros_command_in_metres_and_xyzw(result):
    text = ex.ros_static_transform_command(result)
    parent = "tool0" if result.mounting == "eye_in_hand" else "base"
    _check_ros(ex.read_ros_command(text), result, parent, "sensor")
    assert "ros2 run tf2_ros static_transform_publisher --x " in text
    assert "METRES" in text and "(x, y, z, w)" in text


def test_ros_yaml_in_metres_and_xyzw(result):
    text = ex.ros_static_transform_yaml(result, frame_id="robot/tool0", child_frame_id="laser_link")
    _check_ros(ex.read_ros_yaml(text), result, "robot/tool0", "laser_link")
    assert "METRES" in text and "(x, y, z, w)" in text


def test_ros_frame_ids_are_checked(results):
    r = results["eye_in_hand"]
    with pytest.raises(InputError, match="child_frame_id 'my sensor' is not a valid tf2 frame id"):
        ex.ros_static_transform_command(r, child_frame_id="my sensor")
    with pytest.raises(InputError, match="frame_id '/tool0' is not a valid"):
        ex.ros_static_transform_yaml(r, frame_id="/tool0")
    with pytest.raises(InputError, match="both 'sensor'"):
        ex.ros_static_transform_command(r, frame_id="sensor")


def test_ros_launch_compiles_and_publishes_the_result(result):
    text = ex.ros_launch_py(result, frame_id="robot/tool0", child_frame_id="laser")
    compile(text, "ros_static_transform.launch.py", "exec")  # valid Python, as `ros2 launch` needs
    d = ex.read_ros_launch(text)
    _check_ros(d, result, "robot/tool0", "laser")
    assert "def generate_launch_description():" in text and 'executable="static_transform_publisher"' in text
    assert 'package="tf2_ros"' in text and "METRES" in text and "(x, y, z, w)" in text
    # the same arguments as the command line, in the Humble+ form (--x ... --child-frame-id)
    assert d.keys() == ex.read_ros_command(ex.ros_static_transform_command(result, "robot/tool0", "laser")).keys()


def test_ros_launch_runs_with_the_launch_api_stubbed(result, monkeypatch):
    """Executed, not only parsed: generate_launch_description() builds one Node with
    the arguments static_transform_publisher takes."""
    import sys
    import types

    made = []
    launch, launch_ros, actions = (types.ModuleType(n) for n in ("launch", "launch_ros", "launch_ros.actions"))
    launch.LaunchDescription = lambda entities: ("description", entities)
    actions.Node = lambda **kw: made.append(kw) or kw
    launch_ros.actions = actions
    for name, mod in (("launch", launch), ("launch_ros", launch_ros), ("launch_ros.actions", actions)):
        monkeypatch.setitem(sys.modules, name, mod)
    namespace = {}
    exec(compile(ex.ros_launch_py(result), "launch.py", "exec"), namespace)
    kind, (node,) = namespace["generate_launch_description"]()
    assert kind == "description" and made == [node]
    assert (node["package"], node["executable"]) == ("tf2_ros", "static_transform_publisher")
    args = dict(zip(node["arguments"][::2], node["arguments"][1::2]))
    parent = "tool0" if result.mounting == "eye_in_hand" else "base"
    assert (args["--frame-id"], args["--child-frame-id"]) == (parent, "sensor")
    np.testing.assert_allclose([float(args[k]) * 1000.0 for k in ("--x", "--y", "--z")],
                               result.transform.translation_mm, atol=1e-4)


def test_ros_launch_reader_rejects_what_is_not_one():
    with pytest.raises(InputError, match="not valid Python: line 1"):
        ex.read_ros_launch("def (:\n")
    with pytest.raises(InputError, match="no static_transform_publisher node"):
        ex.read_ros_launch("x = 1\n")


def _R_from_urdf_rpy(rpy):
    """URDF: rpy about the fixed x, y, z axes (extrinsic), R = Rz(yaw) Ry(pitch) Rx(roll);
    SciPy's lower-case 'xyz' is extrinsic: independent of spherecal's rpy_from_matrix."""
    return Rotation.from_euler("xyz", rpy).as_matrix()


def test_urdf_joint_parses_and_round_trips_the_transform(result):
    text = ex.ros_urdf_joint(result)
    d = ex.read_ros_urdf_joint(text)  # well-formed XML with one fixed joint
    parent = "tool0" if result.mounting == "eye_in_hand" else "base"
    assert (d["frame_id"], d["child_frame_id"], d["joint"]) == (parent, "sensor", f"{parent}_to_sensor")
    np.testing.assert_allclose(d["xyz_m"] * 1000.0, result.transform.translation_mm, rtol=0, atol=1e-12)
    np.testing.assert_allclose(_R_from_urdf_rpy(d["rpy_rad"]), result.transform.rotation_matrix, rtol=0, atol=1e-12)
    assert "METRES" in text and "RADIANS" in text and 'xmlns:xacro="http://www.ros.org/wiki/xacro"' in text


def test_urdf_joint_places_the_sensor_as_pinocchio_reads_it(result):
    """An independent URDF parser (Pinocchio's) puts the sensor link where the result
    says: the flange eye-in-hand, the base eye-to-hand."""
    import xml.etree.ElementTree as ET

    import pinocchio as pin

    parent = "tool0" if result.mounting == "eye_in_hand" else "base"
    snippet = ET.fromstring(ex.ros_urdf_joint(result))
    robot = ET.Element("robot", name="cell")
    ET.SubElement(robot, "link", name=parent)
    robot.extend(list(snippet))
    model = pin.buildModelFromXML(ET.tostring(robot, encoding="unicode"))
    data = model.createData()
    pin.forwardKinematics(model, data, pin.neutral(model))
    pin.updateFramePlacements(model, data)
    M = data.oMf[model.getFrameId("sensor")]  # in the root link, the parent
    np.testing.assert_allclose(M.translation * 1000.0, result.transform.translation_mm, atol=1e-9)
    np.testing.assert_allclose(M.rotation, result.transform.rotation_matrix, atol=1e-12)


@pytest.mark.parametrize("seed", range(4))
def test_rpy_round_trips_everywhere_even_at_gimbal_lock(seed):
    rng = np.random.default_rng(seed)
    rotations = list(Rotation.random(200, random_state=rng).as_matrix())
    for pitch in (np.pi / 2, -np.pi / 2, np.pi / 2 - 1e-9, -np.pi / 2 + 1e-7):  # pitch +-90 deg and next to it
        rotations.append(Rotation.from_euler("xyz", [rng.uniform(-3, 3), pitch, rng.uniform(-3, 3)]).as_matrix())
    for R in rotations:
        rpy = ex.rpy_from_matrix(R)
        np.testing.assert_allclose(_R_from_urdf_rpy(rpy), R, rtol=0, atol=1e-12)


def test_ros2_settings_are_checked():
    with pytest.raises(ValueError, match="child_frame_id 'my sensor' is not a valid tf2 frame id"):
        ex.Ros2ExportSettings(child_frame_id="my sensor")
    with pytest.raises(ValueError, match="both 'sensor'"):
        ex.Ros2ExportSettings(frame_id="sensor")
    with pytest.raises(ValueError, match="both 'laser'"):
        ex.Ros2ExportSettings(frame_id="laser", child_frame_id="laser")
    with pytest.raises(ValueError, match="at most 256 characters"):
        ex.Ros2ExportSettings(frame_id="f" * 257)


# --- JSON and all files at once -----------------------------------------------------------------------------
def test_json_round_trip(result):
    assert ex.read_json(ex.json_text(result)) == result


def test_write_exports_writes_every_export_readably(result, tmp_path):
    plan = PluginHost().export_plan({"run": ["matrix", "xyz_quaternion", "ros2"],
                                     "ros2": {"child_frame_id": "laser"}}, result.mounting, None)
    paths = write_exports(result, tmp_path / "out", plan)
    name = result.transform_name
    assert set(paths) == {f"{name}_4x4.txt", f"{name}_xyz_quat_wxyz.txt", *ex.ROS2_FILES, "result.json"}
    assert all(p.parent == tmp_path / "out" and p.is_file() for p in paths.values())
    assert read_result(paths["result.json"]) == result
    T = ex.read_matrix_text(paths[f"{name}_4x4.txt"].read_text())[result.transform_name]
    np.testing.assert_allclose(T, result.transform.as_matrix(), atol=1e-9)
    _, xyz, q = ex.read_xyz_quaternion(paths[f"{name}_xyz_quat_wxyz.txt"].read_text())
    np.testing.assert_allclose(xyz, result.transform.translation_mm, atol=MM_TOL)
    assert ex.read_ros_command(paths["ros_static_transform.sh"].read_text())["child_frame_id"] == "laser"
    assert ex.read_ros_yaml(paths["ros_static_transform.yaml"].read_text())["child_frame_id"] == "laser"
    assert ex.read_ros_launch(paths["ros_static_transform.launch.py"].read_text())["child_frame_id"] == "laser"
    assert ex.read_ros_urdf_joint(paths["ros_sensor_joint.urdf.xacro"].read_text())["child_frame_id"] == "laser"
    # a second run refuses to replace the files unless asked
    with pytest.raises(InputError, match="exists; pass overwrite=True"):
        write_exports(result, tmp_path / "out", plan)
    write_exports(result, tmp_path / "out", plan, overwrite=True)


def test_the_default_plan_writes_every_installed_exporter(result, tmp_path):
    """The host's plan without settings: every installed exporter for the mounting, default
    settings (the robot is not known, so the built-in robot's export is written too)."""
    host = PluginHost()
    paths = write_exports(result, tmp_path, host.export_plan(None, result.mounting, None))
    expected = {f for e in host.exporters.exporters.values() if result.mounting in e.mountings
                for f in e.file_names(result, e.settings_model())}
    assert set(paths) == expected | {"result.json"} and len(expected) >= 6


def test_every_export_of_a_kinematic_calibration_says_it_needs_the_calibrated_model(result, tmp_path):
    """A transform calibrated with the arm's geometry is copied into files used far from the
    report: each of the core's exports says, in a comment among its first lines, that it
    goes with robot_calibrated.urdf and what to expect on the controller's nominal model,
    and still reads back. A plain calibration's say nothing of it."""
    from kinematic_results import as_kinematic_calibration
    from spherecal.io.exporters import calibrated_model_warning

    plan = PluginHost().export_plan({"run": ["matrix", "xyz_quaternion", "ros2"]}, result.mounting, None)
    kinematic = as_kinematic_calibration(result)
    warning = calibrated_model_warning(kinematic)
    assert "robot_calibrated.urdf" in warning and "nominal model expect 0.362 mm (k = 2)" in warning
    assert calibrated_model_warning(result) == "" and "--" not in warning  # (an XML comment holds no '--')
    for res, folder in ((kinematic, "kinematic"), (result, "plain")):
        paths = write_exports(res, tmp_path / folder, plan)
        for name, path in paths.items():
            if name == "result.json":
                continue
            head = "\n".join(path.read_text().splitlines()[:4])
            assert (warning in head) == (res is kinematic), (name, head)
    paths = write_exports(kinematic, tmp_path / "again", plan)
    name = result.transform_name
    T = ex.read_matrix_text(paths[f"{name}_4x4.txt"].read_text())[name]
    np.testing.assert_allclose(T, result.transform.as_matrix(), atol=1e-9)
    ex.read_xyz_quaternion(paths[f"{name}_xyz_quat_wxyz.txt"].read_text())
    ex.read_ros_command(paths["ros_static_transform.sh"].read_text())
    ex.read_ros_yaml(paths["ros_static_transform.yaml"].read_text())
    ex.read_ros_launch(paths["ros_static_transform.launch.py"].read_text())
    ex.read_ros_urdf_joint(paths["ros_sensor_joint.urdf.xacro"].read_text())


def test_exports_need_a_result():
    with pytest.raises(InputError, match="expected a CalibrationResult, got dict"):
        ex.matrix_text({})
