"""The IRB 2400 plugin reads RAPID tooldata and wobjdata (compare/validate --tooldata)."""

import numpy as np
import pytest

from spherecal.core.errors import InputError
from spherecal.core.models import Pose
from spherecal.robots.abb_irb2400.frames import read_frame
from reference_sensor import reference_fov

X = Pose.from_xyz_quat_wxyz((44.5123, -19.8, 166.25), (0.02714, -0.96565, 0.25663, 0.03026))


def test_a_tooldata_value_is_the_tool_frame_w_first():
    frame = read_frame("[TRUE,[[44.5123,-19.8,166.25],[0.02714,-0.96565,0.25663,0.03026]],"
                       "[1,[22.3,-9.9,83.1],[1,0,0,0],0,0,0]]")
    assert frame.transform_name == "flange_from_sensor" and frame.kind == "tooldata" and frame.name is None
    np.testing.assert_allclose(frame.pose.as_matrix(), X.as_matrix(), atol=1e-12)


def test_a_declaration_with_comments_and_without_the_load():
    text = """MODULE Cell3
      ! the laser sensor, calibrated 2024-05-02
      TASK PERS tooldata tLaser := [TRUE, [[44.5123, -19.8, 166.25],  ! tframe
                                            [0.02714, -0.96565, 0.25663, 0.03026]]];
    ENDMODULE"""
    frame = read_frame(text)
    assert frame.name == "tLaser" and frame.transform_name == "flange_from_sensor"
    np.testing.assert_allclose(frame.pose.as_matrix(), X.as_matrix(), atol=1e-12)


def test_a_fixed_work_object_is_base_from_sensor_uframe_then_oframe():
    u = Pose.from_xyz_quat_wxyz((1250.0, -200.0, 900.0), (0.0, 0.70710678, 0.70710678, 0.0))
    o = Pose.from_xyz_quat_wxyz((1.0, 2.0, 3.0), (0.9659258, 0.0, 0.0, 0.2588190))
    frame = read_frame('PERS wobjdata wobjSensor := [FALSE, TRUE, "", [[1250, -200, 900], [0, 0.70710678, '
                       '0.70710678, 0]], [[1, 2, 3], [0.9659258, 0, 0, 0.2588190]]];')
    assert frame.transform_name == "base_from_sensor" and frame.kind == "wobjdata"
    np.testing.assert_allclose(frame.pose.as_matrix(), (u @ o).as_matrix(), atol=1e-6)
    assert "world" in frame.note


def test_a_stationary_tool_is_base_from_sensor():
    frame = read_frame("[FALSE,[[1250,-200,900],[0,1,0,0]],[1,[0,0,1],[1,0,0,0],0,0,0]]")
    assert frame.transform_name == "base_from_sensor" and "stationary" in frame.note


def test_what_the_exporter_writes_reads_back():
    from spherecal.estimation import calibrate
    from spherecal.robots.abb_irb2400.export import rapid_declaration
    from spherecal.sim import SweepPlan, simulate_dataset, standard_cell

    for mounting in ("eye_in_hand", "eye_to_hand"):
        result = calibrate(simulate_dataset(standard_cell(mounting, seed=2, fov=reference_fov()),
                                            SweepPlan(profiles_per_station=5)))
        frame = read_frame(rapid_declaration(result))
        assert frame.transform_name == result.transform_name
        # the export rounds to 4 decimals (mm) and 8 (quaternion)
        np.testing.assert_allclose(frame.pose.translation, result.transform.translation, atol=1e-4)
        np.testing.assert_allclose(frame.pose.rotation_matrix, result.transform.rotation_matrix, atol=1e-7)


@pytest.mark.parametrize("text", ["1,2,3,1,0,0,0", "", "result.json", "tSensor"])
def test_text_that_is_not_rapid_is_left_to_others(text):
    assert read_frame(text) is None


@pytest.mark.parametrize("text, message", [
    ("[TRUE,[[1,2,3],[1,0,0,0]]", "a ']' is missing at the end of the text"),
    ("[TRUE,[[1,2,3],[1,0,0]]]", "tooldata tframe.rot: expected 4 numbers, got 3"),
    ("[TRUE,[[1,2,3],[0.5,0,0,0]]]", "tooldata tframe.rot: the quaternion [0.5, 0, 0, 0] has norm 0.500000"),
    ("[TRUE,[[1,2],[1,0,0,0]]]", "tooldata tframe.trans: expected 3 numbers, got 2"),
    ("[TRUE,[[1,2,x],[1,0,0,0]]]", "'x' is not a value"),
    ("[1,[[1,2,3],[1,0,0,0]]]", "tooldata robhold: expected TRUE or FALSE, got 1"),
    ("[TRUE,[[1,2,3],[1,0,0,0]],[1,[0,0],[1,0,0,0],0,0,0]]", "tooldata tload.cog: expected 3 numbers, got 2"),
    ("[TRUE,[[1,2,3],[1,0,0,0]],[1,[0,0,1]]]", "tooldata tload: expected [mass,"),
    ("[TRUE,[[1,2,3],[1,0,0,0]]] extra", "unexpected text after the closing ']'"),
    ("[TRUE;[[1,2,3],[1,0,0,0]]]", "expected ',' or ']', found ';'"),
    ('[FALSE,FALSE,"STN1",[[0,0,0],[1,0,0,0]],[[0,0,0],[1,0,0,0]]]', "ufprog is FALSE"),
    ('[FALSE,TRUE,"",[[0,0,0],[1,0,0,0]]]', "tooldata: expected [robhold"),
    ("PERS tooldata tSensor := [TRUE,[[1,2,3],[1,0,0]]];", "tooldata tSensor tframe.rot: expected 4 numbers"),
    ("PERS tooldata t1 := [TRUE,[[1,2,3],[1,0,0,0]]]; PERS tooldata t2 := [TRUE,[[1,2,3],[1,0,0,0]]];",
     "declares 2 frames (t1, t2): give one"),
    ("PERS wobjdata w1 := 5;", "wobjdata w1: the value after ':=' must start with '['"),
])
def test_bad_lines_name_what_is_wrong(text, message):
    with pytest.raises(InputError) as exc:
        read_frame(text)
    assert message in str(exc.value)
