"""How fast a dataset file loads and saves (spherecal.io.dataset).

Builds a dataset of 1,000 profiles of 1,000 points (an arc of a 19.05 mm sphere with
10 um noise, every value at full double precision, the worst case for parsing; and the
same values rounded to the sensor's 5 um resolution), writes it, reads it back several
times and prints the median times. The target is a load of <= 0.3 s on the 2-core
reference machine. Run with the stdlib parser as well (``--no-orjson``) to see what
the optional orjson accelerator buys.

    python benchmarks/bench_load.py [--profiles 1000] [--points 1000] [--repeat 5] [--no-orjson]
"""

from __future__ import annotations

import argparse
import statistics
import tempfile
import time
import warnings
from datetime import datetime, timedelta, timezone
from pathlib import Path

import numpy as np

from spherecal.io import dataset as dataio
from spherecal.io import observation_line
from spherecal.core.models import Dataset, Observation, Pose, Profile


def make_dataset(n_profiles: int, n_points: int, resolution_mm: float | None, seed: int = 0) -> Dataset:
    rng = np.random.default_rng(seed)
    t0 = datetime(2026, 1, 1, tzinfo=timezone.utc)
    radius = 19.05
    obs = []
    for i in range(n_profiles):
        r_cut = radius * rng.uniform(0.5, 1.0)
        a = np.linspace(-1.2, 1.2, n_points)
        y = r_cut * np.sin(a) + rng.normal(0.0, 0.01, n_points)
        z = -20.0 + r_cut * np.cos(a) + rng.normal(0.0, 0.01, n_points)
        if resolution_mm:
            y = np.round(y / resolution_mm) * resolution_mm
            z = np.round(z / resolution_mm) * resolution_mm
        q = rng.normal(size=4)
        q /= np.linalg.norm(q)
        pose = Pose(translation_mm=tuple(rng.uniform(-1500, 1500, 3).tolist()), quaternion_wxyz=tuple(q.tolist()))
        obs.append(
            Observation(
                index=i,
                station=f"S{i // 10 + 1}",
                timestamp=t0 + timedelta(seconds=0.5 * i),
                base_from_flange=pose,
                joints_deg=tuple(rng.uniform(-90, 90, 6).tolist()),
                profile=Profile(y_mm=y, z_mm=z),
            )
        )
    return Dataset(mounting="eye_in_hand", sphere_radius_mm=radius, observations=obs, provenance={"source": "bench"})


def median_time(fn, repeat: int) -> float:
    times = []
    for _ in range(repeat):
        t = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t)
    return statistics.median(times)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--profiles", type=int, default=1000)
    ap.add_argument("--points", type=int, default=1000)
    ap.add_argument("--repeat", type=int, default=5)
    ap.add_argument("--no-orjson", action="store_true", help="use the standard library's json only")
    args = ap.parse_args()
    if args.no_orjson:
        observation_line._orjson = None
    parser = "orjson" if observation_line._orjson is not None else "stdlib json"
    print(f"{args.profiles} profiles x {args.points} points, parser: {parser}, median of {args.repeat}")
    with tempfile.TemporaryDirectory() as tmp:
        for label, resolution in (("full precision", None), ("5 um resolution", 0.005)):
            ds = make_dataset(args.profiles, args.points, resolution)
            path = Path(tmp) / f"bench-{resolution}.dataset.jsonl"
            t_write = median_time(lambda: dataio.write_dataset(path, ds, overwrite=True), max(1, args.repeat // 2))
            size_mb = path.stat().st_size / 1e6
            with warnings.catch_warnings():
                warnings.simplefilter("error")  # a clean file must load without warnings
                t_read = median_time(lambda: dataio.read_dataset(path), args.repeat)
            back = dataio.read_dataset(path)
            assert len(back.observations) == args.profiles
            assert np.array_equal(back.observations[-1].profile.y_mm, ds.observations[-1].profile.y_mm)
            print(f"  {label:16s} file {size_mb:6.1f} MB   read_dataset {t_read:6.3f} s   write_dataset {t_write:6.3f} s")


if __name__ == "__main__":
    main()
