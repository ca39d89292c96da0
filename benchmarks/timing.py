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
