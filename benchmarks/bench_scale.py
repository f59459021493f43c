"""Speed and memory of ``solve`` as datasets grow, and the mapping throughput of the
default install, against the targets in docs/estimation.md. One core.

Datasets come from the simulator (the standard eye-in-hand cell, 4 stations, about 460
points a profile): 40, 400 and 4,000 profiles (18 k, 185 k and 1.85 M points) and, with
``--huge``, 5,000 profiles of about 1,000 points (5 M points, a sensor of 1,400
columns). Each is written once to a dataset file (JSON Lines, cached in ``--cache``) and
solved in a fresh Python process per size and measurement, pinned to one CPU with one
BLAS thread, so that sizes share neither caches nor memory peaks:

* a timing run: wall and CPU time of :func:`spherecal.estimation.solve` on the loaded
  dataset (no report, no exports), the process's resident set before ``solve`` and its
  peak (``ru_maxrss``, MB: everything the process held at its worst, imports and
  dataset included);
* a tracing run (``tracemalloc`` started just before ``solve``): the peak of the memory
  ``solve`` allocated on top of the loaded dataset, MB, and per point, bytes.

"ratio" is the figure's ratio to the previous size's: with 10 x the points, a
linear solver shows about 10. Then ``spherecal solve --no-report`` is timed end to end
(process start to exit, imports and reading the file included) on the smallest set, with
Python's cache of compiled modules as an install has it, beside the floor of importing
NumPy and pydantic alone.

The mapping figures: :func:`spherecal.core.mapping.map_profiles` with the NumPy backend (the
default install has no numba) on 2,000 profiles x 3,200 points, median of ``--repeats``,
in million points per second and as a fraction of the speed of a plain copy of the same
output (``np.copyto``, the memory-bound limit). The targets: at least 100 M
points/s and 0.25 of a copy.

The machine's load average is printed first: on a shared machine, times vary with it.

With ``--report``: the HTML report (every figure) on about 1 M points (2,160 profiles),
timed on its own after a solve; the target is under 3 s.

Run:  python benchmarks/bench_scale.py [--huge] [--report] [--repeats 9] [--cache DIR] [--skip-mapping]
"""

from __future__ import annotations

import os

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "NUMBA_NUM_THREADS"):
    os.environ[_var] = "1"

import argparse  # noqa: E402
import json  # noqa: E402
import subprocess  # noqa: E402
import sys  # noqa: E402
import tempfile  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

#: (label, profiles per station (4 stations), sensor columns)
SIZES = [("18 k", 10, 640), ("185 k", 100, 640), ("1.85 M", 1000, 640)]
HUGE = ("5 M", 1250, 1400)
#: The report's size (``--report``): about 1 M points, 2,160 profiles.
REPORT = ("1 M", 540, 640)
SEED = 13


def _pin_one_cpu() -> str:
    try:
        os.sched_setaffinity(0, {sorted(os.sched_getaffinity(0))[0]})
        return "pinned to one CPU"
    except (AttributeError, OSError):
        return "not pinned (no sched_setaffinity)"


def _rss_mb() -> float:
    """Resident set now, MB (Linux; NaN elsewhere)."""
    try:
        with open("/proc/self/statm") as f:
            return int(f.read().split()[1]) * os.sysconf("SC_PAGE_SIZE") / 1e6
    except OSError:
        return float("nan")


def dataset_file(cache: Path, per_station: int, columns: int) -> Path:
    """The simulated dataset for one size, written once into ``cache``."""
    path = cache / f"scale-{per_station}x4-{columns}col-seed{SEED}.jsonl"
    if path.exists():
        return path
    from spherecal.io import dataset as dataio
    from spherecal.sim import SweepPlan, simulate_dataset, standard_cell

    sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))
    from reference_sensor import reference_fov  # the reference sensor's field of view

    cell = standard_cell("eye_in_hand", seed=SEED, fov=reference_fov(n_columns=columns))
    ds = simulate_dataset(cell, SweepPlan(profiles_per_station=per_station))
    tmp = path.with_suffix(".part")
    dataio.write_dataset(tmp, ds, overwrite=True)
    tmp.replace(path)
    return path


def child(path: str, mode: str) -> None:
    """One measurement in this (fresh) process; prints one JSON line."""
    import gc
    import resource

    _pin_one_cpu()
    from spherecal.io import dataset as dataio
    from spherecal.estimation import CalibrationOptions, solve

    ds = dataio.read_dataset(path)
    n_points = sum(o.profile.y_mm.size for o in ds.observations if o.profile is not None)
    gc.collect()
    rss_before = _rss_mb()
    if mode == "report":  # what the HTML report adds to a solve (not timed): its imports, figures, HTML
        import tempfile as _tempfile

        sol = solve(ds, CalibrationOptions(), progress=lambda _m: None)
        with _tempfile.TemporaryDirectory() as tmp:
            wall, cpu = time.perf_counter(), time.process_time()
            from spherecal.report.html import write_report  # (matplotlib with it)

            write_report(sol, Path(tmp))
            wall, cpu = time.perf_counter() - wall, time.process_time() - cpu
        print(json.dumps({"points": n_points, "profiles": len(ds.observations), "wall_s": wall, "cpu_s": cpu}))
        return
    if mode == "trace":
        import tracemalloc

        tracemalloc.start()
    wall, cpu = time.perf_counter(), time.process_time()
    sol = solve(ds, CalibrationOptions(), progress=lambda _m: None)
    wall, cpu = time.perf_counter() - wall, time.process_time() - cpu
    out = {"points": n_points, "profiles": len(ds.observations), "wall_s": wall, "cpu_s": cpu,
           "rss_before_mb": rss_before, "maxrss_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1e3,
           "points_used": sol.result.residuals.n_points_used,
           "translation_mm": list(sol.result.transform.translation_mm)}
    if mode == "trace":
        out["traced_peak_mb"] = tracemalloc.get_traced_memory()[1] / 1e6
        tracemalloc.stop()
    print(json.dumps(out))


def _run_child(path: Path, mode: str) -> dict:
    proc = subprocess.run([sys.executable, __file__, "--child", str(path), "--mode", mode],
                          capture_output=True, text=True, check=False)
    if proc.returncode != 0:
        raise SystemExit(f"bench_scale: the {mode} run on {path} failed:\n{proc.stderr}")
    return json.loads(proc.stdout.strip().splitlines()[-1])


def _ratio(now: float, before: float | None) -> str:
    return f"{now / before:6.1f}" if before else f"{'':>6}"


def solve_table(cache: Path, sizes) -> None:
    print(f"{'size':>7} {'points':>9} {'wall s':>7} {'ratio':>6} {'CPU s':>7} {'ratio':>6} {'RSS0 MB':>8} "
          f"{'maxRSS MB':>9} {'ratio':>6} {'solve MB':>8} {'B/pt':>5} {'ratio':>6}")
    prev = None
    for label, per_station, columns in sizes:
        path = dataset_file(cache, per_station, columns)
        t = _run_child(path, "time")
        m = _run_child(path, "trace")
        n = t["points"]
        print(f"{label:>7} {n:9d} {t['wall_s']:7.2f} {_ratio(t['wall_s'], prev and prev[0])} {t['cpu_s']:7.2f} "
              f"{_ratio(t['cpu_s'], prev and prev[1])} {t['rss_before_mb']:8.0f} {t['maxrss_mb']:9.0f} "
              f"{_ratio(t['maxrss_mb'], prev and prev[2])} {m['traced_peak_mb']:8.0f} "
              f"{m['traced_peak_mb'] * 1e6 / n:5.0f} {_ratio(m['traced_peak_mb'], prev and prev[3])}", flush=True)
        prev = (t["wall_s"], t["cpu_s"], t["maxrss_mb"], m["traced_peak_mb"])


#: The floor of a program that validates its input with pydantic: NumPy, pydantic and one
#: model with a constrained field, built and used (pydantic then loads its validators'
#: modules and looks for its own plugins).
ONE_MODEL = ("import numpy\nfrom pydantic import BaseModel, Field\n"
             "class M(BaseModel):\n    x: float = Field(1.0, gt=0)\nM(x=2.0)")


def cli_start(cache: Path) -> None:
    """``spherecal solve --no-report`` end to end on the smallest set, median of 3, as a
    user's install runs it: Python caches the compiled modules (``PYTHONDONTWRITEBYTECODE``
    is dropped from the environment, and a first run fills the cache). Beside it, the
    floor no program built on NumPy and pydantic can go below on this machine: Python
    importing those two, and importing them and validating one model (:data:`ONE_MODEL`)."""
    path = dataset_file(cache, SIZES[0][1], SIZES[0][2])
    exe = Path(sys.executable).with_name("spherecal")
    cmd = [str(exe)] if exe.exists() else [sys.executable, "-m", "spherecal.cli"]
    env = {k: v for k, v in os.environ.items() if k != "PYTHONDONTWRITEBYTECODE"}

    def wall(args) -> float:
        t = time.perf_counter()
        proc = subprocess.run(args, capture_output=True, text=True, check=False, env=env)
        if proc.returncode not in (0, 7):
            raise SystemExit(f"bench_scale: {' '.join(args)} failed:\n{proc.stderr}")
        return time.perf_counter() - t

    with tempfile.TemporaryDirectory() as tmp:
        runs = [wall([*cmd, "solve", str(path), "--no-report", "--out", str(Path(tmp) / f"r{i}")]) for i in range(4)]
        solve_s = sorted(runs[1:])[1]  # (the first run compiled what was not cached yet)
        help_s = sorted(wall([*cmd, "--help"]) for _ in range(3))[1]
        floor_s = sorted(wall([sys.executable, "-c", "import numpy, pydantic.main"]) for _ in range(3))[1]
        model_s = sorted(wall([sys.executable, "-c", ONE_MODEL]) for _ in range(3))[1]
    print(f"spherecal solve --no-report, {SIZES[0][0]} points, end to end: {solve_s:.2f} s wall (median of 3); "
          f"spherecal --help: {help_s:.2f} s; python -c 'import numpy, pydantic': {floor_s:.2f} s; "
          f"the same and one validated model: {model_s:.2f} s")


def report_time(cache: Path) -> None:
    """The report (write_report: every figure and the HTML) on about 1 M points, after
    the solve, in a fresh process (matplotlib's import included)."""
    label, per_station, columns = REPORT
    r = _run_child(dataset_file(cache, per_station, columns), "report")
    print(f"report on {r['points']} points ({r['profiles']} profiles): {r['wall_s']:.2f} s wall, {r['cpu_s']:.2f} s "
          "CPU, on top of the solve (importing the report's modules and matplotlib included)")


def mapping_table(repeats: int) -> None:
    import numpy as np

    from spherecal.core import geometry as geo
    from spherecal.core.mapping import map_profiles

    def median_s(fn) -> tuple[float, float]:
        """Median wall and median CPU seconds of one call."""
        fn()
        walls, cpus = [], []
        for _ in range(repeats):
            t, c = time.perf_counter(), time.process_time()
            fn()
            walls.append(time.perf_counter() - t)
            cpus.append(time.process_time() - c)
        return float(np.median(walls)), float(np.median(cpus))

    n, m = 2000, 3200
    rng = np.random.default_rng(0)
    R = geo.matrix_from_rotvec(rng.normal(size=(n, 3)))
    t = rng.uniform(-1500, 1500, (n, 3))
    print(f"mapping {n} profiles x {m} points, NumPy backend, median of {repeats} (wall; and CPU time, which a "
          "loaded machine disturbs less)")
    print(f"{'in':>8} {'out':>8} {'ms':>7} {'Mpts/s':>7} {'vs copy':>8} {'copy ms':>8} {'CPU ms':>7} {'Mpts/s':>7} "
          f"{'vs copy':>8} {'copy CPU':>8}")
    for in_dtype, out_dtype in ((np.float64, np.float64), (np.float32, np.float32), (np.float32, np.float64)):
        y = rng.uniform(-24, 24, (n, m)).astype(in_dtype)
        z = rng.uniform(-60, 40, (n, m)).astype(in_dtype)
        y[:, ::50] = np.nan
        out = np.empty((n, m, 3), dtype=out_dtype)
        src = np.ones_like(out)
        copy_wall, copy_cpu = median_s(lambda: np.copyto(out, src))
        wall, cpu = median_s(lambda: map_profiles(R, t, y, z, out, backend="numpy"))
        flag = "" if n * m / cpu >= 100e6 and copy_cpu / cpu >= 0.25 else "  below target (CPU)"
        print(f"{np.dtype(in_dtype).name:>8} {np.dtype(out_dtype).name:>8} {wall * 1e3:7.1f} {n * m / wall / 1e6:7.0f} "
              f"{copy_wall / wall:8.2f} {copy_wall * 1e3:8.1f} {cpu * 1e3:7.1f} {n * m / cpu / 1e6:7.0f} "
              f"{copy_cpu / cpu:8.2f} {copy_cpu * 1e3:8.1f}{flag}")
        del out, src


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--huge", action="store_true", help="add the 5 M point set (minutes; about 0.5 GB peak)")
    ap.add_argument("--repeats", type=int, default=9, help="mapping: repeats per figure (median)")
    ap.add_argument("--cache", type=Path, default=Path(tempfile.gettempdir()) / "spherecal-bench-scale",
                    help="folder for the simulated dataset files (kept between runs)")
    ap.add_argument("--skip-solve", action="store_true")
    ap.add_argument("--skip-mapping", action="store_true")
    ap.add_argument("--child", help=argparse.SUPPRESS)
    ap.add_argument("--report", action="store_true", help="add the report's time on about 1 M points (a minute)")
    ap.add_argument("--mode", choices=("time", "trace", "report"), help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.child:
        child(args.child, args.mode)
        return
    args.cache.mkdir(parents=True, exist_ok=True)
    pinned = _pin_one_cpu()
    print(f"load average {' '.join(f'{x:.2f}' for x in os.getloadavg())}, {os.cpu_count()} CPUs, {pinned}, "
          f"Python {sys.version.split()[0]}")
    if not args.skip_solve:
        solve_table(args.cache, SIZES + ([HUGE] if args.huge else []))
        cli_start(args.cache)
    if args.report:
        report_time(args.cache)
    if not args.skip_mapping:
        mapping_table(args.repeats)
    print(f"load average {' '.join(f'{x:.2f}' for x in os.getloadavg())}")


if __name__ == "__main__":
    main()
