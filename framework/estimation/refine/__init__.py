"""Joint refinement over every raw profile point, with its covariance. Part of
:mod:`spherecal.estimation` (imports its layers, core to devices).

Model: for profile i the sphere centre in the sensor frame is
``C_i = X^-1 A_i^-1 c`` (see :mod:`spherecal.estimation.problem`); the laser plane x = 0
cuts the sphere in the circle of centre (C_y, C_z) and radius ``rho_i = sqrt(r^2 - C_x^2)``.
The residual of point p = (y, z) is its in-plane distance to that circle,
``|p - C_yz| - rho_i``: the maximum-likelihood residual for isotropic Gaussian noise in
the laser plane.

Noise model: point noise sigma (each of y, z) and robot pose noise (rotation and
translation, base frame) that is shared by all points of one profile. The residuals of a
profile are therefore correlated, ``Cov_i = sigma^2 I + G_i S_Ci G_i^T`` with
``S_Ci`` the covariance of C_i due to the pose noise. Gauss-Newton on the rotation
manifold (``R <- exp([w]) R``, w about the target frame's axes) solves the generalised
least-squares problem, reduced to each shot (:class:`.linearisation._Reduced`: no
per-point Jacobian). Unknowns: w (3), t (3), c (3) and optionally r. The pose-noise scale
is re-estimated from the data (variance component) unless fixed. The covariance is
``(J^T Cov^-1 J)^-1``.

Where each part lives:

* :mod:`.linearisation`: residuals, Jacobians and the whitened problem reduced to each
  shot; the noise assumptions; the centre observations' rows and variance.
* :mod:`.effects`: the robot's systematic error as random effects (station offsets, the
  arm's geometric error) and their normal-equation blocks.
* :mod:`.reml`: the random effects' scales by restricted maximum likelihood.
* :mod:`.covariance`: the reported covariances at the solution.
* :mod:`.design`: identifiability and the Cramer-Rao bound of a problem or a plan.
* :mod:`.state`: the state the steps share; :mod:`.driver`: :func:`refine` itself.
"""

from spherecal.estimation.refine.covariance import SEEN_POSTERIOR_SHARE
from spherecal.estimation.refine.design import (
    IDENTIFIABILITY_TOLERANCE, _centre_design, cramer_rao_bound, design_identifiability,
    identifiable_kinematic_parameters, plan_design,
)
from spherecal.estimation.refine.driver import (
    STALLED_CUT_STEPS, STALLED_STEP_SHARE, RefineProgress, RefineResult, cost_at, refine,
)
from spherecal.estimation.refine.effects import KinematicEffects, StationEffects
from spherecal.estimation.refine.linearisation import (
    NoiseAssumptions, _centres, _linearise, _point_sums, _Points, _pose_cov,
)
from spherecal.estimation.refine.reml import (
    _SCALE_BOUNDS, KINEMATIC_EVIDENCE_LR, _neg2_reml_derivatives, _reml_batch, _reml_search,
)

__all__ = [
    "IDENTIFIABILITY_TOLERANCE", "KINEMATIC_EVIDENCE_LR", "SEEN_POSTERIOR_SHARE", "STALLED_CUT_STEPS",
    "STALLED_STEP_SHARE", "KinematicEffects", "NoiseAssumptions", "RefineProgress", "RefineResult", "StationEffects",
    "cost_at", "cramer_rao_bound", "design_identifiability", "identifiable_kinematic_parameters", "plan_design", "refine",
]
# The underscored names above are the refinement's internals that prediction, the
# benchmarks and the tests reach for: importable here as they were from one module.
