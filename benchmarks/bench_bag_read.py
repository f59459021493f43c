"""How fast a ROS 2 bag converts into a stream recording (spherecal.io.rosbag, .streams).

Writes a rosbag2 recording with rosbags: 10,000 profiles of 1,280 points (PointCloud2,
float32 x, y, z in metres, 200 Hz) and the flange pose at 250 Hz (PoseStamped) over the
same 50 s. Then converts it, each run in a fresh process: ``read_bag`` and
``write_recording`` (the stream format, version 3), on one core (the converting
process pinned, one BLAS thread). Prints the median of the runs in points a second
(target: at least 20 M/s; also by CPU time, which a busy machine disturbs less), the
converting process's peak memory (and what it held before converting), and the median
time ``read_recording`` takes to read the stream file back (target: well under 2 s).

    python benchmarks/bench_bag_read.py [--profiles 10000] [--points 1280] [--runs 3] [--storage mcap|sqlite3]
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ[_var] = "1"  # one core, as the figures are stated (children inherit it)

import numpy as np  # noqa: E402 - after the thread settings


def write_bag(path: Path, storage: str, n_profiles: int, n_points: int) -> int:
    """The benchmark's bag; returns the number of points."""
    from rosbags.rosbag2 import Writer
    from rosbags.rosbag2.enums import StoragePlugin
    from rosbags.typesys import Stores, get_typestore

    ts = get_typestore(Stores.ROS2_HUMBLE)
    T = ts.types
    cloud_t, pose_t = "sensor_msgs/msg/PointCloud2", "geometry_msgs/msg/PoseStamped"

    def header(ns, frame):
        return T["std_msgs/msg/Header"](stamp=T["builtin_interfaces/msg/Time"](sec=ns // 10**9, nanosec=ns % 10**9),
                                        frame_id=frame)

    fields = [T["sensor_msgs/msg/PointField"](name=a, offset=4 * i, datatype=7, count=1) for i, a in enumerate("xyz")]
    rng = np.random.default_rng(0)
    t0 = 1_767_600_000_000_000_000
    profile_period, pose_period = 5_000_000, 4_000_000  # 200 Hz, 250 Hz
    n_poses = (n_profiles * profile_period) // pose_period + 10
    angle = np.linspace(-1.0, 1.0, n_points)
    plugin = StoragePlugin.MCAP if storage == "mcap" else StoragePlugin.SQLITE3
    with Writer(path, version=9, storage_plugin=plugin) as w:
        cc = w.add_connection("/profiles", cloud_t, typestore=ts)
        pc = w.add_connection("/robot/flange_pose", pose_t, typestore=ts)
        pose_ns = t0 - 20_000_000 + pose_period * np.arange(n_poses)
        next_pose = 0
        for j in range(n_profiles):
            ns = t0 + profile_period * j
            while next_pose < n_poses and pose_ns[next_pose] <= ns:
                p = int(pose_ns[next_pose])
                s = next_pose / n_poses
                msg = T[pose_t](header=header(p, "base_link"), pose=T["geometry_msgs/msg/Pose"](
                    position=T["geometry_msgs/msg/Point"](x=0.9 + 0.1 * s, y=-0.15, z=0.6),
                    orientation=T["geometry_msgs/msg/Quaternion"](x=0.0, y=1.0, z=0.0, w=0.0)))
                w.write(pc, p + 1_000_000, ts.serialize_cdr(msg, pose_t))
                next_pose += 1
            r = 0.019 * rng.uniform(0.5, 1.0)
            xyz = np.zeros((n_points, 3), np.float32)
            xyz[:, 1] = r * np.sin(angle)
            xyz[:, 2] = -0.02 + r * np.cos(angle) + rng.normal(0, 1e-5, n_points)
            msg = T[cloud_t](header=header(ns, "sensor"), height=1, width=n_points, fields=fields, is_bigendian=False,
                             point_step=12, row_step=12 * n_points, data=xyz.view(np.uint8).ravel(), is_dense=True)
            w.write(cc, ns + 3_000_000 + j * 250, ts.serialize_cdr(msg, cloud_t))  # a sensor clock 50 ppm slow
        while next_pose < n_poses:
            p = int(pose_ns[next_pose])
            msg = T[pose_t](header=header(p, "base_link"), pose=T["geometry_msgs/msg/Pose"](
                position=T["geometry_msgs/msg/Point"](x=1.0, y=-0.15, z=0.6),
                orientation=T["geometry_msgs/msg/Quaternion"](x=0.0, y=1.0, z=0.0, w=0.0)))
            w.write(pc, p + 1_000_000, ts.serialize_cdr(msg, pose_t))
            next_pose += 1
    return n_profiles * n_points


def convert(bag: str, out: str) -> None:
    """One conversion (run in its own process): prints JSON with the time and memory."""
    import warnings

    if hasattr(os, "sched_setaffinity"):
        os.sched_setaffinity(0, {min(os.sched_getaffinity(0))})  # one core
    t = time.perf_counter()
    import rosbags.rosbag2  # noqa: F401 - read_bag imports it on first use: timed apart, once per process

    from spherecal.io.rosbag import read_bag
    from spherecal.io.streams import write_recording

    t_import = time.perf_counter() - t
    before_kb = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    cpu = time.process_time()
    t = time.perf_counter()
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # a clean bag converts without warnings
        rec = read_bag(bag, profile_topic="/profiles", pose_topic="/robot/flange_pose", mounting="eye_in_hand",
                       sphere_radius_mm=19.05)
    t_read = time.perf_counter() - t
    write_recording(out, rec, overwrite=True)
    total = time.perf_counter() - t
    cpu = time.process_time() - cpu
    peak_kb = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    print(json.dumps({"seconds": total, "cpu_s": cpu, "import_s": t_import, "read_bag_s": t_read, "points": int(rec.profiles.start[-1]),
                      "peak_mb": peak_kb / 1024, "before_mb": before_kb / 1024}))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--profiles", type=int, default=10_000)
    ap.add_argument("--points", type=int, default=1_280)
    ap.add_argument("--runs", type=int, default=3)
    ap.add_argument("--storage", choices=("mcap", "sqlite3"), default="mcap")
    ap.add_argument("--convert", nargs=2, metavar=("BAG", "OUT"), help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.convert:
        convert(*args.convert)
        return
    with tempfile.TemporaryDirectory() as tmp:
        bag = Path(tmp) / "bench_bag"
        t = time.perf_counter()
        n = write_bag(bag, args.storage, args.profiles, args.points)
        size = sum(f.stat().st_size for f in bag.iterdir()) / 1e6
        print(f"bag: {args.profiles} profiles x {args.points} points = {n / 1e6:.1f} M points, {args.storage}, "
              f"{size:.0f} MB, written in {time.perf_counter() - t:.1f} s")
        runs = []
        for k in range(args.runs):
            # each run writes a new file, as a conversion into a new output folder does (replacing
            # a file of 140 MB costs its unlinking, about 0.1 s here, which is not the conversion's)
            out = Path(tmp) / f"bench-{k}.stream.jsonl"
            res = subprocess.run([sys.executable, __file__, "--convert", str(bag), str(out)], check=True,
                                 capture_output=True, text=True)
            runs.append(json.loads(res.stdout.strip().splitlines()[-1]))
        secs = statistics.median(r["seconds"] for r in runs)
        cpu = statistics.median(r["cpu_s"] for r in runs)
        print(f"convert (read_bag + write_recording), median of {args.runs}: {secs:.3f} s "
              f"(read_bag {statistics.median(r['read_bag_s'] for r in runs):.3f} s) = "
              f"{n / secs / 1e6:.1f} M points/s (target >= 20); CPU time {cpu:.3f} s = {n / cpu / 1e6:.1f} M points/s")
        print(f"  (importing rosbags and spherecal's readers, once per process: "
              f"{statistics.median(r['import_s'] for r in runs):.2f} s, not counted)")
        print(f"  peak memory of the converting process: {max(r['peak_mb'] for r in runs):.0f} MB "
              f"({statistics.median(r['before_mb'] for r in runs):.0f} MB before converting); "
              f"stream file {out.stat().st_size / 1e6:.0f} MB")
        from spherecal.io.streams import read_recording

        times = []
        for _ in range(args.runs):
            t = time.perf_counter()
            rec = read_recording(out)
            times.append(time.perf_counter() - t)
        assert rec.profiles.start[-1] == n
        print(f"read_recording of the stream file, median of {args.runs}: {statistics.median(times):.3f} s "
              f"= {n / statistics.median(times) / 1e6:.1f} M points/s")


if __name__ == "__main__":
    main()
