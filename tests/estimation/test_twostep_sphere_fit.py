"""The two-step's fixed-radius sphere fit when the points barely determine a direction:
points on one circle as large as the sphere (a laser plane through its centre) leave the
distance from their plane free to first order. The fit must then leave that direction
where it started (least squares, minimum norm), not take a large step along it from
ill-conditioned normal equations (up to 17 mm there)."""

from __future__ import annotations

import numpy as np
import pytest

from spherecal.core import geometry as geo
from spherecal.estimation.twostep import fit_sphere_fixed_radius


@pytest.mark.parametrize("circle_radius", [12.7, 12.75])
def test_points_on_a_great_circle_leave_the_normal_direction_where_it_started(circle_radius):
    rng = np.random.default_rng(3)
    r = 12.7
    theta = rng.uniform(0.3, 2.8, 100)
    local = np.column_stack([np.zeros(100), circle_radius * np.cos(theta), circle_radius * np.sin(theta)])
    local[:, 1:] += rng.normal(0, 0.005, (100, 2))
    R = geo.matrix_from_rotvec(np.array([0.4, -1.1, 0.7]))
    T = np.array([400.0, -200.0, 900.0])
    points = local @ R.T + T
    start = T.copy()  # in the plane, at the circle's centre
    c = fit_sphere_fixed_radius(points, r, start)
    normal = R[:, 0]
    assert abs((c - start) @ normal) < 0.05  # (least squares: 0.012 mm; the normal equations: 0.4-17 mm)
    in_plane = (c - T) - ((c - T) @ normal) * normal
    assert np.linalg.norm(in_plane) < 0.2  # (a circle larger than the sphere pulls it toward the arc)


def test_a_well_determined_sphere_is_found_from_a_start_far_off():
    rng = np.random.default_rng(4)
    d = rng.normal(size=(500, 3))
    d = d[d[:, 2] > -0.3]  # a cap, as a sensor sees the sphere
    d /= np.linalg.norm(d, axis=1)[:, None]
    centre = np.array([1100.0, 150.0, 400.0])
    points = centre + 19.1 * d + rng.normal(0, 0.01, (len(d), 3))
    c = fit_sphere_fixed_radius(points, 19.1, centre + [3.0, -2.0, 4.0])
    np.testing.assert_allclose(c, centre, atol=0.01)
