"""The causal running median of the AHRS prefilter (:mod:`blenav.filters.attitude`, step 2) and of the step
detector: in batch (:func:`causal_median`, compiled; :func:`causal_median_numpy` the reference) and per sample
(:class:`CausalMedian`), the same numbers as ``np.median`` over the window padded with the first sample.
"""

from __future__ import annotations

from collections import deque

import numpy as np
from numpy.lib.stride_tricks import sliding_window_view

__all__ = ["causal_median", "causal_median_numpy", "CausalMedian", "median_of"]


def _median_windows(win: np.ndarray) -> np.ndarray:
    """Median over the last axis; the one routine for batch and streaming (identical rounding)."""
    return np.median(win, axis=-1)


def causal_median(x: np.ndarray, window: int) -> np.ndarray:
    """Causal running median (T, d) -> (T, d): out[k] = median(x[k-w+1 .. k]) per column, the window
    padded with copies of x[0] before the start. Compiled (:func:`~blenav.filters.ahrs_jit.causal_median_jit`,
    np.median's numbers bit for bit); :func:`causal_median_numpy` is the numpy reference."""
    x = np.asarray(x, float)
    if window <= 1 or len(x) == 0:
        return x.copy()
    from .ahrs_jit import causal_median_jit

    return causal_median_jit(np.ascontiguousarray(x.reshape(len(x), -1)), int(window)).reshape(x.shape)


def causal_median_numpy(x: np.ndarray, window: int) -> np.ndarray:
    """:func:`causal_median` with np.median over the padded sliding window (the reference)."""
    x = np.asarray(x, float)
    if window <= 1 or len(x) == 0:
        return x.copy()
    padded = np.concatenate([np.repeat(x[:1], window - 1, axis=0), x], axis=0)
    return _median_windows(sliding_window_view(padded, window, axis=0))  # (T, d, w)


class CausalMedian:
    """Streaming equivalent of :func:`causal_median` (bit-identical).

    Per sample of a few axes, Python's sort of the window is ~10x faster than ``np.median``; the median is
    the same number (the middle element, or the mean (a + b) / 2 of the two middle ones for an even window,
    NaN when the window holds a NaN, as ``np.median``)."""

    def __init__(self, window: int):
        self.window = int(window)
        self._buf: list[deque] | None = None  # per axis, the last ``window`` values, oldest first

    def __call__(self, x: np.ndarray) -> np.ndarray:
        x = np.asarray(x, float)
        if self.window <= 1:
            return x.copy()
        vals = x.tolist()
        if self._buf is None:
            self._buf = [deque([v] * self.window, maxlen=self.window) for v in vals]
        else:
            for b, v in zip(self._buf, vals):
                b.append(v)
        return np.array([median_of(b) for b in self._buf])


def median_of(values) -> float:
    """``np.median`` of a short sequence of floats, in Python."""
    s = sorted(values)
    if any(v != v for v in s):
        return float("nan")
    n = len(s)
    return s[n // 2] if n % 2 else (s[n // 2 - 1] + s[n // 2]) / 2
