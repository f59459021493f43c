"""Throughput of profile mapping (spherecal.core.mapping) on ONE core.

Maps n profiles of m points (y, z) into base with one transform per profile and reports
the median over repeats of: points per second, the ratio to a plain copy of the same
number of output bytes (np.copyto: the memory-bound limit), and the ratio to the fastest
profilers' rate (about 3,200 points at 16 kHz = 51.2 million points/s). The
target is at least 100 million points/s (docs/validation-and-scanning.md).

Run:  python benchmarks/bench_mapping.py [--profiles 2000] [--points 3200] [--repeats 15]
"""

from __future__ import annotations

import os

# one thread, before numpy is imported
for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "NUMBA_NUM_THREADS"):
    os.environ[_var] = "1"

import argparse  # noqa: E402
import time  # noqa: E402

import numpy as np  # noqa: E402

from spherecal.core import geometry as geo  # noqa: E402
from spherecal.core.mapping import NUMBA_AVAILABLE, map_profiles  # noqa: E402

PROFILER_RATE_PTS_PER_S = 3200 * 16000.0
TARGET_PTS_PER_S = 100e6


def _median_seconds(fn, repeats: int) -> float:
    fn()  # warm up (and compile)
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return float(np.median(times))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--profiles", type=int, default=2000)
    ap.add_argument("--points", type=int, default=3200)
    ap.add_argument("--repeats", type=int, default=15)
    args = ap.parse_args()
    try:
        os.sched_setaffinity(0, {sorted(os.sched_getaffinity(0))[0]})
        pinned = "pinned to one CPU"
    except (AttributeError, OSError):
        pinned = "not pinned (no sched_setaffinity)"
    n, m = args.profiles, args.points
    rng = np.random.default_rng(0)
    R = geo.matrix_from_rotvec(rng.normal(size=(n, 3)))
    t = rng.uniform(-1500, 1500, (n, 3))
    print(f"mapping {n} profiles x {m} points = {n * m / 1e6:.1f} M points, {pinned}, numba: {NUMBA_AVAILABLE}")
    print(f"{'input':>8} {'output':>8} {'backend':>8} {'ms':>8} {'Mpts/s':>8} {'vs copy':>8} {'vs 51M':>8}")
    for in_dtype in (np.float32, np.float64):
        y = rng.uniform(-24, 24, (n, m)).astype(in_dtype)
        z = rng.uniform(-60, 40, (n, m)).astype(in_dtype)
        y[:, ::50] = np.nan  # invalid columns, as a sensor delivers them
        for out_dtype in (np.float32, np.float64):
            out = np.empty((n, m, 3), dtype=out_dtype)
            src = np.ones_like(out)
            t_copy = _median_seconds(lambda: np.copyto(out, src), args.repeats)
            for backend in (("numba", "numpy") if NUMBA_AVAILABLE else ("numpy",)):
                sec = _median_seconds(lambda: map_profiles(R, t, y, z, out, backend=backend), args.repeats)
                rate = n * m / sec
                print(
                    f"{np.dtype(in_dtype).name:>8} {np.dtype(out_dtype).name:>8} {backend:>8} {sec * 1e3:8.1f} "
                    f"{rate / 1e6:8.0f} {t_copy / sec:8.2f} {rate / PROFILER_RATE_PTS_PER_S:8.2f}"
                    + ("" if rate >= TARGET_PTS_PER_S else "  below the 100 Mpts/s target")
                )
            print(f"{'':>8} {'':>8} {'copy':>8} {t_copy * 1e3:8.1f} {n * m / t_copy / 1e6:8.0f} {1.0:8.2f}")


if __name__ == "__main__":
    main()
