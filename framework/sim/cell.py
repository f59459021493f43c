"""A virtual robot cell with a known true transform.

The laser line sensor is modelled as a fan of rays in its x = 0 plane from an apex on
its z axis, chosen so that the fan's width matches the sensor's declared field of view
(:class:`~spherecal.devices.contract.SensorFieldOfView`, which the sensor type declares: the
simulator knows no sensor of its own; a line 28 mm wide at z = +40 mm and 48 mm at
z = -60 mm, for example, puts the apex at z = +180 mm); the sensor looks towards -z. Each ray returns its first hit on the sphere, so only the side the sensor can
see is measured; hits outside the measuring range are dropped. Gaussian noise
is added to y and z of every point (isotropic in the laser plane); stray points
(reflections, edge points) are added to some profiles. Robot pose noise: the reported
pose is the true one with rotation ``exp(eps_r) R`` and translation ``t + eps_t``, both
errors in the base frame.

Time: the cell keeps the simulated world's true time (``clock``, a
:class:`~spherecal.sim.timeline.SimClock`) and the arm's motion over it (``timeline``,
a :class:`~spherecal.sim.timeline.MotionTimeline`, which a simulated controller extends
with every move), and the clocks of its two devices (``controller_clock``,
``sensor_clock``). A shot at the current pose (:meth:`SimulatedCell.measure_profile`
without a pose) takes ``exposure_s`` of it. Random numbers: each simulated device draws
from a generator of its own (:meth:`SimulatedCell.device_rng`,
:meth:`SimulatedCell.standstill_rng`), so that one device's draws never shift another's.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from spherecal.config import NoiseModel, RobotErrorModel
from spherecal.core import geometry as geo
from spherecal.devices.contract import SensorFieldOfView
from spherecal.core.models import SPHERE_FRAME, TRANSFORM_NAME, MountingMode, Pose
from spherecal.sim.objects import BallBar, SceneObject, Sphere
from spherecal.sim.rngs import device_rng
from spherecal.sim.robot_error import SimulatedArm
from spherecal.sim.timeline import DeviceClock, MotionTimeline, SimClock

#: Simulated time a shot at a standstill takes (a triggered exposure), s: the
#: nxSensor-I's default exposure (200 us); a sensor simulator that knows its own sets
#: ``SimulatedCell.exposure_s``.
DEFAULT_EXPOSURE_S = 200e-6
#: Where the devices' clocks start counting, s: the controller from its power-on an hour
#: before, the sensor from 1970 (2026-01-01 UTC), as :class:`~spherecal.config.ClockSettings`.
CONTROLLER_EPOCH_S = 3725.25
SENSOR_EPOCH_S = 1767225600.0


def device_clocks(seed: int | None) -> tuple[DeviceClock, DeviceClock]:
    """The controller's and the sensor's clocks of a cell seeded ``seed``: their epochs
    (:data:`CONTROLLER_EPOCH_S`, :data:`SENSOR_EPOCH_S`, 1.77e9 s apart), each a rate
    error of 10-50 ppm of either sign and a phase under a second, drawn from the
    stream of the device key "clocks"; stamp jitter 20 us (controller) and 10 us
    (sensor), as the stream simulation's defaults."""
    rng = device_rng(seed, "clocks")
    drift = rng.uniform(10.0, 50.0, 2) * rng.choice([-1.0, 1.0], 2)
    offset = rng.uniform(0.0, 1.0, 2)
    return (DeviceClock(float(offset[0]), float(drift[0]), CONTROLLER_EPOCH_S, 2e-5),
            DeviceClock(float(offset[1]), float(drift[1]), SENSOR_EPOCH_S, 1e-5))


def _field_of_view(fov, who: str) -> SensorFieldOfView:
    """``fov`` checked: a cell measures with the field of view its sensor declares; the
    simulator has none of its own."""
    if isinstance(fov, SensorFieldOfView):
        return fov
    if fov is None:
        raise TypeError(
            f"{who}: fov is required: the field of view of the sensor the cell simulates, a "
            "spherecal.devices.contract.SensorFieldOfView (a sensor type declares its own: "
            "PluginHost().registry.sensor_type(name).field_of_view); the simulator knows no sensor's"
        )
    raise TypeError(f"{who}: fov must be a spherecal.devices.contract.SensorFieldOfView, got {type(fov).__name__}")


class FanHits(NamedTuple):
    """What the laser fan sees at one flange pose, before noise.

    ``points_mm`` (N, 2) are (y, z) in the sensor's laser plane, in the sensor's column
    order; ``object_index`` (N,) says which of ``cell.objects`` each point lies on."""

    points_mm: np.ndarray
    object_index: np.ndarray


class SimulatedCell:
    """A scene of objects, a robot flange and a sensor with a known truth, in one mounting
    mode.

    ``true_transform`` is ``flange_from_sensor`` (eye-in-hand) or ``base_from_sensor``
    (eye-to-hand). The reference sphere (``sphere_centre_mm``, ``sphere_radius_mm``) is
    ``objects[0]``, fixed in base (eye-in-hand) or flange (eye-to-hand). More objects
    (:mod:`spherecal.sim.objects`: ball bars, plates, panels), each fixed in base or
    flange, join the scene with :meth:`add_object`; the fan sees the nearest surface
    along each ray (objects occlude each other). Simulated devices share one cell: the
    robot calls :meth:`move_flange_to`, the sensor :meth:`measure_profile`.

    What a simulated controller uses besides (docs/writing-a-robot-plugin.md, "A simulator
    of your own protocol"):

    - ``arm``: the simulated arm (:class:`~spherecal.sim.robot_error.SimulatedArm`), or
      None until :meth:`attach_arm` gives the cell one: ``true_flange_pose(joints_deg)`` is
      where its true geometry (with ``robot_error``) puts the flange, and
      ``nominal_flange_pose`` what its controller reports;
    - ``clock``: the simulated world's true time (:class:`~spherecal.sim.timeline.SimClock`),
      moved on by simulated events only;
    - ``timeline``: the arm's flange over that time
      (:class:`~spherecal.sim.timeline.MotionTimeline`): a controller's
      ``timeline.move_linear(target, speed_mm_s, orientation_speed_deg_s, joints_deg=...)``
      adds a move and its settle and advances ``clock``;
    - ``controller_clock``, ``sensor_clock``: the devices' clocks against true time
      (:class:`~spherecal.sim.timeline.DeviceClock`: ``stamp(T)``);
    - ``exposure_s``: the simulated time a shot takes;
    - :meth:`standstill_rng`, :meth:`device_rng`: a device's own random stream, so that a
      seeded run is the same whatever order the devices draw in; :attr:`rng` is the
      sensor's.
    """

    def __init__(
        self,
        mounting: MountingMode,
        true_transform: Pose,
        sphere_centre_mm,
        sphere_radius_mm: float,
        fov: SensorFieldOfView,
        noise: NoiseModel | None = None,
        seed: int | None = 0,
        base_from_flange: Pose | None = None,
        robot_error: RobotErrorModel | None = None,
    ):
        if mounting not in TRANSFORM_NAME:
            raise ValueError(f"mounting must be one of {sorted(TRANSFORM_NAME)}, got {mounting!r}")
        self.mounting = mounting
        self.true_transform = true_transform
        self.objects: list[SceneObject] = [
            Sphere(sphere_centre_mm, sphere_radius_mm, frame=SPHERE_FRAME[mounting], name="reference_sphere")
        ]
        self.fov = _field_of_view(fov, "SimulatedCell")
        self.noise = noise or NoiseModel()
        self.seed = seed
        #: The sensor's stream (profile noise and strays); the dataset simulators, which
        #: play no devices, draw the pose noise from it too (:meth:`report_pose`).
        self.rng = np.random.default_rng(seed)
        #: When True, every standstill draws its noise from generators seeded by (seed,
        #: pose), one per device: the same pose gives the same noisy readings whatever came
        #: before, so an interrupted and resumed simulated acquisition reproduces an
        #: uninterrupted one.
        self.noise_per_pose = False
        self.current_base_from_flange = base_from_flange or Pose.identity()
        #: The arm's geometric error (None: the arm is exactly its nominal model).
        self.robot_error = robot_error
        #: Set by :meth:`attach_arm`: the simulated arm with its true geometry.
        self.arm: SimulatedArm | None = None
        #: True time of the simulated world, s: moved on by simulated events only.
        self.clock = SimClock()
        #: The arm's flange over true time; a simulated controller appends its moves.
        self.timeline = MotionTimeline(self.current_base_from_flange, clock=self.clock)
        #: Simulated time a shot at a standstill takes, s.
        self.exposure_s = DEFAULT_EXPOSURE_S
        #: The controller's joints (deg) where the arm stands when a simulated controller
        #: starts: None for its home; a resumed run's last joints (the arm stayed where the
        #: interrupted run left it, as a real one does).
        self.arm_start_joints_deg: np.ndarray | None = None
        #: The devices' clocks against true time (seeded: the same seed, the same clocks).
        self.controller_clock, self.sensor_clock = device_clocks(seed)
        self._standstill_rngs: dict[str, np.random.Generator] = {}

    def attach_arm(self, kinematics) -> SimulatedArm:
        """Give the cell a robot arm described by a plugin's
        :class:`~spherecal.core.kinematics.ArmKinematics`. Its true geometry carries
        ``robot_error`` (drawn once, from the cell's seed unless the model has its own);
        simulated controllers and :func:`~spherecal.sim.simulate_dataset` then move the
        flange to where the true geometry puts it and report the nominal model's pose."""
        error = self.robot_error if self.robot_error is not None else RobotErrorModel(
            joint_zero_offset_deg=(0, 0), link_length_mm=(0, 0), link_offset_mm=(0, 0), axis_tilt_deg=(0, 0)
        )
        self.arm = SimulatedArm(kinematics, error, self.seed)
        return self.arm

    # scene -----------------------------------------------------------------------------
    @property
    def reference_sphere(self) -> Sphere:
        """The calibration sphere, ``objects[0]``."""
        return self.objects[0]

    @property
    def sphere_centre_mm(self) -> np.ndarray:
        """Reference sphere centre, mm, in base (eye-in-hand) or flange (eye-to-hand)."""
        return self.reference_sphere.centre_mm

    @sphere_centre_mm.setter
    def sphere_centre_mm(self, value) -> None:
        s = self.reference_sphere
        self.objects[0] = Sphere(value, s.radius_mm, frame=s.frame, name=s.name)

    @property
    def sphere_radius_mm(self) -> float:
        return self.reference_sphere.radius_mm

    @sphere_radius_mm.setter
    def sphere_radius_mm(self, value: float) -> None:
        s = self.reference_sphere
        self.objects[0] = Sphere(s.centre_mm, value, frame=s.frame, name=s.name)

    def add_object(self, obj: SceneObject) -> SceneObject:
        """Put ``obj`` (fixed in ``obj.frame``, 'base' or 'flange') into the scene; returns it."""
        if not isinstance(obj, SceneObject):
            raise TypeError(
                f"add_object: {obj!r} is not a scene object (it needs .frame, .name and "
                ".intersect(origins_mm, directions)); see spherecal.sim.objects"
            )
        if obj.frame not in ("base", "flange"):
            raise ValueError(f"add_object: {obj.name}: frame must be 'base' or 'flange', got {obj.frame!r}")
        self.objects.append(obj)
        return obj

    # geometry --------------------------------------------------------------------------
    def base_from_sensor(self, base_from_flange: Pose) -> Pose:
        """The true ``base_from_sensor`` at a true flange pose."""
        if self.mounting == "eye_in_hand":
            return base_from_flange @ self.true_transform
        return self.true_transform

    def frame_from_sensor(self, frame: str, base_from_flange: Pose) -> tuple[np.ndarray, np.ndarray]:
        """(R, t) of ``base_from_sensor`` or ``flange_from_sensor`` (``frame``) at a true flange pose."""
        X = self.true_transform
        if frame == "base":
            T = self.base_from_sensor(base_from_flange)
        elif frame == "flange":
            T = X if self.mounting == "eye_in_hand" else base_from_flange.inverse() @ X
        else:
            raise ValueError(f"frame must be 'base' or 'flange', got {frame!r}")
        return T.rotation_matrix, T.translation

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

    def fan_rays(self) -> tuple[np.ndarray, np.ndarray]:
        """The laser fan in the sensor frame: apex (3,) and unit directions (n_columns, 3)."""
        fov = self.fov
        angles = np.linspace(-fov.half_angle_rad, fov.half_angle_rad, fov.n_columns)
        d = np.column_stack([np.zeros_like(angles), np.sin(angles), -np.cos(angles)])
        return np.array([0.0, 0.0, fov.apex_z_mm]), d

    def cast_fan(self, base_from_flange: Pose) -> FanHits:
        """Noise-free hits of the fan at a true flange pose: the nearest surface along each
        ray over all objects, kept when its z lies in the measuring range."""
        apex, d = self.fan_rays()
        dist = np.full(len(d), np.inf)
        which = np.full(len(d), -1)
        frames: dict[str, tuple[np.ndarray, np.ndarray, np.ndarray]] = {}
        for k, obj in enumerate(self.objects):
            if obj.frame not in frames:
                R, t = self.frame_from_sensor(obj.frame, base_from_flange)
                frames[obj.frame] = (R, t, *geo.invert_rt(R, t))
            R, t, R_inv, t_inv = frames[obj.frame]
            spheres = [obj] if isinstance(obj, Sphere) else [obj.sphere_a, obj.sphere_b] if isinstance(obj, BallBar) else []
            if spheres:
                # the fan lies in the laser plane: cut each sphere there (in the sensor frame)
                s = np.full(len(d), np.inf)
                for sph in spheres:
                    s = np.minimum(s, sph.intersect_laser_plane(R_inv @ sph.centre_mm + t_inv, apex[1:], d[:, 1:]))
            else:
                d_f = d @ R.T
                s = np.asarray(obj.intersect(np.broadcast_to(R @ apex + t, d_f.shape), d_f), dtype=float)
            nearer = s < dist
            dist[nearer] = s[nearer]
            which[nearer] = k
        hit = np.isfinite(dist)
        s = dist[hit]
        pts = apex[1:] + s[:, None] * d[hit][:, 1:]
        fov = self.fov
        keep = (pts[:, 1] <= fov.z_near_mm) & (pts[:, 1] >= fov.z_far_mm)
        return FanHits(pts[keep], which[hit][keep])

    def ideal_profile(self, base_from_flange: Pose) -> np.ndarray:
        """Noise-free (N, 2) points (y, z) in mm the sensor sees at a true flange pose."""
        return self.cast_fan(base_from_flange).points_mm

    # measurement -----------------------------------------------------------------------
    def measure_profile(self, base_from_flange: Pose | None = None, exposure_s: float | None = None) -> np.ndarray:
        """A noisy profile (N, 2) in mm at the given true pose (default: where the robot
        is now: a shot, which takes ``exposure_s`` of simulated time, default the cell's
        :attr:`exposure_s`); empty when the sphere is out of view. The noise comes from
        :attr:`rng`, the sensor's stream."""
        if base_from_flange is None:
            self.clock.advance(self.exposure_s if exposure_s is None else exposure_s)
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

    def flange_pose_for_view(self, sensor_from_frame: Pose, frame: str) -> Pose:
        """The true ``base_from_flange`` that puts the sensor at ``sensor_from_frame``
        relative to ``frame`` ('base' in eye-in-hand, 'flange' in eye-to-hand: the frame
        the robot can move relative to the sensor)."""
        X = self.true_transform
        if self.mounting == "eye_in_hand" and frame == "base":
            return sensor_from_frame.inverse() @ X.inverse()
        if self.mounting == "eye_to_hand" and frame == "flange":
            return X @ sensor_from_frame
        raise ValueError(
            f"flange_pose_for_view: in {self.mounting} the robot cannot move the sensor relative to "
            f"frame {frame!r}; use {SPHERE_FRAME[self.mounting]!r}"
        )

    def sweep_poses(
        self,
        target_mm,
        frame: str,
        frame_from_sensor_rotation,
        half_length_mm: float,
        n_profiles: int,
        standoff_z_mm: float | None = None,
    ) -> list[Pose]:
        """True flange poses of a pure-translation sweep that carries ``target_mm`` (a point
        in ``frame``) through the laser plane along the sensor's x, from -half_length to
        +half_length, at sensor-frame (y, z) = (0, ``standoff_z_mm``; default the middle of
        the field of view's measuring range). The sensor's orientation relative to
        ``frame`` is ``frame_from_sensor_rotation`` (3x3)."""
        if standoff_z_mm is None:
            standoff_z_mm = self.fov.middle_z_mm
        R = geo.check_rotation_matrix(frame_from_sensor_rotation, "frame_from_sensor_rotation")
        target = np.asarray(target_mm, dtype=float).reshape(3)
        poses = []
        for x in np.linspace(-half_length_mm, half_length_mm, n_profiles):
            frame_from_sensor = Pose.from_rt(R, target - R @ np.array([x, 0.0, standoff_z_mm]))
            poses.append(self.flange_pose_for_view(frame_from_sensor.inverse(), frame))
        return poses

    def scan(self, true_poses: list[Pose]) -> tuple[list[Pose], list[np.ndarray]]:
        """Move the flange through ``true_poses``, measuring at each: returns the reported
        poses (with pose noise) and the noisy profiles (N_i, 2), empty ones included."""
        reported, profiles = [], []
        for pose in true_poses:
            self.move_flange_to(pose)
            profiles.append(self.measure_profile())
            reported.append(self.report_pose(pose))
        return reported, profiles

    def report_pose(self, true_base_from_flange: Pose, rng: np.random.Generator | None = None) -> Pose:
        """The pose a robot controller would report: the true one plus pose noise, drawn
        from ``rng`` (a simulated controller passes its own,
        ``standstill_rng("controller")``; default the cell's :attr:`rng`, which the
        dataset simulators share between pose and profile noise)."""
        n = self.noise
        rng = self.rng if rng is None else rng
        R = true_base_from_flange.rotation_matrix
        t = true_base_from_flange.translation
        if n.pose_rotation_noise_deg > 0:
            R = geo.matrix_from_rotvec(rng.normal(0, np.radians(n.pose_rotation_noise_deg), 3)) @ R
        if n.pose_translation_noise_mm > 0:
            t = t + rng.normal(0, n.pose_translation_noise_mm, 3)
        return Pose.from_rt(R, t)

    def move_flange_to(self, true_base_from_flange: Pose) -> None:
        """Where the (simulated) robot has put its flange: a new standstill."""
        self.current_base_from_flange = true_base_from_flange
        if self.noise_per_pose:
            self._standstill_rngs.clear()
            self.rng = np.random.default_rng([self.seed or 0, *self._pose_key()])

    def _pose_key(self) -> list[int]:
        """The current standstill's pose as non-negative integers (0.1 um, 1e-4 of a
        quaternion component)."""
        pose = self.current_base_from_flange
        key = np.round(np.concatenate([pose.translation_mm, pose.quaternion_wxyz]) * 1e4).astype(np.int64)
        return [int(k) & 0xFFFFFFFF for k in key]

    def device_rng(self, device: str) -> np.random.Generator:
        """A generator for the simulated device named ``device`` ("controller", "sensor
        stream", "pose stream", ...): its own stream, spawned from the cell's seed by the
        name (:func:`spherecal.sim.rngs.device_rng`), whatever the other devices draw.
        Each call starts the stream afresh: a device asks once and keeps it."""
        return device_rng(self.seed, device)

    def standstill_rng(self, device: str) -> np.random.Generator:
        """The generator ``device`` draws a standstill's noise from (a controller's pose
        noise). With :attr:`noise_per_pose`, one per device and standstill, from (seed,
        device, pose): the same pose gives the same reading whatever came before; else
        the device's one stream for the cell's life."""
        rng = self._standstill_rngs.get(device)
        if rng is None:
            keys = self._pose_key() if self.noise_per_pose else []
            rng = self._standstill_rngs[device] = device_rng(self.seed, device, *keys)
        return rng

    @property
    def transform_name(self) -> str:
        return TRANSFORM_NAME[self.mounting]


def _rot(rotvec_deg) -> np.ndarray:
    return geo.matrix_from_rotvec(np.radians(rotvec_deg))


#: Fractions of the reach-scaled layout tried, in order, until the arm reaches the default plan.
LAYOUT_SHRINK = (1.0, 0.9, 0.8, 0.7, 0.6)


def _reaches_default_plan(arm, cell: "SimulatedCell") -> bool:
    """Whether the arm's inverse kinematics reaches every target of the default plan on
    ``cell``, each from the last one's joints (the first from each of the seeds of
    :func:`~spherecal.core.kinematics.ik_seeds_deg`: the arm's home first)."""
    from spherecal.core.errors import InputError
    from spherecal.core.kinematics import ik_seeds_deg
    from spherecal.motion.planning import plan_stations

    targets = [p for _, poses in plan_stations(cell.mounting, cell.true_transform, cell.sphere_centre_mm,
                                              cell.sphere_radius_mm, field_of_view=cell.fov) for p in poses]
    for seed in ik_seeds_deg(arm):
        try:
            q = seed
            for pose in targets:
                q = arm.joints_from_flange_pose(pose, q)
            return True
        except InputError:
            continue
    return False


#: The arm the standard cell is drawn for (an IRB 2400-class arm): its reach
#: (:func:`spherecal.core.kinematics.chain_reach_mm` within its joint limits) and its shoulder
#: (the second joint's origin at zero joints), base frame, mm.
REFERENCE_REACH_MM = 1556.7908961103235
REFERENCE_SHOULDER_MM = (100.0, 0.0, 615.0)


def arm_layout(kinematics) -> tuple[float, np.ndarray]:
    """(reach in mm, shoulder position in base, mm) of a robot plugin's arm
    (:class:`~spherecal.core.kinematics.ArmKinematics`), for laying a cell out for it: its
    ``reach_mm`` when it has one, else :func:`~spherecal.core.kinematics.chain_reach_mm` of
    its chain within ``model_joint_limits_rad()`` when it has them; the shoulder is the
    second joint's origin at zero joints (the first's for a one-joint arm)."""
    from spherecal.core.kinematics import chain_reach_mm

    chain = kinematics.chain
    reach = getattr(kinematics, "reach_mm", None)
    if reach is None:
        limits = getattr(kinematics, "model_joint_limits_rad", None)
        reach = chain_reach_mm(chain, limits() if callable(limits) else None)
    T = chain.placements[0] @ chain.placements[1] if chain.n_joints > 1 else chain.placements[0]
    return float(reach), T[:3, 3].copy()


def standard_cell(
    mounting: MountingMode = "eye_in_hand",
    seed: int | None = 0,
    noise: NoiseModel | None = None,
    fov: SensorFieldOfView | None = None,
    sphere_radius_mm: float = 19.1,
    robot_error: RobotErrorModel | None = None,
    arm=None,
    reach_mm: float | None = None,
    shoulder_mm=None,
) -> SimulatedCell:
    """A cell with a generic (not axis-aligned) true transform, laid out for an arm's reach.

    For the reference arm (an IRB 2400-class arm, :data:`REFERENCE_REACH_MM`, shoulder at
    :data:`REFERENCE_SHOULDER_MM`); the sensor looks towards its own -z (module
    docstring). Eye-in-hand: the sensor sits about 160 mm out from the flange and looks
    along the flange's +z, away from the flange; the sphere stands at (1100, 150, 400) mm
    in base. Eye-to-hand: the sensor frame's origin is at about (1250, -200, 900) mm in
    base with its z axis pointing down, so the sensor looks **up** (along base +z, within
    6 deg), and the robot, reaching down, holds the sphere above it on a 150 mm stylus on
    the flange's z axis.

    For another arm (``reach_mm`` and ``shoulder_mm``, base frame, mm; by default those of
    ``arm``, :func:`arm_layout`) the points fixed in base (the eye-in-hand sphere, the
    eye-to-hand sensor) are the reference's, scaled about the shoulder by the ratio of
    the reaches: the same place in the arm's workspace. What the flange carries (the
    sensor's mounting, the stylus) does not change. With ``arm`` given, the layout is
    moved in towards the shoulder (by :data:`LAYOUT_SHRINK` steps) until the arm's inverse
    kinematics reaches every target of the default plan (an arm with a long wrist, such as
    a UR5, reaches less of its sphere of reach with a tilted flange).

    ``arm`` (a robot plugin's :class:`~spherecal.core.kinematics.ArmKinematics`) also attaches
    a simulated arm, with ``robot_error`` in its true geometry when given.

    ``fov`` is required: the field of view of the sensor the cell simulates, as its sensor
    type declares it (:attr:`spherecal.devices.contract.SensorType.field_of_view`); a TypeError
    without one (the simulator knows no sensor's)."""
    fov = _field_of_view(fov, "standard_cell")
    if arm is not None and reach_mm is None:
        reach_mm, arm_shoulder = arm_layout(arm)
        shoulder_mm = arm_shoulder if shoulder_mm is None else shoulder_mm
        for shrink in LAYOUT_SHRINK:
            cell = standard_cell(mounting, seed, noise, fov, sphere_radius_mm, None, None, reach_mm * shrink, shoulder_mm)
            if _reaches_default_plan(arm, cell):
                break
        cell.robot_error = robot_error
        cell.attach_arm(arm)
        return cell
    ref_shoulder = np.asarray(REFERENCE_SHOULDER_MM)
    if reach_mm is None:
        scale, shoulder = 1.0, ref_shoulder
    else:
        if not (np.isfinite(reach_mm) and reach_mm > 0):
            raise ValueError(f"standard_cell: reach_mm must be a positive length, got {reach_mm!r}")
        scale = float(reach_mm) / REFERENCE_REACH_MM
        shoulder = ref_shoulder if shoulder_mm is None else np.asarray(shoulder_mm, dtype=float).reshape(3)

    def in_base(point_mm) -> np.ndarray:  # a point fixed in base, for this arm
        return shoulder + scale * (np.asarray(point_mm, dtype=float) - ref_shoulder)

    if mounting == "eye_in_hand":
        R = _rot([180.0, 0.0, 0.0]) @ _rot([2.0, -4.0, 31.0])
        X = Pose.from_rt(R, [42.5, -18.3, 163.7])
        centre = in_base([1100.0, 150.0, 400.0])
    else:
        R = _rot([0.0, 180.0, 0.0]) @ _rot([3.0, 5.0, -20.0])
        X = Pose.from_rt(R, in_base([1250.0, -200.0, 900.0]))
        centre = [4.2, -2.7, 151.3]
    cell = SimulatedCell(mounting, X, centre, sphere_radius_mm, fov=fov, noise=noise, seed=seed, robot_error=robot_error)
    if arm is not None:
        cell.attach_arm(arm)
    elif robot_error is not None:
        raise ValueError("standard_cell: robot_error needs an arm (a robot plugin's kinematics) to act on")
    return cell
