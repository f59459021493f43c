"""Calibration from any poses against a station plan, in a world harder than the model.

World (per seed): the simulated IRB 2400 with the arm's geometric error
(``spherecal.sim.RobotErrorModel`` defaults: the flange 0.5-2 mm and 0.03-0.16 deg off its
reported pose, a new arm per seed), orientation read noise 0.01 deg and translation
noise 0.02 mm per axis and shot, point noise 0.01 mm, an nxSensor-I-sized profiler.

General plans (``spherecal.sim.simulate_general_dataset``): every shot at an orientation
of its own, tilted up to 20 deg about a random direction across the view axis and turned
up to 20 deg about it, the sphere at a random place of the field of view; each shot its
own station label. Station plans of as many rows: 5 stations tilted 15-25 deg about
different axes (the accuracy benchmark's plan B tilts), pure-translation sweeps.

Cases, both mountings:

- ``a``: sphere-centre tables (centre noise 0.02 mm per axis), 30 rows at general
  orientations, no nominal, no joints (solve defaults: ``auto``, which is the station
  model without joints), against a station plan of 5 x 6 rows;
- ``b``: raw profiles, 40 shots at general orientations, a nominal 5 deg and 10 mm off,
  joints and the robot's kinematics given (``auto``), against a station plan of 5 x 8
  profiles solved the same way;
- ``c``: the same raw profiles without a nominal: a correct result, a refusal (an error,
  or a RED verdict: exit 7), or a wrong result with exit 0 (not RED, and the transform
  more than 5 stated standard deviations off in a component, or more than 1 deg or 2
  mm off while more than 3 stated standard deviations off in a component: with the
  arm's geometric error an eye-to-hand result is often 2 mm off and says so).

Printed per mounting and case: solved / refused / wrong-with-exit-0 counts, median
rotation (deg) and translation (mm) errors, the median of the error over the stated
standard deviation (``sqrt(NEES / 6)``, 1 when honest) and the median NEES, and for a and b
the ratio of the general plan's median errors to the station plan's (target: at most
1.2) with the medians of CPU time per solve.

Run:  python benchmarks/bench_any_poses.py [--seeds 10] [--mounting both]
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

from spherecal.core import geometry as geo
from spherecal.core.errors import SpherecalError
from spherecal.core.models import Pose
from spherecal.estimation import CalibrationOptions, solve
from spherecal.plugins.host import PluginHost
from spherecal.report.assess import verdict
from spherecal.sim import (
    NoiseModel, RobotErrorModel, SweepPlan, simulate_centre_dataset, simulate_dataset, simulate_general_dataset,
    standard_cell,
)

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))  # tests/reference_sensor.py
from reference_sensor import reference_fov  # noqa: E402 (after the path) the reference sensor's field of view

NOISE = NoiseModel(point_noise_mm=0.01, pose_translation_noise_mm=0.02, pose_rotation_noise_deg=0.01)
CENTRE_NOISE_MM = 0.02
OPTIONS = dict(pose_translation_noise_mm=0.02, pose_rotation_noise_deg=0.01)
STATION_TILTS = [(0, 0, 0), (0, 20, 10), (-20, 0, 15), (15, -15, -20), (0, 0, -25)]
#: A result with exit 0 is wrong beyond this many stated standard deviations in a
#: component, or beyond these absolute errors and OFF_SDS stated standard deviations.
WRONG_SDS, WRONG_DEG, WRONG_MM, OFF_SDS = 5.0, 1.0, 2.0, 3.0


def off_by(X: Pose, deg: float, mm: float, rng: np.random.Generator) -> Pose:
    a, b = rng.normal(size=3), rng.normal(size=3)
    R = geo.matrix_from_rotvec(np.radians(deg) * a / np.linalg.norm(a)) @ X.rotation_matrix
    return Pose.from_rt(R, X.translation + mm * b / np.linalg.norm(b))


def without_joints(ds):
    return ds.model_copy(update={"observations": [o.model_copy(update={"joints_deg": None}) for o in ds.observations]})


def judged(ds, cell, opts: CalibrationOptions, kin) -> dict:
    """One solve: its outcome (solved, refused), errors against the truth, NEES, time."""
    t0 = time.process_time()
    try:
        res = solve(ds, opts, kinematics=kin).result
    except SpherecalError as exc:
        return {"outcome": "refused", "why": str(exc)[:160], "s": time.process_time() - t0}
    s = time.process_time() - t0
    X = cell.true_transform
    w = geo.rotvec_from_matrix(res.transform.rotation_matrix @ X.rotation_matrix.T)
    e = np.concatenate([w, res.transform.translation - X.translation])
    P = np.array(res.covariance)[:6, :6]
    nees = float(e @ np.linalg.solve(P, e))
    rot, trans = float(np.degrees(np.linalg.norm(w))), float(np.linalg.norm(e[3:]))
    level = verdict(res).level
    z = np.abs(e) / np.sqrt(np.diag(P))
    wrong = bool(np.any(z > WRONG_SDS) or ((rot > WRONG_DEG or trans > WRONG_MM) and np.any(z > OFF_SDS)))
    outcome = "refused" if level == "red" else ("wrong" if wrong else "solved")
    return {"outcome": outcome, "rot": rot, "trans": trans, "nees": nees, "z": float(np.sqrt(nees / 6)), "s": s,
            "level": level, "why": f"RED: {verdict(res).headline}"[:160] if level == "red" else (
                f"{rot:.3f} deg, {trans:.3f} mm off, largest component {z.max():.1f} "
                "stated sd" if wrong else "")}


def cell_for(mounting: str, seed: int, kin):
    return standard_cell(mounting, seed=seed, noise=NOISE, robot_error=RobotErrorModel(), arm=kin,
                         fov=reference_fov())


def case_a(mounting, seed, kin):
    cell = cell_for(mounting, seed, kin)
    general = without_joints(simulate_general_dataset(cell, 30, kind="sphere_centre", plan_seed=seed,
                                                      centre_noise_mm=CENTRE_NOISE_MM))
    cell = cell_for(mounting, seed, kin)
    station = without_joints(simulate_centre_dataset(cell, SweepPlan(profiles_per_station=6, tilts_deg=STATION_TILTS),
                                                     centre_noise_mm=CENTRE_NOISE_MM))
    opts = CalibrationOptions(**OPTIONS)
    return judged(general, cell, opts, None), judged(station, cell, opts, None)


def case_bc(mounting, seed, kin):
    cell = cell_for(mounting, seed, kin)
    general = simulate_general_dataset(cell, 40, kind="profile", plan_seed=seed)
    nominal = off_by(cell.true_transform, 5.0, 10.0, np.random.default_rng([seed, 5]))
    b = judged(general, cell, CalibrationOptions(**OPTIONS, nominal_transform=nominal), kin)
    c = judged(general, cell, CalibrationOptions(**OPTIONS), kin)
    cell = cell_for(mounting, seed, kin)
    station = simulate_dataset(cell, SweepPlan(profiles_per_station=8, tilts_deg=STATION_TILTS))
    return b, c, judged(station, cell, CalibrationOptions(**OPTIONS), kin)


def medians(rows: list[dict]) -> dict:
    ok = [r for r in rows if r["outcome"] != "refused"]
    out = {k: sum(r["outcome"] == k for r in rows) for k in ("solved", "refused", "wrong")}
    for key in ("rot", "trans", "z", "nees"):
        out[key] = float(np.median([r[key] for r in ok])) if ok else float("nan")
    out["s"] = float(np.median([r["s"] for r in rows]))
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--seeds", type=int, default=10)
    ap.add_argument("--mounting", choices=["eye_in_hand", "eye_to_hand", "both"], default="both")
    args = ap.parse_args()
    kin = PluginHost().arm_kinematics({"type": "abb_irb2400"})
    mountings = ["eye_in_hand", "eye_to_hand"] if args.mounting == "both" else [args.mounting]
    header = (f"{'mounting':12} {'case':34} {'ok':>3} {'ref':>3} {'bad':>3} {'rot deg':>8} {'tr mm':>7} "
              f"{'err/sd':>6} {'NEES':>6} {'ratio rot':>9} {'ratio tr':>8} {'CPU s':>6}")
    print(header)
    print("-" * len(header))
    notes = []
    for mounting in mountings:
        rows = {k: [] for k in ("a", "a-station", "b", "c", "b-station")}
        for seed in range(args.seeds):
            a, a_st = case_a(mounting, seed, kin)
            b, c, b_st = case_bc(mounting, seed, kin)
            for key, r in zip(("a", "a-station", "b", "c", "b-station"), (a, a_st, b, c, b_st)):
                rows[key].append(r)
                if r["outcome"] != "solved":
                    notes.append(f"{mounting} {key} seed {seed}: {r['outcome']}: {r['why']}")
        m = {k: medians(v) for k, v in rows.items()}
        names = {"a": "a centres, 30 general, no nominal", "a-station": "  station plan 5 x 6",
                 "b": "b profiles, 40 general, nominal", "b-station": "  station plan 5 x 8",
                 "c": "c profiles, 40 general, no nominal"}
        for key in ("a", "a-station", "b", "b-station", "c"):
            r = m[key]
            ratio = ""
            if key in ("a", "b"):
                ref = m[f"{key}-station"]
                ratio = f"{r['rot'] / ref['rot']:9.2f} {r['trans'] / ref['trans']:8.2f}"
            elif key == "c":
                ref = m["b-station"]
                ratio = f"{r['rot'] / ref['rot']:9.2f} {r['trans'] / ref['trans']:8.2f}"
            print(f"{mounting:12} {names[key]:34} {r['solved']:3d} {r['refused']:3d} {r['wrong']:3d} {r['rot']:8.4f} "
                  f"{r['trans']:7.4f} {r['z']:6.2f} {r['nees']:6.1f} {ratio:>18} {r['s']:6.2f}")
    print(f"\nseeds per case: {args.seeds}; ok / ref / bad: solved, refused (error or RED), wrong with exit 0; "
          "ratio: median error over the station plan's (c: over b's station plan)")
    for note in notes:
        print(note)


if __name__ == "__main__":
    main()
