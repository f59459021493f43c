"""Simulated objects: ray casting with known answers, occlusion, frames, and the cell."""

import numpy as np
import pytest

from spherecal.core import geometry as geo
from spherecal.core.mapping import frame_from_sensor_stack, map_profile_list, rt_from_poses
from spherecal.core.models import Pose
from spherecal.sim.cell import NoiseModel, standard_cell
from spherecal.sim.objects import BallBar, CarDoorPanel, FlatPlate, SceneObject, Sphere
from reference_sensor import reference_fov

NOISE_FREE = NoiseModel(point_noise_mm=0.0, pose_translation_noise_mm=0.0)


def _unit(v):
    v = np.asarray(v, dtype=float)
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


# sphere and ball bar ------------------------------------------------------------------
def test_sphere_distances_known_answers():
    s = Sphere([1.0, 2.0, 3.0], 2.0)
    o = np.array([[1.0, 2.0, 13.0], [1.0, 2.0, 13.0], [1.0, 2.0, 3.5], [1.0, 2.0, -10.0], [1.0, 5.0, 13.0]])
    d = np.array([[0, 0, -1.0], [0, 0, 1.0], [0, 0, -1.0], [0, 0, -1.0], [0, 0, -1.0]])
    np.testing.assert_allclose(s.intersect(o, d), [8.0, np.inf, np.inf, np.inf, np.inf])
    # oblique: ray through the point at 60 degrees from the pole, along the normal
    n = np.array([np.sin(np.pi / 3), 0.0, np.cos(np.pi / 3)])
    p = s.centre_mm + 2.0 * n
    assert s.intersect([p + 7.5 * n], [-n])[0] == pytest.approx(7.5, abs=1e-12)


def test_sphere_and_ballbar_reject_bad_geometry():
    with pytest.raises(ValueError, match="radius_mm must be a positive"):
        Sphere([0, 0, 0], -1.0)
    with pytest.raises(ValueError, match="frame must be 'base' or 'flange'"):
        Sphere([0, 0, 0], 1.0, frame="tool")
    with pytest.raises(ValueError, match="the spheres overlap"):
        BallBar([0, 0, 0], [10, 0, 0], 6.0)
    with pytest.raises(ValueError, match=r"origins and directions must both be \(n, 3\)"):
        Sphere([0, 0, 0], 1.0).intersect(np.zeros((2, 3)), np.zeros((3, 3)))


def test_ballbar_returns_the_nearer_sphere():
    bar = BallBar([0, 0, 0], [100, 0, 0], 10.0)
    assert bar.certified_distance_mm == pytest.approx(100.0)
    o = np.array([[-50.0, 0, 0], [150.0, 0, 0], [50.0, 0, 50.0]])
    d = np.array([[1.0, 0, 0], [-1.0, 0, 0], [0, 0, -1.0]])
    np.testing.assert_allclose(bar.intersect(o, d), [40.0, 40.0, np.inf])
    assert isinstance(bar, SceneObject)


def test_laser_plane_cut_matches_general_ray_cast():
    cell = standard_cell("eye_in_hand", noise=NOISE_FREE, fov=reference_fov())
    sph = cell.reference_sphere
    apex, d = cell.fan_rays()
    pose = cell.sweep_poses(sph.centre_mm, "base", geo.matrix_from_rotvec([0.2, -0.1, 0.4]), 10.0, 3)[1]
    R, t = cell.frame_from_sensor("base", pose)
    general = sph.intersect(np.broadcast_to(R @ apex + t, d.shape), d @ R.T)
    plane = sph.intersect_laser_plane(cell.sphere_centre_in_sensor(pose), apex[1:], d[:, 1:])
    assert np.isfinite(general).sum() > 100
    np.testing.assert_array_equal(np.isfinite(general), np.isfinite(plane))
    np.testing.assert_allclose(general[np.isfinite(general)], plane[np.isfinite(plane)], atol=1e-9)


# flat plate ---------------------------------------------------------------------------
def test_flat_plate_known_answers_both_sides_and_edges():
    R = geo.matrix_from_rotvec([0.3, 0.0, 0.0])
    plate = FlatPlate(Pose.from_rt(R, [10.0, 0.0, 5.0]), 40.0, 20.0)
    n = plate.normal
    centre = np.array([10.0, 0.0, 5.0])
    inside = centre + R @ [15.0, -8.0, 0.0]
    outside = centre + R @ [15.0, 11.0, 0.0]
    o = np.array([inside + 30 * n, inside - 12 * n, outside + 30 * n, inside + 30 * n])
    d = np.array([-n, n, -n, n])
    np.testing.assert_allclose(plate.intersect(o, d), [30.0, 12.0, np.inf, np.inf], atol=1e-12)
    along = R @ [1.0, 0.0, 0.0]
    assert plate.intersect([centre - 50 * along], [along])[0] == np.inf  # in its plane: parallel


# car door panel -----------------------------------------------------------------------
def _panel(**kw):
    return CarDoorPanel(Pose.from_rt(geo.matrix_from_rotvec([0.1, -0.2, 0.3]), [500.0, -100.0, 200.0]), **kw)


def test_car_door_panel_hits_known_surface_points_to_1e_6_mm():
    panel = _panel()
    rng = np.random.default_rng(0)
    u = rng.uniform(-480, 480, 400)
    v = rng.uniform(-330, 330, 400)
    # points near the crease line too
    u[:50] = rng.uniform(-400, 400, 50)
    v[:50] = panel.crease_offset_mm + panel.crease_slope * u[:50] + rng.uniform(-3, 3, 50)
    inside = panel.contains(u, v)
    u, v = u[inside], v[inside]
    target = panel.surface_point_mm(u, v)
    R = panel.frame_from_panel.rotation_matrix
    # directions from above the sheet (local +z side), within 40 degrees of -z
    tilt = rng.uniform(-0.5, 0.5, (len(u), 2))
    d_local = _unit(np.column_stack([tilt, -np.ones(len(u))]))
    d = d_local @ R.T
    dist = rng.uniform(50.0, 400.0, len(u))
    got = panel.intersect(target - dist[:, None] * d, d)
    # f is concave: the body under the sheet is convex, so the known point is the first hit
    np.testing.assert_allclose(got, dist, atol=1e-6, rtol=0)


def test_car_door_panel_misses_outside_the_rounded_outline_and_has_a_crease():
    panel = _panel()
    a, b, rc = panel.length_mm / 2, panel.height_mm / 2, panel.corner_radius_mm
    corner_out = (a - 0.2 * rc, b - 0.2 * rc)  # cut off by the rounded corner
    corner_in = (a - rc, b - 0.5)
    assert not panel.contains(*corner_out) and panel.contains(*corner_in)
    R = panel.frame_from_panel.rotation_matrix
    down = -R[:, 2]
    for (u, v), expect in ((corner_out, np.inf), (corner_in, 100.0)):
        p = panel.surface_point_mm(u, v)
        got = panel.intersect([p - 100.0 * down], [down])[0]
        assert got == pytest.approx(expect, abs=1e-6)
    # the crease: across it the slope drops by about 2 * crease_depth more than the dome's
    vc, h = panel.crease_offset_mm, 20.0

    def slope_drop(p):
        below = p.surface_z_mm(0.0, vc - h) - p.surface_z_mm(0.0, vc - h - 1.0)
        above = p.surface_z_mm(0.0, vc + h + 1.0) - p.surface_z_mm(0.0, vc + h)
        return below - above

    crease = slope_drop(panel) - slope_drop(_panel(crease_depth=0.0))
    assert crease == pytest.approx(2 * panel.crease_depth, rel=0.02)


def test_car_door_panel_rejects_bad_parameters():
    with pytest.raises(ValueError, match="corner_radius_mm must be in"):
        _panel(corner_radius_mm=500.0)
    with pytest.raises(ValueError, match="crease_depth must be >= 0"):
        _panel(crease_depth=-0.1)


# the cell -----------------------------------------------------------------------------
def test_a_plate_in_front_of_the_sphere_occludes_it():
    cell = standard_cell("eye_in_hand", noise=NOISE_FREE, fov=reference_fov())
    pose = cell.sweep_poses(cell.sphere_centre_mm, "base", np.eye(3), 0.0, 1)[0]
    assert len(cell.ideal_profile(pose)) > 100
    base_from_sensor = cell.base_from_sensor(pose)
    # a plate across the fan, 5 mm in front of the sphere's top (sensor z = +15 mm)
    plate_pose = Pose.from_rt(base_from_sensor.rotation_matrix, base_from_sensor.apply([0.0, 0.0, 15.0]))
    cell.add_object(FlatPlate(plate_pose, 30.0, 200.0))
    hits = cell.cast_fan(pose)
    on_plate = hits.object_index == 1
    assert on_plate.sum() > 100
    np.testing.assert_allclose(hits.points_mm[on_plate, 1], 15.0, atol=1e-9)
    # rays that miss the 30 mm wide plate (|y| > 15 mm) reach the sphere or nothing
    assert np.all(np.abs(hits.points_mm[~on_plate, 0]) >= 15.0 - 1e-9)


def test_sphere_only_cell_points_lie_on_the_sphere():
    cell = standard_cell("eye_to_hand", noise=NOISE_FREE, fov=reference_fov())
    for pose in cell.sweep_poses(cell.sphere_centre_mm, "flange", np.eye(3), 12.0, 5):
        pts = cell.ideal_profile(pose)
        c = cell.sphere_centre_in_sensor(pose)
        r = np.linalg.norm(np.column_stack([np.zeros(len(pts)), pts]) - c, axis=1)
        np.testing.assert_allclose(r, cell.sphere_radius_mm, atol=1e-9)


def test_ball_bar_on_the_flange_eye_to_hand_maps_back_onto_its_spheres():
    cell = standard_cell("eye_to_hand", noise=NOISE_FREE, fov=reference_fov())
    bar = cell.add_object(BallBar([60.0, 0.0, 120.0], [-60.0, 10.0, 120.0], 10.0, frame="flange"))
    poses = cell.sweep_poses(bar.sphere_a.centre_mm, "flange", geo.matrix_from_rotvec([0.0, 0.3, 0.0]), 8.0, 9)
    reported, profiles = cell.scan(poses)
    Rb, tb = rt_from_poses(reported)
    R, t = frame_from_sensor_stack("eye_to_hand", Rb, tb, cell.true_transform, frame="flange")
    pts, _ = map_profile_list(R, t, profiles)
    assert len(pts) > 500
    np.testing.assert_allclose(np.linalg.norm(pts - bar.sphere_a.centre_mm, axis=1), 10.0, atol=1e-9)


def test_object_on_the_flange_moves_with_the_sensor_in_eye_in_hand():
    cell = standard_cell("eye_in_hand", noise=NOISE_FREE, fov=reference_fov())
    X = cell.true_transform
    # a plate 20 mm in front of the sensor, fixed to the flange
    cell.add_object(FlatPlate(X @ Pose.from_rt(np.eye(3), [0.0, 0.0, -20.0]), 100.0, 100.0, frame="flange"))
    a = cell.ideal_profile(Pose.identity())
    b = cell.ideal_profile(Pose.from_rt(geo.matrix_from_rotvec([0.3, 0.2, 0.1]), [500.0, 20.0, 700.0]))
    assert len(a) == cell.fov.n_columns
    np.testing.assert_allclose(a, b, atol=1e-9)
    np.testing.assert_allclose(a[:, 1], -20.0, atol=1e-9)


def test_scanned_car_door_points_lie_on_the_panel():
    cell = standard_cell("eye_in_hand", noise=NOISE_FREE, fov=reference_fov())
    panel = cell.add_object(CarDoorPanel(Pose.from_rt(np.eye(3), [900.0, -600.0, 100.0])))
    target = panel.surface_point_mm(0.0, panel.crease_offset_mm)
    poses = cell.sweep_poses(target, "base", np.eye(3), 20.0, 6)
    hits = [cell.cast_fan(p) for p in poses]
    assert all(len(h.points_mm) == cell.fov.n_columns and np.all(h.object_index == 1) for h in hits)
    Rb, tb = rt_from_poses(poses)
    R, t = frame_from_sensor_stack("eye_in_hand", Rb, tb, cell.true_transform)
    pts, _ = map_profile_list(R, t, [h.points_mm for h in hits])
    local = panel.frame_from_panel.inverse().apply(pts)
    np.testing.assert_allclose(local[:, 2], panel.surface_z_mm(local[:, 0], local[:, 1]), atol=1e-6)


def test_cell_rejects_non_objects_and_impossible_views():
    cell = standard_cell("eye_in_hand", fov=reference_fov())
    with pytest.raises(TypeError, match="is not a scene object"):
        cell.add_object("a plate")
    with pytest.raises(ValueError, match="cannot move the sensor relative to frame 'flange'"):
        cell.sweep_poses([0, 0, 0], "flange", np.eye(3), 5.0, 3)


def test_reference_sphere_attributes_stay_in_step_with_the_scene():
    cell = standard_cell("eye_in_hand", noise=NOISE_FREE, fov=reference_fov())
    cell.sphere_centre_mm = [1000.0, 0.0, 300.0]
    cell.sphere_radius_mm = 12.7
    assert cell.objects[0].radius_mm == 12.7
    np.testing.assert_array_equal(cell.reference_sphere.centre_mm, [1000.0, 0.0, 300.0])
