"""Estimation: from (robot pose, profile) observations of a sphere to the calibrated
transform with its uncertainty. Imports :mod:`spherecal.core`, :mod:`spherecal.io`,
:mod:`spherecal.config` and :mod:`spherecal.devices`, nothing that moves a robot.

1. :mod:`.problem`: both mounting modes as one problem, ``|A_i X p - c| = r``.
2. :mod:`.circle`: a robust circle fit per profile.
3. :mod:`.twostep`: the published two-step method (rotation by SVD from pure
   translations, translation by least squares over orientations).
4. :mod:`.refine`: joint refinement over every point with the robot pose noise in the
   noise model, and the covariance; :func:`.refine.cramer_rao_bound`.
5. :mod:`.pipeline`: the solve, step by step, its diagnostics and the result;
   :mod:`.screening`: the checks that flag and leave out observations.

Centre observations (a circle fitted on board, a sphere centre from a table) join every
step beside the profiles; :mod:`.centres` checks a typed table row by row.

The names below load on first use (PEP 562): a module that needs one light part of the
estimator (the robust median, the circle fit) does not load the whole of it.
"""

from spherecal.core.lazy import lazy_attributes

#: name -> the module that defines it
_WHERE = {
    "CalibrationOptions": "spherecal.config.calibration",
    "Solution": ".pipeline",
    "calibrate": ".pipeline",
    "solve": ".pipeline",
}

__all__ = sorted(_WHERE)

__getattr__, __dir__ = lazy_attributes(__name__, _WHERE)
