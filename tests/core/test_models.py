"""Data model: poses, profiles, observations, datasets; bad input fails clearly."""

import math

import numpy as np
import pytest
from pydantic import ValidationError
from scipy.spatial.transform import Rotation

from spherecal.core import geometry as geo
from spherecal.core.models import Dataset, Observation, Pose, Profile


def random_pose(rng) -> Pose:
    return Pose.from_rt(Rotation.random(random_state=rng.integers(1 << 31)).as_matrix(), rng.uniform(-1000, 1000, 3))


def test_pose_matrix_round_trip():
    rng = np.random.default_rng(1)
    for _ in range(20):
        p = random_pose(rng)
        q = Pose.from_matrix(p.as_matrix())
        assert np.allclose(q.as_matrix(), p.as_matrix(), atol=1e-12)


def test_pose_quaternion_is_w_first():
    # 90 deg about z: ABB orient [cos 45, 0, 0, sin 45]
    p = Pose.from_xyz_quat_wxyz([1.0, 2.0, 3.0], [math.cos(math.pi / 4), 0, 0, math.sin(math.pi / 4)])
    assert np.allclose(p.apply([1.0, 0.0, 0.0]), [1.0, 3.0, 3.0])
    xyz, q = p.as_xyz_quat_wxyz()
    assert xyz == (1.0, 2.0, 3.0)
    assert np.allclose(q, [math.sqrt(0.5), 0, 0, math.sqrt(0.5)])
    # SciPy order is the other way round
    assert np.allclose(geo.quat_xyzw_from_wxyz(q), [0, 0, math.sqrt(0.5), math.sqrt(0.5)])
    assert np.allclose(Rotation.from_quat(geo.quat_xyzw_from_wxyz(q)).as_matrix(), p.rotation_matrix)


def test_the_brand_named_pose_constructors_warn_and_still_work():
    """``from_abb`` and ``as_abb`` are deprecated aliases for one release."""
    with pytest.warns(DeprecationWarning, match=r"Pose\.from_abb is renamed Pose\.from_xyz_quat_wxyz"):
        p = Pose.from_abb([1.0, 2.0, 3.0], [0.0, 1.0, 0.0, 0.0])
    assert p == Pose.from_xyz_quat_wxyz([1.0, 2.0, 3.0], [0.0, 1.0, 0.0, 0.0])
    with pytest.warns(DeprecationWarning, match=r"Pose\.as_abb is renamed Pose\.as_xyz_quat_wxyz"):
        assert p.as_abb() == p.as_xyz_quat_wxyz()


def test_q_and_minus_q_are_one_rotation():
    q = np.array([0.3, -0.5, 0.1, 0.8])
    q /= np.linalg.norm(q)
    a = Pose.from_xyz_quat_wxyz([0, 0, 0], q)
    b = Pose.from_xyz_quat_wxyz([0, 0, 0], -q)
    assert np.allclose(a.rotation_matrix, b.rotation_matrix)
    assert a.quaternion_wxyz == pytest.approx(b.quaternion_wxyz)


def test_composition_and_inverse():
    rng = np.random.default_rng(2)
    a, b = random_pose(rng), random_pose(rng)
    assert np.allclose((a @ b).as_matrix(), a.as_matrix() @ b.as_matrix())
    assert np.allclose((a @ a.inverse()).as_matrix(), np.eye(4), atol=1e-9)
    pts = rng.normal(size=(5, 3))
    assert np.allclose(a.inverse().apply(a.apply(pts)), pts)


@pytest.mark.parametrize(
    "R, message",
    [
        (np.diag([1.0, 1.0, -1.0]), "reflection"),
        (np.eye(3) * 1.1, "not orthonormal"),
        (np.full((3, 3), np.nan), "NaN"),
        (np.eye(4), "3x3"),
    ],
)
def test_pose_rejects_bad_rotations(R, message):
    with pytest.raises(ValueError, match=message):
        Pose.from_rt(R, [0, 0, 0])


def test_pose_rejects_non_unit_quaternion_and_nan():
    with pytest.raises(ValidationError, match="unit quaternion"):
        Pose.from_xyz_quat_wxyz([0, 0, 0], [1, 1, 0, 0])
    with pytest.raises(ValidationError, match="NaN or infinite"):
        Pose.from_xyz_quat_wxyz([0, math.inf, 0], [1, 0, 0, 0])


def test_profile_validation():
    p = Profile.from_points([[0.0, 1.0], [2.0, 3.0]])
    assert p.points_mm.shape == (2, 2) and len(p) == 2
    with pytest.raises(ValidationError, match="profile is empty"):
        Profile(y_mm=[], z_mm=[])
    with pytest.raises(ValidationError, match="NaN or infinite values .first at index 1"):
        Profile(y_mm=[0.0, float("nan")], z_mm=[1.0, 2.0])
    with pytest.raises(ValidationError, match="y_mm has 2 values but z_mm has 3"):
        Profile(y_mm=[0.0, 1.0], z_mm=[1.0, 2.0, 3.0])
    with pytest.raises(ValueError, match=r"expected shape \(N, 2\)"):
        Profile.from_points(np.zeros((5, 3)))
    with pytest.raises(ValidationError, match="flat list"):
        Profile(y_mm=[[0.0, 1.0]], z_mm=[[1.0, 2.0]])


def test_observation_needs_a_pose_or_joints():
    prof = Profile.from_points([[0.0, 1.0], [2.0, 3.0], [4.0, 5.0]])
    with pytest.raises(ValidationError, match="needs base_from_flange or joints_deg"):
        Observation(index=0, station="S1", profile=prof)
    with pytest.raises(ValidationError, match="joints_deg contains NaN"):
        Observation(index=0, station="S1", profile=prof, joints_deg=[0, 0, float("nan"), 0, 0, 0])
    with pytest.raises(ValidationError, match="at least 1 character"):
        Observation(index=0, station="", profile=prof, joints_deg=[0] * 6)


@pytest.mark.parametrize("radius, message", [(0.0, "greater than 0"), (-5.0, "greater than 0"),
                                             (0.0191, "looks like metres"), (float("inf"), "finite")])
def test_dataset_radius_must_be_positive_millimetres(radius, message):
    with pytest.raises(ValidationError, match=message):
        Dataset(mounting="eye_in_hand", sphere_radius_mm=radius)


def test_dataset_rejects_unknown_mounting_and_fields():
    with pytest.raises(ValidationError, match="eye_in_hand"):
        Dataset(mounting="eye_on_hand", sphere_radius_mm=19.1)
    with pytest.raises(ValidationError, match="Extra inputs"):
        Dataset(mounting="eye_in_hand", sphere_radius_mm=19.1, radius=3)


def test_result_diagnostics_read_as_a_dict_still_work_with_a_warning():
    """Plugins written when diagnostics was a free dict keep working for one release:
    ``diagnostics["x"]`` and ``.get`` give the attribute (or the extra key) and warn."""
    from spherecal.core.models import ResultDiagnostics

    d = ResultDiagnostics(orientations=4, plugin_figure=1.5)
    with pytest.warns(DeprecationWarning, match="diagnostics.<name>"):
        assert d["orientations"] == 4
    with pytest.warns(DeprecationWarning):
        assert d.get("plugin_figure") == 1.5 and d.get("noise", "none") == "none"
    with pytest.warns(DeprecationWarning), pytest.raises(KeyError):
        d["noise"]
    assert d.model_dump() == {"orientations": 4, "plugin_figure": 1.5}
