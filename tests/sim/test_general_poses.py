"""Simulated hand-eye logs: shots each at an orientation of its own (sim.datasets.general_pose_targets)."""

from __future__ import annotations

import numpy as np
import pytest

from spherecal.core import geometry as geo
from spherecal.sim import NoiseModel, general_pose_targets, simulate_general_dataset, standard_cell
from reference_sensor import reference_fov

EXACT = NoiseModel(point_noise_mm=0.0, pose_translation_noise_mm=0.0, pose_rotation_noise_deg=0.0)


def test_each_shot_has_its_own_orientation_within_the_tilts_and_the_sphere_in_view(mounting):
    cell = standard_cell(mounting, seed=2, noise=EXACT, fov=reference_fov())
    targets = general_pose_targets(cell, 25, max_tilt_deg=20.0, max_turn_deg=20.0, seed=4)
    assert [label for label, _ in targets] == [f"P{k + 1}" for k in range(25)]
    poses = [poses[0] for _, poses in targets]
    assert all(len(p) == 1 for _, p in targets)
    R = np.array([p.rotation_matrix for p in poses])
    angles = [geo.rotation_angle_deg(R[i], R[j]) for i in range(25) for j in range(i)]
    assert min(angles) > 0.5 and 20.0 < max(angles) < 2 * np.hypot(20.0, 20.0)
    r, fov = cell.sphere_radius_mm, cell.fov
    for p in poses:
        c = cell.sphere_centre_in_sensor(p)
        assert abs(c[0]) <= 0.8 * r + 1e-9 and fov.z_far_mm < c[2] < fov.z_near_mm
        assert len(cell.ideal_profile(p)) >= 20


@pytest.mark.parametrize("kind", ["sphere_centre", "circle", "profile"])
def test_a_general_dataset_measures_each_shot_as_asked(kind):
    cell = standard_cell("eye_in_hand", seed=2, noise=EXACT, fov=reference_fov())
    ds = simulate_general_dataset(cell, 12, kind=kind, centre_noise_mm=0.0)
    assert len(ds.observations) == 12 and len({o.station for o in ds.observations}) == 12
    assert all(o.kind == kind for o in ds.observations)
    assert ds.provenance["plan"]["general_poses"] == 12
    if kind == "sphere_centre":
        for o in ds.observations:
            np.testing.assert_allclose(o.sphere_centre_mm, cell.sphere_centre_in_sensor(o.base_from_flange), atol=1e-9)
