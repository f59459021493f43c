"""What an on-the-fly simulation costs (spherecal.sim.streams): time and peak memory.

Simulates the default on-the-fly plan (four stations, 32 sweeps) on the standard
eye-in-hand cell with the IRB 2400's arm and its geometric error, with the profiler's
rate and line resolution raised so that about 10,000 profiles see the sphere with
about 1,280 points each on average (12.8 M points; the line's columns are 1 / 0.65 of
that: a sphere crossing fills 65 % of the line on average). Prints the time and the
process's peak resident set, before the simulation (imports, the cell) and after.

    python benchmarks/bench_sim_streams.py [--seeing 10000] [--points 1280] [--no-arm]
"""

from __future__ import annotations

import argparse
import resource
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))

from reference_sensor import reference_fov  # noqa: E402

from spherecal.config import OnTheFlyPlan, SensorStreamSettings, StreamSimSettings  # noqa: E402
from spherecal.sim import RobotErrorModel, simulate_recording, standard_cell  # noqa: E402

#: Shares measured on the default plan at 300 Hz: profiles that see the sphere per
#: exposure second, and the share of the line's columns such a profile fills.
SEEING_PER_S_AT_300_HZ = 5930 / 47.806
FILL = 0.652


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeing", type=int, default=10_000, help="profiles that see the sphere (about)")
    ap.add_argument("--points", type=int, default=1280, help="mean points per such profile (about)")
    ap.add_argument("--no-arm", action="store_true", help="no arm: the commanded path is the flange's")
    a = ap.parse_args()
    arm = None
    if not a.no_arm:
        from spherecal.plugins.host import PluginHost

        arm = PluginHost(autoload=False).arm_kinematics({"type": "abb_irb2400"})
    duration_s = 47.806
    rate_hz = 300.0 * a.seeing / (SEEING_PER_S_AT_300_HZ * duration_s)
    cell = standard_cell("eye_in_hand", seed=0, fov=reference_fov(n_columns=round(a.points / FILL)), arm=arm,
                         robot_error=RobotErrorModel() if arm else None)
    settings = StreamSimSettings(sensor=SensorStreamSettings(rate_hz=rate_hz))
    rss0_mb = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    t0 = time.perf_counter()
    rec = simulate_recording(cell, OnTheFlyPlan(), settings)
    seconds = time.perf_counter() - t0
    rss_mb = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    counts = rec.profiles.counts
    seeing = counts > 0
    print(f"arm: {'IRB 2400 with geometric error' if arm else 'none'}; line {cell.fov.n_columns} columns; "
          f"profiler {rate_hz:.0f} Hz; {rec.provenance['duration_s']:.1f} s of motion, {len(rec.sweeps)} sweeps")
    print(f"pose samples {rec.poses.n}; profiles {rec.profiles.n} ({int(seeing.sum())} see the sphere, "
          f"{counts[seeing].mean():.0f} points each on average); points {len(rec.profiles.points_yz_mm) / 1e6:.2f} M")
    print(f"time {seconds:.2f} s; peak RSS {rss_mb:.0f} MiB ({rss0_mb:.0f} MiB before simulating)")


if __name__ == "__main__":
    main()
