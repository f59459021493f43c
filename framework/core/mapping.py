"""Map laser-line profiles into the base (or flange) frame: the hot path of scanning.

A profile point (y, z) lies in the sensor's laser plane x = 0, so with the profile's
``target_from_sensor = (R, t)``::

    p_target = y * R[:, 1] + z * R[:, 2] + t

Which transform that is (see docs/conventions.md for ``A_from_B``):

- eye-in-hand, object fixed in base: ``base_from_sensor_i = base_from_flange_i @ flange_from_sensor``;
- eye-to-hand, object fixed in base: ``base_from_sensor`` (the same for every profile);
- eye-to-hand, object on the flange: ``flange_from_sensor_i = flange_from_base_i @ base_from_sensor``;
- eye-in-hand, object on the flange: ``flange_from_sensor`` (the same for every profile).

:func:`frame_from_sensor_stack` builds these stacks from the robot poses and the
calibrated transform. :func:`map_profiles` maps many profiles of equal length (``(n, m)``
arrays of y and z, NaN marking invalid points) into a preallocated ``(n, m, 3)`` buffer
in one pass; :func:`map_profile_list` does ragged lists. Two backends give the same
numbers (to rounding): ``"numba"`` (a compiled loop, used when numba is installed) and
``"numpy"``; ``backend="auto"`` picks numba when it can, and the environment variable
``SPHERECAL_MAPPING_BACKEND=numpy`` forces the NumPy one. Lengths are mm.
"""

from __future__ import annotations

import importlib.util
import os
from functools import lru_cache
from typing import Literal, Sequence

import numpy as np

from spherecal.core.models import Pose

Backend = Literal["auto", "numba", "numpy"]

#: True when the compiled backend can be used (numba is imported on first use only).
NUMBA_AVAILABLE = importlib.util.find_spec("numba") is not None

#: Points per block in the NumPy backend: keeps its scratch buffers in cache (a float32
#: block is half the bytes, and its product ran fastest in blocks of this size).
_BLOCK_POINTS = 1 << 13
_BLOCK_POINTS_FLOAT32 = 1 << 16
#: Points per block of :func:`map_profile_list`'s NumPy path (its temporaries: a few
#: (block, 3) arrays).
_BLOCK_POINTS_RAGGED = 1 << 16


# transforms -------------------------------------------------------------------------
def rt_from_poses(poses: Sequence[Pose]) -> tuple[np.ndarray, np.ndarray]:
    """Stack poses into rotations (n, 3, 3) and translations (n, 3), mm."""
    if len(poses) == 0:
        return np.empty((0, 3, 3)), np.empty((0, 3))
    return np.stack([p.rotation_matrix for p in poses]), np.stack([p.translation for p in poses])


def frame_from_sensor_stack(
    mounting: Literal["eye_in_hand", "eye_to_hand"],
    base_from_flange_R,
    base_from_flange_t,
    calibrated: Pose,
    frame: Literal["base", "flange"] = "base",
) -> tuple[np.ndarray, np.ndarray]:
    """Per-profile ``<frame>_from_sensor`` as (R (n, 3, 3), t (n, 3)).

    ``calibrated`` is the result of the calibration: ``flange_from_sensor``
    (eye-in-hand) or ``base_from_sensor`` (eye-to-hand). ``base_from_flange_R/_t`` are
    the robot poses of the profiles. ``frame`` is where the measured object is fixed."""
    Rb = np.asarray(base_from_flange_R, dtype=float)
    tb = np.asarray(base_from_flange_t, dtype=float)
    if Rb.ndim != 3 or Rb.shape[1:] != (3, 3) or tb.shape != (len(Rb), 3):
        raise ValueError(
            f"base_from_flange: expected R (n, 3, 3) and t (n, 3), got {Rb.shape} and {tb.shape}"
        )
    Rx, tx = calibrated.rotation_matrix, calibrated.translation
    n = len(Rb)
    if mounting == "eye_in_hand":
        if frame == "base":  # base_from_flange_i @ flange_from_sensor
            return Rb @ Rx, Rb @ tx + tb
        if frame == "flange":
            return np.broadcast_to(Rx, (n, 3, 3)).copy(), np.broadcast_to(tx, (n, 3)).copy()
    elif mounting == "eye_to_hand":
        if frame == "base":
            return np.broadcast_to(Rx, (n, 3, 3)).copy(), np.broadcast_to(tx, (n, 3)).copy()
        if frame == "flange":  # flange_from_base_i @ base_from_sensor
            RbT = np.swapaxes(Rb, 1, 2)
            return RbT @ Rx, np.einsum("nij,nj->ni", RbT, tx - tb)
    else:
        raise ValueError(f"mounting must be 'eye_in_hand' or 'eye_to_hand', got {mounting!r}")
    raise ValueError(f"frame must be 'base' or 'flange', got {frame!r}")


# kernels ----------------------------------------------------------------------------
@lru_cache(maxsize=None)
def _numba_kernels():
    """Compile (or load from numba's cache) the two loops; imported lazily to keep
    ``import spherecal.core.mapping`` light."""
    import numba

    @numba.njit(cache=True, nogil=True, boundscheck=False)
    def _map_numba(R, t, y, z, out):  # pragma: no cover - compiled
        n, m = y.shape
        for i in range(n):
            r01 = R[i, 0, 1]
            r02 = R[i, 0, 2]
            r11 = R[i, 1, 1]
            r12 = R[i, 1, 2]
            r21 = R[i, 2, 1]
            r22 = R[i, 2, 2]
            t0 = t[i, 0]
            t1 = t[i, 1]
            t2 = t[i, 2]
            for j in range(m):
                yy = np.float64(y[i, j])
                zz = np.float64(z[i, j])
                out[i, j, 0] = r01 * yy + r02 * zz + t0
                out[i, j, 1] = r11 * yy + r12 * zz + t1
                out[i, j, 2] = r21 * yy + r22 * zz + t2

    @numba.njit(cache=True, nogil=True, boundscheck=False)
    def _map_ragged_numba(R, t, yz, offsets, out):  # pragma: no cover - compiled
        for i in range(len(offsets) - 1):
            r01 = R[i, 0, 1]
            r02 = R[i, 0, 2]
            r11 = R[i, 1, 1]
            r12 = R[i, 1, 2]
            r21 = R[i, 2, 1]
            r22 = R[i, 2, 2]
            t0 = t[i, 0]
            t1 = t[i, 1]
            t2 = t[i, 2]
            for j in range(offsets[i], offsets[i + 1]):
                yy = np.float64(yz[j, 0])
                zz = np.float64(yz[j, 1])
                out[j, 0] = r01 * yy + r02 * zz + t0
                out[j, 1] = r11 * yy + r12 * zz + t1
                out[j, 2] = r21 * yy + r22 * zz + t2

    return _map_numba, _map_ragged_numba


def _map_numpy(R, t, y, z, out) -> None:
    """Per block of profiles, one batched matrix product writes the interleaved output:
    ``[y z 1] @ [R[:, 1]; R[:, 2]; t]`` per point, (rows, m, 3) @ (rows, 3, 3). The
    (rows, m, 3) operand holds y and z interleaved with a column of ones set once, so the
    only passes over the data are filling it and the product itself (no per-component
    strided stores). A float64 output is computed in float64; a float32 output, asked
    for, in float32 from the float64 transform rounded once: half the memory traffic,
    and an error of about one float32 unit of the largest coordinate involved (measured:
    at most 1.5e-4 mm with translations up to 1.5 m and 2.0e-4 mm up to 2 m, where
    float32 itself resolves 1.2e-4 mm; a float64 product rounded to float32 is within
    half of one unit)."""
    n, m = y.shape
    single = out.dtype == np.float32
    rows = max(1, min(n, (_BLOCK_POINTS_FLOAT32 if single else _BLOCK_POINTS) // max(m, 1)))
    operand = np.ones((rows, m, 3), dtype=out.dtype)
    M = np.empty((n, 3, 3), dtype=out.dtype)
    M[:, 0, :] = R[:, :, 1]
    M[:, 1, :] = R[:, :, 2]
    M[:, 2, :] = t
    for a in range(0, n, rows):
        b = min(a + rows, n)
        op = operand[: b - a]
        op[:, :, 0] = y[a:b]
        op[:, :, 1] = z[a:b]
        np.matmul(op, M[a:b], out=out[a:b])


def _resolve(backend: str) -> str:
    if backend == "auto":
        forced = os.environ.get("SPHERECAL_MAPPING_BACKEND", "").strip().lower()
        if forced in ("numpy", "numba"):
            backend = forced
        else:
            return "numba" if NUMBA_AVAILABLE else "numpy"
    if backend == "numba":
        if not NUMBA_AVAILABLE:
            raise ImportError("mapping backend 'numba' was asked for but numba is not installed: pip install numba")
        return "numba"
    if backend == "numpy":
        return "numpy"
    raise ValueError(f"backend must be 'auto', 'numba' or 'numpy', got {backend!r}")


def _check_rt(R, t, n: int) -> tuple[np.ndarray, np.ndarray]:
    R = np.ascontiguousarray(R, dtype=np.float64)
    t = np.ascontiguousarray(t, dtype=np.float64)
    if R.shape != (n, 3, 3) or t.shape != (n, 3):
        raise ValueError(
            f"transforms: expected R ({n}, 3, 3) and t ({n}, 3) for {n} profiles, got {R.shape} and {t.shape}"
        )
    return R, t


# public API -------------------------------------------------------------------------
def map_profiles(
    target_from_sensor_R,
    target_from_sensor_t,
    y_mm,
    z_mm,
    out: np.ndarray | None = None,
    *,
    dtype=np.float64,
    backend: Backend = "auto",
) -> np.ndarray:
    """Map n profiles of m points each into the target frame; returns ``out`` (n, m, 3).

    ``target_from_sensor_R`` (n, 3, 3) and ``_t`` (n, 3, mm): one transform per profile
    (see :func:`frame_from_sensor_stack`). ``y_mm``, ``z_mm``: (n, m) float32 or float64,
    NaN for invalid points (they map to NaN). ``out``: a C-contiguous (n, m, 3) float32
    or float64 buffer to write into (reused across calls, so a scan allocates nothing per
    batch); allocated with ``dtype`` when None. A float64 output is computed in float64
    whatever the input's dtype; a float32 output in float32 by the NumPy backend (an
    error of about one float32 unit of the largest coordinate: 1.2e-4 mm at 1-2 m) and in
    float64, rounded once, by numba."""
    y = np.asarray(y_mm)
    z = np.asarray(z_mm)
    if y.ndim != 2 or z.shape != y.shape:
        raise ValueError(f"profiles: y_mm and z_mm must be (n, m) arrays of one shape, got {y.shape} and {z.shape}")
    for name, a in (("y_mm", y), ("z_mm", z)):
        if a.dtype not in (np.float32, np.float64):
            raise ValueError(f"profiles: {name} must be float32 or float64, got {a.dtype}")
    n, m = y.shape
    R, t = _check_rt(target_from_sensor_R, target_from_sensor_t, n)
    if out is None:
        out = np.empty((n, m, 3), dtype=dtype)
    elif out.shape != (n, m, 3) or out.dtype not in (np.float32, np.float64) or not out.flags.c_contiguous:
        raise ValueError(
            f"out: expected a C-contiguous ({n}, {m}, 3) float32 or float64 array, "
            f"got {out.shape} {out.dtype} (contiguous: {out.flags.c_contiguous})"
        )
    if _resolve(backend) == "numba":
        _numba_kernels()[0](R, t, np.ascontiguousarray(y), np.ascontiguousarray(z), out)
    else:
        _map_numpy(R, t, y, z, out)
    return out


def map_profile_list(
    target_from_sensor_R,
    target_from_sensor_t,
    profiles_mm: Sequence[np.ndarray],
    *,
    dtype=np.float64,
    backend: Backend = "auto",
) -> tuple[np.ndarray, np.ndarray]:
    """Map a ragged list of profiles, each (N_i, 2) of (y, z) mm, into the target frame.

    Returns the points (sum N_i, 3) in profile order and, for each point, the index of
    its profile (int64)."""
    n = len(profiles_mm)
    R, t = _check_rt(target_from_sensor_R, target_from_sensor_t, n)
    counts = np.zeros(n, dtype=np.int64)
    for i, p in enumerate(profiles_mm):
        shape = np.shape(p)
        if len(shape) != 2 or shape[1] != 2:
            if len(shape) == 1 and shape[0] == 0:
                continue
            raise ValueError(f"profiles_mm[{i}]: expected an (N, 2) array of (y, z) mm, got shape {shape}")
        counts[i] = shape[0]
    offsets = np.zeros(n + 1, dtype=np.int64)
    np.cumsum(counts, out=offsets[1:])
    total = int(offsets[-1])
    index = np.repeat(np.arange(n, dtype=np.int64), counts)
    out = np.empty((total, 3), dtype=dtype)
    if total == 0:
        return out, index
    yz = np.concatenate([np.asarray(p, dtype=np.float64).reshape(-1, 2) for p in profiles_mm])
    if _resolve(backend) == "numba":
        _numba_kernels()[1](R, t, yz, offsets, out)
    else:
        # every point through its profile's transform, a block of points at a time (one
        # call a profile cost more than the arithmetic with thousands of short profiles)
        for a in range(0, total, _BLOCK_POINTS_RAGGED):
            b = min(a + _BLOCK_POINTS_RAGGED, total)
            i = index[a:b]
            out[a:b] = yz[a:b, 0:1] * R[i, :, 1] + yz[a:b, 1:2] * R[i, :, 2] + t[i]
    return out, index
