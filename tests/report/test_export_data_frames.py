"""The exports of a result whose data named their frames (a ROS 2 bag's): the ROS files
name the bag's frames and publish the clouds' own frame, composed with the turn between
the clouds' frame and the calibrated sensor frame; every other export says the sensor
frame is not the clouds' when they differ."""

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from spherecal.core.models import DataFrames
from spherecal.estimation import solve
from spherecal.io.bag_frames import SENSOR_FROM_CLOUD_TEXT, sensor_from_cloud
from spherecal.io.dataset import read_result, write_result
from spherecal.report import export as ex
from spherecal.sim import SweepPlan, simulate_dataset, standard_cell
from reference_sensor import reference_fov


@pytest.fixture(scope="module")
def results():
    plan = SweepPlan(profiles_per_station=6)
    return {m: solve(simulate_dataset(standard_cell(m, seed=5, fov=reference_fov()), plan)).result
            for m in ("eye_in_hand", "eye_to_hand")}


def _with_frames(result, line_axis):
    frames = DataFrames(source="rosbag2", base_frame_id="world", flange_frame_id="ee_link",
                        cloud_frame_id="profiler_link", sensor_from_cloud=sensor_from_cloud(line_axis),
                        sensor_from_cloud_text=SENSOR_FROM_CLOUD_TEXT.get(line_axis))
    return result.model_copy(update={"data_frames": frames})


def _cloud_to_sensor(line_axis, p_cloud):
    """How the bag reader takes a cloud point into the sensor frame, written out: the line
    along the cloud's y is the sensor's own; along x, (x, y, z) is the sensor point
    (-y, x, z) (docs/conventions.md, "A ROS 2 bag's frames")."""
    x, y, z = p_cloud.T
    return p_cloud if line_axis == "y" else np.column_stack([-y, x, z])


def _parsed(result, settings=ex.Ros2ExportSettings()):
    files = ex.ROS2_EXPORTER.write(result, settings)
    out = {name: reader(files[name]) for name, reader in (
        ("ros_static_transform.sh", ex.read_ros_command), ("ros_static_transform.yaml", ex.read_ros_yaml),
        ("ros_static_transform.launch.py", ex.read_ros_launch))}
    urdf = ex.read_ros_urdf_joint(files["ros_sensor_joint.urdf.xacro"])
    urdf["R"] = Rotation.from_euler("xyz", urdf["rpy_rad"]).as_matrix()  # URDF: Rz(yaw) Ry(pitch) Rx(roll)
    out["ros_sensor_joint.urdf.xacro"] = urdf
    for d in out.values():
        if "quaternion_xyzw" in d:
            d["R"] = Rotation.from_quat(d["quaternion_xyzw"]).as_matrix()
    return files, out


@pytest.mark.parametrize("line_axis", ["x", "y"])
def test_ros_exports_name_the_bags_frames_and_publish_the_clouds_frame(results, mounting, line_axis):
    result = _with_frames(results[mounting], line_axis)
    files, parsed = _parsed(result)
    parent = "ee_link" if mounting == "eye_in_hand" else "world"
    p_cloud = np.array([[0.0, 0.0, 0.0], [0.02, 0.0, -0.03], [-0.01, 0.004, 0.05]])  # m
    # where the calibration puts the points the clouds' frame holds, in the mount frame (m)
    expected = result.transform.apply(_cloud_to_sensor(line_axis, p_cloud) * 1000.0) / 1000.0
    for name, d in parsed.items():
        assert (d["frame_id"], d["child_frame_id"]) == (parent, "profiler_link"), name
        np.testing.assert_allclose(p_cloud @ d["R"].T + d["xyz_m"], expected, atol=2e-7, err_msg=name)
    turned = "'profiler_link' is the clouds' own frame" in files["ros_static_transform.sh"]
    assert turned == (line_axis == "x")
    note = ex.ROS2_EXPORTER.note(result, ex.Ros2ExportSettings())
    assert f"'{parent}' is the {'flange' if mounting == 'eye_in_hand' else 'base'} frame the rosbag2 data named" \
        in note.text and not note.warning


def test_a_child_frame_set_to_another_name_is_the_sensor_frame_with_a_warning(results):
    result = _with_frames(results["eye_in_hand"], "x")
    settings = ex.Ros2ExportSettings(child_frame_id="laser")
    files, parsed = _parsed(result, settings)
    R = result.transform.rotation_matrix
    for name, d in parsed.items():
        assert (d["frame_id"], d["child_frame_id"]) == ("ee_link", "laser"), name
        np.testing.assert_allclose(d["R"], R, atol=1e-7, err_msg=name)
        assert "WARNING: 'laser' is spherecal's calibrated sensor frame, NOT the clouds' frame 'profiler_link'" \
            in files[name], name
    note = ex.ROS2_EXPORTER.note(result, settings)
    assert "'laser' is spherecal's calibrated sensor frame" in note.warning and "Rz(+90 deg)" in note.warning


def test_the_other_exports_say_the_sensor_frame_is_not_the_clouds(results, tmp_path):
    turned = _with_frames(results["eye_in_hand"], "x")
    for text in (ex.matrix_text(turned), ex.xyz_quaternion_text(turned)):
        assert "SENSOR FRAME: 'sensor' here is spherecal's calibrated sensor frame, not the frame the clouds came in " \
               "'profiler_link': sensor_from_cloud = Rz(+90 deg)" in text
    for plain in (_with_frames(results["eye_in_hand"], "y"), results["eye_in_hand"]):
        assert "SENSOR FRAME" not in ex.matrix_text(plain) and "SENSOR FRAME" not in ex.xyz_quaternion_text(plain)
    # result.json keeps the frames
    write_result(tmp_path / "result.json", turned)
    assert read_result(tmp_path / "result.json").data_frames == turned.data_frames
