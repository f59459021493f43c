"""The estimator's settings, the ``[calibration]`` section (:class:`CalibrationOptions`).
Lengths in mm, angles in degrees."""

from __future__ import annotations

from typing import Literal

from pydantic import Field

from spherecal.config.base import CHI2_3DOF_1E4, Section
from spherecal.core.models import Pose


class CalibrationOptions(Section):
    """Settings of the estimator. Lengths in mm, angles in degrees."""

    fit_radius: bool = Field(False, description="estimate the sphere radius too (else the certified one is used)")
    point_noise_mm: float | None = Field(
        None, gt=0, description="sensor point noise (each of y, z), mm; None: estimated from the circle fits"
    )
    pose_translation_noise_mm: float = Field(0.02, ge=0, description="robot position noise, each axis, mm")
    pose_rotation_noise_deg: float = Field(0.002, ge=0, description="robot orientation noise, each axis, deg")
    estimate_pose_noise: bool = Field(True, description="rescale the pose noise to what the data show")
    min_points_per_profile: int = Field(20, ge=3, description="profiles with fewer points are left out")
    min_profiles_per_station: int = Field(4, ge=3, description="stations with fewer usable profiles are left out")
    max_circle_rms_mm: float = Field(0.5, gt=0, description="a profile whose circle fit is worse is not the sphere")
    point_outlier_k: float = Field(5.0, gt=2, description="points beyond k robust standard deviations are strays")
    profile_outlier_chi2: float = Field(
        CHI2_3DOF_1E4, gt=0, description="profiles whose whitened chi^2 (3 dof) exceeds this are left out"
    )
    max_rejected_profile_fraction: float = Field(0.2, ge=0, le=1, description="stop rejecting profiles beyond this share")
    max_stray_point_fraction: float = Field(
        0.3, gt=0, le=1, description="a profile with a larger share of its points beyond point_outlier_k robust SDs "
        "of the sphere the other profiles agree on is left out and flagged (its pose is wrong, not its points)"
    )
    nominal_transform: Pose | None = Field(
        None, description="rough X (flange_from_sensor or base_from_sensor), used only to choose between "
        "solutions the data cannot tell apart"
    )
    station_rotation_tolerance_deg: float | None = Field(
        None, gt=0, description="a shot turned more than this from its station's mean orientation is left out "
        "(or, with enough like it, split off as a station of its own), deg; None: derived from the orientation "
        "read noise, max(0.02, 4 sqrt(3) s) with s the larger of pose_rotation_noise_deg and the scatter the "
        "stations show"
    )
    robot_error_model: Literal["auto", "kinematic", "station", "kinematic+station", "none"] = Field(
        "auto", description="the robot's systematic error (docs/estimation.md): 'kinematic': the arm's geometric "
        "error (joint zero offsets, joint origins, axis tilts), from each shot's joints through the robot's "
        "kinematics, marginalised; 'station': a pose offset shared by the shots of a station, marginalised; "
        "'kinematic+station': both; 'none': pose noise only; 'auto': with the joints and the robot's kinematics "
        "known, kinematic when the data show the arm's geometric error (else pose noise only, the arm's geometry "
        "considered in the uncertainty), without them station"
    )
    identify_kinematics: bool = Field(
        False, description="estimate the arm's identifiable geometric errors (kinematic calibration, "
        "docs/estimation.md); needs joint readings and the robot's kinematics"
    )
    kinematic_prior_zero_offset_deg: float = Field(
        0.05, ge=0, le=5, description="spread of each joint's zero offset on an uncalibrated arm, 1 sigma, deg"
    )
    kinematic_prior_length_mm: float = Field(
        0.3, ge=0, le=50, description="spread of each joint origin's position, per axis, 1 sigma, mm"
    )
    kinematic_prior_tilt_deg: float = Field(
        0.02, ge=0, le=5, description="spread of each joint axis' tilt, per direction, 1 sigma, deg"
    )
    station_rotation_error_deg: float | None = Field(
        None, ge=0, le=5, description="station-to-station robot orientation error, per axis, deg (None: estimated)"
    )
    station_translation_error_mm: float | None = Field(
        None, ge=0, le=50, description="station-to-station robot position error, per axis, mm (None: estimated)"
    )
    robot_accuracy_mm: float = Field(
        0.75, ge=0, le=50, description="the robot's position error shared by every station of the plan, per axis, "
        "1 sigma, mm (an uncalibrated industrial arm: 0.3-1.2); one sphere location cannot measure it, so it "
        "enters the uncertainty only (docs/estimation.md)"
    )
    robot_accuracy_deg: float = Field(
        0.06, ge=0, le=5, description="the robot's orientation error shared by every station, per axis, 1 sigma, deg"
    )

    def uses_kinematic_model(self, joints_known: bool) -> bool:
        return self.identify_kinematics or self.robot_error_model in ("kinematic", "kinematic+station") or (
            self.robot_error_model == "auto" and joints_known)
