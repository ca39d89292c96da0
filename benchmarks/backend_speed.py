"""Smoothing back-end speed and memory on a 384 s session (issue 14): batch (LM) and online (iSAM2), and the
closed loop.

Budgets: the back-end on a 384 s session under 10 s on this machine (reference: Ghaffari Jadidi et al. report
92 s for front plus back end in MATLAB); the online mode keeps up with real time at every keyframe (each iSAM2
update shorter than the keyframe interval). Printed: wall and CPU seconds with the ratio to the budget, the
iSAM2 update times (median, p99, max) against the keyframe interval, the closed loop's back-end seconds, peak
RSS of the process, and the load average (a shared machine is slower).

    .venv/bin/python benchmarks/backend_speed.py [--duration 384] [--keyframe-every 1] [--set KEY=VALUE ...]
        [--no-online]

``--set``: a back-end setting for every mode (conf/backend/default.yaml keys, e.g. ``range.estimate_offset=true``);
``--no-online``: skip the iSAM2 mode (the closed loop uses LM). Under the batch mode: one LM iteration against its
pieces called from Python (:func:`lm_split`).
"""

from __future__ import annotations

import argparse
import os
import resource
import tempfile
import time
from pathlib import Path

import numpy as np

from blenav.backend.config import load_backend_config
from blenav.backend.graph import RadioInertialGraph, smooth
from blenav.backend.inputs import (beacon_priors, keyframes_from_front_end, path_loss_model, session_attitude,
                                   session_imu, session_ranges)
from blenav.backend.loop import run_closed_loop
from blenav.cli.sim import run as sim_run
from blenav.configs import compose
from blenav.data import Dataset
from blenav.eval.harness import build_methods
from blenav.filters.calibration import apply_fit, fit_sessions
from blenav.filters.runner import run_session

BUDGET_S = 10.0
PAPER_S = 92.0


def _rss_mib() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024


def lm_split(cfg, kf, imu, ranges, beacons) -> str:
    """One LM iteration of the first pass's graph against its pieces called from Python (linearize, solve, error at
    the step): GTSAM copies the optimizer's own values into every Python error call of a CustomFactor (the channel's
    range factors, ``range.estimate_offset``), not values handed over from Python, so the difference is that copy."""
    import gtsam

    graph, initial = RadioInertialGraph(cfg, kf, imu, ranges, beacons).batch_graph()
    t0 = time.perf_counter()
    lin = graph.linearize(initial)
    t1 = time.perf_counter()
    delta = lin.optimize()
    t2 = time.perf_counter()
    graph.error(initial.retract(delta))
    t3 = time.perf_counter()
    opt = gtsam.LevenbergMarquardtOptimizer(graph, initial, gtsam.LevenbergMarquardtParams())
    t4 = time.perf_counter()
    opt.iterate()
    t5 = time.perf_counter()
    return (f"one LM iteration {t5 - t4:.3f} s; from Python: linearize {t1 - t0:.3f} s, solve {t2 - t1:.3f} s, "
            f"error {t3 - t2:.3f} s ({graph.size()} factors, {initial.size()} values)")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--duration", type=float, default=384.0)
    ap.add_argument("--keyframe-every", type=int, default=1)
    ap.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                    help="a back-end setting for every mode (repeatable), e.g. range.estimate_offset=true")
    ap.add_argument("--no-online", action="store_true", help="skip the iSAM2 mode")
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp) / "office"
        sim_run(compose("sim", "sim=office_45x55", "seed=0", f"out={out}", f"duration_s={args.duration}",
                        "sessions=1", "progress=false"))
        ds = Dataset.open(out)
        s = ds.session(ds.session_ids[0])
        m = build_methods(compose("eval", "experiment=frontend_000", "data=x", "filter.n_particles=300"))["IMU"].method
        apply_fit(m.measurements, fit_sessions([s]))
        front = run_session(m, s, 1, seed=0)
        base = _rss_mib()
        common = [f"solver.keyframe_every={args.keyframe_every}", *args.set]
        cfg = load_backend_config(overrides=common)
        anchors = s.building.anchors_of("ble")
        beacons = beacon_priors(anchors, cfg.priors.beacon_sigma_m, cfg.priors.beacon_sigma_z_m)
        ranges = session_ranges(s, beacons, path_loss_model(cfg), anchors)
        imu = session_imu(s)
        att = session_attitude(s)
        kf, _ = keyframes_from_front_end(front.t, front.position, *att, cfg)
        interval = float(np.median(np.diff(kf.t)))
        print(f"settings: {' '.join(args.set) or 'defaults'}")
        print(f"session {args.duration:.0f} s: {len(kf.t)} keyframes ({interval:.2f} s apart), {len(imu.t):,} IMU "
              f"samples, {len(ranges.t):,} ranges to {len(beacons.ids)} beacons")
        print(f"{'mode':22s} {'wall [s]':>9s} {'/ budget':>9s} {'vs paper':>9s} {'CPU [s]':>8s} {'load':>5s}")
        modes = [("batch (LM, 2 passes)", ["solver.method=lm"])]
        modes += [] if args.no_online else [("online (iSAM2)", ["solver.method=isam2"])]
        for name, over in modes:
            c = load_backend_config(overrides=[*common, *over])
            t0, c0 = time.perf_counter(), time.process_time()
            res = smooth(c, kf, imu, ranges, beacons)
            wall, cpu = time.perf_counter() - t0, time.process_time() - c0
            print(f"{name:22s} {wall:9.2f} {wall / BUDGET_S:9.2f} {PAPER_S / wall:8.1f}x {cpu:8.2f} "
                  f"{os.getloadavg()[0]:5.2f}" + ("" if res.ok else f"  failures: {res.failures[:2]}"))
            if name.startswith("batch"):
                print("  " + lm_split(c, kf, imu, ranges, beacons))
            if name.startswith("online"):
                u = res.update_s[np.isfinite(res.update_s)]
                late = int(np.count_nonzero(u > interval))
                print(f"  iSAM2 update per keyframe: median {np.median(u) * 1e3:.1f} ms, p99 "
                      f"{np.percentile(u, 99) * 1e3:.1f} ms, max {u.max() * 1e3:.1f} ms against the {interval * 1e3:.0f} "
                      f"ms keyframe interval: {late} of {len(u)} updates slower than real time")
        loop_cfg = load_backend_config(overrides=[*common, "solver.method=lm"])
        t0 = time.perf_counter()
        lo = run_closed_loop(m, s, 1, 0, loop_cfg, imu, ranges, beacons, att)
        wall = time.perf_counter() - t0
        print(f"closed loop (front-end 1 run + {len(lo.feedbacks)} window solves + final LM): {wall:.2f} s, of it "
              f"back-end {lo.backend_s:.2f} s ({lo.backend_s / BUDGET_S:.2f} x the budget); "
              f"{args.duration / wall:.1f}x real time")
        print(f"peak RSS {_rss_mib():.0f} MiB (after the front-end: {base:.0f} MiB)")


if __name__ == "__main__":
    main()
