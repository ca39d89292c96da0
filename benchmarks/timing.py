"""Timing helpers shared by the benchmark scripts (run as ``python benchmarks/NAME.py``; this folder is then
on the import path)."""

from __future__ import annotations

import time

import numpy as np


def median_ms(fn, calls: int, warmup: int = 20) -> float:
    """Median wall time of ``fn()`` in milliseconds over ``calls`` calls after ``warmup`` calls."""
    for _ in range(warmup):
        fn()
    t = np.empty(calls)
    for i in range(calls):
        t0 = time.perf_counter()
        fn()
        t[i] = time.perf_counter() - t0
    return float(np.median(t) * 1e3)


def timed_updates(loc, events):
    """Push ``events`` (time-ordered replay tuples, t at index 1) through ``loc.push_event`` (the runtime bundle's
    push API) and time the updates: yields (estimates, wall ms, CPU ms) once per push call that returned estimates,
    the times being the sums of the wall (``time.perf_counter``) and process CPU (``time.process_time``) times of the
    push calls since the previous yield, divided by the number of estimates (an update = the push calls between two
    estimates). Last, the estimates of ``loc.close(t of the last event)`` with NaN times (not an update), when any.
    ``events`` may be a lazy iterator: the next event is taken before the clocks start."""
    wall = cpu = 0.0
    t_last = None
    for ev in events:
        w0, c0 = time.perf_counter(), time.process_time()
        out = loc.push_event(ev)
        wall += time.perf_counter() - w0
        cpu += time.process_time() - c0
        t_last = ev[1]
        if out:
            yield out, wall * 1e3 / len(out), cpu * 1e3 / len(out)
            wall = cpu = 0.0
    if t_last is not None:
        out = loc.close(t_last)
        if out:
            yield out, float("nan"), float("nan")
