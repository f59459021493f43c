"""Speed and memory of solving a large recording with the time model, one core.

The recording: the default on-the-fly plan (4 stations, 32 sweeps, 48 s) on the standard
eye-in-hand cell, the profiler's rate and line resolution raised so that about
``--seeing`` profiles see the sphere with about ``--points`` points each (default 10,000 x
1,280 = 12.8 M points), simulated once and written in the stream form to ``--cache``.
Then, in a fresh Python process pinned to one CPU with one BLAS thread:
reading the file (``read_recording``) and
:func:`spherecal.estimation.on_the_fly.solve_recording` (the offset searched from
nothing, the clock relation, the transform and the sphere fitted over every point),
wall and CPU time of each, and the process's peak resident set (``ru_maxrss``: imports,
the recording and the solve at their worst). ``--repeats`` runs give the median.

Targets (docs/on-the-fly.md): the solve under 15 s, the peak under 1 GB.

Run:  python benchmarks/bench_on_the_fly_scale.py [--seeing 10000] [--points 1280] [--repeats 3] [--cache DIR]
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ[_var] = "1"

CHILD = r"""
import json, os, resource, sys, time
os.sched_setaffinity(0, {min(os.sched_getaffinity(0))})
from spherecal.io.streams import read_recording
from spherecal.estimation.on_the_fly import solve_recording
t0, c0 = time.perf_counter(), time.process_time()
rec = read_recording(sys.argv[1])
t1, c1 = time.perf_counter(), time.process_time()
sol = solve_recording(rec)
t2, c2 = time.perf_counter(), time.process_time()
r = sol.result
print(json.dumps({"read_s": t1 - t0, "solve_s": t2 - t1, "solve_cpu_s": c2 - c1,
                  "peak_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024,
                  "points": int(len(rec.profiles.points_yz_mm)), "used": r.residuals.n_points_used,
                  "offset_err_ms": r.timing.offset_ms - 1e3 * rec.provenance["true_offset_s"],
                  "offset_sd_ms": r.timing.offset_std_ms}))
"""


def _simulate(path: Path, seeing: int, points: int) -> None:
    sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))
    from reference_sensor import reference_fov

    from spherecal.config import OnTheFlyPlan, SensorStreamSettings, StreamSimSettings
    from spherecal.io.streams import write_recording
    from spherecal.sim import simulate_recording, standard_cell

    seeing_per_s_at_300_hz, duration_s, fill = 5930 / 47.806, 47.806, 0.652  # measured on the default plan
    rate_hz = 300.0 * seeing / (seeing_per_s_at_300_hz * duration_s)
    cell = standard_cell("eye_in_hand", seed=0, fov=reference_fov(n_columns=round(points / fill)))
    rec = simulate_recording(cell, OnTheFlyPlan(), StreamSimSettings(sensor=SensorStreamSettings(rate_hz=rate_hz)))
    write_recording(path, rec, overwrite=True)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeing", type=int, default=10_000)
    ap.add_argument("--points", type=int, default=1280)
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--cache", default=tempfile.gettempdir())
    a = ap.parse_args()
    path = Path(a.cache) / f"spherecal-bench-otf-{a.seeing}x{a.points}.stream.jsonl"
    if not path.exists():
        _simulate(path, a.seeing, a.points)
    print(f"load average {os.getloadavg()[0]:.2f}; recording {path} ({path.stat().st_size / 1e6:.0f} MB)")
    runs = []
    for _ in range(a.repeats):
        out = subprocess.run([sys.executable, "-c", CHILD, str(path)], capture_output=True, text=True, check=True)
        runs.append(json.loads(out.stdout.strip().splitlines()[-1]))
        r = runs[-1]
        print(f"  read {r['read_s']:.2f} s; solve {r['solve_s']:.2f} s wall, {r['solve_cpu_s']:.2f} s CPU; peak "
              f"{r['peak_mb']:.0f} MB; {r['points'] / 1e6:.2f} M points ({r['used'] / 1e6:.2f} M used); offset error "
              f"{r['offset_err_ms']:+.4f} ms (sd {r['offset_sd_ms']:.4f})", flush=True)
    med = {k: sorted(r[k] for r in runs)[len(runs) // 2] for k in ("read_s", "solve_s", "peak_mb")}
    print(f"median of {len(runs)}: read {med['read_s']:.2f} s, solve {med['solve_s']:.2f} s (target < 15 s), peak "
          f"{med['peak_mb']:.0f} MB (target < 1000 MB); {runs[0]['points'] / med['solve_s'] / 1e6:.2f} M points/s")


if __name__ == "__main__":
    main()
