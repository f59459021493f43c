"""Kinematic calibration from the sphere: does the identified arm model take the robot's
own error out of new measurements, and are its reported uncertainties honest?

World: the simulated IRB 2400 with geometric errors drawn per seed
(``spherecal.sim.RobotErrorModel`` defaults: flange 0.5-2 mm off its reported pose), an
nxSensor-I-sized profiler, point noise 0.01 mm, robot translation noise 0.02 mm per shot;
with ``--sag`` also gravity sag of every joint (0.01-0.03 deg per metre of lever), which no
kinematic model holds. Plan: the example's (``examples/sim-kinematic-eye-in-hand.toml``
style) 20 stations x 8 profiles, tilts up to 50 deg turned -90..90 deg about the view axis.

Figures per mode: the sphere centre measured from six fresh stations (not used in the
calibration, other orientations) and mapped through the nominal model and the default
(marginalised) calibration ("before"), and through the identified model and its transform
("after"): their RMS scatter about their mean (mm); the share of identified parameters
within 3 reported standard deviations of the truth (the truth expressed in the identified
parameters: the simulated arm's error, with what the data cannot see absorbed as the
transform and sphere absorb it); transform errors against the truth; median solve time.

With ``--plan planner`` the calibration stations are the kinematic planner's
(``spherecal.motion.kinematic_plan``, for the example cells' nominal transform and sphere) instead of the
hand-written spread.

Run:  python benchmarks/bench_kinematic.py [--seeds 30] [--mounting both] [--sag] [--plan planner]
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

from spherecal.core import geometry as geo
from spherecal.estimation import CalibrationOptions, solve
from spherecal.estimation.twostep import fit_sphere_fixed_radius
from spherecal.core.kinematics import chain_with_errors, corrected_flange_poses, error_tilt_basis, flange_error_jacobian
from spherecal.core.models import Pose
from spherecal.plugins.host import PluginHost
from spherecal.sim import NoiseModel, RobotErrorModel, SimulatedArm, SweepPlan, simulate_dataset, standard_cell
from spherecal.motion.validation import points_in_object_frame

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))  # tests/reference_sensor.py
from reference_sensor import reference_fov  # noqa: E402 (after the path) the reference sensor's field of view


def spread_tilts(n: int, rng: np.random.Generator, max_deg: float, max_turn_deg: float = 90.0):
    out = []
    for k in range(n):
        d = rng.normal(size=2)
        d /= np.linalg.norm(d)
        ang = max_deg * np.sqrt((k + 0.5) / n)
        out.append((float(d[0] * ang), float(d[1] * ang), float(rng.uniform(-max_turn_deg, max_turn_deg))))
    return out


#: Per mode: (tilt, turn) limits, deg. Eye-to-hand turns the sphere on the flange in front of a
#: fixed sensor: the arm reaches less of that.
REACH = {"eye_in_hand": (50.0, 90.0), "eye_to_hand": (30.0, 40.0)}


def planned(mode: str, kin) -> SweepPlan:
    """The kinematic planner's 20 stations (spherecal.motion.kinematic_plan) for the example cell of
    ``mode`` (its nominal transform and rough sphere), 8 profiles each."""
    import re
    import tempfile
    from pathlib import Path

    from spherecal.config import load_config
    from spherecal.motion.kinematic_plan import plan_kinematic_stations

    text = (Path(__file__).resolve().parents[1] / "examples" / f"sim-{mode.replace('_', '-')}.toml").read_text()
    text = re.sub(r"(?m)^profiles_per_station = .*$", "profiles_per_station = 8\nstation_offsets_mm = "
                  "[[0.0, 0.0], [8.0, -15.0], [-8.0, 10.0]]", text)
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "cell.toml"
        path.write_text(text + "\n[acquisition.kinematic_plan]\nstations = 20\n" if "[acquisition.kinematic_plan]"
                        not in text else text)
        from spherecal.plugins.host import PluginHost
        from spherecal.app.cell import configured_for_sensor

        loaded, _ = configured_for_sensor(load_config(path), PluginHost())  # the sweep's standoff: the sensor's
        cfg = loaded.config
        return plan_kinematic_stations(cfg.acquisition, cfg.calibration, cfg.mounting, cfg.nominal_transform,
                                       cfg.sphere, kin).sweep


def plans(mode: str, kin=None) -> tuple[SweepPlan, SweepPlan]:
    """The calibration plan (hand-written spread tilts, or the planner's with ``kin``) and
    the fresh stations."""
    tilt, turn = REACH[mode]
    plan = SweepPlan(profiles_per_station=8, tilts_deg=spread_tilts(20, np.random.default_rng(7), tilt, turn),
                     station_offsets_mm=[(0.0, 0.0), (8.0, -15.0), (-8.0, 10.0)])
    if kin is not None:
        plan = planned(mode, kin)
    fresh = SweepPlan(profiles_per_station=8, tilts_deg=spread_tilts(6, np.random.default_rng(99), 0.9 * tilt, turn),
                      station_offsets_mm=[(0.0, -5.0)])
    return plan, fresh


def true_errors(arm: SimulatedArm) -> np.ndarray:
    """The simulated arm's geometric error in the estimator's parameters (rad, mm)."""
    nom, true = arm.kinematics.chain, arm.true_chain
    out = []
    for i in range(nom.n_joints):
        d = true.placements[i, :3, 3] - nom.placements[i, :3, 3]
        a = nom.axes[i]
        R = nom.placements[i, :3, :3].T @ true.placements[i, :3, :3] @ geo.matrix_from_rotvec(a * arm.zero_offsets_rad[i])
        phi = geo.rotvec_from_matrix(R)
        u, v = error_tilt_basis(a)
        out.extend([phi @ a, *d, phi @ u, phi @ v])
    return np.array(out)


def fresh_scatter(cell, kin, sol, kappa, fresh: SweepPlan) -> float:
    """RMS scatter (mm) of the sphere centres of fresh stations mapped through the arm
    model with errors ``kappa`` and the solution's transform."""
    views = simulate_dataset(cell, fresh)
    by: dict[str, list] = {}
    for o in views.observations:
        by.setdefault(o.station, []).append(o)
    X = Pose.from_rt(sol.refined.R, sol.refined.t)
    model = chain_with_errors(kin.chain, kappa)
    centres = []
    for obs in by.values():
        q = np.array([kin.model_joints_rad(o.joints_deg) for o in obs])
        poses = corrected_flange_poses(kin.chain, model, q, [o.base_from_flange for o in obs])
        pts = points_in_object_frame(cell.mounting, X, poses, [o.profile.points_mm for o in obs])
        centres.append(fit_sphere_fixed_radius(pts, cell.sphere_radius_mm, sol.refined.centre))
    c = np.array(centres)
    return float(np.sqrt(np.mean(np.sum((c - c.mean(axis=0)) ** 2, axis=1))))


def identified_truth(sol, kin, truth: np.ndarray) -> np.ndarray:
    """The truth in the identified parameters: the centre shifts the whole true error
    causes, fitted by the identified parameters together with the transform and sphere."""
    from spherecal.estimation.refine import _centre_design

    ref, problem = sol.refined, sol.problem
    ke = ref.diagnostics["kinematic_effects"]
    ident = np.flatnonzero(ke["identified"])
    Jg, Jk = _centre_design(problem, ref.R, ref.t, ref.centre, kin.chain)
    A = np.hstack([Jk[:, ident], Jg])
    sol_ls = np.linalg.lstsq(A, Jk @ truth, rcond=None)[0]
    return sol_ls[:len(ident)]


def run(mode: str, seeds: int, kin, sag: bool, planner: bool = False) -> dict:
    before, after, z, rot, trans, times = [], [], [], [], [], []
    error = RobotErrorModel(joint_compliance_deg_per_m=(0.01, 0.03)) if sag else RobotErrorModel()
    noise = NoiseModel(point_noise_mm=0.01, pose_translation_noise_mm=0.02)
    plan, fresh = plans(mode, kin if planner else None)
    for seed in range(seeds):
        cell = standard_cell(mode, seed=seed, noise=noise, sphere_radius_mm=19.1, robot_error=error, arm=kin,
                             fov=reference_fov())
        ds = simulate_dataset(cell, plan)
        opts = CalibrationOptions(pose_translation_noise_mm=0.02)
        t0 = time.perf_counter()
        sol = solve(ds, opts.model_copy(update={"identify_kinematics": True}), kinematics=kin)
        times.append(time.perf_counter() - t0)
        plain = solve(ds, opts, kinematics=kin)
        before.append(fresh_scatter(cell, kin, plain, np.zeros(6 * kin.chain.n_joints), fresh))
        ke = sol.refined.diagnostics["kinematic_effects"]
        ident = np.array(ke["identified"])
        after.append(fresh_scatter(cell, kin, sol, np.where(ident, sol.refined.kinematic_errors, 0.0), fresh))
        truth = identified_truth(sol, kin, true_errors(cell.arm))
        est = np.asarray(sol.refined.kinematic_errors)[ident]
        sd = np.asarray(sol.refined.kinematic_sd)[ident]
        z.extend(np.abs(est - truth) / sd)
        X = cell.true_transform
        rot.append(geo.rotation_angle_deg(X.rotation_matrix, sol.refined.R))
        trans.append(float(np.linalg.norm(X.translation - sol.refined.t)))
        print(f"  {mode} seed {seed}: fresh scatter before {before[-1]:.4f} mm, after {after[-1]:.4f} mm, "
              f"{int(ident.sum())} identified, max |z| {np.max(np.abs(est - truth) / sd):.2f}, {times[-1]:.1f} s",
              flush=True)
    z = np.array(z)
    return {"before": np.array(before), "after": np.array(after), "coverage": float((z <= 3).mean()),
            "n_identified": int(ident.sum()), "rot": float(np.sqrt(np.mean(np.square(rot)))),
            "trans": float(np.sqrt(np.mean(np.square(trans)))), "time": float(np.median(times))}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--seeds", type=int, default=30)
    ap.add_argument("--mounting", choices=["eye_in_hand", "eye_to_hand", "both"], default="both")
    ap.add_argument("--sag", action="store_true", help="add gravity sag, which no kinematic model holds")
    ap.add_argument("--plan", choices=["spread", "planner"], default="spread",
                    help="spread: 20 hand-written stations, tilts spread evenly; planner: the kinematic planner's 20")
    args = ap.parse_args()
    kin = PluginHost().arm_kinematics({"type": "abb_irb2400"})
    modes = ["eye_in_hand", "eye_to_hand"] if args.mounting == "both" else [args.mounting]
    rows = []
    for mode in modes:
        r = run(mode, args.seeds, kin, args.sag, args.plan == "planner")
        rows.append((mode, r))
    print(f"\n{args.seeds} seeds per mode; 20 stations x 8 profiles ({args.plan})"
          f"{'; with gravity sag' if args.sag else ''}")
    print(f"{'mode':12s}{'fresh before mm (median, range)':>34s}{'after mm (median, max)':>26s}{'cov3':>6s}"
          f"{'n id':>6s}{'rot deg':>9s}{'trans mm':>10s}{'solve s':>9s}")
    for mode, r in rows:
        b, a = r["before"], r["after"]
        print(f"{mode:12s}{np.median(b):12.4f} ({b.min():.3f}-{b.max():.3f}){'':8s}{np.median(a):10.4f} ({a.max():.4f})"
              f"{'':6s}{r['coverage']:6.2f}{r['n_identified']:6d}{r['rot']:9.4f}{r['trans']:10.4f}{r['time']:9.1f}")


if __name__ == "__main__":
    main()
