"""A result restated as a kinematic calibration states itself, for the tests of what the
exports, the terminal and the report say about one: the arm's geometry identified, the
accuracy through the calibrated model and on the controller's nominal model. (Importable
from every test folder, as ``reference_sensor``.) The estimator's own kinematic results
are tested in tests/estimation; these tests need only what a result file holds."""

from __future__ import annotations

from spherecal.core.models import CalibrationResult, KinematicParameter


def as_kinematic_calibration(result: CalibrationResult, point_k2_mm: float = 0.075,
                             nominal_k2_mm: float | None = 0.362) -> CalibrationResult:
    """``result`` with a robot error of the kinematic model whose arm was calibrated: two
    parameters identified (joint 2's zero offset, joint 3's z), one left at its prior;
    ``point_k2_mm`` through the calibrated model, ``nominal_k2_mm`` on the nominal one (None:
    a result file that does not hold it)."""
    params = [
        KinematicParameter(name="joint_1.zero_offset", unit="deg", value=0.0, std=0.05, identifiable=False,
                           identified=False),
        KinematicParameter(name="joint_2.zero_offset", unit="deg", value=0.0321, std=0.0012, identifiable=True,
                           identified=True),
        KinematicParameter(name="joint_3.z", unit="mm", value=-0.214, std=0.0087, identifiable=True, identified=True),
    ]
    err = result.robot_error.model_copy(update={
        "model": "kinematic", "kinematic_parameters": params, "kinematic_prior_scale": 1.0, "model_choice": None,
        "point_error_k2_mm": point_k2_mm, "point_error_nominal_arm_k2_mm": nominal_k2_mm})
    return result.model_copy(update={"robot_error": err})
