"""Calibrate on a simulated cell with the example plugins, from start to finish.

    pip install ./examples/third_party_plugin
    python examples/third_party_plugin/calibrate_simulated.py --mounting eye_in_hand

Steps: build a plugin host (it finds ``example_arm`` and ``example_profiler`` through
their entry points), validate both configuration sections, create the robot (its driver
connected over XA/1 to a simulated controller) and the sensor on one cell, plan stations from a nominal transform, acquire, calibrate,
and compare with the cell's true transform. ``--json`` prints the numbers as JSON.

Everything but the calibration itself comes from the plugin API, ``spherecal.plugins``;
the calibration is the library's ``spherecal.estimation.calibrate``.
"""

from __future__ import annotations

import argparse
import json
import sys

import numpy as np

from spherecal.estimation import calibrate
from spherecal.plugins import (
    Dataset,
    DeviceContext,
    Observation,
    PluginHost,
    Pose,
    matrix_from_rotvec,
    plan_stations,
    standard_cell,
)

ROBOT_SECTION = {"type": "example_arm", "max_speed_mm_s": 200.0,
                 "workspace": {"min_mm": [0.0, -1000.0, 0.0], "max_mm": [2000.0, 1000.0, 1400.0]}}
SENSOR_SECTION = {"type": "example_profiler", "min_points": 20}


def nominal_guess(true: Pose, rng: np.random.Generator) -> Pose:
    """What a user would put in the configuration: the truth off by a few mm and a degree."""
    R = matrix_from_rotvec(np.radians(rng.normal(0.0, 0.7, 3))) @ true.rotation_matrix
    return Pose.from_rt(R, true.translation + rng.normal(0.0, 2.0, 3))


def acquire(host: PluginHost, robot, sensor, stations, mounting: str, radius_mm: float) -> Dataset:
    """Move to every planned flange target, read the pose the robot reports and a profile."""
    observations = []
    for label, targets in stations:
        for target in targets:  # base_from_flange, mm, quaternion (w, x, y, z)
            robot.move_linear(target, speed_mm_s=100.0)
            reported = robot.read_flange_pose()
            joints = robot.read_joints_deg()
            profile = sensor.read_profile()
            if profile is None:  # the line missed the sphere: skip the shot
                continue
            obs = Observation(index=len(observations), station=label, base_from_flange=reported,
                              joints_deg=None if joints is None else tuple(joints), profile=profile)
            observations.append(obs)
            host.observation_taken(observation=obs)
    dataset = Dataset(mounting=mounting, sphere_radius_mm=radius_mm, observations=observations,
                      provenance={"source": "calibrate_simulated.py"})
    host.acquisition_finished(dataset=dataset)
    return dataset


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--mounting", choices=["eye_in_hand", "eye_to_hand"], default="eye_in_hand")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--acquire-only", action="store_true", help="stop after the acquisition")
    parser.add_argument("--json", action="store_true", help="print the outcome as JSON")
    args = parser.parse_args(argv)

    host = PluginHost()
    robot_config = host.validate_robot_config("example_arm", ROBOT_SECTION)
    sensor_config = host.validate_sensor_config("example_profiler", SENSOR_SECTION)

    # the cell measures with the field of view the profiler declares, laid out for the arm's reach
    fov = host.registry.sensor_type("example_profiler").field_of_view
    cell = standard_cell(args.mounting, seed=args.seed, fov=fov, arm=host.arm_kinematics(ROBOT_SECTION))
    context = DeviceContext(cell=cell, log=lambda message: print(message, file=sys.stderr))
    robot = host.create_robot(ROBOT_SECTION, context)
    sensor = host.create_sensor(SENSOR_SECTION, context)

    rng = np.random.default_rng(args.seed)
    nominal = nominal_guess(cell.true_transform, rng)
    rough_centre_mm = cell.sphere_centre_mm + rng.normal(0.0, 2.0, 3)
    stations = plan_stations(cell.mounting, nominal, rough_centre_mm, cell.sphere_radius_mm,
                             field_of_view=cell.fov)
    try:
        dataset = acquire(host, robot, sensor, stations, cell.mounting, cell.sphere_radius_mm)
    finally:
        robot.close()
        sensor.close()

    outcome = {
        "plugins": host.plugin_names(),
        "robot_config": robot_config.model_dump(),
        "sensor_config": sensor_config.model_dump(),
        "mounting": cell.mounting,
        "n_observations": len(dataset.observations),
        "stations": sorted({o.station for o in dataset.observations}),
    }
    if not args.acquire_only:
        result = calibrate(dataset)
        host.calibration_finished(result=result, dataset=dataset)
        true = cell.true_transform
        R_err = result.transform.rotation_matrix.T @ true.rotation_matrix
        outcome.update(
            transform_name=result.transform_name,
            transform_translation_mm=list(result.transform.translation_mm),
            transform_quaternion_wxyz=list(result.transform.quaternion_wxyz),
            error_translation_mm=float(np.linalg.norm(result.transform.translation - true.translation)),
            error_rotation_deg=float(np.degrees(np.arccos(np.clip((np.trace(R_err) - 1) / 2, -1, 1)))),
            rms_mm=result.residuals.rms_mm,
        )
    if args.json:
        print(json.dumps(outcome))
    else:
        for key, value in outcome.items():
            print(f"{key}: {value}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
