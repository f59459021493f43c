"""Exports of a calibration result: every export parsed back and checked against the
result it came from, in both mounting modes."""

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from spherecal.dataio import read_result
from spherecal.errors import InputError
from spherecal.estimation import solve
from spherecal.report import export as ex
from spherecal.sim import SweepPlan, simulate_dataset, standard_cell

MM_TOL = 0.5 * 10 ** -ex.MM_DECIMALS + 1e-12
Q_TOL = 0.5 * 10 ** -ex.QUAT_DECIMALS + 1e-15


@pytest.fixture(scope="module")
def results():
    plan = SweepPlan(profiles_per_station=6)
    return {m: solve(simulate_dataset(standard_cell(m, seed=4), plan)).result for m in ("eye_in_hand", "eye_to_hand")}


@pytest.fixture
def result(results, mounting):
    return results[mounting]


def _R_from_wxyz(q):
    """Independent of spherecal.geometry: SciPy wants (x, y, z, w)."""
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


# --- RAPID --------------------------------------------------------------------------------------------
def test_rapid_tooldata_eye_in_hand(results):
    r = results["eye_in_hand"]
    text = ex.rapid_declaration(r)
    d = ex.read_rapid(text)
    assert d["kind"] == "tooldata" and d["name"] == "tSensor" and d["robhold"] is True
    np.testing.assert_allclose(d["xyz_mm"], r.transform.translation_mm, atol=MM_TOL)
    np.testing.assert_allclose(d["quaternion_wxyz"], r.transform.quaternion_wxyz, atol=Q_TOL)
    assert abs(np.linalg.norm(d["quaternion_wxyz"]) - 1) < 1e-7
    # the tool frame is flange_from_sensor: orient [q1..q4] is (w, x, y, z)
    np.testing.assert_allclose(_R_from_wxyz(d["quaternion_wxyz"]), r.transform.rotation_matrix, atol=1e-7)
    # default load: 1 kg at half way from the flange to the sensor
    assert d["mass_kg"] == 1.0
    np.testing.assert_allclose(d["cog_mm"], np.asarray(r.transform.translation_mm) / 2, atol=0.05)
    assert f"{r.std_rotation_deg[1]:.4f}" in text and f"{r.std_translation_mm[0]:.4f}" in text


def test_rapid_wobjdata_eye_to_hand(results):
    r = results["eye_to_hand"]
    text = ex.rapid_declaration(r)
    d = ex.read_rapid(text)
    assert d["kind"] == "wobjdata" and d["name"] == "wobjSensor"
    assert d["robhold"] is False and d["ufprog"] is True  # fixed user frame, not robot-held
    np.testing.assert_allclose(d["xyz_mm"], r.transform.translation_mm, atol=MM_TOL)
    np.testing.assert_allclose(d["quaternion_wxyz"], r.transform.quaternion_wxyz, atol=Q_TOL)
    assert '[FALSE, TRUE, "",' in text and "[[0, 0, 0], [1, 0, 0, 0]]];" in text


def test_rapid_options_and_module(results, mounting):
    r = results[mounting]
    text = ex.rapid_module(r, "tLaser_2", module_name="CalibData", mass_kg=2.25, cog_mm=(1.0, -2.0, 55.5))
    assert text.startswith("MODULE CalibData\n") and text.rstrip().endswith("ENDMODULE")
    d = ex.read_rapid(text)
    assert d["name"] == "tLaser_2"
    np.testing.assert_allclose(d["xyz_mm"], r.transform.translation_mm, atol=MM_TOL)
    if mounting == "eye_in_hand":
        assert d["mass_kg"] == 2.25
        np.testing.assert_allclose(d["cog_mm"], [1.0, -2.0, 55.5])
    for line in text.splitlines():
        assert len(line) <= ex.RAPID_MAX_LINE, line


@pytest.mark.parametrize(
    "name, message",
    [
        ("1tool", "not a valid RAPID identifier"),
        ("my tool", "not a valid RAPID identifier"),
        ("tSensor-1", "not a valid RAPID identifier"),
        ("t" * 33, "at most 32"),
        ("PERS", "reserved word"),
        ("endmodule", "reserved word"),
        ("tool0", "predefined"),
    ],
)
def test_rapid_names_must_be_identifiers(results, name, message):
    with pytest.raises(InputError, match=message):
        ex.rapid_declaration(results["eye_in_hand"], name)
    with pytest.raises(InputError, match=message):
        ex.rapid_module(results["eye_to_hand"], module_name=name)


def test_rapid_tool_load_must_have_mass(results):
    with pytest.raises(InputError, match="mass > 0"):
        ex.rapid_declaration(results["eye_in_hand"], mass_kg=0.0)
    with pytest.raises(InputError, match="cog_mm must be 3 finite numbers"):
        ex.rapid_declaration(results["eye_in_hand"], cog_mm=(1.0, 2.0))


def test_rapid_reader_ignores_comments_and_finds_nothing_else():
    with pytest.raises(InputError, match="no 'PERS tooldata' or 'PERS wobjdata'"):
        ex.read_rapid("! PERS tooldata t := [TRUE, [[0,0,0],[1,0,0,0]], [1,[0,0,0],[1,0,0,0],0,0,0]];\n")


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


# --- JSON and all files at once -----------------------------------------------------------------------------
def test_json_round_trip(result):
    assert ex.read_json(ex.json_text(result)) == result


def test_write_exports_writes_every_export_readably(result, tmp_path):
    paths = ex.write_exports(result, tmp_path / "out", rapid_name="tLaser", ros_child_frame_id="laser")
    assert set(paths) == {"matrix", "xyz_quaternion", "rapid", "ros_command", "ros_yaml", "json"}
    assert all(p.parent == tmp_path / "out" and p.is_file() for p in paths.values())
    assert read_result(paths["json"]) == result
    T = ex.read_matrix_text(paths["matrix"].read_text())[result.transform_name]
    np.testing.assert_allclose(T, result.transform.as_matrix(), atol=1e-9)
    name, xyz, q = ex.read_xyz_quaternion(paths["xyz_quaternion"].read_text())
    np.testing.assert_allclose(xyz, result.transform.translation_mm, atol=MM_TOL)
    d = ex.read_rapid(paths["rapid"].read_text())
    assert d["name"] == "tLaser"
    np.testing.assert_allclose(d["quaternion_wxyz"], result.transform.quaternion_wxyz, atol=Q_TOL)
    assert ex.read_ros_command(paths["ros_command"].read_text())["child_frame_id"] == "laser"
    assert ex.read_ros_yaml(paths["ros_yaml"].read_text())["child_frame_id"] == "laser"
    # a second run refuses to replace the files unless asked
    with pytest.raises(InputError, match="exists; pass overwrite=True"):
        ex.write_exports(result, tmp_path / "out")
    ex.write_exports(result, tmp_path / "out", overwrite=True)


def test_exports_need_a_result():
    with pytest.raises(InputError, match="expected a CalibrationResult, got dict"):
        ex.matrix_text({})
