"""Beacon-map error against walking time (issue 14, sec. 3: "On simulated data, report the estimated-vs-true
beacon error as a function of walking time").

For each walking time T (minutes) the labelled walks are cut to their first T minutes *in total* (sessions taken
in the order given, the last one used cut short; a session's walking time is what its ground truth covers, the
only part whose readings :func:`blenav.backend.mapping_readings.collect_readings` can use), :func:`map_beacons` maps the
beacons from that cut, and the placed beacons are compared with the true positions of anchors.csv
(``x_true, y_true``; horizontal error, m).

The cut is an in-memory view (:func:`cut_sessions`): a :class:`~blenav.data.session.Session` whose every stream
is the original's rows with ``t <= t_end``; nothing is written.

Per T (:func:`error_vs_time`, one row): the walking time actually used (less than T when the data end first),
the sessions used, beacons placed / total, mean, median and 90th-percentile error of the placed beacons, the
share of them whose error is within their stated std (``std_m``, per axis) and within twice it, the median of
error / std_m, the mean error of the beacons placed at *every* T (the same set across rows: placing more,
harder beacons with more data otherwise masks the gain on the easy ones), the fitted path-loss exponent and the
wall time of :func:`map_beacons`. For reference, a 2-D Gaussian error with std sigma per axis lies within sigma
with probability 1 - exp(-1/2) = 0.39 and within 2 sigma with 0.86; the median of |error| / sigma is 1.18.

The command (argparse stays out of the library): ``python benchmarks/mapping_curve.py DATASET --minutes 2,4,8
--out FILE.md`` (``make mapping-curve``).
"""

from __future__ import annotations

import time
from dataclasses import dataclass, fields

import numpy as np
import pandas as pd

from blenav.data.session import Session

from .config import MappingConfig
from .mapping import map_beacons

__all__ = ["CutSession", "cut_sessions", "walking_time_s", "error_vs_time", "markdown_table", "COLUMNS"]

#: Columns of :func:`error_vs_time`'s table (errors in m, times in min / s, shares in [0, 1]).
COLUMNS = ["minutes", "walk_min", "sessions", "placed", "total", "mean_err_m", "median_err_m", "p90_err_m",
           "within_1std", "within_2std", "median_err_over_std", "common_mean_err_m", "gamma", "wall_s"]


@dataclass
class CutSession(Session):
    """A session seen up to ``t_end`` (s, session time): every stream holds the original's rows with
    ``t <= t_end`` (read from the original, which caches the full frames)."""

    t_end: float = float("inf")

    def stream(self, name: str) -> pd.DataFrame:
        cache = self.__dict__.setdefault("_cut", {})
        if name not in cache:
            df = self.__dict__["_full"].stream(name)
            cache[name] = df[df["t"].to_numpy(float) <= self.t_end].reset_index(drop=True)
        return cache[name]


def _cut(sess: Session, t_end: float) -> CutSession:
    base = {f.name: getattr(sess, f.name) for f in fields(Session)}
    view = CutSession(**base, t_end=float(t_end))
    view.__dict__["_full"] = sess
    return view


def walking_time_s(sess: Session) -> float:
    """Time the session's ground truth covers (s): its span plus one (median) sample interval, so that n samples
    at 10 Hz count n / 10 s (a 480 s walk sampled 0.0 ... 479.9 s is 480 s); the time whose readings the mapping
    can use. 0 with fewer than two samples."""
    gt = sess.groundtruth
    if len(gt) < 2:
        return 0.0
    t = gt["t"].to_numpy(float)
    return float(t[-1] - t[0] + np.median(np.diff(t)))


def cut_sessions(sessions, seconds: float) -> list[CutSession]:
    """The first ``seconds`` of walking (ground-truth time) over ``sessions`` in order: whole sessions while they
    fit, then the next one cut at its ground truth's start + what is left. Sessions without ground truth are
    skipped. Returns at least one session when ``seconds`` > 0 and any session has ground truth."""
    if seconds <= 0:
        raise ValueError(f"walking time must be positive, got {seconds} s")
    out, left = [], float(seconds)
    for s in sessions:
        span = walking_time_s(s)
        if span <= 0:
            continue
        t0 = float(s.groundtruth["t"].iloc[0])
        out.append(_cut(s, t0 + min(span, left)))
        left -= span
        if left <= 0:
            break
    return out


def _errors(beacons: pd.DataFrame, truth: pd.DataFrame) -> np.ndarray:
    """(n,) horizontal error (m) of each row of ``beacons`` against ``truth`` (indexed by anchor_id, x_true, y_true)."""
    tr = truth.loc[beacons["anchor_id"].astype(str)]
    return np.hypot(beacons["x"].to_numpy(float) - tr["x_true"].to_numpy(float),
                    beacons["y"].to_numpy(float) - tr["y_true"].to_numpy(float))


def error_vs_time(sessions, anchors: pd.DataFrame, cfg: MappingConfig, minutes: list[float]) -> pd.DataFrame:
    """One row per walking time of ``minutes`` (columns :data:`COLUMNS`, see the module docstring): the labelled
    ``sessions`` (one building, ``anchors`` its anchors.csv rows with ``x_true, y_true``) cut to their first T
    minutes in total, mapped with ``cfg``, the placed beacons compared with the truth. A T beyond the data uses
    all of it (``walk_min`` says how much); a T that repeats the previous row's cut is still run."""
    sessions = list(sessions)
    if not sessions:
        raise ValueError("no session to map beacons from")
    if not minutes or any(not np.isfinite(m) or m <= 0 for m in minutes):
        raise ValueError(f"minutes must be positive walking times, got {minutes}")
    missing = [c for c in ("x_true", "y_true") if c not in anchors.columns]
    if missing:
        raise ValueError(f"anchors.csv lacks column(s) {missing}: the error needs the true beacon positions "
                         "(a simulated dataset has them)")
    ble = anchors[anchors["kind"] == "ble"]
    truth = ble.assign(anchor_id=ble["anchor_id"].astype(str)).set_index("anchor_id")[["x_true", "y_true"]]
    if not np.isfinite(truth.to_numpy(float)).all():
        raise ValueError("anchors.csv: x_true / y_true empty for some BLE beacon: cannot score the map")
    rows, placed_sets, errs = [], [], []
    for m in minutes:
        cut = cut_sessions(sessions, 60.0 * m)
        if not cut:
            raise ValueError("no session has ground truth to walk with")
        walk = sum(walking_time_s(s) for s in cut) / 60.0
        t0 = time.perf_counter()
        res = map_beacons(cut, anchors, cfg)
        wall = time.perf_counter() - t0
        p = res.placed
        e = _errors(p, truth) if len(p) else np.zeros(0)
        ratio = e / p["std_m"].to_numpy(float) if len(p) else np.zeros(0)
        placed_sets.append(set(p["anchor_id"].astype(str)))
        errs.append(dict(zip(p["anchor_id"].astype(str), e)))
        nan = float("nan")
        rows.append({
            "minutes": float(m), "walk_min": walk, "sessions": len(cut), "placed": int(len(p)),
            "total": int(len(res.beacons)),
            "mean_err_m": float(e.mean()) if len(e) else nan,
            "median_err_m": float(np.median(e)) if len(e) else nan,
            "p90_err_m": float(np.percentile(e, 90)) if len(e) else nan,
            "within_1std": float(np.mean(ratio <= 1.0)) if len(e) else nan,
            "within_2std": float(np.mean(ratio <= 2.0)) if len(e) else nan,
            "median_err_over_std": float(np.median(ratio)) if len(e) else nan,
            "gamma": float(res.gamma), "wall_s": wall,
        })
    common = set.intersection(*placed_sets) if placed_sets else set()
    for r, e in zip(rows, errs):
        r["common_mean_err_m"] = float(np.mean([e[a] for a in common])) if common else float("nan")
    out = pd.DataFrame(rows, columns=COLUMNS)
    out.attrs["common_beacons"] = sorted(common)
    return out


def markdown_table(df: pd.DataFrame) -> str:
    """The table of :func:`error_vs_time` as markdown (no extra dependency): errors to 0.01 m, shares in %."""
    head = ["T (min)", "walked (min)", "sessions", "placed / total", "mean err (m)", "median err (m)",
            "p90 err (m)", "err <= std", "err <= 2 std", "median err/std", "mean err, common (m)", "gamma",
            "wall (s)"]

    def f(v, fmt):
        return "-" if v is None or (isinstance(v, float) and not np.isfinite(v)) else format(v, fmt)

    lines = ["| " + " | ".join(head) + " |", "|" + "---:|" * len(head)]
    for r in df.itertuples():
        cells = [f(r.minutes, "g"), f(r.walk_min, ".1f"), str(r.sessions), f"{r.placed} / {r.total}",
                 f(r.mean_err_m, ".2f"), f(r.median_err_m, ".2f"), f(r.p90_err_m, ".2f"),
                 f(100 * r.within_1std, ".0f") + ("" if not np.isfinite(r.within_1std) else " %"),
                 f(100 * r.within_2std, ".0f") + ("" if not np.isfinite(r.within_2std) else " %"),
                 f(r.median_err_over_std, ".2f"), f(r.common_mean_err_m, ".2f"), f(r.gamma, ".2f"),
                 f(r.wall_s, ".1f")]
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"
