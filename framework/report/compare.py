"""Two calibrations side by side, or a calibration and a transform given by hand or as a
robot controller stores it: their difference in mm and degrees, its significance from
both covariances, and whether it is drift (``spherecal compare``, docs/cli.md).

The difference of B from A (A is the reference, e.g. last month's calibration) is taken
in the transform's **target** frame (the A of ``A_from_B``), as the uncertainties are
(docs/conventions.md): the rotation ``R_B R_A^T = exp([w])``, ``w`` its rotation vector
(deg, about the target frame's x, y, z; its norm the rotation angle), and the translation
``t_B - t_A`` (mm, along the target frame's axes). With both covariances of (w, t) the
6-vector ``d = (w, t)`` has covariance ``S_A + S_B`` (the two calibrations independent),
so ``D^2 = d^T (S_A + S_B)^-1 d`` (Mahalanobis) is chi-square with 6 degrees of freedom
when nothing changed. Each component is given in sigma too.

Drift is a difference beyond a threshold (``threshold_mm`` on the translation's length,
``threshold_deg`` on the rotation angle) that is also significant (``D^2`` beyond the
chi-square quantile of the significance level); without any covariance the thresholds
alone decide.
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable

import numpy as np

from spherecal.core import geometry as geo
from spherecal.devices.contract import ControllerFrame
from spherecal.core.errors import ConfigError, InputError, SpherecalError
from spherecal.core.models import TRANSFORM_NAME, CalibrationResult, Pose
from spherecal.io.transform_text import XYZ_QUAT_USAGE, looks_like_numbers, parse_xyz_quat

#: Defaults of the drift thresholds (the verdict's amber limits on a 1-sigma).
THRESHOLD_MM = 0.1
THRESHOLD_DEG = 0.05
SIGNIFICANCE_LEVEL = 0.01
#: The six compared parameters, in the covariance's order.
UNCERTAINTIES = ("robot-frame", "full")
PARAMETERS = ("rotation x", "rotation y", "rotation z", "translation x", "translation y", "translation z")


@dataclass(frozen=True)
class TransformEstimate:
    """A transform with its uncertainty: ``covariance`` (6 x 6) of the small rotation about
    the target frame's axes (rad) and the translation (mm); zeros when not known.
    ``transform_name`` is None when the source does not say (numbers given by hand).
    ``arm_model`` is the arm model the transform is relative to: ``"nominal"`` (the
    controller's, as every pose it reports) or ``"calibrated"`` (the arm geometry a
    kinematic calibration identified with it, through which its poses must be mapped)."""

    pose: Pose
    transform_name: str | None
    covariance: np.ndarray
    source: str
    note: str = ""
    arm_model: str = "nominal"

    @classmethod
    def of_result(cls, result: CalibrationResult, source: str, uncertainty: str = "robot-frame"
                  ) -> "TransformEstimate":
        """``uncertainty``: ``"robot-frame"`` (default) the calibration's own, relative to
        the robot's frame (``covariance_robot_frame`` where the result has one): the
        robot's error shared by every station is its accuracy, the same in two
        calibrations on one robot, and cancels in their difference; ``"full"`` with it
        (``covariance``): for calibrations on different robots, or against a frame the
        robot's accuracy does not enter."""
        if uncertainty not in UNCERTAINTIES:
            raise ConfigError(f"uncertainty: expected one of {', '.join(UNCERTAINTIES)}, got {uncertainty!r}")
        full = uncertainty == "full" or result.covariance_robot_frame is None
        cov = np.asarray(result.covariance if full else result.covariance_robot_frame, dtype=float)[:6, :6]
        return cls(result.transform, result.transform_name, cov, source, arm_model=arm_model_of(result))

    def named(self, name: str) -> "TransformEstimate":
        return TransformEstimate(self.pose, name, self.covariance, self.source, self.note, self.arm_model)


def arm_model_of(result: CalibrationResult) -> str:
    """``"calibrated"`` when the result identified the arm's geometry (its transform holds
    only through that calibrated model), else ``"nominal"``."""
    params = result.robot_error.kinematic_parameters if result.robot_error is not None else None
    return "calibrated" if params and any(p.identified for p in params) else "nominal"


def covariance_from_std(std_mm: float = 0.0, std_deg: float = 0.0) -> np.ndarray:
    """The 6 x 6 covariance of a transform known to ``std_deg`` per rotation axis and
    ``std_mm`` per translation axis (1 sigma, independent)."""
    return np.diag([math.radians(std_deg) ** 2] * 3 + [std_mm ** 2] * 3)


def read_controller_frame(text: str, registry, what: str = "--controller-frame", robot_type: str | None = None
                          ) -> ControllerFrame:
    """The frame in ``text`` as a robot controller writes it, read by the robot plugin of
    ``registry`` (the run's installed plugins: ``PluginHost.registry``) that knows the
    syntax (:attr:`spherecal.devices.contract.RobotType.read_frame`; only ``robot_type``'s
    when given). :class:`ConfigError` naming ``what`` when no plugin reads it, or the
    reader's message (the component at fault) when it is malformed."""
    types = [registry.robot_type(robot_type)] if robot_type else list(registry.robots.values())
    readers = [t for t in types if t.read_frame is not None]
    for t in readers:
        try:
            frame = t.read_frame(text)
        except SpherecalError as exc:
            raise ConfigError(f"{what}: {exc}") from None
        if frame is not None:
            if not isinstance(frame, ControllerFrame) or frame.transform_name not in TRANSFORM_NAME.values():
                from spherecal.core.errors import PluginError

                raise PluginError(f"robot type {t.name!r}: read_frame returned {frame!r:.100}, not a ControllerFrame "
                                  f"of {' or '.join(TRANSFORM_NAME.values())}")
            return frame
    if robot_type and not readers:
        raise ConfigError(f"{what}: robot type {robot_type!r} reads no controller frames; give the transform as "
                          "numbers with --transform")
    known = ", ".join(t.name for t in readers) or "none installed"
    raise ConfigError(f"{what}: {text.strip()[:60]!r} is not a frame "
                      + (f"robot type {robot_type!r} reads" if robot_type else "any installed robot plugin reads")
                      + f" (robot types that read controller frames: {known})")


def read_transform_argument(text: str, read_frame: Callable[[str, str], ControllerFrame], what: str = "--transform",
                            uncertainty: str = "robot-frame") -> TransformEstimate:
    """A transform given on the command line: numbers ``x,y,z,qw,qx,qy,qz`` (no name: it
    takes the other operand's), or a file: a ``result.json`` or run folder (its transform,
    name and covariance), or a text file holding the numbers or a controller frame line,
    read by ``read_frame(text, what)`` (:func:`read_controller_frame` with the run's plugins)."""
    stripped = text.strip()
    if looks_like_numbers(stripped) or not stripped:
        return TransformEstimate(parse_xyz_quat(stripped, what), None, np.zeros((6, 6)), f"{what} {stripped}")
    path = Path(stripped).expanduser()
    if not path.exists() and "," in stripped:
        parse_xyz_quat(stripped, what)  # names the value that is not a number
    if not path.exists():
        raise ConfigError(f"{what}: {stripped[:80]!r} is neither {XYZ_QUAT_USAGE} nor an existing file")
    if path.is_dir() or _is_result_file(path):
        result, where = read_result_operand(path)
        return TransformEstimate.of_result(result, str(where), uncertainty)
    from spherecal.io.files import read_input

    raw = read_input(path, InputError, "a transform file", 1 << 20)
    try:
        body = raw.decode("utf-8").removeprefix("\ufeff")
    except UnicodeDecodeError:
        raise InputError(f"{path}: not a text file (it is not UTF-8)") from None
    code = "\n".join(line.split("#", 1)[0] for line in body.splitlines())
    numbers = ",".join(code.replace(",", " ").split())  # the numbers, by commas or blanks
    if numbers and looks_like_numbers(numbers):
        return TransformEstimate(parse_xyz_quat(numbers, str(path)), None, np.zeros((6, 6)), str(path))
    frame = read_frame(body, str(path))
    return estimate_of_frame(frame, str(path))


def estimate_of_frame(frame: ControllerFrame, source: str) -> TransformEstimate:
    label = f"{frame.kind} {frame.name}" if frame.name else frame.kind
    return TransformEstimate(frame.pose, frame.transform_name, np.zeros((6, 6)), f"{source} ({label})", frame.note)


def _is_result_file(path: Path) -> bool:
    try:
        with open(path, "rb") as f:
            head = f.read(4096)
    except OSError:
        return False
    return b'"spherecal-result"' in head


def read_result_operand(path: str | os.PathLike) -> tuple[CalibrationResult, Path]:
    """A calibration result: a ``result.json`` or a run folder holding one."""
    from spherecal.io import dataset as dataio

    p = Path(path).expanduser()
    if p.is_dir():
        if not (p / "result.json").is_file():
            raise InputError(f"{p} is a folder without a result.json: give a result file or a run folder that holds "
                             "one (a RED result's is written only with --force)")
        p = p / "result.json"
    return dataio.read_result(p), p


def check_same_transform(a: TransformEstimate, b: TransformEstimate) -> TransformEstimate:
    """``b`` named as ``a`` when it has no name; :class:`InputError` when the two are
    different transforms (``flange_from_sensor`` and ``base_from_sensor``)."""
    if b.transform_name is None:
        return b.named(a.transform_name) if a.transform_name else b
    if a.transform_name is not None and a.transform_name != b.transform_name:
        mounting = {v: k for k, v in TRANSFORM_NAME.items()}
        raise InputError(
            f"cannot compare different transforms: {a.source} is {a.transform_name} "
            f"({mounting.get(a.transform_name, '?')}) but {b.source} is {b.transform_name} "
            f"({mounting.get(b.transform_name, '?')}); compare calibrations of the same mounting")
    if a.arm_model != b.arm_model or a.arm_model == "calibrated":
        def said(e: TransformEstimate) -> str:
            return (f"{e.source} is relative to the arm geometry its own kinematic calibration identified"
                    if e.arm_model == "calibrated" else f"{e.source} is relative to the controller's nominal arm model")
        raise InputError(
            f"cannot compare these transforms as they are: {said(a)}, {said(b)}; a transform holds only with the "
            "arm model it was calibrated through, so their difference mixes the two arm models' difference with any "
            "drift. Compare like with like: two calibrations without kinematic calibration, or validate each "
            "through its own model (spherecal validate)")
    return b


def chi2_sf_6(x: float) -> float:
    """P(chi-square with 6 degrees of freedom > x): ``exp(-x/2) (1 + x/2 + x^2/8)``."""
    if x <= 0:
        return 1.0
    h = x / 2
    return math.exp(-h) * (1.0 + h + h * h / 2)


def chi2_isf_6(alpha: float) -> float:
    """The x with ``chi2_sf_6(x) = alpha`` (bisection; alpha in (0, 1))."""
    lo, hi = 0.0, 200.0
    for _ in range(200):
        mid = (lo + hi) / 2
        if chi2_sf_6(mid) > alpha:
            lo = mid
        else:
            hi = mid
    return (lo + hi) / 2


@dataclass(frozen=True)
class Comparison:
    """B relative to A (module docstring). Rotations in deg about the target frame's axes,
    translations in mm along them; ``sigma`` the 1-sigma of each of the six differences
    (deg, deg, deg, mm, mm, mm) and ``in_sigma`` the difference over it (None without
    covariance)."""

    transform_name: str | None
    a: TransformEstimate
    b: TransformEstimate
    rotation_angle_deg: float
    rotation_deg: tuple[float, float, float]
    translation_mm: tuple[float, float, float]
    translation_length_mm: float
    sigma: tuple[float, ...] | None
    in_sigma: tuple[float, ...] | None
    mahalanobis: float | None
    p_value: float | None
    significance_level: float
    threshold_mm: float
    threshold_deg: float

    @property
    def beyond_threshold(self) -> bool:
        return self.translation_length_mm > self.threshold_mm or self.rotation_angle_deg > self.threshold_deg

    @property
    def significant(self) -> bool | None:
        """The difference is more than the two uncertainties explain (None: no covariance)."""
        return None if self.p_value is None else self.p_value < self.significance_level

    @property
    def drift(self) -> bool:
        return self.beyond_threshold and self.significant is not False

    def as_dict(self) -> dict[str, Any]:
        return {
            "transform_name": self.transform_name,
            "a": self.a.source, "b": self.b.source,
            "rotation_angle_deg": self.rotation_angle_deg, "rotation_deg": list(self.rotation_deg),
            "translation_mm": list(self.translation_mm), "translation_length_mm": self.translation_length_mm,
            "sigma": None if self.sigma is None else list(self.sigma),
            "in_sigma": None if self.in_sigma is None else list(self.in_sigma),
            "mahalanobis": self.mahalanobis, "p_value": self.p_value,
            "significance_level": self.significance_level, "significant": self.significant,
            "threshold_mm": self.threshold_mm, "threshold_deg": self.threshold_deg,
            "beyond_threshold": self.beyond_threshold, "drift": self.drift,
        }


def compare(a: TransformEstimate, b: TransformEstimate, *, threshold_mm: float = THRESHOLD_MM,
            threshold_deg: float = THRESHOLD_DEG, significance_level: float = SIGNIFICANCE_LEVEL) -> Comparison:
    """B relative to A (module docstring). Refuses different transforms
    (:func:`check_same_transform`)."""
    if not 0 < significance_level < 1:
        raise ConfigError(f"the significance level must lie between 0 and 1, got {significance_level:g}")
    b = check_same_transform(a, b)
    w = geo.rotvec_from_matrix(b.pose.rotation_matrix @ a.pose.rotation_matrix.T)
    dt = b.pose.translation - a.pose.translation
    d = np.concatenate([w, dt])
    cov = np.asarray(a.covariance, float) + np.asarray(b.covariance, float)
    sigma = in_sigma = dist = p = None
    if np.any(cov):
        var = np.diag(cov)
        scale = np.array([math.degrees(1.0)] * 3 + [1.0] * 3)
        sigma = tuple(float(v) for v in np.sqrt(np.maximum(var, 0.0)) * scale)
        in_sigma = tuple(float(x / s) if s > 0 else (math.inf if abs(x) > 0 else 0.0)
                         for x, s in zip(d * scale, sigma))
        try:
            d2 = float(d @ np.linalg.solve(cov, d))
        except np.linalg.LinAlgError:  # a part not covered (a zero variance): only the covered part counts
            keep = var > 0
            d2 = float(d[keep] @ np.linalg.lstsq(cov[np.ix_(keep, keep)], d[keep], rcond=None)[0])
            if np.any(np.abs(d[~keep]) > 0):
                d2 = math.inf
        dist = math.sqrt(max(d2, 0.0))
        p = chi2_sf_6(d2)
    return Comparison(
        transform_name=a.transform_name or b.transform_name, a=a, b=b,
        rotation_angle_deg=float(np.degrees(np.linalg.norm(w))),
        rotation_deg=tuple(float(v) for v in np.degrees(w)),
        translation_mm=tuple(float(v) for v in dt), translation_length_mm=float(np.linalg.norm(dt)),
        sigma=sigma, in_sigma=in_sigma, mahalanobis=dist, p_value=p, significance_level=significance_level,
        threshold_mm=threshold_mm, threshold_deg=threshold_deg,
    )


def format_comparison(c: Comparison) -> str:
    """The comparison as the terminal shows it."""
    frame = (c.transform_name or "target_from_x").split("_from_")[0]
    name = c.transform_name or "the transform"
    lines = [f"{name}: B relative to A (differences about and along the {frame} frame's x, y, z axes)",
             f"  A: {c.a.source}", f"  B: {c.b.source}"]
    for est in (c.a, c.b):
        if est.note:
            lines.append(f"  note: {est.note}")

    def signed(v: float, decimals: int) -> str:
        text = f"{v:+.{decimals}f}"
        return text if text.strip("+-0.") else "+" + text[1:]  # no "-0.0000"

    def comps(values, unit, start):
        text = ", ".join(signed(v, 4) for v in values) + f" {unit}"
        if c.in_sigma is not None:
            text += " (" + ", ".join(signed(s, 1) for s in c.in_sigma[start:start + 3]) + " sigma)"
        return text

    lines.append(f"  rotation:    {c.rotation_angle_deg:.4f} deg; about x, y, z: {comps(c.rotation_deg, 'deg', 0)}")
    lines.append(f"  translation: {c.translation_length_mm:.4f} mm; along x, y, z: {comps(c.translation_mm, 'mm', 3)}")
    if c.sigma is not None:
        lines.append(f"  1-sigma of the difference: rotation {', '.join(f'{s:.4f}' for s in c.sigma[:3])} deg; "
                     f"translation {', '.join(f'{s:.4f}' for s in c.sigma[3:])} mm")
        k = chi2_isf_6(c.significance_level)
        lines.append(f"  significance: Mahalanobis distance {c.mahalanobis:.2f} over the 6 parameters "
                     f"(D^2 {c.mahalanobis ** 2:.2f}, p = {c.p_value:.3g}); "
                     + (f"significant at {c.significance_level:g} (D^2 > {k:.2f})" if c.significant else
                        f"not significant at {c.significance_level:g} (D^2 <= {k:.2f}): within the two uncertainties"))
    else:
        lines.append("  significance: not judged (neither side has a covariance; give --std-mm and --std-deg)")
    lines.append(f"  thresholds: {c.threshold_mm:g} mm, {c.threshold_deg:g} deg: "
                 + ("exceeded" if c.beyond_threshold else "within"))
    if c.drift:
        lines.append("drift: YES: " + ("the difference exceeds a threshold and is significant" if c.significant
                                       else "the difference exceeds a threshold (significance not judged)"))
    elif c.beyond_threshold:
        lines.append("drift: no: the difference exceeds a threshold but the two uncertainties explain it")
    else:
        lines.append("drift: no")
    return "\n".join(lines)
