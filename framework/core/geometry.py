"""Rotations and rigid transforms as plain NumPy arrays.

Names say the direction (``matrix_from_quat_wxyz``) and the quaternion order. See
``docs/conventions.md``: ``A_from_B`` maps a point expressed in frame B into frame A;
lengths in mm; ABB quaternions are (w, x, y, z), SciPy's are (x, y, z, w).
"""

from __future__ import annotations

import numpy as np

ROTATION_TOLERANCE = 1e-6


def check_rotation_matrix(R, name: str = "rotation") -> np.ndarray:
    """Return ``R`` as a float (3, 3) array or raise ``ValueError`` naming the problem.

    A rotation must be finite, orthonormal to ``ROTATION_TOLERANCE`` and proper (det = +1).
    """
    R = np.asarray(R, dtype=float)
    if R.shape != (3, 3):
        raise ValueError(f"{name}: expected a 3x3 matrix, got shape {R.shape}")
    if not np.all(np.isfinite(R)):
        raise ValueError(f"{name}: contains NaN or infinite values: {R.tolist()}")
    err = np.abs(R @ R.T - np.eye(3)).max()
    if err > ROTATION_TOLERANCE:
        raise ValueError(f"{name}: not orthonormal (max |R R^T - I| = {err:.3g})")
    det = np.linalg.det(R)
    if det < 0:
        raise ValueError(f"{name}: det = {det:.6f}, a reflection, not a rotation")
    return R


def quat_xyzw_from_wxyz(q_wxyz) -> np.ndarray:
    """Reorder an ABB-style (w, x, y, z) quaternion to SciPy's (x, y, z, w)."""
    q = np.asarray(q_wxyz, dtype=float)
    return np.concatenate([q[..., 1:4], q[..., :1]], axis=-1)


def quat_wxyz_from_xyzw(q_xyzw) -> np.ndarray:
    """Reorder a SciPy-style (x, y, z, w) quaternion to ABB's (w, x, y, z)."""
    q = np.asarray(q_xyzw, dtype=float)
    return np.concatenate([q[..., 3:4], q[..., :3]], axis=-1)


def matrix_from_quat_wxyz(q_wxyz) -> np.ndarray:
    """Rotation matrix from a unit quaternion in (w, x, y, z) order (ABB's ``orient``);
    works on (..., 4). The quaternion is normalised first (its norm must be 1 within
    1e-3: a typo is refused, rounding is not)."""
    q = np.asarray(q_wxyz, dtype=float)
    if q.shape[-1] != 4 or not np.all(np.isfinite(q)):
        raise ValueError(f"quaternion (w, x, y, z): expected 4 finite numbers, got {q.tolist()}")
    norm = np.linalg.norm(q, axis=-1)
    if np.any(np.abs(norm - 1.0) > 1e-3):
        raise ValueError(f"quaternion (w, x, y, z) {q.tolist()}: norm {norm} is not 1")
    w, x, y, z = np.moveaxis(q / norm[..., None], -1, 0)
    R = np.empty(q.shape[:-1] + (3, 3))
    R[..., 0, 0] = 1.0 - 2.0 * (y * y + z * z)
    R[..., 0, 1] = 2.0 * (x * y - w * z)
    R[..., 0, 2] = 2.0 * (x * z + w * y)
    R[..., 1, 0] = 2.0 * (x * y + w * z)
    R[..., 1, 1] = 1.0 - 2.0 * (x * x + z * z)
    R[..., 1, 2] = 2.0 * (y * z - w * x)
    R[..., 2, 0] = 2.0 * (x * z - w * y)
    R[..., 2, 1] = 2.0 * (y * z + w * x)
    R[..., 2, 2] = 1.0 - 2.0 * (x * x + y * y)
    return R


def quat_wxyz_from_matrix(R) -> np.ndarray:
    """Unit quaternion (w, x, y, z), w >= 0, from a rotation matrix; works on (..., 3, 3).

    Each matrix is read from its largest diagonal term (of w, x, y, z, the largest
    component is computed from the diagonal, the others from the off-diagonal terms
    divided by it), which keeps every division away from zero."""
    R = np.asarray(R, dtype=float)
    m = R.reshape(-1, 3, 3)
    trace = m[:, 0, 0] + m[:, 1, 1] + m[:, 2, 2]
    largest = np.argmax(np.stack([trace, m[:, 0, 0], m[:, 1, 1], m[:, 2, 2]], axis=1), axis=1)
    q = np.empty((len(m), 4))
    sel = largest == 0
    if sel.any():
        a = m[sel]
        four_w = 2.0 * np.sqrt(1.0 + trace[sel])
        q[sel, 0] = 0.25 * four_w
        q[sel, 1] = (a[:, 2, 1] - a[:, 1, 2]) / four_w
        q[sel, 2] = (a[:, 0, 2] - a[:, 2, 0]) / four_w
        q[sel, 3] = (a[:, 1, 0] - a[:, 0, 1]) / four_w
    for i in range(3):
        sel = largest == i + 1
        if not sel.any():
            continue
        a = m[sel]
        j, k = (i + 1) % 3, (i + 2) % 3
        four_qi = 2.0 * np.sqrt(1.0 + a[:, i, i] - a[:, j, j] - a[:, k, k])
        q[sel, 0] = (a[:, k, j] - a[:, j, k]) / four_qi
        q[sel, 1 + i] = 0.25 * four_qi
        q[sel, 1 + j] = (a[:, j, i] + a[:, i, j]) / four_qi
        q[sel, 1 + k] = (a[:, k, i] + a[:, i, k]) / four_qi
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    q = np.where(q[:, :1] < 0, -q, q)
    return q.reshape(R.shape[:-2] + (4,))


def matrix_from_rotvec(rotvec) -> np.ndarray:
    """Rotation matrix from a rotation vector (axis times angle, radians); works on
    (..., 3). Rodrigues' formula, with its coefficients' series below 1e-4 rad."""
    v = np.asarray(rotvec, dtype=float)
    angle = np.linalg.norm(v, axis=-1)
    small = angle < 1e-4
    a = np.where(small, 1.0, angle)
    sin_term = np.where(small, 1.0 - angle**2 / 6.0 + angle**4 / 120.0, np.sin(a) / a)
    cos_term = np.where(small, 0.5 - angle**2 / 24.0 + angle**4 / 720.0, (1.0 - np.cos(a)) / a**2)
    K = skew(v)
    return np.eye(3) + sin_term[..., None, None] * K + cos_term[..., None, None] * (K @ K)


def rotvec_from_matrix(R) -> np.ndarray:
    """Rotation vector (axis times angle, radians, angle in [0, pi]) from a rotation
    matrix; works on (..., 3, 3). Through the quaternion (w >= 0): angle = 2 atan2(|v|, w)."""
    q = quat_wxyz_from_matrix(R)
    w, v = q[..., 0], q[..., 1:]
    s = np.linalg.norm(v, axis=-1)
    small = s < 1e-6
    # angle / s = 2 atan2(s, w) / s; near 0: (2 / w) (1 - s^2 / (3 w^2)) to second order
    w_small = np.where(small, w, 1.0)  # (w is near 1 there; 0 only at half a turn)
    factor = np.where(small, 2.0 / w_small * (1.0 - s**2 / (3.0 * w_small**2)),
                      2.0 * np.arctan2(s, w) / np.where(small, 1.0, s))
    return v * factor[..., None]


def rotation_angle_deg(R_a, R_b) -> float:
    """Angle in degrees of the rotation R_a^T R_b (0 when equal)."""
    return float(np.degrees(np.linalg.norm(rotvec_from_matrix(np.asarray(R_a).T @ np.asarray(R_b)))))


def skew(v) -> np.ndarray:
    """Cross-product matrix: ``skew(v) @ u == np.cross(v, u)``; works on (..., 3)."""
    v = np.asarray(v, dtype=float)
    S = np.zeros(v.shape[:-1] + (3, 3))
    S[..., 0, 1], S[..., 0, 2] = -v[..., 2], v[..., 1]
    S[..., 1, 0], S[..., 1, 2] = v[..., 2], -v[..., 0]
    S[..., 2, 0], S[..., 2, 1] = -v[..., 1], v[..., 0]
    return S


def matrix_from_rt(R, t) -> np.ndarray:
    """4x4 homogeneous matrix from rotation (3, 3) and translation (3,) (mm)."""
    T = np.eye(4)
    T[:3, :3] = R
    T[:3, 3] = t
    return T


def invert_rt(R, t) -> tuple[np.ndarray, np.ndarray]:
    """Inverse of a rigid transform: ``B_from_A`` from ``A_from_B``; works on stacks."""
    R = np.asarray(R, dtype=float)
    t = np.asarray(t, dtype=float)
    Rt = np.swapaxes(R, -1, -2)
    return Rt, -np.einsum("...ij,...j->...i", Rt, t)


def proper_procrustes(A, B) -> np.ndarray:
    """The proper rotation R (det +1) minimising ||R A - B||_F for 3xN column sets.

    Kabsch/Umeyama: with A B^T = U S V^T, R = V diag(1, 1, det(V U^T)) U^T. The middle
    sign keeps R a rotation when the columns are coplanar or noisy, where plain V U^T
    can be a reflection.
    """
    A = np.asarray(A, dtype=float)
    B = np.asarray(B, dtype=float)
    U, _, Vt = np.linalg.svd(A @ B.T)
    d = np.sign(np.linalg.det(Vt.T @ U.T)) or 1.0
    return Vt.T @ np.diag([1.0, 1.0, d]) @ U.T
