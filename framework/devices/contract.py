"""What the core expects of a robot and of a sensor, and how a plugin describes one.

The core talks to devices only through these interfaces; it never imports a plugin.
A plugin registers a :class:`RobotType` or :class:`SensorType` (a name, a pydantic
configuration model and a factory) through the ``spherecal_register_devices`` hook, one
of the hooks in :mod:`spherecal.plugins.hookspecs`. A robot that streams its pose while
it moves also implements :class:`PoseStreamingRobot` (:mod:`spherecal.devices.pose_streaming`,
re-exported here). Plugins import these names from :mod:`spherecal.plugins`; :class:`SensorFieldOfView` and :class:`SensorBody` are value
objects of :mod:`spherecal.core.field_of_view`, re-exported here.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, Callable, Protocol, Sequence, runtime_checkable

import numpy as np
from pydantic import BaseModel

from spherecal.core.errors import DeviceError
from spherecal.core.field_of_view import SensorBody, SensorFieldOfView
from spherecal.core.models import Pose, Profile
from spherecal.devices.pose_streaming import (PoseStreamClockError, PoseStreamCounts, PoseStreamError,
                                              PoseStreamingRobot, PoseStreamStalled)
from spherecal.io.runlog import progress_log

if TYPE_CHECKING:  # pragma: no cover
    from spherecal.core.kinematics import ArmKinematics
    from spherecal.core.streams import ProfileStream  # (not loaded by a dataset's solve)

__all__ = ["IDENTITY_KEYS", "POSE_STREAM_SOURCE_KEY", "RESERVED_OPTION_NAMES", "SIM_CLOCK_KEY",
           "SIM_CONTROLLER_CLOCK_KEY", "SIM_NOW_KEY", "SIM_PROFILE_SOURCE_KEY", "SIM_SENSOR_CLOCK_KEY",
           "ControllerFrame", "DeviceContext", "PoseStreamClockError",
           "PoseStreamCounts", "PoseStreamError", "PoseStreamStalled", "PoseStreamingRobot", "ProfileStreamCounts",
           "ProfileStreamError", "ProfileStreamingSensor", "Robot", "RobotType", "Sensor", "SensorBody",
           "SensorFieldOfView", "SensorType", "device_identity"]

_LOG = progress_log("devices")  # the default ``log``: logger spherecal.devices


@runtime_checkable
class Robot(Protocol):
    """A connected robot. Poses are ``base_from_flange`` (the flange in the robot's base
    frame, as its controller reports them), mm, quaternion (w, x, y, z).

    Besides the four methods below a robot may have ``check_target(base_from_flange,
    speed_mm_s) -> None``: a pre-motion check of one planned target against the robot's
    own limits (reach, joint limits, workspace, speed) that moves nothing and raises a
    :class:`~spherecal.core.errors.SpherecalError` naming the limit. A robot that has it joins
    the plan check: ``calibrate`` (``--dry-run`` too), ``validate`` and ``scan`` call it for
    every target of an automatic plan before the first motion, and refuse the whole plan, listing
    each target at fault, when one fails. Without it only the configured limits
    (``[acquisition]``) are checked before motion, and the robot's own limits only when
    ``move_linear`` refuses a move. Likewise optional, ``check_move(base_from_flange,
    speed_mm_s) -> None`` checks the straight move from wherever the arm stands now to the
    target (the limits ``move_linear`` checks before sending it, along the path) without
    moving, raising the same way; the same commands call it for the first move of a run
    (or of a resumed run) before the first motion. Both are optional so that the runtime
    protocol check (``isinstance(device, Robot)``) does not require them."""

    def read_flange_pose(self) -> Pose:
        """The flange pose now (robot standing still), ``base_from_flange``."""

    def read_joints_deg(self) -> np.ndarray | None:
        """Joint readings in degrees, controller convention, or None if not available."""

    def move_linear(self, base_from_flange: Pose, speed_mm_s: float) -> None:
        """Move the flange in a straight line to the target and return when in position.
        ``speed_mm_s`` limits the speed of the context's ``tool_point_mm`` (the sensor),
        not only the flange's, where the robot can. Limits (speed, workspace) are checked
        before anything is sent."""

    def close(self) -> None:
        """Release the connection. Safe to call twice."""


@runtime_checkable
class Sensor(Protocol):
    """A connected laser line sensor. Profiles are (y, z) in the sensor frame, mm."""

    def read_profile(self) -> Profile | None:
        """One profile on request, taken now (never one of an earlier call); None when
        the line sees nothing valid. Its optional ``shot_id`` is the sensor's name for
        the shot, kept in the journal for audits."""

    def close(self) -> None:
        """Release the device. Safe to call twice."""


@dataclass(frozen=True)
class ProfileStreamCounts:
    """What one profile stream took: ``received`` frames kept, ``lost`` frames the sensor
    numbered but that never arrived (the gaps in its frame counter), ``late`` frames the
    sensor exposed later than their slot in its own schedule (kept: their stamps say
    when). Counts, unitless."""

    received: int = 0
    lost: int = 0
    late: int = 0


class ProfileStreamError(DeviceError):
    """A profile stream ended abnormally (no frame for too long, the device failed, its
    clock or counter broke the stream's time line). The message names the cause;
    ``taken`` holds the :class:`~spherecal.core.streams.ProfileStream` of the frames
    received before it (None when there were none) and ``counts`` its
    :class:`ProfileStreamCounts`, so that the caller keeps what was taken and says what
    was not."""

    def __init__(self, message: str, taken: ProfileStream | None = None,
                 counts: ProfileStreamCounts | None = None):
        super().__init__(message)
        self.taken = taken
        self.counts = counts or ProfileStreamCounts()


@runtime_checkable
class ProfileStreamingSensor(Sensor, Protocol):
    """A sensor that can also stream profiles at a rate, each stamped by its own clock
    (optional: the core asks ``isinstance(sensor, ProfileStreamingSensor)`` before an
    on-the-fly acquisition).

    Between :meth:`start_profile_stream` and :meth:`stop_profile_stream` the sensor keeps
    its input drained by itself (the caller moves the robot meanwhile). The profiles come
    back as a :class:`~spherecal.core.streams.ProfileStream`: ``t_sensor_s`` the middle of
    each exposure in seconds of the sensor's clock (monotonic: a wrapping hardware counter
    is unwrapped), ``points_yz_mm`` and ``start`` the profiles ((y, z) mm in the sensor
    frame; a profile that saw nothing has no points), ``frame`` the sensor's frame
    counters, increasing, whose gaps are the lost frames."""

    #: The counts of the last stream stopped (all zero before the first).
    profile_stream_counts: ProfileStreamCounts

    def start_profile_stream(self, rate_hz: float | None = None) -> None:
        """Start streaming at ``rate_hz`` (None: the sensor's configured rate). Raises
        :class:`~spherecal.core.errors.DeviceError` when a stream already runs or the
        sensor refuses."""

    def stop_profile_stream(self) -> ProfileStream:
        """Stop, take the frames still in flight, and return the stream. A stream that
        ended abnormally raises :class:`ProfileStreamError` here, with what was taken."""


# The keys of ``DeviceContext.extras`` under which a simulated run (``spherecal.sim.live``)
# gives simulated streaming devices the simulated world's time, the arm's motion and the
# devices' clocks. A plugin reads them with ``context.extras.get(KEY)`` (absent on
# hardware and when a test builds its own context); one that knows none ignores them. A
# simulated device may instead read the same from ``context.cell`` (``cell.clock``,
# ``cell.timeline``, ``cell.controller_clock``, ``cell.sensor_clock``).

POSE_STREAM_SOURCE_KEY = "pose_stream_source"
"""``source(T_true_s (N,)) -> (R (N, 3, 3), t_mm (N, 3), joints_deg (N, J) or None)``:
what the robot's controller reports at simulated true times (``base_from_flange``, mm;
the cell's ``timeline.reported_at``), for a simulated pose stream."""

SIM_CLOCK_KEY = "sim_clock"
"""``clock() -> T_true_s``: the simulated true time now, s (the cell's ``clock.now_s``)."""

SIM_CONTROLLER_CLOCK_KEY = "sim_controller_clock"
"""The controller's clock: an object with ``stamp(T_true_s)`` (seconds of the controller's
clock) and ``rate`` (its seconds per true second), the cell's ``controller_clock``."""

SIM_NOW_KEY = "sim_now_s"
"""``now_s() -> T_true_s``: the simulated true time now, s (what :data:`SIM_CLOCK_KEY`
gives, under the name a simulated sensor asks for)."""

SIM_SENSOR_CLOCK_KEY = "sim_sensor_clock"
"""The sensor's clock as its hardware counts it: an object with ``to_sensor_s(T_true_s)``
and ``to_true_s(t_sensor_s)``, seconds."""

SIM_PROFILE_SOURCE_KEY = "sim_profile_source"
"""``source(T_true_s) -> (N, 2)``: the profile, (y, z) mm in the sensor frame, the sensor
sees at a simulated true time (where the flange truly is, with the cell's point noise)."""


@dataclass
class DeviceContext:
    """What the host hands a device factory besides its own configuration.

    ``cell`` is set when the run is simulated: a :class:`spherecal.sim.SimulatedCell`, of
    which simulated devices are views (the robot moves its flange, the sensor measures the
    sphere from there), so they stay consistent without knowing about each other. (The
    simulator sits above the devices' layer, so the annotation does not name its class.)

    ``extras`` holds objects a configuration cannot name, handed to the factory
    untouched: a test's stand-in for a controller, or, in a simulated run, the simulated
    world's time, motion and clocks under :data:`POSE_STREAM_SOURCE_KEY`,
    :data:`SIM_CLOCK_KEY`, :data:`SIM_CONTROLLER_CLOCK_KEY` (for a pose stream),
    :data:`SIM_NOW_KEY`, :data:`SIM_SENSOR_CLOCK_KEY` and :data:`SIM_PROFILE_SOURCE_KEY`
    (for a profile stream)."""

    cell: Any = None
    log: Callable[[str], None] = _LOG
    extras: dict[str, Any] = field(default_factory=dict)
    #: The point the flange carries whose speed a move's ``speed_mm_s`` limits, flange
    #: frame, mm: the sensor's origin (eye-in-hand) or the sphere's centre (eye-to-hand),
    #: from the configuration. A robot that can should limit every move's speed at this
    #: point (a reorientation moves it faster than the flange); None: at the flange.
    tool_point_mm: tuple[float, float, float] | None = None


@dataclass(frozen=True)
class RobotType:
    """A kind of robot a plugin provides.

    ``factory(config, context)`` returns a connected :class:`Robot`; ``config`` is an
    instance of ``config_model`` validated by the host. ``flange_pose_from_joints`` is
    the forward kinematics ``joints_deg -> base_from_flange`` (or None when the robot
    only reports poses); the core uses it for observations that carry joints only.
    ``arm_kinematics(config)`` describes the arm's nominal geometry as an
    :class:`~spherecal.core.kinematics.ArmKinematics` (or None when unknown). It unlocks
    the simulated cell laid out for the arm's reach, whose simulated arm carries a real
    arm's geometric error (``[simulation.robot_error]``) and gives the joints of simulated
    runs and recordings; the kinematic planner; and the kinematic calibration of the arm
    (the estimator models the robot's error through its chain)."""

    name: str
    config_model: type[BaseModel]
    factory: Callable[[BaseModel, DeviceContext], Robot]
    description: str = ""
    flange_pose_from_joints: Callable[[BaseModel, np.ndarray], Pose] | None = None
    arm_kinematics: Callable[[BaseModel], "ArmKinematics"] | None = None
    #: ``read_frame(text) -> ControllerFrame | None``: reads a frame as this robot's
    #: controller writes it (a tool or work-object data line), for ``compare
    #: --controller-frame`` and ``validate --controller-frame``. Returns None when the text
    #: is not in its controller's syntax; raises :class:`~spherecal.core.errors.InputError`
    #: naming the field at fault when it is but is malformed. None: this robot type reads
    #: no such text.
    read_frame: Callable[[str], "ControllerFrame | None"] | None = None
    #: The arm's home: the joints (controller convention, deg) where the core seeds inverse
    #: kinematics when the arm's own joints are not known (the kinematic planner and its
    #: check before the robot is connected, a simulated arm's first target, a simulated
    #: controller that is given no start). A sequence, or ``home_joints_deg(config)``
    #: returning one (or None). Choose joints in the working region away from
    #: singularities (elbow and wrist bent). None: zero joints, then a few spread seeds
    #: (:func:`~spherecal.core.kinematics.ik_seeds_deg`); an arm whose zero joints are a
    #: singularity (a stretched elbow) should declare one.
    home_joints_deg: "Sequence[float] | Callable[[BaseModel], Sequence[float] | None] | None" = None
    #: Another name for ``--controller-frame`` in the words of this controller's users
    #: (without the dashes: lower case letters, digits and ``-``, starting with a letter),
    #: which ``compare`` and ``validate`` then accept too; it needs :attr:`read_frame`.
    #: Several robot types may give the same name. None: only ``--controller-frame``.
    frame_option: str | None = None


#: Option names of ``spherecal compare`` and ``validate`` (and the global ones), which a
#: robot type's :attr:`RobotType.frame_option` must not take.
RESERVED_OPTION_NAMES = frozenset({
    "help", "version", "debug", "out", "no-report", "yes", "transform", "controller-frame", "std-mm", "std-deg",
    "threshold-mm", "threshold-deg", "significance", "uncertainty", "fail-on-drift", "json", "verbose", "quiet",
})


@dataclass(frozen=True)
class SensorType:
    """A kind of sensor a plugin provides; ``factory(config, context)`` returns a
    connected :class:`Sensor`. ``field_of_view`` is the sensor's
    :class:`SensorFieldOfView` (None: not declared; a simulated run must then give all of
    it in ``[simulation.fov]`` and a calibration ``[acquisition.sweep] standoff_z_mm``).
    ``body`` is the sensor's housing as a box in its frame, :class:`SensorBody`, which the
    keep-out check before motion holds away from the sphere and its stand (None: not
    declared; the configuration's ``[keep_out.sensor_body]`` gives it, else the check is
    not made and the run says so)."""

    name: str
    config_model: type[BaseModel]
    factory: Callable[[BaseModel, DeviceContext], Sensor]
    description: str = ""
    field_of_view: SensorFieldOfView | None = None
    body: SensorBody | None = None


@dataclass(frozen=True)
class ControllerFrame:
    """A calibrated frame as a robot controller stores it, read by the robot plugin that
    knows the controller's syntax (:attr:`RobotType.read_frame`).

    ``transform_name`` is ``flange_from_sensor`` (a robot-held tool) or
    ``base_from_sensor`` (a fixed frame, read in the controller's world frame, taken as
    the robot's base); ``pose`` the transform (mm, quaternion (w, x, y, z)); ``kind`` what
    the text was (the controller's name for its data type), ``name`` the declared name if the text declared
    one, ``note`` an assumption the reader made, for the user."""

    transform_name: str
    pose: Pose
    kind: str
    name: str | None = None
    note: str = ""


#: Keys :func:`device_identity` keeps from a device's ``identity()``, in this order.
IDENTITY_KEYS = ("manufacturer", "model", "serial_number", "firmware", "controller")


def device_identity(device: Any) -> dict[str, str]:
    """What a connected robot or sensor says it is, for the report and the result's
    provenance (traceability): the device's optional ``identity()`` method, which returns
    a mapping with any of :data:`IDENTITY_KEYS` (strings: ``manufacturer``, ``model``,
    ``serial_number``, ``firmware``, ``controller``). A device without the method, or
    whose method fails, reports nothing (an empty dict): identity is informative and never
    stops a run. Other keys and empty values are dropped; values are cut to 200
    characters."""
    method = getattr(device, "identity", None)
    if not callable(method):
        return {}
    try:
        found = method()
    except Exception:  # noqa: BLE001 - informative only: a failing identity() must not stop a run
        return {}
    if not isinstance(found, dict):
        return {}
    return {k: str(found[k])[:200] for k in IDENTITY_KEYS if found.get(k) not in (None, "")}
