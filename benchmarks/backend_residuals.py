"""Why the back-end's ranges mislead it on some channels (issue 32, "measure why"): the residual of every range
factor's measurement against the true distance, on simulated datasets (true beacon and receiver positions known).

For each session: the ranges the back-end builds (:func:`blenav.backend.inputs.session_ranges`: PF-PL's path loss
of 000 Table I, its 10 m clamp), their residual r - d (m) by true distance d, the share a perfect validation gate
(``range.gate_m`` around the true position) would keep and their bias, the spread of the per-beacon median residual,
and the median residual per 30 s of the walk. A range model that fits the channel has residuals centred on 0 at
every distance; the clamp alone makes far beacons' kept ranges short.

    .venv/bin/python benchmarks/backend_residuals.py DATASET [DATASET ...] [--out docs/results/backend_residuals.md]
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from blenav.backend.config import load_backend_config
from blenav.backend.inputs import beacon_priors, path_loss_model, session_ranges
from blenav.data import Dataset

BINS = [(0, 3), (3, 6), (6, 10), (10, 20), (20, 100)]


def residuals(session, cfg) -> dict:
    """The session's range residuals (see the module docstring) as plain numbers."""
    anchors = session.building.anchors_of("ble")
    true = anchors.copy()
    for c in "xyz":
        if f"{c}_true" in true:
            true[c] = true[f"{c}_true"]
    beacons = beacon_priors(true, 0.5, 0.5)
    ranges = session_ranges(session, beacons, path_loss_model(cfg), true)
    gt = session.groundtruth
    p = np.stack([np.interp(ranges.t, gt["t"], gt["x"]), np.interp(ranges.t, gt["t"], gt["y"]),
                  np.full(len(ranges.t), cfg.range.device_z)], -1)
    d = np.linalg.norm(p - beacons.xyz[ranges.anchor], axis=-1)
    res = ranges.range_m - d
    out = {"n": int(len(res)), "median": float(np.median(res)), "bins": {}}
    for lo, hi in BINS:
        m = (d >= lo) & (d < hi)
        if m.any():
            out["bins"][f"{lo}-{hi}"] = (int(m.sum()), float(np.median(res[m])))
    gate = d <= float(cfg.range.gate_m or np.inf)
    out["gate"] = (float(gate.mean()), float(np.median(res[gate])) if gate.any() else float("nan"))
    by_beacon = [gate & (ranges.anchor == j) for j in np.unique(ranges.anchor[gate])]
    per_beacon = [float(np.median(res[m])) for m in by_beacon if np.count_nonzero(m) >= 10]
    out["per_beacon"] = (len(per_beacon), *np.percentile(per_beacon, [10, 50, 90]).tolist()) if per_beacon else None
    t0 = float(ranges.t.min()) if len(ranges.t) else 0.0
    win = np.floor((ranges.t - t0) / 30.0).astype(int)
    by_window = [gate & (win == w) for w in np.unique(win)]
    out["over_time"] = [float(np.median(res[m])) for m in by_window if m.any()]
    return out


def markdown(rows: list[tuple[str, str, dict]], cfg) -> str:
    bins = [f"{lo}-{hi}" for lo, hi in BINS]
    lines = ["# Range residuals of the back-end (issue 32)", "",
             "`python benchmarks/backend_residuals.py DATASET ...`: r - d (m), the back-end's range (PF-PL's path "
             f"loss, a_X {cfg.range.a_x} dBm, gamma {cfg.range.gamma}, d0 {cfg.range.d0} m, clamp "
             f"{cfg.range.max_range_m} m) minus the true distance; medians. 'gate': the ranges whose true distance "
             f"is within the {cfg.range.gate_m} m gate (what a perfect gate keeps), their share and median; 'per "
             "beacon': 10th / 50th / 90th percentile of the beacons' median residuals inside the gate; 'over time': "
             "min / max of the per-30 s medians inside the gate.", "",
             "| dataset | session | ranges | " + " | ".join(f"d {b} m" for b in bins)
             + " | gate: share, median | per beacon p10 / p50 / p90 | over time min / max |",
             "|---|---|---|" + "---|" * len(bins) + "---|---|---|"]
    for ds, sid, r in rows:
        cells = [f"{r['bins'][b][1]:+.2f} ({r['bins'][b][0]})" if b in r["bins"] else "-" for b in bins]
        pb = r["per_beacon"]
        pbs = f"{pb[1]:+.2f} / {pb[2]:+.2f} / {pb[3]:+.2f} ({pb[0]})" if pb else "-"
        ot = f"{min(r['over_time']):+.2f} / {max(r['over_time']):+.2f}" if r["over_time"] else "-"
        lines.append(f"| {ds} | {sid} | {r['n']} | " + " | ".join(cells)
                     + f" | {r['gate'][0]:.2f}, {r['gate'][1]:+.2f} | {pbs} | {ot} |")
    return "\n".join(lines) + "\n"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("datasets", nargs="+", type=Path)
    ap.add_argument("--out", type=Path, default=None, help="also write the table here (markdown)")
    args = ap.parse_args()
    cfg = load_backend_config()
    rows = []
    for root in args.datasets:
        ds = Dataset.open(root)
        for sid in ds.session_ids:
            s = ds.session(sid)
            if s.has("rssi") and len(s.groundtruth):
                rows.append((root.name, sid, residuals(s, cfg)))
    text = markdown(rows, cfg)
    print(text)
    if args.out:
        from blenav.eval.common import write_text

        write_text(args.out, text)


if __name__ == "__main__":
    main()
