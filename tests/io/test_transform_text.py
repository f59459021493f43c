"""spherecal.io.transform_text: a transform typed as ``x,y,z,qw,qx,qy,qz`` (mm, w first)."""

import numpy as np
import pytest

from spherecal.core.errors import ConfigError
from spherecal.io.transform_text import looks_like_numbers, parse_xyz_quat


@pytest.mark.parametrize("text, message", [
    ("1,2,3,1,0,0", "got 6 value"),
    ("1,2,3,1,0,0,zero", "value 7 is 'zero', not a number"),
    ("1,2,3,1,0,0,nan", "value 7 is 'nan'"),
    ("1,2,3,1e7,0,0,0", "value 4 is '1e7': a finite number of at most 1e6"),
    ("1,2,3,0.5,0,0,0", "has norm 0.500000, not 1"),
])
def test_bad_numbers_are_named(text, message):
    with pytest.raises(ConfigError, match="--transform takes x,y,z,qw,qx,qy,qz") as exc:
        parse_xyz_quat(text)
    assert message in str(exc.value)


def test_the_option_at_fault_is_named():
    with pytest.raises(ConfigError, match=r"^--nominal takes x,y,z,qw,qx,qy,qz .*got 3 value"):
        parse_xyz_quat("1,2,3", "--nominal")


def test_numbers_are_w_first():
    pose = parse_xyz_quat("10, 20, 30, 0.7071068, 0.7071068, 0, 0")
    np.testing.assert_allclose(pose.rotation_matrix @ [0, 1, 0], [0, 0, 1], atol=1e-6)  # 90 deg about x
    assert pose.translation_mm == (10.0, 20.0, 30.0)


def test_brackets_and_semicolons_are_read_as_commas():
    pose = parse_xyz_quat("[10; 20; 30; 0; 0; 0; 1]")  # 180 deg about z
    np.testing.assert_allclose(pose.rotation_matrix @ [1, 0, 0], [-1, 0, 0], atol=1e-12)
    assert pose.translation_mm == (10.0, 20.0, 30.0)


@pytest.mark.parametrize("text, numbers", [
    ("1,2,3,1,0,0,0", True), ("(1, 2.5e3)", True), ("result.json", False),
    ("runs/2024-05-01", False), ("tooldata t := [TRUE,[[1,2,3],[1,0,0,0]]]", False),
])
def test_numbers_are_told_from_a_file_or_a_frame(text, numbers):
    assert looks_like_numbers(text) is numbers
