"""The simulated cell: the reference for tests and benchmarks, and the world behind the
simulated devices."""

from .cell import NoiseModel, SensorFieldOfView, SimulatedCell, arm_layout, standard_cell
from .objects import BallBar, CarDoorPanel, FlatPlate, SceneObject, Sphere
from ..planning import SweepPlan, plan_stations  # re-exported: the simulated acquisition plans with them
from .planner import simulate_centre_dataset, simulate_dataset
from .robot_error import RobotErrorModel, SimulatedArm

__all__ = [
    "BallBar",
    "CarDoorPanel",
    "FlatPlate",
    "SceneObject",
    "Sphere",
    "NoiseModel",
    "RobotErrorModel",
    "SimulatedArm",
    "SensorFieldOfView",
    "SimulatedCell",
    "arm_layout",
    "standard_cell",
    "SweepPlan",
    "plan_stations",
    "simulate_centre_dataset",
    "simulate_dataset",
]
