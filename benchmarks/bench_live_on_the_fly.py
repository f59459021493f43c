"""Live on-the-fly `spherecal calibrate` against stop-and-go on the same stations, through
the devices' real protocols on the simulated cell, with the arm's systematic geometric
error on.

For each seed and mounting two configurations are made from the shipped stop-and-go
example (examples/sim-eye-in-hand.toml, sim-eye-to-hand.toml) with the simulation seed
set and the station robot-error model for both:

* **stop-and-go**: as shipped (move, settle, one profile at a standstill);
* **on the fly**: the same stations, ``[acquisition] mode = "on_the_fly"`` (forth and back
  at 50 and 100 mm/s along two directions at each station), the IRB 2400 streaming its
  pose over EGM at 250 Hz on the controller's clock and the nxSensor-I streaming at
  ``--rate`` Hz on its own clock, the clock offset and drift estimated with the transform.

The simulated world gives the estimator what it does not assume: the arm's geometric
error (the controller reports its nominal model's pose of its joints), repeatability
noise smooth in time on the fly, the two clocks with offset, drift and jitter.

Each run is ``spherecal calibrate CONFIG --yes --no-report --json`` in its own process;
its JSON gives the error against the simulated truth, the stated uncertainty, the
verdict and the robot time. Printed per mounting: rotation (deg) and translation (mm)
error, median and RMS, for both; their ratio (on the fly / stop-and-go); the share within
2 stated sd (per axis, the largest |error| / sd); the clock offset error RMS (ms) and
error / sd RMS; profiles a minute of simulated robot time (all, and on the sphere); the
verdicts; the median wall time of a run.

    python benchmarks/bench_live_on_the_fly.py [--seeds 20] [--rate 100] [--mountings eye_in_hand,eye_to_hand]
"""

from __future__ import annotations

import argparse
import json
import os
import re
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
#: chi-square quantile of 3 degrees of freedom at the coverage of 2 sd in one (95.45 %)
CHI2_3DOF_2SD = 8.02
BASE = {"eye_in_hand": "sim-eye-in-hand.toml", "eye_to_hand": "sim-eye-to-hand.toml"}


def _set_in_section(text: str, section: str, lines: str) -> str:
    """``lines`` added at the top of ``[section]`` (the section appended when missing)."""
    pattern = re.compile(rf"(?m)^\[{re.escape(section)}\]\s*$")
    m = pattern.search(text)
    if m is None:
        return text.rstrip("\n") + f"\n\n[{section}]\n{lines}\n"
    return text[:m.end()] + "\n" + lines + text[m.end():]


def configs(mounting: str, seed: int, rate_hz: float, folder: Path) -> tuple[Path, Path]:
    text = (ROOT / "examples" / BASE[mounting]).read_text()
    text = re.sub(r"(?m)^output_dir = .*$", 'output_dir = "out-sg"', text)
    text = re.sub(r"(?m)^(\[simulation\]\s*\n)seed = \d+", rf"\g<1>seed = {seed}", text)
    text = _set_in_section(text, "calibration", 'robot_error_model = "station"')
    text = re.sub(r"(?m)^scan_object = .*$", "", text)
    sg = folder / f"{mounting}-{seed}-sg.toml"
    sg.write_text(text)
    otf = text.replace('output_dir = "out-sg"', 'output_dir = "out-otf"')
    otf = _set_in_section(otf, "sensor", f"rate_hz = {rate_hz}")
    otf = _set_in_section(otf, "acquisition", 'mode = "on_the_fly"')
    otf = otf.rstrip("\n") + ("\n\n[robot.egm]\nport = 0\nstall_timeout_s = 1.0\n\n"
                              "[acquisition.on_the_fly]\nspeeds_mm_s = [50.0, 100.0]\n")
    path = folder / f"{mounting}-{seed}-otf.toml"
    path.write_text(otf)
    return sg, path


def run(config: Path) -> dict:
    t = time.perf_counter()
    proc = subprocess.run([sys.executable, "-m", "spherecal.cli", "calibrate", str(config), "--yes", "--no-report",
                           "--json"], capture_output=True, text=True, cwd=config.parent)
    wall = time.perf_counter() - t
    try:
        doc = json.loads(proc.stdout)
    except json.JSONDecodeError:
        raise SystemExit(f"{config.name}: no JSON (exit {proc.returncode}):\n{proc.stderr[-2000:]}") from None
    doc["wall_s"] = wall
    if doc.get("error"):
        print(f"    {config.name}: exit {proc.returncode}: {str(doc['error'])[:400]}", flush=True)
    return doc


def _figures(doc: dict) -> dict:
    truth = doc.get("simulated_truth") or {}
    unc = doc.get("uncertainty") or {}
    out = {"rot": truth.get("rotation_error_deg", np.nan), "trans": truth.get("translation_error_mm", np.nan),
           "level": (doc.get("verdict") or {}).get("level", doc.get("exit_meaning")), "wall": doc["wall_s"],
           "acq": doc.get("acquisition") or {}}
    # the error per axis of the transform's parent frame against the stated sd there: within "2 sd" in 3-D
    # when the sum of squared ratios is below the chi-square quantile of 2 sd's coverage (95.45 %, 3 dof)
    out["within2"] = False
    if truth and unc.get("std_translation_mm"):
        from spherecal.core import geometry as geo

        tr = doc["transform"]
        e_t = np.subtract(tr["translation_mm"], truth["true_translation_mm"])
        R = geo.matrix_from_quat_wxyz(np.asarray([tr["quaternion_wxyz"]]))[0]
        R_true = geo.matrix_from_quat_wxyz(np.asarray([truth["true_quaternion_wxyz"]]))[0]
        e_r = np.degrees(geo.rotvec_from_matrix(R @ R_true.T))
        chi_t = float(np.sum((e_t / np.asarray(unc["std_translation_mm"])) ** 2))
        chi_r = float(np.sum((e_r / np.asarray(unc["std_rotation_deg"])) ** 2))
        out["within2"] = chi_t <= CHI2_3DOF_2SD and chi_r <= CHI2_3DOF_2SD
    out["offset_err"] = truth.get("clock_offset_error_ms")
    out["offset_z"] = truth.get("clock_offset_error_sd")
    return out


def _rms(values) -> float:
    v = np.asarray([x for x in values if x is not None], float)
    return float(np.sqrt(np.mean(v ** 2))) if v.size else float("nan")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=20)
    ap.add_argument("--first-seed", type=int, default=1)
    ap.add_argument("--rate", type=float, default=100.0, help="profiler rate on the fly, Hz (sensor clock)")
    ap.add_argument("--mountings", default="eye_in_hand,eye_to_hand")
    args = ap.parse_args()
    print(f"load average {os.getloadavg()[0]:.2f}; {args.seeds} seeds a mounting; profiler {args.rate:g} Hz on the fly")
    with tempfile.TemporaryDirectory() as tmp:
        for mounting in args.mountings.split(","):
            rows = []
            for seed in range(args.first_seed, args.first_seed + args.seeds):
                folder = Path(tmp) / f"{mounting}-{seed}"
                folder.mkdir()
                sg_cfg, otf_cfg = configs(mounting, seed, args.rate, folder)
                sg, otf = _figures(run(sg_cfg)), _figures(run(otf_cfg))
                rows.append((sg, otf))
                print(f"  {mounting} seed {seed}: stop-and-go {sg['rot']:.4f} deg {sg['trans']:.4f} mm {sg['level']}; "
                      f"on the fly {otf['rot']:.4f} deg {otf['trans']:.4f} mm {otf['level']}, offset error "
                      f"{otf['offset_err'] if otf['offset_err'] is None else round(otf['offset_err'], 4)} ms",
                      flush=True)
            _summary(mounting, rows)


def _summary(mounting: str, rows: list[tuple[dict, dict]]) -> None:
    sg = [r[0] for r in rows]
    otf = [r[1] for r in rows]

    def med(xs, k):
        return float(np.median([x[k] for x in xs]))

    def rms(xs, k):
        return _rms([x[k] for x in xs])

    print(f"{mounting}, {len(rows)} seeds:")
    for k, unit in (("rot", "deg"), ("trans", "mm")):
        print(f"  {k:5s} error: stop-and-go median {med(sg, k):.4f} {unit}, RMS {rms(sg, k):.4f}; on the fly median "
              f"{med(otf, k):.4f}, RMS {rms(otf, k):.4f}; ratio of medians {med(otf, k) / med(sg, k):.2f}, of RMS "
              f"{rms(otf, k) / rms(sg, k):.2f}")
    print(f"  within the stated uncertainty (3-D, 2 sd): stop-and-go {sum(x['within2'] for x in sg)}/{len(sg)}, "
          f"on the fly {sum(x['within2'] for x in otf)}/{len(otf)}")
    print(f"  clock offset error RMS {_rms([x['offset_err'] for x in otf]):.4f} ms, error / sd RMS "
          f"{_rms([x['offset_z'] for x in otf]):.2f}")
    rate_sg = statistics.median(x["acq"].get("profiles_per_minute", np.nan) for x in sg)
    rate_otf = statistics.median(x["acq"].get("profiles_per_minute", np.nan) for x in otf)
    print(f"  profiles a minute of simulated robot time, median: stop-and-go {rate_sg:.1f}, on the fly "
          f"{rate_otf:.1f} ({rate_otf / rate_sg:.0f} x)")
    levels = lambda xs: ", ".join(f"{n} {lv}" for lv, n in sorted(  # noqa: E731
        {lv: sum(x["level"] == lv for x in xs) for lv in {x["level"] for x in xs}}.items()))
    print(f"  verdicts: stop-and-go {levels(sg)}; on the fly {levels(otf)}")
    print(f"  wall time a run, median: stop-and-go {med(sg, 'wall'):.1f} s, on the fly {med(otf, 'wall'):.1f} s")


if __name__ == "__main__":
    main()
