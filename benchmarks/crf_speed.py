"""CRF speed (issue 15): one hour of data on a ~2,500 m^2 floor at 0.5 m resolution and 1 Hz.

Target: at least 200x real time on this machine for the CRF of Duembgen et al. (004) with every modality and
online calibration (RTT + BLE + IMU, visual resets, backtracking), the whole ``CrfLocalizer.run``: grid and
transitions, AHRS and step detection, pre-processing, calibration, the Viterbi steps and the backtrack. The
session is the simulator's office_45x55 floor (45 m x 55 m, 79 BLE beacons, 8 WiFi RTT APs), one pedestrian walk
of ``--duration`` s, simulated once into ``--data`` (kept for the next run; streams are read before the
timing). Printed: wall time, real-time factor with its ratio to the target (>= 1: met), the time per part,
the number of grid cells and edges, the mean number of active (unpruned) cells, and the peak memory of a
second, untimed run (tracemalloc: numpy and Python allocations during ``run``) and of the process (ru_maxrss). The machine
is shared: the load average is printed too. The numba kernel is compiled (or loaded from its cache) before
the timing.

    .venv/bin/python benchmarks/crf_speed.py [--duration 3600] [--data data/bench/crf_office_3600]
"""

from __future__ import annotations

import argparse
import os
import resource
import time
import tracemalloc
from pathlib import Path

import numpy as np

from blenav.cli.sim import run as sim_run
from blenav.configs import compose
from blenav.crf.grid import grid_from_occupancy
from blenav.crf.viterbi import maxprod_step
from blenav.data import FREE, Dataset
from blenav.localizers.base import RunInputs
from blenav.localizers.crf import CrfLocalizer

TARGET_RTF = 200.0


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--duration", type=float, default=3600.0)
    ap.add_argument("--data", default="data/bench/crf_office_3600")
    args = ap.parse_args()
    data = Path(args.data)
    if not (data / "dataset.yaml").is_file():
        print(f"simulating {args.duration:.0f} s of office_45x55 into {data} (once) ...", flush=True)
        sim_run(compose("sim", "sim=office_45x55", "seed=0", f"out={data}", f"duration_s={args.duration}",
                        "sessions=1", "sim.carriers=[pedestrian]", "progress=false", "overwrite=true"))
    ds = Dataset.open(data)
    s = ds.session(ds.session_ids[0])
    _ = s.imu, s.mag, s.rssi, s.rtt, s.visual, s.floor.occupancy  # read outside the timing
    dur = s.duration_s
    # compile (or load) the Viterbi kernel outside the timing
    g0 = grid_from_occupancy(np.full((4, 4), FREE, np.int8), 0.5, (0.0, 0.0), 0.5, 1.0)
    maxprod_step(g0, np.zeros(g0.n_cells), imu=(0.5, 0.0, True))
    loc = CrfLocalizer("CRF", modalities="RTT+BLE+IMU", calibration="online")
    inputs = RunInputs()
    t0, c0 = time.perf_counter(), time.process_time()
    est = loc.run(s, 1, 0, inputs)
    wall, cpu = time.perf_counter() - t0, time.process_time() - c0
    rss_run = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    tracemalloc.start()  # a second, untimed run for the memory (tracemalloc slows allocations down)
    loc.run(s, 1, 0, RunInputs())
    _, peak = tracemalloc.get_traced_memory()
    tracemalloc.stop()
    grid = next(v for k, v in inputs.cache.items() if k[0] == "crf-grid")
    # the parts: grid alone, IMU alone (fresh caches), the rest is pre-processing + Viterbi
    t1 = time.perf_counter()
    loc._grid(s, RunInputs())
    t_grid = time.perf_counter() - t1
    t1 = time.perf_counter()
    loc._imu(s, RunInputs())
    t_imu = time.perf_counter() - t1
    rtf = dur / wall
    K = len(est.t)
    print(f"session: {dur:.0f} s, {len(s.imu):,} IMU samples, {len(s.rssi):,} BLE packets, {len(s.rtt):,} RTT ranges, "
          f"{len(s.visual)} visual fixes")
    print(f"grid: {grid.n_cells:,} cells of {grid.cell_m} m ({grid.area_m2:,.0f} m^2 free), {grid.n_edges:,} edges, "
          f"{grid.nbytes() / 2**20:.1f} MiB")
    print(f"steps: {K:,} (1 Hz); active (unpruned) cells per step: mean {np.mean(est.outputs['active_cells']):.0f}, "
          f"max {np.max(est.outputs['active_cells']):,}")
    print(f"wall {wall:.2f} s (CPU {cpu:.2f} s): grid {t_grid:.2f} s, AHRS + steps {t_imu:.2f} s, pre-processing + "
          f"calibration + Viterbi + backtrack {wall - t_grid - t_imu:.2f} s")
    print(f"real-time factor {rtf:.0f}x (wall); target >= {TARGET_RTF:.0f}x: ratio {rtf / TARGET_RTF:.2f} "
          f"({'met' if rtf >= TARGET_RTF else 'NOT met'}); on CPU time {dur / cpu:.0f}x, ratio "
          f"{dur / cpu / TARGET_RTF:.2f}")
    print(f"peak memory of the run (tracemalloc, second run) {peak / 2**20:.0f} MiB; process peak RSS after the "
          f"timed run {rss_run:.0f} MiB (includes the loaded streams); load average {os.getloadavg()[0]:.2f} on "
          f"{os.cpu_count()} CPUs")


if __name__ == "__main__":
    main()
