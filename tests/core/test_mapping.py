"""Profile mapping against a straightforward reference (Pose.apply per profile), both backends."""

import numpy as np
import pytest

from spherecal.core import geometry as geo
from spherecal.core import mapping
from spherecal.core.mapping import frame_from_sensor_stack, map_profile_list, map_profiles, rt_from_poses
from spherecal.core.models import Pose

BACKENDS = ["numpy"] + (["numba"] if mapping.NUMBA_AVAILABLE else [])


def _poses(n, seed=0):
    rng = np.random.default_rng(seed)
    return [Pose.from_rt(geo.matrix_from_rotvec(rng.normal(size=3)), rng.uniform(-1500, 1500, 3)) for _ in range(n)]


def _reference(poses, y, z):
    """Pose.apply on (0, y, z) per profile, float64."""
    return np.stack(
        [p.apply(np.column_stack([np.zeros(len(yy)), yy, zz]).astype(float)) for p, yy, zz in zip(poses, y, z)]
    )


@pytest.mark.parametrize("backend", BACKENDS)
@pytest.mark.parametrize("in_dtype", [np.float32, np.float64])
@pytest.mark.parametrize("out_dtype", [np.float32, np.float64])
def test_batched_mapping_matches_reference(backend, in_dtype, out_dtype):
    rng = np.random.default_rng(1)
    n, m = 7, 301
    poses = _poses(n)
    y = rng.uniform(-24, 24, (n, m)).astype(in_dtype)
    z = rng.uniform(-60, 40, (n, m)).astype(in_dtype)
    y[2, 5] = np.nan
    z[4, :3] = np.nan
    R, t = rt_from_poses(poses)
    out = np.empty((n, m, 3), dtype=out_dtype)
    got = map_profiles(R, t, y, z, out, backend=backend)
    assert got is out
    ref = _reference(poses, y.astype(float), z.astype(float))
    invalid = np.isnan(y) | np.isnan(z)
    assert np.all(np.isnan(got[invalid])) and not np.any(np.isnan(got[~invalid]))
    # float64: rounding only; float32 output: float32 arithmetic (NumPy) or one rounding
    # (numba) of ~1500 mm values, whose float32 unit is 1.2e-4 mm
    atol = 1e-9 if out_dtype == np.float64 else 2e-4
    np.testing.assert_allclose(got[~invalid], ref[~invalid], rtol=0, atol=atol)


@pytest.mark.parametrize("backend", BACKENDS)
def test_ragged_mapping_matches_reference_and_indexes_profiles(backend):
    rng = np.random.default_rng(2)
    poses = _poses(5, seed=3)
    profiles = [rng.uniform(-20, 20, (k, 2)) for k in (10, 0, 3, 250, 1)]
    profiles[1] = np.empty((0, 2))
    R, t = rt_from_poses(poses)
    pts, index = map_profile_list(R, t, profiles, backend=backend)
    assert pts.shape == (264, 3)
    np.testing.assert_array_equal(index, np.repeat(np.arange(5), [10, 0, 3, 250, 1]))
    for i, (pose, prof) in enumerate(zip(poses, profiles)):
        ref = pose.apply(np.column_stack([np.zeros(len(prof)), prof]))
        np.testing.assert_allclose(pts[index == i], ref, rtol=0, atol=1e-9)


def test_backend_choice_environment_and_fallback(monkeypatch):
    monkeypatch.setenv("SPHERECAL_MAPPING_BACKEND", "numpy")
    assert mapping._resolve("auto") == "numpy"
    monkeypatch.delenv("SPHERECAL_MAPPING_BACKEND")
    assert mapping._resolve("auto") == ("numba" if mapping.NUMBA_AVAILABLE else "numpy")
    with pytest.raises(ValueError, match="backend must be 'auto', 'numba' or 'numpy'"):
        mapping._resolve("cuda")
    # where numba is absent, auto falls back to NumPy and asking for numba says what to do
    monkeypatch.setattr(mapping, "NUMBA_AVAILABLE", False)
    assert mapping._resolve("auto") == "numpy"
    with pytest.raises(ImportError, match="pip install numba"):
        mapping._resolve("numba")


@pytest.mark.parametrize("mounting", ["eye_in_hand", "eye_to_hand"])
@pytest.mark.parametrize("frame", ["base", "flange"])
def test_frame_from_sensor_stack_composes_like_poses(mounting, frame):
    flanges = _poses(4, seed=5)
    X = _poses(1, seed=6)[0]
    Rb, tb = rt_from_poses(flanges)
    R, t = frame_from_sensor_stack(mounting, Rb, tb, X, frame)
    for i, base_from_flange in enumerate(flanges):
        if mounting == "eye_in_hand":
            expect = base_from_flange @ X if frame == "base" else X
        else:
            expect = X if frame == "base" else base_from_flange.inverse() @ X
        np.testing.assert_allclose(R[i], expect.rotation_matrix, atol=1e-12)
        np.testing.assert_allclose(t[i], expect.translation, atol=1e-9)


def test_bad_shapes_and_dtypes_are_named():
    R, t = rt_from_poses(_poses(2))
    y = np.zeros((2, 5))
    with pytest.raises(ValueError, match=r"y_mm and z_mm must be \(n, m\) arrays of one shape"):
        map_profiles(R, t, y, np.zeros((2, 4)))
    with pytest.raises(ValueError, match="z_mm must be float32 or float64, got int64"):
        map_profiles(R, t, y, np.zeros((2, 5), dtype=np.int64))
    with pytest.raises(ValueError, match=r"expected R \(3, 3, 3\) and t \(3, 3\) for 3 profiles"):
        map_profiles(R, t, np.zeros((3, 5)), np.zeros((3, 5)))
    with pytest.raises(ValueError, match=r"out: expected a C-contiguous \(2, 5, 3\)"):
        map_profiles(R, t, y, y, out=np.empty((2, 5, 3), dtype=np.float16))
    with pytest.raises(ValueError, match=r"profiles_mm\[1\]: expected an \(N, 2\) array"):
        map_profile_list(R, t, [np.zeros((3, 2)), np.zeros((3, 3))])
    with pytest.raises(ValueError, match="frame must be 'base' or 'flange'"):
        frame_from_sensor_stack("eye_in_hand", R, t, Pose.identity(), "sensor")
