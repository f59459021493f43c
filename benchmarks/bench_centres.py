"""Accuracy on centre observations against the same data as raw profiles.

Each seed simulates the default plan (4 stations, ``--profiles`` per station) in the
standard cell, point noise 0.01 mm, robot pose noise 0.02 mm and 0.002 deg per axis (an
exact arm: the robot error model is 'none', so that only the observations differ), and
solves the same shots three ways:

- ``profiles``: the raw profiles (every point in the joint fit);
- ``circles``: the circle fitted to each profile, as a sensor that fits on board would
  report it (``spherecal.estimation.centres.circles_from_profiles``), noise estimated;
- ``spheres``: those circles resolved to sphere centres with the side of the laser plane
  such a sensor would report (here the truth's), noise estimated.

Printed per mounting and way: RMS rotation (deg) and translation (mm) errors against the
simulated truth, the NEES of the six transform parameters under the reported covariance
(6 when honest), the median solve time (CPU s) and how many solves did not converge.
``--robot-error-model station`` (the default of ``spherecal solve`` without joints) solves
with the station random effect instead. ``--world systematic`` gives the arm what a real
arm has and the exact world does not: an IRB 2400 whose geometry differs from its
nominal model (``RobotErrorModel()``, the flange 0.5-2 mm off, drawn per seed; the
world of benchmarks/bench_accuracy.py), so that the robot error the station model
assumes is there, and not only noise.

    python benchmarks/bench_centres.py --seeds 10 [--robot-error-model station] [--world systematic]
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

from spherecal.core import geometry as geo
from spherecal.estimation import CalibrationOptions, solve
from spherecal.estimation.centres import circles_from_profiles
from spherecal.plugins.host import PluginHost
from spherecal.sim import NoiseModel, RobotErrorModel, SweepPlan, simulate_dataset, standard_cell

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))  # tests/reference_sensor.py
from reference_sensor import reference_fov  # noqa: E402 (after the path) the reference sensor's field of view

NOISE = NoiseModel(point_noise_mm=0.01, pose_translation_noise_mm=0.02, pose_rotation_noise_deg=0.002)


def resolved(circles, profiles, cell):
    """Circles turned into sphere centres on the true side of the laser plane."""
    r = circles.sphere_radius_mm
    pose = {o.index: o.base_from_flange for o in profiles.observations}
    out = []
    for o in circles.observations:
        x = np.copysign(np.sqrt(max(r * r - o.circle.radius_mm**2, 0.0)), cell.sphere_centre_in_sensor(pose[o.index])[0])
        out.append(o.model_copy(update={"circle": None, "sphere_centre_mm": (float(x), *o.circle.centre_yz_mm)}))
    return circles.model_copy(update={"observations": out})


def errors(result, cell):
    X = cell.true_transform
    w = geo.rotvec_from_matrix(result.transform.rotation_matrix @ X.rotation_matrix.T)
    e = np.concatenate([w, result.transform.translation - X.translation])
    return np.degrees(np.linalg.norm(w)), np.linalg.norm(e[3:]), float(e @ np.linalg.solve(np.array(result.covariance)[:6, :6], e))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--seeds", type=int, default=10)
    ap.add_argument("--profiles", type=int, default=8, help="profiles per station")
    ap.add_argument("--robot-error-model", default="none", choices=["none", "station"])
    ap.add_argument("--world", default="exact", choices=["exact", "systematic"],
                    help="exact: the arm is its nominal model; systematic: an IRB 2400 with geometric error")
    args = ap.parse_args()
    opts = CalibrationOptions(robot_error_model=args.robot_error_model)
    arm = PluginHost().arm_kinematics({"type": "abb_irb2400"}) if args.world == "systematic" else None
    world = {"robot_error": RobotErrorModel(), "arm": arm} if arm is not None else {}
    print(f"robot error model: {args.robot_error_model}; world: {args.world}; {args.seeds} seeds")
    print(f"{'mounting':12} {'way':9} {'rot RMS deg':>12} {'trans RMS mm':>13} {'NEES':>6} {'CPU s':>6} {'not conv.':>9}")
    for mounting in ("eye_in_hand", "eye_to_hand"):
        rows: dict[str, list] = {"profiles": [], "circles": [], "spheres": []}
        for seed in range(args.seeds):
            cell = standard_cell(mounting, seed=seed, noise=NOISE, fov=reference_fov(), **world)
            profiles = simulate_dataset(cell, SweepPlan(profiles_per_station=args.profiles))
            circles = circles_from_profiles(profiles)
            for way, ds in (("profiles", profiles), ("circles", circles), ("spheres", resolved(circles, profiles, cell))):
                t = time.process_time()
                sol = solve(ds, opts)
                rows[way].append((*errors(sol.result, cell), time.process_time() - t, not sol.refined.converged))
        for way, v in rows.items():
            a = np.array(v)
            print(f"{mounting:12} {way:9} {np.sqrt(np.mean(a[:, 0] ** 2)):12.4f} {np.sqrt(np.mean(a[:, 1] ** 2)):13.4f} "
                  f"{np.mean(a[:, 2]):6.2f} {np.median(a[:, 3]):6.2f} {int(a[:, 4].sum()):9d}")


if __name__ == "__main__":
    main()
