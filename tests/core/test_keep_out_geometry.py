"""The keep-out geometry: the signed distance of a box to points and rods, the sensor's
body against the sphere and its stand (eye-in-hand) or stem (eye-to-hand) at flange poses,
and the closest approach along a straight move, each against answers worked by hand or
by brute force."""

import numpy as np
import pytest

from spherecal.core.field_of_view import SensorBody, SensorFieldOfView
from spherecal.core.geometry import matrix_from_rotvec
from spherecal.core.keep_out import (KeepOutGeometry, box_signed_distance_mm, closest_along_moves, closest_at_poses,
                                     linear_move, rod_box_signed_distance_mm)
from spherecal.core.models import Pose

LO, HI = (-10.0, -20.0, 40.0), (10.0, 20.0, 80.0)  # a box 20 x 40 x 40 mm


@pytest.mark.parametrize("point, expected", [
    ((0.0, 0.0, 0.0), 40.0),            # below the bottom face
    ((13.0, 24.0, 60.0), 5.0),          # beside an edge: (3, 4) away
    ((13.0, 24.0, 90.0), np.sqrt(9 + 16 + 100)),  # beside a corner
    ((0.0, 0.0, 60.0), -10.0),          # at the centre: 10 mm from the nearest faces (x)
    ((9.0, 0.0, 60.0), -1.0),           # inside, 1 mm from the x face
    ((10.0, 0.0, 60.0), 0.0),           # on a face
])
def test_box_signed_distance(point, expected):
    assert box_signed_distance_mm(LO, HI, np.array(point)) == pytest.approx(expected, abs=1e-12)


def test_rod_distance_is_the_least_of_its_points():
    """Against a brute-force minimum over 20,001 points of each rod: never above it, and at
    most the sampling's 0.02 mm below."""
    rng = np.random.default_rng(3)
    a, b = rng.uniform(-150, 150, (500, 3)), rng.uniform(-150, 150, (500, 3))
    got = rod_box_signed_distance_mm(LO, HI, a, b)
    t = np.linspace(0.0, 1.0, 20_001)[:, None]
    brute = np.array([box_signed_distance_mm(LO, HI, a[i] + t * (b[i] - a[i])).min() for i in range(len(a))])
    assert np.all(got <= brute + 1e-9) and np.all(got >= brute - 0.02)
    assert (got < 0).any() and (got > 0).any()  # rods through the box and beside it


def test_rod_through_the_box_sideways():
    """A rod along x at y = 0, z = 50 runs through the box: 10 mm deep (the z face)."""
    assert rod_box_signed_distance_mm(LO, HI, np.array([-100.0, 0, 50]), np.array([100.0, 0, 50])) == \
        pytest.approx(-10.0, abs=1e-6)


def _eye_in_hand(**kw):
    """The sensor at the flange (identity), looking down (-z of base); the sphere of
    radius 20 fixed 100 mm below the flange on a stand of radius 5 reaching 200 mm down."""
    args = dict(mounting="eye_in_hand", transform=Pose.identity(), body=SensorBody(min_mm=LO, max_mm=HI),
                sphere_centre_mm=(0.0, 0.0, -100.0), sphere_radius_mm=20.0, rod_radius_mm=5.0, rod_length_mm=200.0)
    return KeepOutGeometry(**{**args, **kw})


def test_eye_in_hand_sphere_below_the_sensor():
    # the sphere's top at z = -80, the body's bottom at z = 40: 120 mm; the stand hangs below
    (c,) = closest_at_poses(_eye_in_hand(), [Pose.identity()])
    assert c.part == "sphere" and c.clearance_mm == pytest.approx(120.0)
    # the flange lowered by 130 mm: the sphere's top 10 mm into the body
    (c,) = closest_at_poses(_eye_in_hand(), [Pose.from_rt(np.eye(3), [0, 0, -130.0])])
    assert c.clearance_mm == pytest.approx(-10.0)


def test_eye_in_hand_sensor_beside_the_stand():
    """The sensor turned to look along base -x (its z along base +x), 200 mm below the
    flange's start: its body spans base x -50..-10 at z -210..-190, beside the stand
    (x = 0, radius 5, from z = -100 down to -300): 10 - 5 = 5 mm."""
    R = matrix_from_rotvec(np.radians([0.0, 90.0, 0.0]))
    sphere, rod = _eye_in_hand().clearances_mm(R[None], np.array([[-90.0, 0.0, -200.0]]))
    assert rod[0] == pytest.approx(5.0)
    assert sphere[0] == pytest.approx(np.hypot(10.0, 90.0) - 20.0)


def test_eye_to_hand_sphere_and_stem():
    """The sensor fixed at base (identity); the sphere 100 mm out on the flange's z, the
    flange turned over (z down) at base z = 300: the sphere's centre at z = 200, the stem up
    to the flange. A body box beside the stem's path: the stem is nearer than the sphere."""
    body = SensorBody(min_mm=(20.0, -10.0, 220.0), max_mm=(40.0, 10.0, 280.0))
    g = KeepOutGeometry("eye_to_hand", Pose.identity(), body, (0.0, 0.0, 100.0), 10.0, 5.0, 0.0)
    flange = Pose.from_rt(matrix_from_rotvec(np.radians([180.0, 0.0, 0.0])), [0.0, 0.0, 300.0])
    sphere, rod = g.clearances_mm(flange.rotation_matrix[None], flange.translation[None])
    assert rod[0] == pytest.approx(20.0 - 5.0)  # the stem at x = 0, the box from x = 20
    assert sphere[0] == pytest.approx(np.hypot(20.0, 20.0) - 10.0)  # centre (0, 0, 200), corner edge (20, *, 220)
    (c,) = closest_at_poses(g, [flange])
    assert c.part == "stem" and c.clearance_mm == pytest.approx(15.0)


def test_linear_move_ends_and_middle():
    start = Pose.from_rt(np.eye(3), [0.0, 0.0, 0.0])
    end = Pose.from_rt(matrix_from_rotvec(np.radians([0.0, 0.0, 90.0])), [100.0, 0.0, 0.0])
    R, t = linear_move(start, end, [0.0, 0.5, 1.0])
    assert np.allclose(R[0], np.eye(3)) and np.allclose(R[2], end.rotation_matrix, atol=1e-12)
    assert np.allclose(R[1], matrix_from_rotvec(np.radians([0.0, 0.0, 45.0])))
    assert np.allclose(t[1], [50.0, 0.0, 0.0])


def test_a_turn_swings_the_body_through_the_sphere_between_two_clear_poses():
    """The sensor 150 mm out on the flange's z (its body 160-210 mm out); the flange turns
    150 deg about base x, from its z along base z to (0, 0.5, -0.87). Half way (-90 deg)
    the body stands where the sphere is, (0, 185, 0): both ends are clear, the move is not,
    and its closest pose agrees with a brute force over 20,001 poses."""
    X = Pose.from_rt(np.eye(3), [0.0, 0.0, 150.0])  # flange_from_sensor
    body = SensorBody(min_mm=(-20.0, -20.0, 10.0), max_mm=(20.0, 20.0, 60.0))
    g = KeepOutGeometry("eye_in_hand", X, body, (0.0, 185.0, 0.0), 20.0, 0.0, 0.0)
    start, end = Pose.identity(), Pose.from_rt(matrix_from_rotvec(np.radians([-150.0, 0.0, 0.0])), [0.0, 0.0, 0.0])
    assert all(c.clearance_mm > 100 for c in closest_at_poses(g, [start, end]))
    (c,), n = closest_along_moves(g, [start, end])
    R, t = linear_move(start, end, np.linspace(0, 1, 20_001))
    brute = np.minimum(*g.clearances_mm(R, t)).min()
    assert brute < -30 and c.clearance_mm == pytest.approx(brute, abs=0.5)
    assert c.part == "sphere" and c.fraction == pytest.approx(0.6, abs=0.01)  # -90 of -150 deg
    # no point of the body (at most 211.9 mm from the flange's origin) moves more than 1 mm a sample
    assert n >= np.hypot(np.hypot(20.0, 20.0), 210.0) * np.radians(150.0)


def test_a_body_in_its_own_measuring_range_is_told():
    fov = SensorFieldOfView(z_near_mm=40.0, z_far_mm=-60.0, width_near_mm=28.0, width_far_mm=48.0)
    assert SensorBody(min_mm=(-10, -10, -70), max_mm=(10, 10, -50)).overlap_with_range(fov)
    assert not SensorBody(min_mm=(-100, -35, 80), max_mm=(30, 35, 165)).overlap_with_range(fov)


def test_a_body_box_must_be_ordered():
    with pytest.raises(ValueError, match="min_mm z = 50.0 must be below max_mm z = 40.0"):
        SensorBody(min_mm=(0, 0, 50), max_mm=(1, 1, 40))


def test_no_stand_is_no_rod():
    """stand_length_mm = 0: only the sphere counts, whatever the stand's radius."""
    g = _eye_in_hand(rod_length_mm=0.0, rod_radius_mm=50.0)
    (c,) = closest_at_poses(g, [Pose.identity()])
    assert c.part == "sphere" and c.clearance_mm == pytest.approx(120.0)
