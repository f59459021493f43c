"""The plugin API: everything a robot, sensor or exporter plugin may rely on, and only that.

A plugin imports from ``spherecal.plugins`` alone (the built-in plugins in
``spherecal.robots`` and ``spherecal.sensors`` do, and a test holds them to it); the
modules behind these names may move between releases, these names stay. What it holds:

- the markers :data:`hookimpl` and :data:`hookspec`, the hooks (:mod:`.hookspecs`, the
  module: ``spherecal.plugins.hookspecs``) and the registries a plugin adds to
  (:class:`DeviceRegistry`, :class:`ExporterRegistry`);
- the devices' contract: :class:`Robot`, :class:`Sensor`, :class:`RobotType`,
  :class:`SensorType`, :class:`DeviceContext`, :class:`ControllerFrame`,
  :func:`device_identity`, the optional streaming contract
  (:class:`ProfileStreamingSensor`, :class:`ProfileStreamCounts`, :class:`ProfileStreamError`,
  :class:`ProfileStream`), and the value objects :class:`SensorFieldOfView`,
  :class:`SensorBody` and :class:`WorkspaceBox`;
- pose streaming, for a robot that streams its pose while it moves:
  :class:`PoseStreamingRobot`, :class:`PoseStream` (what a stream gives),
  :class:`PoseStreamCounts` and the errors :class:`PoseStreamError`,
  :class:`PoseStreamStalled`, :class:`PoseStreamClockError`; for a stream computed from
  the programmed line (not measured), the text its ``assumption`` starts with
  (:data:`PROGRAMMED_LINE_ASSUMPTION`);
- robot safety whatever the protocol: :class:`MotionSafety` (speed at the tool point,
  workspace box, reach along the path, the first move from where the arm stands, the
  controller's frame), :class:`MotionLimits`, :class:`FrameOffset`;
- kinematics: :class:`ArmKinematics`, :class:`SerialChain`, the URDF chain
  (:func:`read_urdf_chain`, :func:`chain_from_urdf`, :func:`chain_inverse_kinematics`),
  where inverse kinematics starts when no joints are known (:func:`ik_seeds_deg`,
  :func:`joints_from_home`: the home a robot type declares)
  and the rotation helpers (:func:`matrix_from_rotvec`, ...);
- the spherecal line protocol, both ends: :mod:`line_protocol` (the module), the PC side
  (:class:`LineRobot`, :class:`LineLinkSettings`, :class:`TcpLink`) and the simulated
  controller's server (:class:`SimulatedController`, :class:`ControllerServer`,
  :class:`SimulatedControllerSettings`, :func:`start_controller`);
- exporters: the contract (:class:`Exporter`, :class:`ExportNote`, :func:`red_warning`,
  :func:`calibrated_model_warning`, :func:`sensor_frame_warning`)
  and the formatting helpers of the core's exports (:func:`fixed`, :data:`MM_DECIMALS`, ...);
- the errors and data models plugins use (:class:`Pose`, :class:`Profile`,
  :class:`Dataset`, :class:`CalibrationResult`, :class:`DeviceError`, ...), the
  ``base_dir`` validation-context key (:data:`BASE_DIR_CONTEXT_KEY`), the host
  (:class:`PluginHost`, for a plugin's tests), the simulated cell and planner a plugin's
  tests run on, the simulated world's time for a simulated streaming device
  (:class:`SimClock`, :class:`MotionTimeline` and its :meth:`~MotionTimeline.sample`,
  :class:`DeviceClock`, :class:`SmoothNoise`, :class:`Samples`) and the devices' own
  random streams (:func:`device_rng`), the keys under which a simulated run hands a
  factory the simulated world's time, motion and clocks in ``DeviceContext.extras``
  (:data:`POSE_STREAM_SOURCE_KEY`, :data:`SIM_CLOCK_KEY`, :data:`SIM_CONTROLLER_CLOCK_KEY`
  for a pose stream; :data:`SIM_NOW_KEY`, :data:`SIM_SENSOR_CLOCK_KEY`,
  :data:`SIM_PROFILE_SOURCE_KEY` for a profile stream), a simulated device's server for a
  protocol of one's own (:class:`SimulatedDeviceServer`, :func:`line_frames`), and
  :func:`lazy_attributes` (names a package defines on first use).

What a robot author uses, and what each unlocks (docs/writing-a-robot-plugin.md; its
worked example, ``examples/third_party_plugin``, drives an arm over a TCP protocol of
its own):

- :class:`MotionSafety` with :class:`MotionLimits` and :class:`WorkspaceBox`: every move
  checked before anything is sent, whatever the protocol (the speed at the tool point,
  the box at both ends, reach along the path by inverse kinematics from the joints read
  now, the first move, the controller's frame); the robot joins the run's plan check.
- :class:`ArmKinematics` (a protocol: ``chain``, ``model_joints_rad``,
  ``flange_pose_from_joints``, ``joints_from_flange_pose``): given as
  ``RobotType(arm_kinematics=...)`` it unlocks the simulated cell laid out for the arm's
  reach and moving its simulated arm (``SimulatedCell.arm``, with a real arm's geometric
  error), joints in simulated runs and recordings, the kinematic planner and the
  kinematic calibration of the arm's geometry; its two kinematic methods are what
  :class:`MotionSafety` needs for the reach checks. Build one from a URDF
  (:func:`read_urdf_chain`, a :class:`UrdfChain`; :func:`chain_inverse_kinematics`, raising
  :class:`IkNotConverged`) or by hand (:class:`SerialChain`).
- ``RobotType(flange_pose_from_joints=...)``: observations that carry joints only are
  solved, and the robot harness checks reported joints against the reported pose.
- The simulated world a simulated controller runs on: :class:`SimulatedCell` (its
  ``arm``, ``timeline``, a :class:`MotionTimeline` whose ``move_linear`` advances
  ``clock``, a :class:`SimClock`; ``controller_clock``, a :class:`DeviceClock`;
  ``standstill_rng(name)`` and ``device_rng(name)``, a device's own random stream), and
  :class:`SimulatedDeviceServer` to serve it over TCP or UDP. A controller speaking the
  line protocol has one ready: :class:`SimulatedController` behind :class:`ControllerServer`
  (:func:`start_controller`, :class:`SimulatedControllerSettings`, :class:`Faults`).
- Streaming, optional: a robot that streams its pose while it moves is a
  :class:`PoseStreamingRobot` (giving a :class:`PoseStream`), a sensor that streams
  profiles a :class:`ProfileStreamingSensor` (giving a :class:`ProfileStream`): what an
  on-the-fly acquisition asks its devices for.

Importing this package is cheap: every name but the markers and constants loads on first
use (PEP 562), so that ``spherecal --help`` and ``spherecal plugins`` load nothing a
command does not use. :mod:`spherecal.plugins.testing` holds the pytest fixtures for
plugin authors (a ``pytest11`` entry point: no import needed).

A plugin module marks its hook implementations with :data:`hookimpl`::

    from spherecal.plugins import RobotType, hookimpl

    @hookimpl
    def spherecal_register_devices(registry):
        registry.add_robot(RobotType(...))
"""

from __future__ import annotations

import importlib
from typing import Any

from spherecal.core.lazy import lazy_attributes
from spherecal.plugins.markers import ENTRY_POINT_GROUP, PROJECT_NAME, hookimpl, hookspec

#: name -> the module that defines it (loaded on first use)
_WHERE = {
    # the host and the registries
    "PluginHost": ".host",
    "DeviceRegistry": ".registry",
    "ExporterRegistry": ".registry",
    "DISABLE_AUTOLOAD_ENV": ".registry",
    "EXPORT_RUN_KEY": ".registry",
    "TYPE_KEY": ".registry",
    # the devices' contract and its value objects
    "ControllerFrame": "spherecal.devices.contract",
    "DeviceContext": "spherecal.devices.contract",
    "IDENTITY_KEYS": "spherecal.devices.contract",
    "RESERVED_OPTION_NAMES": "spherecal.devices.contract",
    "Robot": "spherecal.devices.contract",
    "RobotType": "spherecal.devices.contract",
    "Sensor": "spherecal.devices.contract",
    "SensorType": "spherecal.devices.contract",
    "device_identity": "spherecal.devices.contract",
    # what a simulated run puts in DeviceContext.extras for simulated streaming devices
    "POSE_STREAM_SOURCE_KEY": "spherecal.devices.contract",
    "SIM_CLOCK_KEY": "spherecal.devices.contract",
    "SIM_CONTROLLER_CLOCK_KEY": "spherecal.devices.contract",
    "SIM_NOW_KEY": "spherecal.devices.contract",
    "SIM_PROFILE_SOURCE_KEY": "spherecal.devices.contract",
    "SIM_SENSOR_CLOCK_KEY": "spherecal.devices.contract",
    "PoseStreamingRobot": "spherecal.devices.pose_streaming",
    "PoseStreamCounts": "spherecal.devices.pose_streaming",
    "PoseStreamError": "spherecal.devices.pose_streaming",
    "PoseStreamStalled": "spherecal.devices.pose_streaming",
    "PoseStreamClockError": "spherecal.devices.pose_streaming",
    "PoseStream": "spherecal.core.streams",
    "PROGRAMMED_LINE_ASSUMPTION": "spherecal.core.streams",
    "ProfileStreamCounts": "spherecal.devices.contract",
    "ProfileStreamError": "spherecal.devices.contract",
    "ProfileStreamingSensor": "spherecal.devices.contract",
    "ProfileStream": "spherecal.core.streams",
    "SensorBody": "spherecal.core.field_of_view",
    "SensorFieldOfView": "spherecal.core.field_of_view",
    "WorkspaceBox": "spherecal.core.workspace",
    # robot safety, whatever the protocol
    "FrameOffset": "spherecal.devices.motion_safety",
    "MIN_SPEED_MM_S": "spherecal.devices.motion_safety",
    "MotionLimits": "spherecal.devices.motion_safety",
    "MotionSafety": "spherecal.devices.motion_safety",
    # kinematics and rotations
    "ArmKinematics": "spherecal.core.kinematics",
    "SerialChain": "spherecal.core.kinematics",
    "chain_reach_mm": "spherecal.core.kinematics",
    "ik_seeds_deg": "spherecal.core.kinematics",
    "arm_joint_names": "spherecal.core.kinematics",
    "joints_from_home": "spherecal.core.kinematics",
    "IkNotConverged": "spherecal.core.urdf",
    "UrdfChain": "spherecal.core.urdf",
    "chain_from_urdf": "spherecal.core.urdf",
    "chain_inverse_kinematics": "spherecal.core.urdf",
    "chain_to_urdf": "spherecal.core.urdf",
    "read_urdf_chain": "spherecal.core.urdf",
    "write_urdf": "spherecal.core.urdf",
    "check_rotation_matrix": "spherecal.core.geometry",
    "matrix_from_quat_wxyz": "spherecal.core.geometry",
    "matrix_from_rotvec": "spherecal.core.geometry",
    "quat_wxyz_from_matrix": "spherecal.core.geometry",
    "quat_wxyz_from_xyzw": "spherecal.core.geometry",
    "quat_xyzw_from_wxyz": "spherecal.core.geometry",
    "rotation_angle_deg": "spherecal.core.geometry",
    "rotvec_from_matrix": "spherecal.core.geometry",
    # the line protocol: the PC side and the simulated controller's server
    "LineLinkSettings": "spherecal.devices.line_robot",
    "LineRobot": "spherecal.devices.line_robot",
    "LinkSettings": "spherecal.devices.line_robot",
    "TcpLink": "spherecal.devices.line_robot",
    "initial_seq": "spherecal.devices.line_robot",
    "link_transport": "spherecal.devices.line_robot",
    "ControllerServer": "spherecal.sim.controller",
    "Faults": "spherecal.sim.controller",
    "SimulatedController": "spherecal.sim.controller",
    "start_controller": "spherecal.sim.controller",
    "SimulatedControllerSettings": "spherecal.sim.settings",
    # exporters: the contract and the formatting helpers of the core's exports
    "ExportNote": "spherecal.io.exporters",
    "Exporter": "spherecal.io.exporters",
    "MOUNTINGS": "spherecal.io.exporters",
    "NoSettings": "spherecal.io.exporters",
    "RED_WARNING": "spherecal.io.exporters",
    "TEMPLATE_FIELDS": "spherecal.io.exporters",
    "red_warning": "spherecal.io.exporters",
    "calibrated_model_warning": "spherecal.io.exporters",
    "sensor_frame_warning": "spherecal.io.exporters",
    "MATRIX_DECIMALS": "spherecal.report.export",
    "METRE_DECIMALS": "spherecal.report.export",
    "MM_DECIMALS": "spherecal.report.export",
    "QUAT_DECIMALS": "spherecal.report.export",
    "check_result": "spherecal.report.export",
    "fixed": "spherecal.report.export",
    "frames_of": "spherecal.report.export",
    "inverse_name": "spherecal.report.export",
    "rounded_quaternion_wxyz": "spherecal.report.export",
    "uncertainty_sentence": "spherecal.report.export",
    # errors
    "ConfigError": "spherecal.core.errors",
    "DatasetFileError": "spherecal.core.errors",
    "DegenerateDataError": "spherecal.core.errors",
    "DeviceError": "spherecal.core.errors",
    "FileWriteError": "spherecal.core.errors",
    "FitBreakdownError": "spherecal.core.errors",
    "InputError": "spherecal.core.errors",
    "PluginError": "spherecal.core.errors",
    "SpherecalError": "spherecal.core.errors",
    # data models
    "CalibrationResult": "spherecal.core.models",
    "Circle": "spherecal.core.models",
    "Dataset": "spherecal.core.models",
    "MountingMode": "spherecal.core.models",
    "Observation": "spherecal.core.models",
    "Pose": "spherecal.core.models",
    "Profile": "spherecal.core.models",
    "TRANSFORM_NAME": "spherecal.core.models",
    "Vec3": "spherecal.core.models",
    # the validation-context key of the folder relative paths resolve against
    "BASE_DIR_CONTEXT_KEY": "spherecal.config.base",
    # the simulated cell and the planner a plugin's tests run on
    "SimulatedCell": "spherecal.sim.cell",
    "standard_cell": "spherecal.sim.cell",
    # simulated time and the devices' random streams, for simulated streaming devices
    "SimClock": "spherecal.sim.timeline",
    "MotionTimeline": "spherecal.sim.timeline",
    "DeviceClock": "spherecal.sim.timeline",
    "SmoothNoise": "spherecal.sim.timeline",
    "Samples": "spherecal.sim.timeline",
    "device_rng": "spherecal.sim.rngs",
    # a simulated device's server (TCP or UDP, in a thread), for a protocol of one's own
    "SimulatedDeviceServer": "spherecal.sim.device_server",
    "line_frames": "spherecal.sim.device_server",
    "SweepPlan": "spherecal.motion.planning",
    "plan_stations": "spherecal.motion.planning",
}
#: modules of the API, by the name they go by here (loaded on first use)
_MODULES = {
    "hookspecs": "spherecal.plugins.hookspecs",
    "line_protocol": "spherecal.devices.line_protocol",
}

__all__ = sorted(["ENTRY_POINT_GROUP", "PROJECT_NAME", "hookimpl", "hookspec",
                  "lazy_attributes", *_WHERE, *_MODULES])

_name_getattr, _name_dir = lazy_attributes(__name__, _WHERE)


def __getattr__(name: str) -> Any:
    module = _MODULES.get(name)
    if module is None:
        return _name_getattr(name)
    value = importlib.import_module(module)
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    return sorted(set(_name_dir()) | set(_MODULES))
