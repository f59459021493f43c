"""The rotation conversions of :mod:`spherecal.core.geometry` are written in NumPy (SciPy's
``scipy.spatial`` takes 0.3-0.4 s to import, paid by every command that reads a pose).
They are checked here against SciPy's ``Rotation``, an independent implementation, over
random rotations, tiny and half-turn angles and stacks. Quaternion order: ours (w, x,
y, z), SciPy's (x, y, z, w)."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from spherecal.core import geometry as geo


@pytest.fixture(scope="module")
def rotations():
    return Rotation.random(5000, random_state=7)


def test_quaternion_and_matrix_agree_with_scipy(rotations):
    M = rotations.as_matrix()
    q_scipy = geo.quat_wxyz_from_xyzw(rotations.as_quat())
    q_scipy = np.where(q_scipy[:, :1] < 0, -q_scipy, q_scipy)
    np.testing.assert_allclose(geo.matrix_from_quat_wxyz(q_scipy), M, atol=2e-15)
    q = geo.quat_wxyz_from_matrix(M)
    assert np.all(q[:, 0] >= 0)
    np.testing.assert_allclose(q, q_scipy, atol=1e-15)
    np.testing.assert_allclose(np.linalg.norm(q, axis=1), 1.0, atol=1e-15)


def test_rotation_vector_and_matrix_agree_with_scipy(rotations):
    M = rotations.as_matrix()
    np.testing.assert_allclose(geo.matrix_from_rotvec(rotations.as_rotvec()), M, atol=2e-15)
    np.testing.assert_allclose(geo.rotvec_from_matrix(M), rotations.as_rotvec(), atol=4e-15)


@pytest.mark.parametrize("angle", [0.0, 1e-14, 1e-9, 3e-7, 1e-5, 9.9e-5, 1e-4, 1.01e-4, 1e-3, 0.5, 3.0, np.pi - 1e-6])
def test_small_and_large_angles_round_trip(angle):
    rng = np.random.default_rng(int(angle * 1e6) % 1000)
    axes = rng.normal(size=(200, 3))
    v = axes / np.linalg.norm(axes, axis=1, keepdims=True) * angle
    M = geo.matrix_from_rotvec(v)
    np.testing.assert_allclose(M, Rotation.from_rotvec(v).as_matrix(), atol=2e-15)
    np.testing.assert_allclose(M @ np.swapaxes(M, 1, 2), np.broadcast_to(np.eye(3), M.shape), atol=2e-15)
    np.testing.assert_allclose(geo.rotvec_from_matrix(M), v, atol=1e-15 + 1e-9 * (angle > 3))


@pytest.mark.parametrize("axis", np.eye(3).tolist() + [[1 / np.sqrt(2), -1 / np.sqrt(2), 0.0]])
def test_half_turns(axis):
    M = Rotation.from_rotvec(np.pi * np.array(axis)).as_matrix()
    v = geo.rotvec_from_matrix(M)
    assert np.linalg.norm(v) == pytest.approx(np.pi, abs=1e-12)
    np.testing.assert_allclose(geo.matrix_from_rotvec(v), M, atol=1e-15)
    np.testing.assert_allclose(geo.matrix_from_quat_wxyz(geo.quat_wxyz_from_matrix(M)), M, atol=1e-15)


def test_shapes_follow_the_input():
    assert geo.matrix_from_quat_wxyz([1.0, 0.0, 0.0, 0.0]).shape == (3, 3)
    assert geo.quat_wxyz_from_matrix(np.eye(3)).tolist() == [1.0, 0.0, 0.0, 0.0]
    assert geo.rotvec_from_matrix(np.eye(3)).tolist() == [0.0, 0.0, 0.0]
    stack = Rotation.random(6, random_state=1).as_matrix().reshape(2, 3, 3, 3)
    assert geo.quat_wxyz_from_matrix(stack).shape == (2, 3, 4)
    assert geo.rotvec_from_matrix(stack).shape == (2, 3, 3)
    assert geo.matrix_from_rotvec(np.zeros((2, 3, 3))).shape == (2, 3, 3, 3)


def test_a_quaternion_that_is_not_unit_is_refused_and_rounding_is_normalised():
    with pytest.raises(ValueError, match="norm"):
        geo.matrix_from_quat_wxyz([1.0, 0.1, 0.0, 0.0])
    R = geo.matrix_from_quat_wxyz([1.0000004, 0.0, 0.0, 0.0])
    np.testing.assert_allclose(R, np.eye(3), atol=1e-15)
