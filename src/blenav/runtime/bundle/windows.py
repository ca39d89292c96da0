"""RSSI packets -> the bundle localizer's fixes, live.

The localizer sees RSSI windows built live with the recipe of :func:`blenav.features.windows.session_windows` (steps
of ``1 / step_hz`` s from the first packet, mean of u = max(rssi + offset_db, floor_u) per step and beacon, H steps
per window); a window's fix is made at the end of its newest step, as soon as a sample at or after that time
arrives, and enters the filter's step that holds that time (:mod:`blenav.runtime.bundle.live`).
"""

from __future__ import annotations

import math

import numpy as np

from blenav.limits import check_range

from .graphs import LocalizerGraph


#: the most window steps one sample may close (100,000: 2.8 h at 10 Hz); a larger jump is an error, not 10^9 runs
MAX_GAP_STEPS = 100_000


class WindowFixer:
    """RSSI packets -> the localizer's fixes, live, with the windowing of
    :func:`blenav.features.windows.session_windows` (``steps: time``): step k = floor((t - t0) step_hz) from the
    first packet t0; per step and beacon the mean of u; the window of the last H steps ends at t0 + (k + 1) / step_hz.

    :meth:`advance` (t) closes the steps that end at or before ``t`` and returns their fixes (t, x, y, std) (std: the
    graph's own std per fix in m, ``std_m`` of a LocNet with a std head, else None; windows whose
    prediction is not finite give none; a jump of more than :data:`MAX_GAP_STEPS` steps is a ValueError); :meth:`add` a packet; :meth:`flush` closes the open step at the end of the data."""

    def __init__(self, graph: LocalizerGraph):
        w = graph.meta["window"]
        if str(w.get("steps", "time")) != "time":
            raise ValueError("the bundle's localizer was trained on scan windows (a fingerprint survey): it cannot "
                             "localize a stream")
        where = f"{graph.path} metadata"  # the localizer's window, bounded before H steps are kept
        self.graph = graph
        self.hz = check_range(w["step_hz"], "step_hz", where, field="window.step_hz")
        self.H = check_range(w["history"], "history", where, field="window.history")
        self.offset, self.floor_u = float(w["offset_db"]), float(w["floor_u"])
        self.col = {b: i for i, b in enumerate(graph.beacons)}
        B = len(self.col)
        self.t0: float | None = None
        self.k = 0
        self.sums, self.counts = [0.0] * B, [0.0] * B  # the open step, per beacon (Python floats: cheap per packet)
        self.steps: list[np.ndarray] = []
        self.unknown: dict[str, int] = {}
        self.windows = 0

    def _close(self) -> tuple | None:
        sums, counts = np.array(self.sums), np.array(self.counts)
        self.steps.append(np.divide(sums, counts, out=np.zeros_like(sums), where=counts > 0))
        self.sums, self.counts = [0.0] * len(self.col), [0.0] * len(self.col)
        k, self.k = self.k, self.k + 1
        if len(self.steps) > self.H:
            self.steps.pop(0)
        if len(self.steps) < self.H:
            return None
        self.windows += 1
        S = np.stack(self.steps, axis=1)[None].astype(np.float32)  # (1, B, H), oldest step first
        xy, std = self.graph.predict_windows_std(S)
        xy = xy[0]
        if not np.isfinite(xy).all():
            return None
        sd = float(std[0]) if std is not None and np.isfinite(std[0]) else None  # NaN: the graph's std unknown
        return (self.t0 + (k + 1) / self.hz, float(xy[0]), float(xy[1]), sd)

    def advance(self, t: float) -> list[tuple]:
        if self.t0 is None:
            return []
        kk = int(math.floor((t - self.t0) * self.hz))
        if kk - self.k > MAX_GAP_STEPS:  # a clock jump in the data must not buy one network run per step
            raise ValueError(f"the stream's time jumps from {self.t0 + self.k / self.hz:.3f} s to {t:.3f} s: "
                             f"{kk - self.k:,} window steps of {1 / self.hz:g} s with nothing heard (at most "
                             f"{MAX_GAP_STEPS:,}); split the recording at the gap")
        out = []
        while self.k < kk:
            fix = self._close()
            if fix is not None:
                out.append(fix)
        return out

    def add(self, t: float, anchor_id: str, rssi: float) -> None:
        if self.t0 is None:
            self.t0, self.k = float(t), 0
        j = self.col.get(str(anchor_id))
        if j is None:
            self.unknown[str(anchor_id)] = self.unknown.get(str(anchor_id), 0) + 1
            return
        u = float(rssi) + self.offset  # rssi_to_u, in Python floats (the same IEEE result, NaN stays NaN)
        self.sums[j] += self.floor_u if u < self.floor_u else u
        self.counts[j] += 1.0

    def flush(self) -> list[tuple]:
        """Close the open step (the last, partial one: offline windowing keeps it too)."""
        if self.t0 is None:
            return []
        fix = self._close()
        return [fix] if fix is not None else []
