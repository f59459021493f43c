"""Accuracy of the two-step method and of the joint refinement against the Cramer-Rao
bound, on the standard simulated scenario.

Scenario: the IRB 2400-sized cell of ``spherecal.sim.standard_cell`` (sensor about
160 mm out from the flange, sphere r = 19.1 mm at about 1.1 m from the base), the
default plan (4 orientations tilted 30/30/45 deg about different axes, 10 profiles per
pure-translation sweep, sweeps at different places of the field of view), point noise
0.01 mm (each of y, z), robot translation noise 0.02 mm (each base axis), no rotation
noise, no stray points.

The Cramer-Rao bound is computed from the simulated noise model at the true parameters:
the Fisher information of the linearised Gaussian model ``sum_i J_i^T Cov_i^-1 J_i``
over the noise-free points of every profile, where J_i is the Jacobian of the in-plane
point-to-circle distances with respect to (rotation, translation, sphere centre) and
``Cov_i = s^2 I + G_i S_i G_i^T`` carries the pose noise shared by the points of a
profile (see spherecal.estimation.refine.cramer_rao_bound). The bound on the RMS
rotation error is ``sqrt(trace)`` of the rotation block (deg), on the translation error
``sqrt(trace)`` of the translation block (mm).

Run:  python benchmarks/bench_accuracy.py [--seeds 60] [--mounting eye_in_hand]
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from spherecal import geometry as geo
from spherecal.estimation import CalibrationOptions, solve
from spherecal.estimation.problem import build_problem
from spherecal.estimation.refine import NoiseAssumptions, cramer_rao_bound
from spherecal.sim import NoiseModel, SweepPlan, simulate_dataset, standard_cell


def rms(values) -> float:
    return float(np.sqrt(np.mean(np.square(values))))


def run(mounting: str, seeds: int, profiles: int) -> dict:
    noise = NoiseModel(point_noise_mm=0.01, pose_translation_noise_mm=0.02, pose_rotation_noise_deg=0.0)
    plan = SweepPlan(profiles_per_station=profiles)
    options = CalibrationOptions(pose_translation_noise_mm=0.02, pose_rotation_noise_deg=0.0)
    err = {"two_step": ([], []), "refined": ([], [])}
    times = []
    for seed in range(seeds):
        cell = standard_cell(mounting, seed=seed, noise=noise)
        ds = simulate_dataset(cell, plan)
        t0 = time.perf_counter()
        sol = solve(ds, options)
        times.append(time.perf_counter() - t0)
        X = cell.true_transform
        for name, (R, t) in {"two_step": (sol.two_step.R, sol.two_step.t), "refined": (sol.refined.R, sol.refined.t)}.items():
            err[name][0].append(geo.rotation_angle_deg(X.rotation_matrix, R))
            err[name][1].append(float(np.linalg.norm(X.translation - t)))
    # the bound, at the truth, on the noise-free points of the same plan
    truth = standard_cell(mounting, seed=0, noise=NoiseModel(point_noise_mm=0, pose_translation_noise_mm=0))
    problem = build_problem(simulate_dataset(truth, plan))
    X = truth.true_transform
    crb = cramer_rao_bound(problem, X.rotation_matrix, X.translation, truth.sphere_centre_mm, NoiseAssumptions(0.01, 0.02, 0.0))
    bound_rot_deg = float(np.degrees(np.sqrt(np.trace(crb[:3, :3]))))
    bound_trans_mm = float(np.sqrt(np.trace(crb[3:6, 3:6])))
    return {
        "two_step": (rms(err["two_step"][0]), rms(err["two_step"][1])),
        "refined": (rms(err["refined"][0]), rms(err["refined"][1])),
        "bound": (bound_rot_deg, bound_trans_mm),
        "median_solve_s": float(np.median(times)),
        "points_per_dataset": int(sum(len(p) for p in problem.profiles)),
        "profiles": problem.n_profiles,
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--seeds", type=int, default=60)
    ap.add_argument("--profiles", type=int, default=10, help="profiles per station (4 stations)")
    ap.add_argument("--mounting", choices=["eye_in_hand", "eye_to_hand", "both"], default="both")
    args = ap.parse_args()
    modes = ["eye_in_hand", "eye_to_hand"] if args.mounting == "both" else [args.mounting]
    for mode in modes:
        r = run(mode, args.seeds, args.profiles)
        (r2, t2), (rr, tr), (rb, tb) = r["two_step"], r["refined"], r["bound"]
        print(f"\n== {mode}: {args.seeds} seeds, {r['profiles']} profiles, ~{r['points_per_dataset']} points per dataset")
        print(f"{'':24s}{'rotation RMS (deg)':>20s}{'translation RMS (mm)':>22s}")
        print(f"{'two-step (paper)':24s}{r2:20.5f}{t2:22.5f}")
        print(f"{'refined (joint fit)':24s}{rr:20.5f}{tr:22.5f}")
        print(f"{'Cramer-Rao bound':24s}{rb:20.5f}{tb:22.5f}")
        print(f"{'two-step / refined':24s}{r2 / rr:20.2f}{t2 / tr:22.2f}")
        print(f"{'two-step / bound':24s}{r2 / rb:20.2f}{t2 / tb:22.2f}")
        print(f"{'refined / bound':24s}{rr / rb:20.2f}{tr / tb:22.2f}")
        print(f"median solve time (two-step + refinement): {r['median_solve_s'] * 1000:.1f} ms")


if __name__ == "__main__":
    main()
