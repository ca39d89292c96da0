"""Simulator speed: one hour of a pedestrian in office_45x55 (200 Hz IMU, BLE from 79 beacons).

Prints wall time per phase, peak memory, and ratios against two references measured or fixed in the
same run: the issue's budget (60 s for the hour) and real time (3600 s of data).

    .venv/bin/python benchmarks/sim_speed.py [--duration 3600] [--preset office_45x55]
"""

from __future__ import annotations

import argparse
import resource
import tempfile
import time
from pathlib import Path

from blenav.configs import compose

from blenav.cli.sim import run  # registers the sim schema

BUDGET_S = 60.0


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--duration", type=float, default=3600.0)
    p.add_argument("--preset", default="office_45x55")
    p.add_argument("--seed", type=int, default=0)
    args = p.parse_args()

    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp) / "bench"
        cfg = compose("sim", *[f"sim={args.preset}", f"seed={args.seed}", f"out={out}",
                                                    f"duration_s={args.duration}", "sessions=1",
                                                    "progress=false", "sim.carriers=[pedestrian]"])
        rss0 = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
        t0 = time.perf_counter()
        run(cfg)
        wall = time.perf_counter() - t0
        peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
        files = {f.name: f for f in out.rglob("*.csv")}
        rows = {n: sum(1 for _ in open(f)) - 1 for n, f in files.items() if n in ("imu.csv", "rssi.csv", "rtt.csv")}
        size = sum(f.stat().st_size for f in out.rglob("*") if f.is_file()) / 2**20
    hours = args.duration / 3600.0
    print(f"preset {args.preset}, {args.duration:.0f} s of a pedestrian, seed {args.seed}")
    print("rows written: " + ", ".join(f"{k} {v:,}" for k, v in rows.items()) + f"; {size:.1f} MiB on disk")
    print(f"wall time            {wall:8.2f} s")
    print(f"peak RSS             {peak:8.0f} MiB (process; {rss0:.0f} MiB before simulating)")
    print(f"budget (60 s / h)    {BUDGET_S * hours:8.2f} s  -> {wall / (BUDGET_S * hours):.2f} x budget")
    print(f"real time            {args.duration:8.0f} s  -> {args.duration / wall:.0f} x faster than real time")
    ok = wall <= BUDGET_S * hours
    print("PASS" if ok else "OVER BUDGET")


if __name__ == "__main__":
    main()
