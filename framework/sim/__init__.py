"""The simulated cell: the reference for tests and benchmarks, and the world behind the
simulated devices. Only the simulated world lives here; it imports the layers below it
(core to motion: the simulated acquisition plans as a run does).

The names below load on first use (PEP 562): a robot plugin's configuration includes
the simulated controller's settings (:mod:`spherecal.sim.settings`), and importing them
should not build the simulated cell's modules."""

from __future__ import annotations

from spherecal.core.lazy import lazy_attributes


#: name -> the module that defines it
_WHERE = {
    "BallBar": ".objects",
    "CarDoorPanel": ".objects",
    "FlatPlate": ".objects",
    "SceneObject": ".objects",
    "Sphere": ".objects",
    "NoiseModel": "spherecal.config",
    "SensorFieldOfView": ".cell",
    "SimulatedCell": ".cell",
    "arm_layout": ".cell",
    "standard_cell": ".cell",
    "SweepPlan": "spherecal.config",  # re-exported: the simulated acquisition plans with them
    "plan_stations": "spherecal.motion.planning",
    "simulate_centre_dataset": ".datasets",
    "simulate_dataset": ".datasets",
    "simulate_general_dataset": ".datasets",
    "general_pose_targets": ".datasets",
    "RobotErrorModel": "spherecal.config",
    "OnTheFlyPlan": "spherecal.config",
    "StreamSimSettings": "spherecal.config",
    "simulate_recording": ".streams",
    "simulate_recording_with_truth": ".streams",
    "SimulatedArm": ".robot_error",
    "DeviceClock": ".timeline",
    "MotionTimeline": ".timeline",
    "SimClock": ".timeline",
    "SmoothNoise": ".timeline",
    "device_rng": ".rngs",
    "SimulatedDeviceServer": ".device_server",
    "line_frames": ".device_server",
}

__all__ = sorted(_WHERE)

__getattr__, __dir__ = lazy_attributes(__name__, _WHERE)
