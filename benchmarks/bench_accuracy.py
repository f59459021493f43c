"""Accuracy and honesty of the two-step method and of the joint refinement, in worlds
harder than the estimator's model.

Each scenario simulates an IRB 2400 (the plugin's own kinematics, attached to the
simulated cell: the controller's nominal inverse kinematics, the arm's true geometry)
with an nxSensor-I-sized profiler, point noise 0.01 mm, robot translation noise 0.02 mm
per shot, and:

- ``random``: nothing else (the arm is exactly its nominal model);
- ``systematic``: the arm's geometry differs from the nominal model
  (``spherecal.sim.RobotErrorModel`` defaults: joint zero offsets 0.02-0.05 deg, link
  lengths 0.1-0.3 mm, offsets up to 0.2 mm, axis tilts up to 0.02 deg; the flange is
  0.5-2 mm and 0.03-0.16 deg off its reported pose); a new arm per seed;
- ``systematic+``: that, plus what no kinematic model holds: gravity sag of every joint
  (0.01-0.03 deg per metre of lever, changing with the configuration), orientation read
  noise 0.01 deg per axis and stray points on 20 % of the profiles;
- ``systematic x3``: an arm three times worse than the estimator's stated prior
  (joint zero offsets 0.06-0.15 deg, link lengths 0.3-0.9 mm, offsets up to 0.6 mm, tilts
  up to 0.06 deg): the data must widen the prior.

Robot error models (``--models``): ``auto``, the default when the joints and the robot's
kinematics are known (the kinematic model when the data show the arm's geometric error,
pose noise only with the arm's geometry considered when they do not); ``kinematic`` (the
arm's geometric error parameters, marginalised, always), and ``station`` (one pose offset
per station: what is left when only poses are known). ``kin`` is the share of seeds for
which ``auto`` chose the kinematic model.

Two plans: ``A`` the default (4 stations tilted 30/30/45 deg, 10 profiles each, sphere
r = 19.1 mm) and ``B`` (5 stations tilted 15-25 deg about other axes, 8 profiles each,
sweeps elsewhere in the field of view, sphere r = 12.7 mm). The estimator runs with its
defaults (it is not told which world it is in), except the noise levels a user would
give: the robot's per-shot translation noise, and in ``systematic+`` the orientation
read noise.

Figures per mode, scenario and plan: RMS rotation (deg) and translation (mm) errors of
the two-step and of the refined result against the simulated truth, their ratio, the
NEES of the six transform parameters under the reported covariance (6 when honest), the
smallest 3-sigma coverage over the six components, and the point error predicted at new
poses (k = 1 RMS, mm) against the error measured there (sphere centres fitted from
sweeps at six new orientations, against the calibrated sphere). For ``random`` the
Cramer-Rao bound of the pose-noise-only model is printed too.

Run:  python benchmarks/bench_accuracy.py [--seeds 50] [--mounting both] [--scenarios ...]
Medians of CPU time (process time: honest on a shared machine, and the solve is single-threaded
but for BLAS) are per solve, on the README's install.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

from spherecal.core import geometry as geo
from spherecal.estimation import CalibrationOptions, solve
from spherecal.estimation.prediction import point_error_budget
from spherecal.estimation.problem import build_problem
from spherecal.estimation.refine import NoiseAssumptions, cramer_rao_bound
from spherecal.estimation.twostep import fit_sphere_fixed_radius
from spherecal.core.models import Pose
from spherecal.plugins.host import PluginHost
from spherecal.sim import NoiseModel, RobotErrorModel, SweepPlan, simulate_dataset, standard_cell
from spherecal.motion.validation import points_in_object_frame

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))  # tests/reference_sensor.py
from reference_sensor import reference_fov  # noqa: E402 (after the path) the reference sensor's field of view

PLANS = {
    "A": (SweepPlan(), 19.1),
    "B": (
        SweepPlan(
            profiles_per_station=8,
            tilts_deg=[(0, 0, 0), (0, 20, 10), (-20, 0, 15), (15, -15, -20), (0, 0, -25)],
            station_offsets_mm=[(5.0, -15.0), (-8.0, 0.0), (0.0, 10.0)],
            sweep_fraction=0.7,
        ),
        12.7,
    ),
}
#: New orientations at which the point-error prediction is checked.
NEW_VIEWS = SweepPlan(
    tilts_deg=[(15, 15, 0), (-20, 10, 0), (0, -25, 20), (25, 0, -30), (-10, -10, 35), (20, -20, 0)],
    station_offsets_mm=[(5.0, -10.0), (-5.0, 5.0), (0.0, -15.0)],
)
POINT_NOISE_MM = 0.01
POSE_NOISE_MM = 0.02


def rms(values) -> float:
    return float(np.sqrt(np.mean(np.square(values))))


def irb2400_kinematics():
    """The IRB 2400's kinematics, found through the plugin host like any robot's."""
    return PluginHost().arm_kinematics({"type": "abb_irb2400"})


SCENARIOS = ("random", "systematic", "systematic+", "systematic x3")


def scenario_world(name: str, seed: int, model: str = "auto"):
    strays = 0.2 if name == "systematic+" else 0.0
    rot = 0.01 if name == "systematic+" else 0.0
    noise = NoiseModel(point_noise_mm=POINT_NOISE_MM, pose_translation_noise_mm=POSE_NOISE_MM,
                       pose_rotation_noise_deg=rot, stray_profile_fraction=strays)
    error = {
        "random": None,
        "systematic": RobotErrorModel(),
        "systematic+": RobotErrorModel(joint_compliance_deg_per_m=(0.01, 0.03)),
        "systematic x3": RobotErrorModel(joint_zero_offset_deg=(0.06, 0.15), link_length_mm=(0.3, 0.9),
                                         link_offset_mm=(0.0, 0.6), axis_tilt_deg=(0.0, 0.06)),
    }[name]
    opts = CalibrationOptions(pose_translation_noise_mm=POSE_NOISE_MM, pose_rotation_noise_deg=max(rot, 0.002),
                              robot_error_model=model)
    return noise, error, opts


def new_view_errors(cell, sol) -> list[float]:
    """|fitted centre - calibrated centre| (mm) of sweeps at new orientations."""
    ref = sol.refined
    views = simulate_dataset(cell, NEW_VIEWS)
    by: dict[str, list] = {}
    for o in views.observations:
        by.setdefault(o.station, []).append(o)
    X = Pose.from_rt(ref.R, ref.t)
    out = []
    for obs in by.values():
        q = points_in_object_frame(cell.mounting, X, [o.base_from_flange for o in obs],
                                   [o.profile.points_mm for o in obs])
        c = fit_sphere_fixed_radius(q, cell.sphere_radius_mm, ref.centre)
        out.append(float(np.linalg.norm(c - ref.centre)))
    return out


def run(mounting: str, scenario: str, plan_name: str, seeds: int, kin, model: str = "auto") -> dict:
    plan, radius = PLANS[plan_name]
    err = {"two_step": ([], []), "refined": ([], [])}
    nees, z, times, pred, meas, chose_kin = [], [], [], [], [], []
    for seed in range(seeds):
        noise, error, opts = scenario_world(scenario, seed, model)
        cell = standard_cell(mounting, seed=seed, noise=noise, sphere_radius_mm=radius, robot_error=error, arm=kin,
                             fov=reference_fov())
        ds = simulate_dataset(cell, plan)
        t0 = time.process_time()
        sol = solve(ds, opts, kinematics=kin)
        times.append(time.process_time() - t0)
        chose_kin.append(sol.result.robot_error is not None and sol.result.robot_error.model.startswith("kinematic"))
        X = cell.true_transform
        for name, (R, t) in {"two_step": (sol.two_step.R, sol.two_step.t), "refined": (sol.refined.R, sol.refined.t)}.items():
            err[name][0].append(geo.rotation_angle_deg(X.rotation_matrix, R))
            err[name][1].append(float(np.linalg.norm(X.translation - t)))
        e = np.concatenate([geo.rotvec_from_matrix(sol.refined.R @ X.rotation_matrix.T), sol.refined.t - X.translation])
        P = sol.refined.covariance[:6, :6]
        nees.append(float(e @ np.linalg.solve(P, e)))
        z.append(np.abs(e) / np.sqrt(np.diag(P)))
        nz = NoiseAssumptions(sol.result.diagnostics.noise["point_noise_mm"], POSE_NOISE_MM, opts.pose_rotation_noise_deg)
        pred.append(point_error_budget(sol.problem, sol.refined, nz, shots_averaged=NEW_VIEWS.profiles_per_station)["rms_mm"])
        meas.extend(new_view_errors(cell, sol))
    out = {
        "two_step": (rms(err["two_step"][0]), rms(err["two_step"][1])),
        "refined": (rms(err["refined"][0]), rms(err["refined"][1])),
        "nees_mean": float(np.mean(nees)),
        "nees_median": float(np.median(nees)),
        "coverage_3sigma_min": float(np.min((np.array(z) <= 3).mean(axis=0))),
        "coverage_3sigma": (np.array(z) <= 3).mean(axis=0).tolist(),
        "predicted_new_view_rms_mm": rms(pred),
        "measured_new_view_rms_mm": rms(meas),
        "median_solve_s": float(np.median(times)),
        "kinematic_share": float(np.mean(chose_kin)),
    }
    if scenario == "random":
        noise, _, _ = scenario_world("random", 0)
        truth = standard_cell(mounting, seed=0, noise=NoiseModel(point_noise_mm=0, pose_translation_noise_mm=0),
                              sphere_radius_mm=radius, fov=reference_fov())
        problem = build_problem(simulate_dataset(truth, plan))
        Xt = truth.true_transform
        crb = cramer_rao_bound(problem, Xt.rotation_matrix, Xt.translation, truth.sphere_centre_mm,
                               NoiseAssumptions(POINT_NOISE_MM, POSE_NOISE_MM, 0.0))
        out["bound"] = (float(np.degrees(np.sqrt(np.trace(crb[:3, :3])))), float(np.sqrt(np.trace(crb[3:6, 3:6]))))
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--seeds", type=int, default=50)
    ap.add_argument("--mounting", choices=["eye_in_hand", "eye_to_hand", "both"], default="both")
    ap.add_argument("--scenarios", nargs="+", default=list(SCENARIOS), choices=SCENARIOS)
    ap.add_argument("--models", nargs="+", default=["auto"], choices=["auto", "kinematic", "station"])
    ap.add_argument("--plans", nargs="+", default=["A", "B"])
    args = ap.parse_args()
    kin = irb2400_kinematics()
    modes = ["eye_in_hand", "eye_to_hand"] if args.mounting == "both" else [args.mounting]
    print(f"{args.seeds} seeds per row; errors are RMS over seeds; NEES honest = 6; coverage: share of |error| <= 3 sd")
    head = (f"{'mode':12s}{'model':10s}{'scenario':14s}{'plan':5s}{'2-step deg':>11s}{'refined deg':>12s}{'ratio':>6s}"
            f"{'2-step mm':>10s}{'refined mm':>11s}{'ratio':>6s}{'NEES':>7s}{'cov3':>6s}{'pred mm':>8s}{'meas mm':>8s}"
            f"{'p/m':>5s}{'kin':>5s}{'s':>6s}")
    print(head)
    rows = [(mode, model, scenario, plan) for mode in modes for model in args.models for scenario in args.scenarios
            for plan in args.plans if not (model == "station" and scenario == "random")]
    for mode, model, scenario, plan in rows:
        r = run(mode, scenario, plan, args.seeds, kin, model)
        (r2, t2), (rr, tr) = r["two_step"], r["refined"]
        print(f"{mode:12s}{model:10s}{scenario:14s}{plan:5s}{r2:11.4f}{rr:12.4f}{rr / r2:6.2f}{t2:10.4f}{tr:11.4f}{tr / t2:6.2f}"
              f"{r['nees_mean']:7.1f}{r['coverage_3sigma_min']:6.2f}{r['predicted_new_view_rms_mm']:8.4f}"
              f"{r['measured_new_view_rms_mm']:8.4f}"
              f"{r['predicted_new_view_rms_mm'] / r['measured_new_view_rms_mm']:5.2f}{r['kinematic_share']:5.2f}"
              f"{r['median_solve_s']:6.2f}",
              flush=True)
        if "bound" in r:
            rb, tb = r["bound"]
            print(f"{'':44s}Cramer-Rao bound {rb:.4f} deg, {tb:.4f} mm; refined / bound {rr / rb:.2f}, {tr / tb:.2f}",
                  flush=True)


if __name__ == "__main__":
    main()
