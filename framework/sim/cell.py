"""A virtual robot cell with a known true transform.

The laser line sensor is modelled as a fan of rays in its x = 0 plane from an apex on
its z axis, chosen so that the fan's width matches the field of view (nxSensor-I: 28 mm
wide at z = +40 mm, 48 mm at z = -60 mm, so the apex is at z = +180 mm and the sensor
looks towards -z). Each ray returns its first hit on the sphere, so only the side the
sensor can see is measured; hits outside z in [-60, +40] mm are dropped. Gaussian noise
is added to y and z of every point (isotropic in the laser plane); stray points
(reflections, edge points) are added to some profiles. Robot pose noise: the reported
pose is the true one with rotation ``exp(eps_r) R`` and translation ``t + eps_t``, both
errors in the base frame.
"""

from __future__ import annotations

import numpy as np
from pydantic import BaseModel, ConfigDict, Field

from .. import geometry as geo
from ..models import TRANSFORM_NAME, MountingMode, Pose


class SensorFieldOfView(BaseModel):
    """Field of view of a laser line sensor, sensor frame, mm (defaults: nxSensor-I)."""

    model_config = ConfigDict(frozen=True, extra="forbid")

    z_near_mm: float = Field(40.0, description="near end of the measuring range (z, mm)")
    z_far_mm: float = Field(-60.0, description="far end of the measuring range (z, mm)")
    width_near_mm: float = Field(28.0, gt=0, description="line width at the near end, mm")
    width_far_mm: float = Field(48.0, gt=0, description="line width at the far end, mm")
    n_columns: int = Field(640, ge=16, description="points across the full line")

    @property
    def apex_z_mm(self) -> float:
        """z of the fan's apex, where the line width extrapolates to zero."""
        slope = (self.width_far_mm - self.width_near_mm) / 2 / (self.z_near_mm - self.z_far_mm)
        return self.z_near_mm + self.width_near_mm / 2 / slope

    @property
    def half_angle_rad(self) -> float:
        slope = (self.width_far_mm - self.width_near_mm) / 2 / (self.z_near_mm - self.z_far_mm)
        return float(np.arctan(slope))


class NoiseModel(BaseModel):
    """Noise of the simulated cell. Standard deviations, per axis."""

    model_config = ConfigDict(frozen=True, extra="forbid")

    point_noise_mm: float = Field(0.01, ge=0, description="sensor point noise, each of y and z, mm")
    pose_translation_noise_mm: float = Field(0.02, ge=0, description="robot position noise, each base axis, mm")
    pose_rotation_noise_deg: float = Field(0.0, ge=0, description="robot orientation noise, about each base axis, deg")
    stray_profile_fraction: float = Field(0.0, ge=0, le=1, description="share of profiles that get stray points")
    strays_per_profile: int = Field(4, ge=0, description="stray points added to such a profile")
    stray_offset_mm: tuple[float, float] = Field((0.3, 3.0), description="range of a stray's distance off the surface, mm")


class SimulatedCell:
    """Sphere, robot flange and sensor with a known truth, in one mounting mode.

    ``true_transform`` is ``flange_from_sensor`` (eye-in-hand) or ``base_from_sensor``
    (eye-to-hand). ``sphere_centre_mm`` is in base (eye-in-hand) or flange (eye-to-hand).
    Simulated devices share one cell: the robot calls :meth:`move_flange_to`, the sensor
    :meth:`measure_profile`.
    """

    def __init__(
        self,
        mounting: MountingMode,
        true_transform: Pose,
        sphere_centre_mm,
        sphere_radius_mm: float,
        fov: SensorFieldOfView | None = None,
        noise: NoiseModel | None = None,
        seed: int | None = 0,
        base_from_flange: Pose | None = None,
    ):
        if mounting not in TRANSFORM_NAME:
            raise ValueError(f"mounting must be one of {sorted(TRANSFORM_NAME)}, got {mounting!r}")
        self.mounting = mounting
        self.true_transform = true_transform
        self.sphere_centre_mm = np.asarray(sphere_centre_mm, dtype=float).reshape(3)
        self.sphere_radius_mm = float(sphere_radius_mm)
        self.fov = fov or SensorFieldOfView()
        self.noise = noise or NoiseModel()
        self.rng = np.random.default_rng(seed)
        self.current_base_from_flange = base_from_flange or Pose.identity()

    # geometry --------------------------------------------------------------------------
    def sensor_from_sphere_frame(self, base_from_flange: Pose) -> tuple[np.ndarray, np.ndarray]:
        """(R, t) mapping points of the frame the sphere is fixed in into the sensor frame."""
        X = self.true_transform
        if self.mounting == "eye_in_hand":
            base_from_sensor = base_from_flange @ X
            return geo.invert_rt(base_from_sensor.rotation_matrix, base_from_sensor.translation)
        flange_from_sensor = base_from_flange.inverse() @ X
        return geo.invert_rt(flange_from_sensor.rotation_matrix, flange_from_sensor.translation)

    def sphere_centre_in_sensor(self, base_from_flange: Pose) -> np.ndarray:
        """True sphere centre in the sensor frame (mm) at a true flange pose."""
        R, t = self.sensor_from_sphere_frame(base_from_flange)
        return R @ self.sphere_centre_mm + t

    def ideal_profile(self, base_from_flange: Pose) -> np.ndarray:
        """Noise-free (N, 2) points (y, z) in mm the sensor sees at a true flange pose."""
        c = self.sphere_centre_in_sensor(base_from_flange)
        r = self.sphere_radius_mm
        if abs(c[0]) >= r:
            return np.empty((0, 2))
        rho = np.sqrt(r * r - c[0] * c[0])
        fov = self.fov
        angles = np.linspace(-fov.half_angle_rad, fov.half_angle_rad, fov.n_columns)
        d = np.column_stack([np.sin(angles), -np.cos(angles)])  # ray directions (y, z)
        apex = np.array([0.0, fov.apex_z_mm])
        w = apex - c[1:]
        b = d @ w
        disc = b * b - (w @ w - rho * rho)
        hit = disc > 0
        s = -b[hit] - np.sqrt(disc[hit])  # first intersection along each ray
        pts = apex + s[:, None] * d[hit]
        keep = (s > 0) & (pts[:, 1] <= fov.z_near_mm) & (pts[:, 1] >= fov.z_far_mm)
        return pts[keep]

    # measurement -----------------------------------------------------------------------
    def measure_profile(self, base_from_flange: Pose | None = None) -> np.ndarray:
        """A noisy profile (N, 2) in mm at the given true pose (default: where the robot
        is now); empty when the sphere is out of view."""
        pose = base_from_flange or self.current_base_from_flange
        pts = self.ideal_profile(pose)
        if len(pts) == 0:
            return pts
        n = self.noise
        pts = pts + self.rng.normal(0.0, n.point_noise_mm, pts.shape) if n.point_noise_mm > 0 else pts.copy()
        if n.strays_per_profile and self.rng.random() < n.stray_profile_fraction:
            pts = np.vstack([pts, self._strays(pts)])
        return pts

    def _strays(self, pts: np.ndarray) -> np.ndarray:
        """Reflections and edge points: points off the surface by a few tenths to mm."""
        n = self.noise
        k = n.strays_per_profile
        picks = pts[self.rng.integers(0, len(pts), k)]
        angle = self.rng.uniform(0, 2 * np.pi, k)
        dist = self.rng.uniform(*n.stray_offset_mm, k)
        return picks + dist[:, None] * np.column_stack([np.cos(angle), np.sin(angle)])

    def report_pose(self, true_base_from_flange: Pose) -> Pose:
        """The pose a robot controller would report: the true one plus pose noise."""
        n = self.noise
        R = true_base_from_flange.rotation_matrix
        t = true_base_from_flange.translation
        if n.pose_rotation_noise_deg > 0:
            R = geo.matrix_from_rotvec(self.rng.normal(0, np.radians(n.pose_rotation_noise_deg), 3)) @ R
        if n.pose_translation_noise_mm > 0:
            t = t + self.rng.normal(0, n.pose_translation_noise_mm, 3)
        return Pose.from_rt(R, t)

    def move_flange_to(self, true_base_from_flange: Pose) -> None:
        """Where the (simulated) robot has put its flange."""
        self.current_base_from_flange = true_base_from_flange

    @property
    def transform_name(self) -> str:
        return TRANSFORM_NAME[self.mounting]


def _rot(rotvec_deg) -> np.ndarray:
    return geo.matrix_from_rotvec(np.radians(rotvec_deg))


#: Flange pointing down (tool0 z along -z of base), as in a typical scanning cell.
FLANGE_DOWN = _rot([0.0, 180.0, 0.0])


def standard_cell(
    mounting: MountingMode = "eye_in_hand",
    seed: int | None = 0,
    noise: NoiseModel | None = None,
    fov: SensorFieldOfView | None = None,
    sphere_radius_mm: float = 19.1,
) -> SimulatedCell:
    """An IRB 2400-sized cell with a generic (not axis-aligned) true transform.

    Eye-in-hand: the sensor sits about 160 mm out from the flange looking along the
    flange's z; the sphere stands at (1100, 150, 400) mm in base. Eye-to-hand: the
    sensor hangs at about (1250, -200, 900) mm in base looking down; the sphere is on a
    150 mm stylus on the flange's z axis."""
    if mounting == "eye_in_hand":
        R = _rot([180.0, 0.0, 0.0]) @ _rot([2.0, -4.0, 31.0])
        X = Pose.from_rt(R, [42.5, -18.3, 163.7])
        centre = [1100.0, 150.0, 400.0]
    else:
        R = _rot([0.0, 180.0, 0.0]) @ _rot([3.0, 5.0, -20.0])
        X = Pose.from_rt(R, [1250.0, -200.0, 900.0])
        centre = [4.2, -2.7, 151.3]
    return SimulatedCell(mounting, X, centre, sphere_radius_mm, fov=fov, noise=noise, seed=seed)
