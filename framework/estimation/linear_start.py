"""A closed-form start from sphere centres seen at any orientations: no stations needed.

With the sphere centre ``C_i`` measured in the sensor frame at shot i (mm), ``A_i =
sphere_from_mount_i`` the robot's pose in the problem's terms (:mod:`.problem`) and ``X =
mount_from_sensor = (R, t)`` the unknown, the sphere centre ``c`` (sphere frame) is one
fixed point:

    R_Ai (R C_i + t) + t_Ai = c          (eye-in-hand: s = R_i (R_X c_i + t_X) + t_i;
                                          eye-to-hand: R_X c_i + t_X = R_i p + t_i)

Both mountings are this one equation. It is linear in the nine entries of R, in t and in
c: 15 unknowns, 3 equations a row. Turned into the mount frame and centred (``D_i = C_i -
mean C``, ``u = R mean C + t``, ``c' = c - mean t_A``, each principal axis of the D_i scaled
to unit spread) it reads

    R D_i + u - R_Ai^T c' = -R_Ai^T (t_Ai - mean t_A)

and is solved by least squares; R is then the proper rotation closest to the linear
solution on the data (Procrustes, det +1), t and c are solved again with R fixed, and a
few Gauss-Newton steps on R, t and c together give the least-squares solution of the
equations with R a rotation. The joint fit (:mod:`.refine`) starts from it.

What the data need (checked before solving, :func:`centres_start` says what to add):

- at least :data:`MIN_ROWS` rows (the 15 unknowns, 3 equations a row);
- the rotation is read from how the centre moves in the sensor frame against how it
  moves in the mount frame, so the rows must put the sphere at places of the sensor frame
  that span a plane at least (not one point, not one line): :func:`centre_spread_mm`;
- the translation and the sphere centre need orientations that differ by rotations about
  at least two different axes: rotations about one axis leave the translation along it
  and the sphere centre along it free to trade (:func:`rotation_spread_deg`).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from spherecal.core import geometry as geo
from spherecal.core.errors import DegenerateDataError
from spherecal.estimation.problem import chordal_mean

#: Fewest rows the linear solve takes: 15 unknowns (R's 9 entries, t, c), 3 equations a row.
MIN_ROWS = 5
#: A principal axis of the centres' spread in the sensor frame counts when its RMS extent
#: is at least this share of the largest one's ...
CENTRE_AXIS_SHARE = 0.05
#: ... and at least this, mm.
MIN_CENTRE_EXTENT_MM = 0.5
#: The translation and sphere centre count as determined when the smallest singular value
#: of their block of the equations is at least this share of the largest: about 1 deg of
#: turn about a second axis (rows tilted about 20 deg: 0.1-0.15). Ten times the two-step's
#: rule for its stations (:func:`.twostep.translation_from_orientations`), whose
#: orientations are distinct by construction: rows turned a few tenths of a degree about
#: a second axis (a station whose orientation drifted) determine the translation along it
#: to millimetres, and are better told to add a turn than given such a result.
TRANSLATION_CONDITION_SHARE = 1e-2
#: Gauss-Newton steps on (R, t, c) after the projection onto the rotations.
REFINE_STEPS = 5

#: What each start needs, as the messages and docs/file-formats.md say it.
REQUIREMENTS = (
    f"the start from any orientations needs at least {MIN_ROWS} rows with a sphere centre in the sensor frame "
    "(15 unknowns: the rotation's 9 entries, the translation and the sphere centre; 3 equations a row; 10 or more "
    "for a margin), the sphere at places of the sensor frame that span a plane (not all at one point or along one "
    "line), and orientations that differ by rotations about at least two different axes (10-30 deg)")


@dataclass
class LinearStart:
    """The start: ``R``, ``t`` (``mount_from_sensor``, mm) and the sphere ``centre``
    (sphere frame, mm); ``row_error_mm`` (n,) the length of each row's residual of the
    equations at the solution; ``diagnostics`` its figures (rows, centre and rotation
    spreads, conditioning, RMS)."""

    R: np.ndarray
    t: np.ndarray
    centre: np.ndarray
    row_error_mm: np.ndarray
    diagnostics: dict = field(default_factory=dict)


def centre_spread_mm(C: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The RMS extents (3,) of the sensor-frame centres ``C`` (n, 3) about their mean along
    their principal axes, largest first, mm, and those axes (3, 3), one a column."""
    D = C - C.mean(axis=0)
    _, s, Vt = np.linalg.svd(D, full_matrices=True)
    s = np.concatenate([s, np.zeros(3 - len(s))])
    return s / np.sqrt(max(len(C), 1)), Vt.T


def rotation_spread_deg(R_A: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """How far the orientations ``R_A`` (n, 3, 3) turn about each principal axis: the RMS
    of their rotation vectors from their chordal mean (sphere frame) along the axes of
    those vectors' spread, largest first, deg, and the axes (3, 3), one a column."""
    mean = chordal_mean(R_A)
    w = geo.rotvec_from_matrix(R_A @ mean.T)
    lam, V = np.linalg.eigh(w.T @ w / max(len(w), 1))
    order = np.argsort(lam)[::-1]
    return np.degrees(np.sqrt(np.maximum(lam[order], 0.0))), V[:, order]


def _check_rows(n: int) -> None:
    if n < MIN_ROWS:
        raise DegenerateDataError(
            f"{n} row(s) with a sphere centre: the start from any orientations needs at least {MIN_ROWS} (15 "
            f"unknowns: the rotation's 9 entries, the translation and the sphere centre; 3 equations a row); add "
            f"rows at other orientations, about at least two different axes")


def _centre_axes(C: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The principal axes of the centres' spread that count (3, k), their RMS extents (k,)
    and all three extents (mm); refuses when fewer than two count."""
    extent, axes = centre_spread_mm(C)
    k = int(np.sum((extent >= CENTRE_AXIS_SHARE * max(extent[0], 1e-12)) & (extent >= MIN_CENTRE_EXTENT_MM)))
    if k < 2:
        where = "at one place" if k == 0 else f"along one line (about {np.round(axes[:, 0], 3).tolist()})"
        raise DegenerateDataError(
            f"the sphere centre is {where} of the sensor frame in every row (spread {extent[0]:.3g}, {extent[1]:.3g}, "
            f"{extent[2]:.3g} mm RMS): the rotation is not determined, as the robot's orientations alone give only "
            "where that place is on the flange or in the base; add rows with the sphere elsewhere in the field of "
            "view: across the laser plane, along the line, nearer and farther")
    return axes[:, :k], extent[:k], extent


def _check_orientations(R_A: np.ndarray) -> tuple[float, np.ndarray]:
    """The translation block's condition (smallest over largest singular value of the
    stacked ``[I, -R_Ai^T]``) and the rotation spreads (deg); refuses when the
    orientations do not differ about two axes."""
    n = len(R_A)
    T = np.concatenate([np.broadcast_to(np.eye(3), (n, 3, 3)), -np.swapaxes(R_A, 1, 2)], axis=2).reshape(3 * n, 6)
    sv = np.linalg.svd(T, compute_uv=False)
    share = float(sv[-1] / sv[0])
    spread, axes = rotation_spread_deg(R_A)
    if share < TRANSLATION_CONDITION_SHARE:
        if spread[0] < 1.0:
            cause = (f"all {n} rows are at about one orientation (within {spread[0]:.2g} deg RMS): the translation "
                     "and the sphere centre are not determined; add rows at other orientations, tilted about two "
                     "different axes (10-30 deg)")
        else:
            cause = (f"the rows' orientations differ only by rotations about one axis (about "
                     f"{np.round(axes[:, 0], 3).tolist()} in the sphere frame, {spread[0]:.1f} deg RMS; "
                     f"{spread[1]:.2g} deg about any other): one component of the translation and of the sphere "
                     "centre is not determined; add rows rotated about a second axis (10-30 deg)")
        raise DegenerateDataError(cause)
    return share, spread


def _translation_given_rotation(R: np.ndarray, R_A: np.ndarray, tA_c: np.ndarray, C: np.ndarray):
    """(t, c') by least squares with R fixed: ``t - R_Ai^T c' = -R C_i - R_Ai^T tA_c_i``."""
    n = len(R_A)
    RAt = np.swapaxes(R_A, 1, 2)
    M = np.concatenate([np.broadcast_to(np.eye(3), (n, 3, 3)), -RAt], axis=2).reshape(3 * n, 6)
    rhs = (-(C @ R.T) - np.einsum("nij,nj->ni", RAt, tA_c)).ravel()
    sol = np.linalg.lstsq(M, rhs, rcond=None)[0]
    return sol[:3], sol[3:]


def _residuals(R, t, c_, R_A, tA_c, C) -> np.ndarray:
    """Each row's residual (n, 3) of ``R C_i + t - R_Ai^T (c' - tA_c_i)`` (mount frame, mm)."""
    return C @ R.T + t - np.einsum("nji,nj->ni", R_A, c_[None, :] - tA_c)


def _gauss_newton(R, t, c_, R_A, tA_c, C, steps: int):
    """A few Gauss-Newton steps on the rows' residuals with R a rotation (left increments)."""
    n = len(R_A)
    RAt = np.swapaxes(R_A, 1, 2)
    for _ in range(steps):
        e = _residuals(R, t, c_, R_A, tA_c, C)
        J = np.concatenate([-geo.skew(C @ R.T), np.broadcast_to(np.eye(3), (n, 3, 3)), -RAt], axis=2)
        step = np.linalg.lstsq(J.reshape(3 * n, 9), -e.ravel(), rcond=None)[0]
        R = geo.matrix_from_rotvec(step[:3]) @ R
        t, c_ = t + step[3:6], c_ + step[6:]
        if np.abs(step[:3]).max() < 1e-12 and np.abs(step[3:]).max() < 1e-9:
            break
    return R, t, c_


def centres_start(R_A: np.ndarray, t_A: np.ndarray, C: np.ndarray) -> LinearStart:
    """The closed-form start (module docstring) from ``A_i = sphere_from_mount_i``
    (``R_A`` (n, 3, 3), ``t_A`` (n, 3), mm) and the sensor-frame sphere centres ``C``
    (n, 3), mm. Raises :class:`DegenerateDataError` naming what to add when the rows do
    not determine the transform (too few, the centres at one place or along one line of
    the sensor frame, the orientations about one axis)."""
    R_A, t_A, C = (np.asarray(a, dtype=float) for a in (R_A, t_A, C))
    n = len(C)
    _check_rows(n)
    axes, extent, all_extents = _centre_axes(C)
    translation_share, spread = _check_orientations(R_A)
    k = axes.shape[1]
    t_bar = t_A.mean(axis=0)
    tA_c = t_A - t_bar
    C_bar = C.mean(axis=0)
    E = (C - C_bar) @ axes / extent  # (n, k) unit spread along each axis that counts
    RAt = np.swapaxes(R_A, 1, 2)
    design = np.concatenate([np.einsum("nj,ab->najb", E, np.eye(3)).reshape(n, 3, 3 * k),
                             np.broadcast_to(np.eye(3), (n, 3, 3)), -RAt], axis=2).reshape(3 * n, 3 * k + 6)
    rhs = -np.einsum("nij,nj->ni", RAt, tA_c).ravel()
    sol, _, _, sv = np.linalg.lstsq(design, rhs, rcond=None)
    condition = float(sv[0] / max(sv[-1], 1e-300))
    if not np.isfinite(condition) or condition > 1e8:
        raise DegenerateDataError(f"the rows do not determine the transform (the linear equations' condition number "
                                  f"is {condition:.3g}): {REQUIREMENTS}")
    M = sol[:3 * k].reshape(k, 3).T  # column j: extent_j R axis_j
    R_lin_axes = M / extent  # R axes[:, j] for each axis that counts
    # the rotation closest to the linear solution on the data (each axis weighted by its spread)
    R = geo.proper_procrustes(axes * extent, R_lin_axes * extent)
    orthogonality = float(np.linalg.norm(R_lin_axes.T @ R_lin_axes - np.eye(k)))
    t, c_ = _translation_given_rotation(R, R_A, tA_c, C)
    R, t, c_ = _gauss_newton(R, t, c_, R_A, tA_c, C, REFINE_STEPS)
    e = _residuals(R, t, c_, R_A, tA_c, C)
    err = np.linalg.norm(e, axis=1)
    return LinearStart(R, t, c_ + t_bar, err, {
        "rows": n,
        "centre_spread_mm": all_extents.tolist(),
        "rotation_spread_deg": spread.tolist(),
        "translation_condition": translation_share,
        "linear_condition_number": condition,
        "linear_rotation_orthogonality": orthogonality,
        "rms_mm": float(np.sqrt(np.mean(err**2))),
    })


# --- circles whose side of the laser plane is not known, without a nominal transform --------------
#: Fewest rows the side-free equations take: 20 unknowns up to scale, about 2 equations a row.
MIN_SIDE_FREE_ROWS = 10
#: The side-free equations fix one solution when their smallest singular value is below
#: this share of the next (clean simulated logs of 12-40 rows: 0.002-0.01).
SIDE_FREE_GAP = 0.1
#: Two choices of the sides count as told apart when the better fits by a likelihood ratio
#: of at least 1000:1 (as :mod:`.starts` decides between starts).
SIDES_DECISIVE_CHI2 = 2.0 * np.log(1000.0)
#: Levi-Civita symbol: ``np.einsum("abc,b,c->a", _EPS, u, v) == np.cross(u, v)``.
_EPS = np.zeros((3, 3, 3))
_EPS[0, 1, 2] = _EPS[1, 2, 0] = _EPS[2, 0, 1] = 1.0
_EPS[0, 2, 1] = _EPS[2, 1, 0] = _EPS[1, 0, 2] = -1.0


def side_free_rotation(R_A: np.ndarray, t_A: np.ndarray, yz: np.ndarray):
    """The rotation, sphere centre and translation across the laser plane's normal from
    circles alone, whatever side of the laser plane each sphere centre is on.

    With ``x_i r1 = R_Ai^T (c - t_Ai) - y_i r2 - z_i r3 - t`` (the row's equation, r_k the
    columns of R), the left side lies along r1 whatever x_i is: its cross product with r1
    vanishes. With r1 x r2 = r3 and r1 x r3 = -r2 (R a rotation) that is
    ``r1 x R_Ai^T c - r1 x R_Ai^T t_Ai - y_i r3 + z_i r2 - r1 x t = 0``: homogeneous and
    linear in r1, r2, r3, w = r1 x t and the nine entries of Q = r1 c^T (21 unknowns up to
    scale). Its null vector (smallest singular vector, columns scaled) gives them; the
    sign is the one with det R > 0 (the mirror image is no rotation). Returns (R, c, the
    translation's part across r1, the singular values' gap: smallest over next)."""
    n = len(R_A)
    B = np.swapaxes(R_A, 1, 2)
    t_bar = t_A.mean(axis=0)
    u = np.einsum("nij,nj->ni", B, t_A - t_bar)
    y_bar, z_bar = yz.mean(axis=0)
    dy, dz = yz[:, 0] - y_bar, yz[:, 1] - z_bar
    M = np.zeros((n, 3, 21))
    M[:, :, 0:3] = geo.skew(u)  # -r1 x u
    M[:, :, 3:6] = dz[:, None, None] * np.eye(3)
    M[:, :, 6:9] = -dy[:, None, None] * np.eye(3)
    M[:, :, 9:12] = -np.eye(3)  # w' = r1 x t - y_bar r3 + z_bar r2
    M[:, :, 12:21] = np.einsum("abc,ncm->nabm", _EPS, B).reshape(n, 3, 9)  # r1 x (R_Ai^T c'), c' = c - t_bar
    A = M.reshape(3 * n, 21)
    scale = np.linalg.norm(A, axis=0)
    scale[scale == 0] = 1.0
    _, s, Vt = np.linalg.svd(A / scale, full_matrices=False)
    v = Vt[-1] / scale
    r1, r2, r3, w, Q = v[0:3], v[3:6], v[6:9], v[9:12], v[12:21].reshape(3, 3)
    k = (np.linalg.norm(r2) + np.linalg.norm(r3)) / 2.0
    if np.linalg.det(np.column_stack([r1, r2, r3])) < 0:
        k = -k
    r1, r2, r3, w, Q = r1 / k, r2 / k, r3 / k, w / k, Q / k
    R = geo.proper_procrustes(np.eye(3), np.column_stack([r1, r2, r3]))
    r1, r2, r3 = R.T
    c = Q.T @ r1 + t_bar
    w = w - y_bar * r3 + z_bar * r2
    return R, c, np.cross(w, r1), float(s[-1] / max(s[-2], 1e-300))


def sides_and_offset(p: np.ndarray, h: np.ndarray) -> tuple[np.ndarray, float, dict]:
    """x_i = p_i - alpha with |x_i| as near h_i as can be: the sides (signs of x) and the
    offset alpha, every choice of the sides tried (each row's candidate offsets
    ``p_i -+ h_i`` start one), least squares within each. Returns the signed x, alpha and
    how decisively the best choice beats the best other one whose offset lies more than
    1 mm away (``margin_chi2``: their cost difference over the best's residual variance;
    inf when there is none)."""
    cands = np.unique(np.concatenate([p - h, p + h]))
    S = np.where(p[None, :] - cands[:, None] >= 0.0, 1.0, -1.0)
    alpha = np.mean(p[None, :] - S * h[None, :], axis=1)
    S = np.where(p[None, :] - alpha[:, None] >= 0.0, 1.0, -1.0)
    alpha = np.mean(p[None, :] - S * h[None, :], axis=1)
    cost = np.sum((p[None, :] - alpha[:, None] - S * h[None, :]) ** 2, axis=1)
    best = int(np.argmin(cost))
    n = len(p)
    variance = max(float(cost[best]) / max(n - 1, 1), 1e-4)
    far = np.abs(alpha - alpha[best]) > 1.0
    margin = float((cost[far].min() - cost[best]) / variance) if far.any() else float("inf")
    other = float(alpha[far][np.argmin(cost[far])]) if far.any() else None
    return S[best] * h, float(alpha[best]), {"margin_chi2": margin, "other_offset_mm": other,
                                             "offset_mm": float(alpha[best])}


def side_free_sides(R_A: np.ndarray, t_A: np.ndarray, yz: np.ndarray, h: np.ndarray) -> tuple[np.ndarray, dict]:
    """The side of the laser plane of each row's sphere centre from circles alone
    (:func:`side_free_rotation`, then :func:`sides_and_offset` on the centres' distances
    along the laser plane's normal): the signed x (n,), mm, and the figures. Refuses
    (:class:`DegenerateDataError`, saying what to add) when the rows are too few, when
    the side-free equations do not fix one solution, or when two choices of the sides
    fit alike (the sphere at about one distance from the laser plane in every row)."""
    R_A, t_A, yz, h = (np.asarray(a, dtype=float) for a in (R_A, t_A, yz, h))
    n = len(yz)
    todo = ("give a nominal transform (calibration.nominal_transform; spherecal solve --nominal), a few degrees and "
            "millimetres off is enough, or sphere centres instead of circles")
    if n < MIN_SIDE_FREE_ROWS:
        raise DegenerateDataError(
            f"{n} circle row(s) at orientations of their own: without a nominal transform the sides of the laser "
            f"plane need at least {MIN_SIDE_FREE_ROWS} (20 unknowns, about 2 equations a row); {todo}")
    _check_orientations(R_A)
    R, c, t_across, gap = side_free_rotation(R_A, t_A, yz)
    if not gap < SIDE_FREE_GAP:
        raise DegenerateDataError(
            f"the circles do not fix one solution without a nominal transform (the side-free equations' two smallest "
            f"singular values are {gap:.2g} apart, under 1/{1 / SIDE_FREE_GAP:g} needed): {todo}; or add rows with "
            "the sphere elsewhere in the field of view (at other distances on both sides of the laser plane, along "
            "the line, nearer and farther) and at orientations turned about other axes")
    p = (np.einsum("nji,nj->ni", R_A, c - t_A) - yz[:, :1] * R[:, 1] - yz[:, 1:] * R[:, 2] - t_across) @ R[:, 0]
    x, alpha, decided = sides_and_offset(p, h)
    if decided["margin_chi2"] < SIDES_DECISIVE_CHI2:
        raise DegenerateDataError(
            f"on which side of the laser plane the sphere centre lies is not decided without a nominal transform: "
            f"two choices of the sides fit alike (offsets {alpha:.2f} and {decided['other_offset_mm']:.2f} mm along "
            "the laser plane's normal; the sphere at about one distance from the laser plane in every row?); "
            f"{todo}; or add rows with the sphere at other distances on both sides of the laser plane")
    return x, {"side_free_gap": gap, **decided}
