"""The Feng et al. real-RTT evaluation (issue 15 sec. 3; ``blenav-eval experiment=crf_004_feng``): the range errors
of the imported dataset at its test points, the part of ``docs/results/feng_rtt.md`` that is not in results.json.

:func:`range_errors`: the absolute range error |range - true 3-D distance| of every RTT reading at the test points,
uncalibrated and with the offline per-AP offsets of the train points
(:func:`blenav.localizers.ranging_windows.rtt_offsets`), with and without the -65 dBm rule (004 Fig. 9's
comparison); :func:`scan_counts`: the scans per test session. The page is written by
:mod:`blenav.reporting.feng_rtt` (``python -m blenav.cli.tables feng ...``, ``make feng-tables``).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

__all__ = ["ENVS", "range_errors", "scan_counts"]

ENVS = ("lecture_theatre", "office", "corridor")


def range_errors(dataset: Path, device_z: float = 1.2) -> list[dict]:
    """Per environment and rule: median / mean / p90 |range error| (m) at the test points, none vs offline."""
    from blenav.data import Dataset
    from blenav.localizers.ranging_windows import WIFI_MIN_RSSI_DBM, dist3, rtt_offsets, rtt_readings

    ds = Dataset.open(dataset)
    rows = []
    for env in ENVS:
        test, train = ds.session(f"{env}_test"), ds.session(f"{env}_train")
        for rule in (WIFI_MIN_RSSI_DBM, None):
            t, idx, rng, anchors, n_weak = rtt_readings(test, rule)
            off = rtt_offsets([train], anchors, device_z, rule)
            d = dist3(test.positions_at(t), device_z, anchors.xyz[idx]) if len(t) else np.zeros(0)
            row = {"env": env, "rule": "-65 dBm" if rule is not None else "none", "n": len(t),
                   "offsets": {a: float(o) for a, o in zip(anchors.ids, off)}}
            for name, e in (("none", rng - d), ("offline", rng - np.where(np.isfinite(off), off, 0.0)[idx] - d)):
                a = np.abs(e)
                row[name] = (float(np.median(a)), float(a.mean()), float(np.percentile(a, 90))) if len(a) else None
            rows.append(row)
    return rows


def scan_counts(dataset: Path) -> dict[str, int]:
    """Test session id -> number of scans (ground-truth rows, one per scan)."""
    from blenav.data import Dataset

    ds = Dataset.open(dataset)
    return {f"{e}_test": len(ds.session(f"{e}_test").groundtruth) for e in ENVS}
