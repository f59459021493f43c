"""Acceptance figures of the calibrated scanning system: spheres, ball bars, flats.

Definitions (VDI/VDE 2634 part 2 / ISO 10360-8 style; see
docs/validation-and-scanning.md):

- probing error, form ``P_F``: range (max - min) of the radial residuals of the points to
  a least-squares sphere with free radius;
- probing error, size ``P_S``: fitted diameter minus the certified diameter;
- sphere-spacing error ``SD``: distance between the fitted centres of the two spheres of
  a ball bar minus its certified distance;
- flatness error ``F``: range of the signed distances of the points to a least-squares
  plane.

Up to ``max_outlier_fraction`` (0.3 %) of a fit's points may be dropped as outliers:
those with the largest absolute residuals, and only when they lie beyond
``outlier_threshold_sigma`` robust standard deviations (None drops the whole allowance);
the fit is then repeated on the points kept. Every figure says how many points it used
and how many it dropped. Each figure is reported per position; the maximum (of P_S and
SD: the largest in magnitude, sign kept) over positions is compared with the user's
MPE. A P_S whose uncertainty from the noise of its view is known (the profile of each
point given, with the sensor's and the robot's noise) fails only when it exceeds the MPE
by more than that expanded uncertainty. Points are (N, 3) arrays in one frame (base), mm.
"""

from __future__ import annotations

import math
from typing import Sequence

import numpy as np
from pydantic import BaseModel, ConfigDict, Field

from spherecal.core.errors import InputError

#: The outlier allowance of VDI/VDE 2634 part 2.
MAX_OUTLIER_FRACTION = 0.003
_MAD_TO_SIGMA = 1.4826


# results ----------------------------------------------------------------------------
class _Frozen(BaseModel):
    model_config = ConfigDict(defer_build=True, frozen=True, extra="forbid")


class SphereFit(_Frozen):
    """A least-squares sphere with free radius (geometric residuals)."""

    centre_mm: tuple[float, float, float] = Field(description="fitted centre, frame of the points, mm")
    radius_mm: float = Field(description="fitted radius, mm")
    centre_std_mm: tuple[float, float, float] = Field(description="standard uncertainty of each centre coordinate, mm")
    radius_std_mm: float = Field(description="standard uncertainty of the radius, mm")
    rms_residual_mm: float = Field(description="RMS of the radial residuals of the points used, mm")
    residual_range_mm: float = Field(description="max - min radial residual of the points used, mm")
    n_points_used: int = Field(ge=0, description="points in the final fit")
    n_points_dropped: int = Field(ge=0, description="points dropped as outliers (at most 0.3 %)")


class PlaneFit(_Frozen):
    """A least-squares (orthogonal distance) plane."""

    point_mm: tuple[float, float, float] = Field(description="centroid of the points used, mm")
    normal: tuple[float, float, float] = Field(description="unit normal of the plane")
    rms_residual_mm: float = Field(description="RMS of the signed distances of the points used, mm")
    residual_range_mm: float = Field(description="max - min signed distance of the points used, mm")
    n_points_used: int = Field(ge=0, description="points in the final fit")
    n_points_dropped: int = Field(ge=0, description="points dropped as outliers (at most 0.3 %)")


class ShotNoise(_Frozen):
    """The noise a scan's points carry: each point's own (the sensor's), and each shot's
    (the robot's pose error at that shot, which moves all the points of one profile
    together). Standard deviations, 1 sigma."""

    point_noise_mm: float = Field(0.0, ge=0, description="noise of each point, per axis, mm")
    shot_translation_noise_mm: float = Field(0.0, ge=0, description="translation error of each shot, per axis, mm")
    shot_rotation_noise_deg: float = Field(0.0, ge=0, description="rotation error of each shot, about each axis, deg")


class ProbingResult(_Frozen):
    """P_F and P_S of one sphere at one position."""

    position: str = Field(description="label of the position of the sphere in the measuring volume")
    certified_diameter_mm: float = Field(gt=0, description="certified diameter of the sphere, mm")
    fitted_diameter_mm: float = Field(description="diameter of the least-squares sphere, mm")
    probing_form_error_mm: float = Field(ge=0, description="P_F: range of the radial residuals, mm")
    probing_size_error_mm: float = Field(description="P_S: fitted minus certified diameter, mm")
    probing_size_std_mm: float | None = Field(
        None, ge=0, description="standard uncertainty of P_S that the noise of this view gives a correct system (the "
        "points' own and each shot's, :func:`probing_size_std_mm`), mm; None when the shots were not given")
    n_shots: int | None = Field(None, ge=0, description="profiles (shots) the points came from; None when not given")
    fit: SphereFit = Field(description="the sphere fit behind the figures")


class SphereSpacingResult(_Frozen):
    """SD of a ball bar at one position."""

    position: str = Field(description="label of the position and orientation of the bar")
    certified_distance_mm: float = Field(gt=0, description="certified centre distance of the bar, mm")
    measured_distance_mm: float = Field(description="distance between the fitted centres, mm")
    sphere_spacing_error_mm: float = Field(description="SD: measured minus certified distance, mm")
    distance_std_mm: float = Field(ge=0, description="standard uncertainty of the measured distance from the fits, mm")
    fit_a: SphereFit = Field(description="fit of the first sphere")
    fit_b: SphereFit = Field(description="fit of the second sphere")


class FlatnessResult(_Frozen):
    """F of a flat at one position."""

    position: str = Field(description="label of the position of the flat")
    flatness_error_mm: float = Field(ge=0, description="F: range of the signed distances to the plane, mm")
    fit: PlaneFit = Field(description="the plane fit behind the figure")


class MaximumPermissibleErrors(_Frozen):
    """The user's MPEs; a figure without an MPE is reported but not judged."""

    probing_form_mm: float | None = Field(None, gt=0, description="MPE of P_F, mm")
    probing_size_mm: float | None = Field(None, gt=0, description="MPE of |P_S|, mm")
    sphere_spacing_mm: float | None = Field(None, gt=0, description="MPE of |SD|, mm")
    flatness_mm: float | None = Field(None, gt=0, description="MPE of F, mm")


class FigureVerdict(_Frozen):
    """One figure's worst value over positions against its MPE."""

    figure: str = Field(description="P_F, P_S, SD or F")
    max_error_mm: float | None = Field(description="worst value over positions (signed for P_S and SD), mm; None without positions")
    worst_position: str | None = Field(description="position of the worst value")
    n_positions: int = Field(ge=0, description="positions measured")
    mpe_mm: float | None = Field(description="the MPE it is compared with, mm; None when not given")
    passed: bool | None = Field(description="|max_error_mm| <= mpe_mm + uncertainty_mm at every position; None when "
                                "not judged")
    uncertainty_mm: float | None = Field(
        None, description="expanded uncertainty U (k = 2) of the worst value from the noise of its view, mm (P_S with "
        "its shots given); None when not known, and then the MPE alone judges")


class AcceptanceReport(_Frozen):
    """All figures per position, the maxima, and the verdicts."""

    probing: list[ProbingResult] = Field(default=[])
    sphere_spacing: list[SphereSpacingResult] = Field(default=[])
    flatness: list[FlatnessResult] = Field(default=[])
    mpe: MaximumPermissibleErrors
    verdicts: list[FigureVerdict] = Field(description="P_F, P_S, SD, F in that order")
    passed: bool | None = Field(description="every judged figure passed; None when none was judged")


# fitting helpers ----------------------------------------------------------------------
def _points(points_mm, what: str, minimum: int) -> np.ndarray:
    p = np.asarray(points_mm, dtype=float)
    if p.ndim != 2 or p.shape[1] != 3:
        raise InputError(f"{what}: expected an (N, 3) array of points in mm, got shape {p.shape}")
    finite = np.all(np.isfinite(p), axis=1)
    p = p[finite]
    if len(p) < minimum:
        raise InputError(f"{what}: {len(p)} finite points, at least {minimum} are needed; scan more of the object")
    return p


def _allowed_drops(n: int, max_outlier_fraction: float) -> int:
    if not 0 <= max_outlier_fraction < 0.5:
        raise InputError(f"max_outlier_fraction must be in [0, 0.5), got {max_outlier_fraction}")
    return int(math.floor(n * max_outlier_fraction + 1e-9))


def _pick_outliers(res: np.ndarray, allowance: int, threshold_sigma: float | None) -> np.ndarray:
    """Indices of at most ``allowance`` points with the largest |res| beyond the threshold."""
    if allowance == 0:
        return np.empty(0, dtype=int)
    mag = np.abs(res - np.median(res))
    worst = np.argpartition(mag, len(mag) - allowance)[len(mag) - allowance :]
    if threshold_sigma is None:
        return worst
    sigma = _MAD_TO_SIGMA * np.median(mag)
    return worst[mag[worst] > threshold_sigma * sigma]


def _algebraic_sphere(p: np.ndarray) -> tuple[np.ndarray, float]:
    """Linear fit |x|^2 = 2 c.x + (r^2 - |c|^2), centred for conditioning."""
    mean = p.mean(axis=0)
    q = p - mean
    A = np.column_stack([2 * q, np.ones(len(q))])
    b = np.einsum("ij,ij->i", q, q)
    sol, *_ = np.linalg.lstsq(A, b, rcond=None)
    c = sol[:3]
    r2 = sol[3] + c @ c
    if not np.isfinite(r2) or r2 <= 0:
        raise InputError("sphere fit: the points do not determine a sphere (coplanar or collinear?); scan more of the sphere")
    return c + mean, float(np.sqrt(r2))


def _robust_sphere_start(p: np.ndarray) -> tuple[np.ndarray, float]:
    """Algebraic fit, then twice refitted on the points within 4 robust sigmas."""
    c, r = _algebraic_sphere(p)
    for _ in range(2):
        res = np.linalg.norm(p - c, axis=1) - r
        mag = np.abs(res - np.median(res))
        sigma = _MAD_TO_SIGMA * np.median(mag)
        keep = mag <= max(4 * sigma, 1e-12)
        if keep.sum() < 4 or keep.all():
            break
        c, r = _algebraic_sphere(p[keep])
    return c, r


def _geometric_sphere(p: np.ndarray, c0: np.ndarray, r0: float) -> tuple[np.ndarray, float, np.ndarray, np.ndarray]:
    """Least squares of the radial residuals; returns centre, radius, residuals, covariance."""
    shift = c0.copy()
    q = p - shift

    def fun(x):
        return np.linalg.norm(q - x[:3], axis=1) - x[3]

    def jac(x):
        d = q - x[:3]
        n = np.linalg.norm(d, axis=1)
        J = np.empty((len(q), 4))
        J[:, :3] = -d / n[:, None]
        J[:, 3] = -1.0
        return J

    from scipy.optimize import least_squares  # (imported here: commands that fit nothing skip it)

    sol = least_squares(fun, np.r_[0.0, 0.0, 0.0, r0], jac=jac, method="lm", xtol=1e-14, ftol=1e-14)
    res = sol.fun
    J = sol.jac
    dof = max(len(p) - 4, 1)
    s2 = float(res @ res) / dof
    try:
        cov = np.linalg.inv(J.T @ J) * s2
    except np.linalg.LinAlgError as exc:
        raise InputError("sphere fit: the points do not determine a sphere; scan more of the sphere") from exc
    return sol.x[:3] + shift, float(sol.x[3]), res, cov


# fits ---------------------------------------------------------------------------------
def fit_sphere(
    points_mm,
    max_outlier_fraction: float = MAX_OUTLIER_FRACTION,
    outlier_threshold_sigma: float | None = 3.0,
    what: str = "sphere",
) -> SphereFit:
    """Least-squares sphere with free radius through (N, 3) points (mm), N >= 5.

    Robust start (algebraic fit refitted on the points within 4 MAD-sigmas), geometric
    least squares on every point, then up to ``max_outlier_fraction`` of the points
    with the largest residuals beyond ``outlier_threshold_sigma`` are dropped and the
    geometric fit repeated. Uncertainties come from the Jacobian and the residual
    variance (independent point errors assumed)."""
    p = _points(points_mm, what, 5)
    c, r = _robust_sphere_start(p)
    c, r, res, cov = _geometric_sphere(p, c, r)
    drop = _pick_outliers(res, _allowed_drops(len(p), max_outlier_fraction), outlier_threshold_sigma)
    if len(drop):
        keep = np.ones(len(p), dtype=bool)
        keep[drop] = False
        c, r, res, cov = _geometric_sphere(p[keep], c, r)
    std = np.sqrt(np.maximum(np.diag(cov), 0.0))
    return SphereFit(
        centre_mm=tuple(c.tolist()),
        radius_mm=r,
        centre_std_mm=tuple(std[:3].tolist()),
        radius_std_mm=float(std[3]),
        rms_residual_mm=float(np.sqrt(np.mean(res**2))),
        residual_range_mm=float(res.max() - res.min()),
        n_points_used=len(res),
        n_points_dropped=len(drop),
    )


def fit_plane(
    points_mm,
    max_outlier_fraction: float = MAX_OUTLIER_FRACTION,
    outlier_threshold_sigma: float | None = 3.0,
    what: str = "flat",
) -> PlaneFit:
    """Orthogonal-distance least-squares plane through (N, 3) points (mm), N >= 4: the
    normal is the singular vector of the centred points with the smallest singular
    value. Outliers as in :func:`fit_sphere`."""
    p = _points(points_mm, what, 4)

    def solve(q):
        centroid = q.mean(axis=0)
        _, sv, Vt = np.linalg.svd(q - centroid, full_matrices=False)
        if sv[1] <= 1e-9 * max(sv[0], 1e-300):
            raise InputError(f"{what}: the points are collinear and do not define a plane; scan a wider area")
        n = Vt[2]
        return centroid, n, (q - centroid) @ n

    centroid, n, res = solve(p)
    drop = _pick_outliers(res, _allowed_drops(len(p), max_outlier_fraction), outlier_threshold_sigma)
    if len(drop):
        keep = np.ones(len(p), dtype=bool)
        keep[drop] = False
        centroid, n, res = solve(p[keep])
    return PlaneFit(
        point_mm=tuple(centroid.tolist()),
        normal=tuple(n.tolist()),
        rms_residual_mm=float(np.sqrt(np.mean(res**2))),
        residual_range_mm=float(res.max() - res.min()),
        n_points_used=len(res),
        n_points_dropped=len(drop),
    )


# figures ------------------------------------------------------------------------------
def probing_size_std_mm(points_mm, fit: SphereFit, shot_index, noise: ShotNoise, shot_origin_mm=None) -> float:
    """Standard uncertainty of P_S (mm) that ``noise`` gives a correct system whose
    points lie as these do: the fitted diameter, linearised in the points' radial
    displacements, under each point's own noise and each shot's pose error, which moves
    all the points of that shot together (a translation; a rotation about the shot's
    ``shot_origin_mm``, (n_shots, 3) in the points' frame, the flange's origin). The
    sphere fit's own ``radius_std_mm`` assumes every point independent; a shot's error
    is shared by hundreds of points, and on a partial view of the sphere it moves the
    fitted radius far more than that figure says.

    ``points_mm`` (N, 3) and ``shot_index`` (N,), integers 0..n_shots-1, row for row;
    rows holding NaN are ignored (as the fit ignores them)."""
    p = np.asarray(points_mm, dtype=float)
    shot = np.asarray(shot_index)
    if p.ndim != 2 or p.shape[1] != 3 or shot.shape != (len(p),):
        raise InputError(f"probing_size_std_mm: points {p.shape} and shot_index {shot.shape} must be (N, 3) and (N,)")
    finite = np.all(np.isfinite(p), axis=1)
    p, shot = p[finite], shot[finite].astype(int)
    if len(shot) and shot.min() < 0:
        raise InputError("probing_size_std_mm: shot_index must count shots from 0")
    d = p - np.asarray(fit.centre_mm)
    normal = d / np.linalg.norm(d, axis=1)[:, None]
    J = np.column_stack([-normal, -np.ones(len(p))])  # of the radial residuals, in (centre, radius)
    try:
        gain = np.linalg.solve(J.T @ J, J.T)[3]  # the fitted radius's change per radial displacement of each point
    except np.linalg.LinAlgError as exc:
        raise InputError("probing_size_std_mm: the points do not determine a sphere") from exc
    n_shots = int(shot.max()) + 1 if len(shot) else 0
    var = noise.point_noise_mm**2 * float(gain @ gain)
    # a shot's translation e moves its points' residuals by n.e; a rotation w about o by w.((p - o) x n)
    per_shot = np.zeros((n_shots, 3))
    np.add.at(per_shot, shot, gain[:, None] * normal)
    var += noise.shot_translation_noise_mm**2 * float(np.sum(per_shot**2))
    if noise.shot_rotation_noise_deg > 0:
        origin = np.zeros((n_shots, 3)) if shot_origin_mm is None else np.asarray(shot_origin_mm, dtype=float)
        if origin.shape[0] < n_shots or origin.shape[1:] != (3,):
            raise InputError(f"probing_size_std_mm: shot_origin_mm {origin.shape} needs a row (x, y, z) for each of "
                             f"{n_shots} shots")
        lever = np.zeros((n_shots, 3))
        np.add.at(lever, shot, gain[:, None] * np.cross(p - origin[shot], normal))
        var += math.radians(noise.shot_rotation_noise_deg) ** 2 * float(np.sum(lever**2))
    return 2.0 * math.sqrt(var)


def probing_errors(
    points_mm,
    certified_diameter_mm: float,
    position: str = "P1",
    max_outlier_fraction: float = MAX_OUTLIER_FRACTION,
    outlier_threshold_sigma: float | None = 3.0,
    shot_index=None,
    noise: ShotNoise | None = None,
    shot_origin_mm=None,
) -> ProbingResult:
    """P_F and P_S of the points (N, 3, mm) measured on a sphere of certified diameter.
    With ``shot_index`` (the profile of each point) and ``noise``, the result carries
    the standard uncertainty of P_S from that noise (:func:`probing_size_std_mm`),
    which :func:`acceptance_report` judges P_S with."""
    if not certified_diameter_mm > 0:
        raise InputError(f"certified_diameter_mm must be positive, got {certified_diameter_mm}")
    fit = fit_sphere(points_mm, max_outlier_fraction, outlier_threshold_sigma, what=f"sphere at {position}")
    std = n_shots = None
    if shot_index is not None and noise is not None:
        std = probing_size_std_mm(points_mm, fit, shot_index, noise, shot_origin_mm)
        n_shots = len(np.unique(np.asarray(shot_index)))
    return ProbingResult(
        position=position,
        certified_diameter_mm=certified_diameter_mm,
        fitted_diameter_mm=2 * fit.radius_mm,
        probing_form_error_mm=fit.residual_range_mm,
        probing_size_error_mm=2 * fit.radius_mm - certified_diameter_mm,
        probing_size_std_mm=std,
        n_shots=n_shots,
        fit=fit,
    )


def sphere_spacing_error(
    points_a_mm,
    points_b_mm,
    certified_distance_mm: float,
    position: str = "B1",
    max_outlier_fraction: float = MAX_OUTLIER_FRACTION,
    outlier_threshold_sigma: float | None = 3.0,
) -> SphereSpacingResult:
    """SD of a ball bar from the points (N, 3, mm) measured on each of its two spheres."""
    if not certified_distance_mm > 0:
        raise InputError(f"certified_distance_mm must be positive, got {certified_distance_mm}")
    fa = fit_sphere(points_a_mm, max_outlier_fraction, outlier_threshold_sigma, what=f"ball bar {position}, sphere a")
    fb = fit_sphere(points_b_mm, max_outlier_fraction, outlier_threshold_sigma, what=f"ball bar {position}, sphere b")
    d = np.subtract(fb.centre_mm, fa.centre_mm)
    dist = float(np.linalg.norm(d))
    u = d / dist if dist > 0 else np.zeros(3)
    var = float(u**2 @ (np.square(fa.centre_std_mm) + np.square(fb.centre_std_mm)))
    return SphereSpacingResult(
        position=position,
        certified_distance_mm=certified_distance_mm,
        measured_distance_mm=dist,
        sphere_spacing_error_mm=dist - certified_distance_mm,
        distance_std_mm=math.sqrt(var),
        fit_a=fa,
        fit_b=fb,
    )


def flatness_error(
    points_mm,
    position: str = "F1",
    max_outlier_fraction: float = MAX_OUTLIER_FRACTION,
    outlier_threshold_sigma: float | None = 3.0,
) -> FlatnessResult:
    """F of the points (N, 3, mm) measured on a flat."""
    fit = fit_plane(points_mm, max_outlier_fraction, outlier_threshold_sigma, what=f"flat at {position}")
    return FlatnessResult(position=position, flatness_error_mm=fit.residual_range_mm, fit=fit)


#: Coverage factor of the expanded uncertainty a figure is judged with (k = 2, about 95 %).
COVERAGE_FACTOR = 2.0


def exceeds(value: float, mpe: float, uncertainty_mm: float | None = None) -> bool:
    """True when ``value`` is shown to exceed ``mpe``: ``|value| > mpe + U`` with U the
    value's expanded uncertainty from the noise of its view (ISO 14253-1's rule for
    proving that a specification is not met; None: ``|value| > mpe``)."""
    return abs(value) > mpe + (uncertainty_mm or 0.0)


def _verdict(figure: str, values: Sequence[tuple[str, float, float | None]], mpe: float | None,
             signed: bool) -> FigureVerdict:
    """``values``: (position, value, expanded uncertainty or None) per position. The
    worst is a position shown to exceed the MPE if any (the largest such), else the
    largest value."""
    if not values:
        return FigureVerdict(figure=figure, max_error_mm=None, worst_position=None, n_positions=0, mpe_mm=mpe, passed=None)

    def key(entry):
        _, value, u = entry
        return (mpe is not None and exceeds(value, mpe, u), abs(value) if signed else value)

    pos, worst, u = max(values, key=key)
    passed = None if mpe is None else not exceeds(worst, mpe, u)
    return FigureVerdict(figure=figure, max_error_mm=worst, worst_position=pos, n_positions=len(values), mpe_mm=mpe,
                         passed=passed, uncertainty_mm=u)


def acceptance_report(
    mpe: MaximumPermissibleErrors,
    probing: Sequence[ProbingResult] = (),
    sphere_spacing: Sequence[SphereSpacingResult] = (),
    flatness: Sequence[FlatnessResult] = (),
) -> AcceptanceReport:
    """The worst value of each figure over its positions against the MPEs.

    P_F and F are ranges (>= 0); for P_S and SD the value largest in magnitude is kept
    with its sign and ``|value| <= MPE`` passes. A P_S that carries its standard
    uncertainty from the noise (``probing_size_std_mm``) fails only when it is shown to
    exceed the MPE, beyond MPE + U with U = :data:`COVERAGE_FACTOR` x that uncertainty
    (:func:`exceeds`): a correct system's P_S scatters by U from the robot's and the
    sensor's noise alone. ``passed`` overall is True when every judged figure passed,
    False when one failed, None when nothing was judged."""

    def expanded(std):
        return None if std is None else COVERAGE_FACTOR * std

    verdicts = [
        _verdict("P_F", [(r.position, r.probing_form_error_mm, None) for r in probing], mpe.probing_form_mm, False),
        _verdict("P_S", [(r.position, r.probing_size_error_mm, expanded(r.probing_size_std_mm)) for r in probing],
                 mpe.probing_size_mm, True),
        _verdict("SD", [(r.position, r.sphere_spacing_error_mm, None) for r in sphere_spacing], mpe.sphere_spacing_mm,
                 True),
        _verdict("F", [(r.position, r.flatness_error_mm, None) for r in flatness], mpe.flatness_mm, False),
    ]
    judged = [v.passed for v in verdicts if v.passed is not None]
    return AcceptanceReport(
        probing=list(probing),
        sphere_spacing=list(sphere_spacing),
        flatness=list(flatness),
        mpe=mpe,
        verdicts=verdicts,
        passed=all(judged) if judged else None,
    )
