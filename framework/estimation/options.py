"""The estimator's reading of its settings (:class:`~spherecal.config.CalibrationOptions`):
the robot's systematic error as the fit models it, and the station rotation tolerance."""

from __future__ import annotations

import numpy as np

from spherecal.config import CalibrationOptions
from spherecal.core.kinematics import SerialChain
from spherecal.estimation.problem import derived_station_rotation_tolerance_deg
from spherecal.estimation.refine import KinematicEffects, StationEffects


def station_effects(options: CalibrationOptions, joints_known: bool = False) -> StationEffects:
    """The per-station pose error the fit marginalises: on for the ``station`` and
    ``kinematic+station`` models, and for ``auto`` when the kinematic model is not used."""
    on = options.robot_error_model in ("station", "kinematic+station") or (
        options.robot_error_model == "auto" and not options.uses_kinematic_model(joints_known))
    return StationEffects(
        on, options.station_rotation_error_deg,
        options.station_translation_error_mm, options.robot_accuracy_deg, options.robot_accuracy_mm,
    )


def kinematic_effects(options: CalibrationOptions, chain: SerialChain) -> KinematicEffects:
    """The arm's geometric error on ``chain``, with the prior spread of each joint's six
    parameters (zero offset in rad, origin in mm, axis tilt in rad) from ``options``."""
    per_joint = [np.radians(options.kinematic_prior_zero_offset_deg)] + [options.kinematic_prior_length_mm] * 3 + [
        np.radians(options.kinematic_prior_tilt_deg)] * 2
    return KinematicEffects(chain, np.tile(per_joint, chain.n_joints), estimate_scale=True,
                            identify=options.identify_kinematics,
                            select_by_evidence=options.robot_error_model == "auto" and not options.identify_kinematics)


def station_rotation_tolerance_deg(options: CalibrationOptions) -> float:
    """The station rotation tolerance in deg: the configured one, or the one derived
    from ``pose_rotation_noise_deg`` alone (before any data are seen)."""
    if options.station_rotation_tolerance_deg is not None:
        return options.station_rotation_tolerance_deg
    return derived_station_rotation_tolerance_deg(options.pose_rotation_noise_deg)
