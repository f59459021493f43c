"""What a failed validation means, and what to do: the verdict of a calibration with its
validation (:func:`validation_verdict`), naming the robot's own error as the likely cause
when the calibration's verdict already said it dominates and it explains every figure
beyond its MPE (:func:`robot_cause`).

The acceptance figures (:data:`spherecal.motion.validation.FIGURE_SCOPE`) are either
*absolute*, positions measured from poses far apart set against each other through the
robot's poses (SD, the spread of the sphere centres), which include the robot's own error
between those poses, or *relative*, from one sweep each (P_F, P_S, F), which do not depend
on where the robot thinks it is. Where the robot's error is what fails them, calibrating
the sensor again cannot help: the remedy is the robot's own calibration (for an arm whose
geometry spherecal models, spherecal's kinematic calibration, measured through the
calibrated model), or accepting the figures. A validation of a calibration that did not
say so (a GREEN one) still says not to use it.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass

from spherecal.core.models import CalibrationResult
from spherecal.motion.validation import FIGURE_SCOPE
from spherecal.report.advice_wording import recording_arm_calibration
from spherecal.report.assess import Verdict, robot_error_dominates, with_validation


@dataclass(frozen=True)
class RobotCause:
    """A failed validation the robot's own error explains: what (``short``), the ``cause``
    and the ``remedy`` (one sentence each), the ``expected_k2_mm`` error of a point at a new
    pose the calibration stated (k = 2, mm) and the failing figures by scope."""

    short: str
    cause: str
    remedy: str
    expected_k2_mm: float
    failed_absolute: tuple[str, ...]
    failed_relative: tuple[str, ...]

    def as_dict(self) -> dict:
        return {"short": self.short, "cause": self.cause, "remedy": self.remedy, "expected_point_error_k2_mm": self.expected_k2_mm,
                "failed_absolute": list(self.failed_absolute), "failed_relative": list(self.failed_relative)}


def _failed(figures: Mapping[str, Mapping]) -> dict[str, float]:
    return {name: abs(float(row["max error (mm)"])) for name, row in figures.items() if row.get("passed") is False}


def robot_cause(result: CalibrationResult | None, figures: Mapping[str, Mapping]) -> RobotCause | None:
    """The robot's own error as the likely cause of a failed validation, when: the
    calibration's verdict said it dominates (:func:`~spherecal.report.assess.robot_error_dominates`),
    the arm's geometry was not identified (a kinematic calibration measures through its
    calibrated model: its failure is not the nominal model's), and every figure beyond its
    MPE is within the error the calibration stated for a point at a new pose (k = 2). None
    otherwise (no result, nothing failed, a clean cell, a figure the robot cannot explain)."""
    failed = _failed(figures)
    err = None if result is None else result.robot_error
    if not failed or err is None or not robot_error_dominates(result):
        return None
    params = err.kinematic_parameters or []
    if any(p.identified for p in params):
        return None
    expected = float(err.point_error_k2_mm)
    if max(failed.values()) > expected:
        return None
    absolute = tuple(n for n in failed if FIGURE_SCOPE.get(n) == "absolute")
    relative = tuple(n for n in failed if FIGURE_SCOPE.get(n) != "absolute")
    if params:  # the arm's geometry is modelled (its joints and kinematics): spherecal can calibrate it
        short = "the arm's own geometry"
        what = f"{short} (its flange is not where its controller's nominal model says)"
        remedy = ("either calibrate the arm's geometry with spherecal ([calibration] identify_kinematics = true; "
                  "examples/sim-kinematic-eye-in-hand.toml) and measure through the calibrated model ([robot] "
                  "calibrated_model = the robot_calibrated.urdf it writes), or accept these figures for this cell")
        if result.timing is not None:  # a recording: the arm's calibration is a stop-and-go run of its own
            seen = sum(p.identifiable for p in params)
            remedy = f"either {recording_arm_calibration(seen, len(params))}, or accept these figures for this cell"
    else:
        short = "the robot's own absolute accuracy"
        what = f"{short} (its flange is not where its controller says)"
        remedy = ("either calibrate the robot's kinematics (spherecal does with joint readings and a robot plugin "
                  "that describes its arm: [calibration] identify_kinematics = true) or use its absolute-accuracy "
                  "option, and measure through it; or accept these figures for this cell")
    cause = (f"{what}, which the calibration's verdict named (a point at a new pose: expected error {expected:.3f} mm, "
             "k = 2, mostly the robot's); every figure beyond its MPE is within that, so the sensor's calibration "
             "is as good as this robot allows and calibrating the sensor again cannot remove it")
    return RobotCause(short, cause, remedy, expected, absolute, relative)


def scope_sentence(figures: Mapping[str, Mapping]) -> str:
    """Which figures are absolute and which relative, with the failing ones named."""

    def names(found: list[str]) -> str:
        return found[0] if len(found) == 1 else f"{', '.join(found[:-1])} and {found[-1]}"

    def part(scope: str) -> str:
        mine = [n for n in figures if FIGURE_SCOPE.get(n) == scope]
        bad = [n for n in mine if figures[n].get("passed") is False]
        good = [n for n in mine if n not in bad]
        bits = ([f"{names(bad)} beyond {'its MPE' if len(bad) == 1 else 'their MPEs'}"] if bad else []) + (
            [f"{names(good)} within"] if good else [])
        return ", ".join(bits) or "none measured"

    return (f"absolute figures (they include the robot's own error): {part('absolute')}; relative figures "
            f"(independent of where the robot thinks it is): {part('relative')}")


def validation_verdict(ver: Verdict, figures: Mapping[str, Mapping], result: CalibrationResult | None = None
                       ) -> tuple[Verdict, RobotCause | None]:
    """The verdict ``ver`` of ``result`` together with its validation ``figures``
    (:func:`~spherecal.report.assess.with_validation`), and the robot cause when
    :func:`robot_cause` names one: a failure then says the cause and the remedy instead
    of "Do not use this calibration", and which figures are absolute and which relative."""
    cause = robot_cause(result, figures)
    if cause is None:
        v = with_validation(ver, figures)
        if _failed(figures):
            v.reasons.append(("amber", scope_sentence(figures)))
        return v, None
    v = with_validation(ver, figures, cause=f"Likely cause: {cause.short}, as the calibration's verdict said: "
                        "calibrating the sensor again cannot remove it (the cause and the remedy below).")
    v.reasons += [("red", f"likely cause: {cause.cause}"), ("red", f"remedy: {cause.remedy}"),
                  ("amber", scope_sentence(figures))]
    return v, cause
