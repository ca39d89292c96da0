"""Streaming cost over one hour: the per-step cost of ``OnlineLocalizer`` must not grow with the stream's length.

A 300 s office_45x55 session (79 beacons, 200 Hz IMU, magnetometer, inertial odometry) is replayed 12 times
back to back (times shifted, so one 3,600 s stream) into one :class:`~blenav.filters.online.OnlineLocalizer`
(the IMU model with 1000 particles, as the streaming figure of ``filter_speed.py``). Each push that closes a
filter step is timed (step assembly + filter step); the script prints the median over the steps of the first
and of the last 60 s and their ratio (flat: about 1).

    .venv/bin/python benchmarks/stream_flat.py [--hours 1] [--particles 1000] [--tile 300]
"""

from __future__ import annotations

import argparse
import os
import tempfile
import time
from pathlib import Path

import numpy as np
from blenav.configs import compose

from blenav.cli.sim import run as sim_run
from blenav.data import Dataset
from blenav.eval.harness import build_methods
from blenav.filters.calibration import apply_fit, fit_sessions
from blenav.filters.online import OnlineLocalizer, replay


def tiled(events: list, period: float, n: int):
    """The events ``n`` times, copy k shifted by k * period seconds."""
    for k in range(n):
        dt = k * period
        for e in events:
            yield (e[0], e[1] + dt, *e[2:])


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--hours", type=float, default=1.0)
    ap.add_argument("--particles", type=int, default=1000)
    ap.add_argument("--tile", type=float, default=300.0, help="length (s) of the simulated session that is tiled")
    ap.add_argument("--window", type=float, default=60.0, help="seconds at each end over which medians are taken")
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp) / "office"
        sim_run(compose("sim", *["sim=office_45x55", "seed=0", f"out={out}", f"duration_s={args.tile}",
                                 "sessions=1", "progress=false"]))
        s = Dataset.open(out).session(Dataset.open(out).session_ids[0])
        ev = replay(s)
        t0 = ev[0][1]
        period = ev[-1][1] - t0 + 0.005  # the next tile starts one IMU period after the last sample
        n_tiles = int(np.ceil(args.hours * 3600.0 / period))
        cfg = compose("eval", *["experiment=frontend_000", "data=x", f"filter.n_particles={args.particles}"])
        m = build_methods(cfg)["IMU"].method  # the particle-filter Method behind the localizer
        apply_fit(m.measurements, fit_sessions([s]))
        loc = OnlineLocalizer(m, s, n_runs=1, seed=0, t_start=t0)
        step_t, cost = [], []
        wall0 = time.perf_counter()
        for e in tiled(ev, period, n_tiles):
            c0 = time.perf_counter()
            res = loc.push_event(e)
            dt = time.perf_counter() - c0
            if res:
                step_t.append(res[-1].t - t0)
                cost.append(dt / len(res))
        wall = time.perf_counter() - wall0
    step_t, cost = np.array(step_t), np.array(cost) * 1e3
    end = step_t[-1]
    first = cost[step_t <= args.window]
    last = cost[step_t > end - args.window]
    print(f"stream: {end:.0f} s ({n_tiles} x {period:.0f} s office_45x55 session), IMU model, {args.particles} "
          f"particles, 1 run; {len(cost):,} steps in {wall:.0f} s; load average {os.getloadavg()[0]:.2f}")
    print(f"per-step cost (push that closes a step: step assembly + filter step), median: first {args.window:.0f} s "
          f"{np.median(first):.3f} ms, last {args.window:.0f} s {np.median(last):.3f} ms, "
          f"ratio last/first {np.median(last) / np.median(first):.2f} (flat: ~1)")


if __name__ == "__main__":
    main()
