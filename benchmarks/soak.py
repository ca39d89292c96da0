"""Soak: hours of simulated data streamed through the runtime bundle's push API, with flat memory and no slowdown.

Issue 18, section 4. One :class:`blenav.runtime.BundleLocalizer` (the bundle's settings: 1000 particles at 1 Hz, BLE
fixes from the bundle's localizer, its map prior) receives ``--hours`` of samples (default 8 h) in time order through
``push_event``, as an app would. The process's resident memory (RSS, /proc/self/status VmRSS) is read every simulated
``--sample-min`` minutes (default 10); the cost of each update (the wall time of the push calls between two
estimates, timed by benchmarks/timing.py's timed_updates as in benchmarks/runtime_latency.py: wall and process
CPU time, the latter less sensitive to other processes on the machine) is kept per step. The bundle is built in
a child process, so that the soak's process holds what an app holds (onnxruntime, numpy; no torch, and no heap
left over from training). Printed:

- RSS and the number of Python objects the garbage collector tracks at every sample, the RSS's least-squares
  slope (MB per simulated hour) after the reference hour and over the whole run, and its growth from the end of
  the reference hour (the first hour: imports, graph sessions, numba and the filter's buffers settle there) to the
  end;
- the per-step cost (wall and CPU): median of the reference hour, of the last hour, their ratio (flat: about 1),
  the medians of every hour, and the slope of the per-block medians (ms per simulated hour);
- every estimate finite (counted).

The data are **synthetic-but-realistic, not an 8-hour simulation**: the simulator's walk of ``--tile`` seconds
(default 600 s) in the bundle's building, played forward, then backward in time, then forward again (a palindrome,
so positions and odometry stay continuous where the copies meet), shifted in time copy after copy until the
duration is reached. RSSI packets and odometry are streamed (what the bundle's settings read).

    .venv/bin/python benchmarks/soak.py                     # builds a small bundle first (~2 min), then 8 h of data
    .venv/bin/python benchmarks/soak.py --hours 0.5 --sample-min 5
    .venv/bin/python benchmarks/soak.py --bundle B --data DIR   # an exported bundle and a dataset of its building
"""

from __future__ import annotations

import argparse
import gc
import importlib.util
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from timing import timed_updates

HERE = Path(__file__).resolve().parent


def _runtime_latency():
    """benchmarks/runtime_latency.py as a module (its bundle builder and core pinning)."""
    spec = importlib.util.spec_from_file_location("blenav_runtime_latency", HERE / "runtime_latency.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def rss_mb() -> float:
    """Resident set size of this process (MB), from /proc/self/status (Linux), else the peak from getrusage."""
    try:
        for line in Path("/proc/self/status").read_text().splitlines():
            if line.startswith("VmRSS:"):
                return int(line.split()[1]) / 1024.0
    except OSError:
        pass
    import resource

    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


def palindrome(events: list, seconds: float):
    """``events`` (time-ordered replay tuples, t at index 1) forward, backward, forward, ... with times shifted so the
    stream is continuous, until ``seconds`` of stream; yields the shifted tuples in time order."""
    t0, t1 = float(events[0][1]), float(events[-1][1])
    span = t1 - t0 + 0.01  # the next copy starts 10 ms after the last sample of the previous one
    k = 0
    while k * span < seconds:
        base = k * span
        seq = events if k % 2 == 0 else events[::-1]
        for e in seq:
            t = (float(e[1]) - t0) if k % 2 == 0 else (t1 - float(e[1]))
            if base + t >= seconds:
                return
            yield (e[0], t0 + base + t, *e[2:])
        k += 1


def tile_session(bundle, data: Path | None, tile_s: float, seed: int, work: Path):
    """(session, where it comes from): ``data``'s first session of the bundle's building, or a new ``tile_s`` walk
    simulated in the 'small' preset (the building runtime_latency.py's bundle is made for) into ``work``."""
    from blenav.data import Dataset
    from blenav.runtime import BuildingMismatch

    if data is None:
        from blenav.cli.sim import run as sim_run
        from blenav.configs import compose

        data = work / "tile"
        sim_run(compose("sim", "sim=small", f"seed={seed}", f"out={data}", f"duration_s={tile_s}", "sessions=1",
                        "progress=false", "sim.carriers=[pedestrian]"))
    ds = Dataset.open(data)
    for s in ds.sessions():
        try:
            bundle.check_session(s)
        except BuildingMismatch:
            continue
        return s, f"{data}: session {s.id} ({float(s.rssi['t'].iloc[-1] - s.rssi['t'].iloc[0]):.0f} s)"
    raise SystemExit(f"no session of {data} is in the bundle's building {bundle.signature['building']!r}")


def fit(x: np.ndarray, y: np.ndarray) -> float:
    """Least-squares slope of y over x (nan with fewer than two points)."""
    return float(np.polyfit(x, y, 1)[0]) if len(x) >= 2 else float("nan")


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--hours", type=float, default=8.0, help="simulated hours streamed (default %(default)s)")
    ap.add_argument("--sample-min", type=float, default=10.0, help="RSS sampled every this many simulated minutes")
    ap.add_argument("--reference-h", type=float, default=1.0, help="the reference: the first this many hours")
    ap.add_argument("--tile", type=float, default=600.0, help="length (s) of the simulated walk that is looped")
    ap.add_argument("--bundle", help="an exported bundle (default: build a small one as runtime_latency.py does)")
    ap.add_argument("--data", help="a dataset with a session in the bundle's building (default: simulate one)")
    ap.add_argument("--seed", type=int, default=21, help="the simulator's seed (21: runtime_latency.py's building)")
    ap.add_argument("--json", help="also write the figures here")
    ap.add_argument("--build-to", help=argparse.SUPPRESS)  # the child process that builds the bundle
    args = ap.parse_args()
    rl = _runtime_latency()
    if args.build_to:
        print(rl.build(Path(args.build_to))["bundle"])
        return 0
    pinned = rl.pin_one_core()
    from blenav.filters.online import replay
    from blenav.runtime import Bundle

    tmp = tempfile.TemporaryDirectory(prefix="soak_")
    if args.bundle is None:
        print("building a small bundle in a child process (simulate, train briefly, export: runtime_latency.build) ...",
              flush=True)
        subprocess.run([sys.executable, __file__, "--build-to", tmp.name], check=True, stdout=subprocess.DEVNULL)
        bundle_dir = Path(tmp.name) / "B"
    else:
        bundle_dir = Path(args.bundle)
    b = Bundle.open(bundle_dir)
    session, where = tile_session(b, Path(args.data) if args.data else None, args.tile, args.seed, Path(tmp.name))
    loc = b.localizer(session.building, floor=session.meta.get("floor"), seed=0)
    kinds = ("rssi", "odo") + (("imu", "mag") if loc.method.needs_imu else ())
    events = [e for e in replay(session) if e[0] in kinds]
    seconds = args.hours * 3600.0
    sample_s = args.sample_min * 60.0
    t_first = float(events[0][1])
    n_steps = int(seconds * float(b.settings["filter"]["rate_hz"])) + 16
    step_t = np.full(n_steps, np.nan)  # preallocated: the soak's own bookkeeping does not grow
    step_ms = np.full(n_steps, np.nan)
    step_cpu = np.full(n_steps, np.nan)
    samples: list[tuple[float, float, int]] = []
    fs = b.settings["filter"]
    prior = ", map prior" if b.prior is not None else ""
    print(f"bundle {bundle_dir}: {fs['n_particles']} particles at {fs['rate_hz']:g} Hz, BLE fixes{prior}; {pinned}")
    print(f"data: SYNTHETIC-BUT-REALISTIC, not a {args.hours:g} h simulation: {where}, streamed forward/backward in "
          f"time (palindrome, continuous positions) with time offsets to {args.hours:g} h; events {', '.join(kinds)}",
          flush=True)
    gc.collect()
    samples.append((0.0, rss_mb(), len(gc.get_objects())))
    next_sample = sample_s
    k, n_bad, n_est = 0, 0, 0
    wall0 = time.perf_counter()

    def sampled(stream):
        """The events, with the RSS sampled (outside the timed push calls) as the simulated clock passes each
        sample time."""
        nonlocal next_sample
        for ev in stream:
            while ev[1] - t_first >= next_sample:
                samples.append((next_sample / 3600.0, rss_mb(), len(gc.get_objects())))
                h = next_sample / 3600.0
                if abs(h - round(h)) < 1e-9:
                    print(f"  {h:5.2f} h simulated, RSS {samples[-1][1]:7.1f} MB, {k:,} steps, "
                          f"{time.perf_counter() - wall0:6.0f} s wall", flush=True)
                next_sample += sample_s
            yield ev

    for out, wall_ms, cpu_ms in timed_updates(loc, sampled(palindrome(events, seconds))):
        n_est += len(out)
        if not np.isfinite(wall_ms):  # the estimates of close(): counted, not an update
            continue
        n_bad += sum(1 for r in out if not (np.isfinite(r.x) and np.isfinite(r.y) and np.isfinite(r.std)))
        if k < n_steps:
            step_t[k], step_ms[k], step_cpu[k] = out[-1].t - t_first, wall_ms, cpu_ms
            k += 1
    wall = time.perf_counter() - wall0
    samples.append((seconds / 3600.0, rss_mb(), len(gc.get_objects())))
    step_t, step_ms, step_cpu = step_t[:k] / 3600.0, step_ms[:k], step_cpu[:k]
    h_s = np.array([s[0] for s in samples])
    mb = np.array([s[1] for s in samples])
    objs = np.array([s[2] for s in samples])
    ref = args.reference_h
    after = h_s >= ref - 1e-9
    rss_ref = float(mb[after][0])
    slope_after, slope_all = fit(h_s[after], mb[after]), fit(h_s, mb)
    first, first_cpu = step_ms[step_t < ref], step_cpu[step_t < ref]
    last, last_cpu = step_ms[step_t >= args.hours - 1.0], step_cpu[step_t >= args.hours - 1.0]
    blocks = np.floor(step_t * 3600.0 / sample_s)
    med = np.array([np.median(step_ms[blocks == j]) for j in np.unique(blocks)])
    mid = (np.unique(blocks) + 0.5) * sample_s / 3600.0
    slope_ms = fit(mid[mid >= ref], med[mid >= ref])
    fixes = getattr(loc, "fixes", [])  # the live fix log: the latest keep_fixes fixes (run_session keeps all)
    fix_mb = (sys.getsizeof(fixes) + sum(sys.getsizeof(f) + sum(sys.getsizeof(v) for v in f) for f in fixes)) / 2**20
    hours = [(step_t >= h) & (step_t < h + 1) for h in range(int(np.ceil(args.hours)))]
    hourly = [float(np.median(step_ms[m])) for m in hours if m.any()]
    hourly_cpu = [float(np.median(step_cpu[m])) for m in hours if m.any()]
    print(f"\n{args.hours:g} h simulated ({k:,} filter steps, {n_est:,} estimates, {n_bad} not finite) in {wall:.0f} s "
          f"wall ({args.hours * 3600.0 / wall:.0f}x real time); load average {os.getloadavg()[0]:.2f}")
    print(f"RSS sampled every {args.sample_min:g} simulated min (MB): " + ", ".join(f"{v:.1f}" for v in mb))
    print(f"Python objects tracked by the gc at the same times: {objs[0]:,} at the start, {int(objs[after][0]):,} "
          f"after the reference, {objs[-1]:,} at the end ({int(objs[-1] - objs[after][0]):+,} after the reference); "
          f"the localizer's fix log (BundleLocalizer.fixes) holds {len(fixes):,} fixes, {fix_mb:.1f} MB; torch "
          f"imported in this process: {'yes' if 'torch' in sys.modules else 'no'}")
    print(f"RSS: {mb[0]:.1f} MB at the start, {rss_ref:.1f} MB after the reference (first {ref:g} h), {mb[-1]:.1f} MB "
          f"at the end: growth {mb[-1] - rss_ref:+.1f} MB ({100 * (mb[-1] - rss_ref) / rss_ref:+.1f} %) after the "
          f"reference; slope {slope_after:+.3f} MB/h after the reference ({slope_all:+.3f} MB/h over the whole run)")
    print(f"per-step cost (update = push calls between two estimates), median: reference (first {ref:g} h) "
          f"{np.median(first):.3f} ms, last hour {np.median(last):.3f} ms, ratio last/reference "
          f"{np.median(last) / np.median(first):.3f} (flat: ~1); p90 {np.percentile(first, 90):.3f} -> "
          f"{np.percentile(last, 90):.3f} ms; slope of the {args.sample_min:g}-min medians after the reference "
          f"{slope_ms * 1e3:+.2f} us per simulated hour")
    print(f"per-step CPU time (process), median: reference {np.median(first_cpu):.3f} ms, last hour "
          f"{np.median(last_cpu):.3f} ms, ratio last/reference {np.median(last_cpu) / np.median(first_cpu):.3f}")
    print("per-step cost, median per simulated hour (ms, wall): " + ", ".join(f"{v:.3f}" for v in hourly))
    print("per-step cost, median per simulated hour (ms, CPU):  " + ", ".join(f"{v:.3f}" for v in hourly_cpu))
    res = {"hours": args.hours, "steps": k, "estimates": n_est, "not_finite": n_bad, "wall_s": wall,
           "data": f"synthetic-but-realistic: {where}, palindrome-looped", "rss_samples": samples,
           "rss_slope_mb_per_h_after_reference": slope_after, "rss_slope_mb_per_h": slope_all,
           "rss_growth_mb_after_reference": float(mb[-1] - rss_ref), "reference_h": ref,
           "step_ms_median_reference": float(np.median(first)), "step_ms_median_last_hour": float(np.median(last)),
           "step_ratio_last_vs_reference": float(np.median(last) / np.median(first)),
           "step_ms_slope_per_h": slope_ms, "step_ms_median_per_hour": hourly,
           "step_cpu_ms_median_reference": float(np.median(first_cpu)),
           "step_cpu_ms_median_last_hour": float(np.median(last_cpu)), "step_cpu_ms_median_per_hour": hourly_cpu,
           "gc_objects": [int(v) for v in objs], "fix_log": {"fixes": len(fixes), "mb": fix_mb},
           "torch_imported": "torch" in sys.modules, "pinned": pinned}
    if args.json:
        Path(args.json).write_text(json.dumps(res, indent=2) + "\n")
    tmp.cleanup()
    return 0


if __name__ == "__main__":
    sys.exit(main())
