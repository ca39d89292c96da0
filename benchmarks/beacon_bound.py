"""How far a 3 m beacon map can be corrected from one walk, with the trajectory known (issue 32, "beacons that move").

The closed loop of 000 corrects the beacon map from the walk's own ranges; issue 32 asks the optimized beacons of
``experiment=mapnoise_000`` (every beacon moved by N(0, 3^2) m per axis) to end at least 25 % closer to the truth.
This benchmark removes the trajectory's error from the question: every session's beacons are re-estimated with
the receiver's positions **pinned at the ground truth**, from the perturbed map as prior, by

* ``range graph``: the back-end's own graph (:func:`blenav.backend.graph.smooth`, LM, the default settings: PF-PL's
  RSSI -> range of 000 Table I, 10 m clamp, gate, median per keyframe, Huber) with every keyframe held at the
  truth (its x, y prior 0.05 m), the beacons' prior std 0.5 m (what the back-end assumes when anchors.csv states
  none) or 3 m (told how wrong the map is); ``+ line``: the same with ``range.refit_channel=line``;
* ``RSSI mapping``: ``blenav-map``'s RSSI-domain model (:func:`blenav.backend.mapping.map_beacons`: each beacon's
  level, the exponent, the receiver offset, body shadow and walls all estimated) from the true poses, with the
  perturbed map as its prior (``mapping.use_map_prior``, std 1.5 or 3 m, every beacon with 10 readings kept).

Each row: the given map's mean horizontal error and the estimate's (m) over every beacon of the building, and the
share by which it is closer; then every row's error by how many readings (rssi.csv rows) each beacon had. The draws of
the perturbation are those of ``experiment=mapnoise_000`` (:func:`blenav.eval.beacon_map.perturb`, runs 0..R-1).

    .venv/bin/python benchmarks/beacon_bound.py DATASET [DATASET ...] [--runs 2] [--out docs/results/beacon_bound.md]
"""

from __future__ import annotations

import argparse
import time
from dataclasses import replace
from pathlib import Path

import numpy as np
import pandas as pd

from blenav.backend.config import load_backend_config
from blenav.backend.graph import smooth
from blenav.backend.inputs import (beacon_priors, keyframes_from_front_end, path_loss_model, session_attitude,
                                   session_imu, session_ranges)
from blenav.backend.mapping import map_beacons
from blenav.data import Dataset
from blenav.eval import beacon_map as BM

PIN_M = 0.05  # m: the keyframes' x, y prior around the ground truth


def pinned_range_graph(session, building, sigma_m: float, overrides: list[str]) -> pd.DataFrame:
    """The back-end's graph on ``session`` with ``building``'s (perturbed) map as prior (std ``sigma_m``) and every
    keyframe (1 s) held at the ground truth: its beacon map (anchor_id, x, y, z, n_heard, ...)."""
    cfg = load_backend_config(overrides=["solver.method=lm", f"priors.front_end_min_sigma_m={PIN_M}",  # not inflated:
                                         "priors.front_end_cloud_scale=1.0", "priors.front_end_corr_s=1.0", *overrides])
    anchors = building.anchors_of("ble")
    bp = beacon_priors(anchors, sigma_m, cfg.priors.beacon_sigma_z_m)
    ranges = session_ranges(session, bp, path_loss_model(cfg), anchors)
    gt = session.groundtruth
    t = np.arange(float(gt["t"].iloc[0]), float(gt["t"].iloc[-1]), 1.0)
    pos = np.column_stack([np.interp(t, gt["t"], gt["x"]), np.interp(t, gt["t"], gt["y"])])
    cov = np.broadcast_to(np.eye(2) * PIN_M ** 2, (1, len(t), 2, 2)).copy()
    q_t, q = session_attitude(session)
    kf, _ = keyframes_from_front_end(t, pos[None], q_t, q, cfg, cov=cov)
    return smooth(cfg, kf, session_imu(session), ranges, bp).beacon_map


def rssi_mapping(session, building, sigma_m: float) -> pd.DataFrame:
    """blenav-map's RSSI-domain estimate from the true poses with ``building``'s map as prior (std ``sigma_m``)."""
    base = load_backend_config().mapping
    cfg = replace(base, use_map_prior=True, prior_sigma_m=sigma_m, max_std_m=1e3, min_readings=10, min_spread_m=0.0)
    return map_beacons([session.with_building(building)], building.anchors, cfg).beacons


ROWS = {  # name -> estimate(session, perturbed building)
    "range graph, prior 0.5 m": lambda s, b: pinned_range_graph(s, b, 0.5, []),
    "range graph, prior 3 m": lambda s, b: pinned_range_graph(s, b, 3.0, []),
    "range graph + line, prior 3 m": lambda s, b: pinned_range_graph(s, b, 3.0, ["range.refit_channel=line"]),
    "RSSI mapping, prior 1.5 m": lambda s, b: rssi_mapping(s, b, 1.5),
    "RSSI mapping, prior 3 m": lambda s, b: rssi_mapping(s, b, 3.0),
}


def bound(root: Path, runs: int) -> tuple[dict, pd.DataFrame]:
    """Per row: (given error, estimated error) pooled over sessions and draws; and per beacon and draw the given /
    estimated errors of every row with the beacon's reading count."""
    ds = Dataset.open(root)
    bm = BM.BeaconMapConfig(source="true", noise_m=3.0, vertical=False)  # as experiment=mapnoise_000
    sessions, _ = BM.with_source([ds.session(sid) for sid in ds.session_ids], bm)
    per_beacon = []
    for si, s in enumerate(sessions):
        truth, heard = BM.true_xy(s.building.anchors), BM.heard_counts(s)
        for run in range(runs):
            b = BM.perturb(s.building, bm, si, run)
            given = BM.given_map(b)
            rows = {name: BM.beacon_rows(given, est(s, b), truth, heard) for name, est in ROWS.items()}
            df = next(iter(rows.values()))[["anchor_id", "heard", "given_m"]].rename(
                columns={"heard": "readings", "given_m": "given"}).assign(session=s.id, run=run)
            for name, r in rows.items():
                df[name] = r["optimized_m"].to_numpy()
            per_beacon.append(df)
    pb = pd.concat(per_beacon)
    summary = {name: (float(pb["given"].mean()), float(pb[name].mean())) for name in ROWS}
    return summary, pb


def markdown(results: list[tuple[str, dict, pd.DataFrame]], runs: int, wall_s: float, command: str = "") -> str:
    lines = ["# How far one walk can correct a 3 m beacon map, the trajectory known (issue 32)", "",
             f"Made by `{command or '.venv/bin/python benchmarks/beacon_bound.py'}` (its docstring says how; the "
             "simulated datasets are those `make backend-robust` makes); every beacon moved by "
             f"N(0, 3^2) m per axis as in `experiment=mapnoise_000`, {runs} draw(s) per session, the receiver's "
             "positions pinned at the ground truth. Mean horizontal beacon error (m), given -> estimated (closer by).",
             "", "| dataset | " + " | ".join(ROWS) + " |", "|---|" + "---|" * len(ROWS)]
    for name, summary, _ in results:
        cells = [f"{g:.2f} -> {e:.2f} ({100 * (1 - e / g):+.0f} %)" for g, e in summary.values()]
        lines.append(f"| {name} | " + " | ".join(cells) + " |")
    lines += ["", "By readings per beacon (rssi.csv rows of the session; all datasets pooled), mean error (m):", "",
              "| readings | beacons | given | " + " | ".join(ROWS) + " |", "|---|---|---|" + "---|" * len(ROWS)]
    pb = pd.concat([r[2] for r in results])
    for lo, hi, label in BM.heard_bins():
        m = (pb["readings"] >= lo) & ((pb["readings"] < hi) if hi is not None else True)
        if not m.any():
            continue
        cells = [f"{pb.loc[m, k].mean():.2f}" for k in ROWS]
        lines.append(f"| {label} | {int(m.sum())} | {pb.loc[m, 'given'].mean():.2f} | " + " | ".join(cells) + " |")
    lines += ["", f"Wall time {wall_s:.0f} s."]
    return "\n".join(lines) + "\n"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("datasets", nargs="+", type=Path, help="simulated datasets (true beacon positions known)")
    ap.add_argument("--runs", type=int, default=2, help="perturbation draws per session (mapnoise_000's runs 0..R-1)")
    ap.add_argument("--out", type=Path, default=None, help="also write the tables here (markdown)")
    args = ap.parse_args()
    t0 = time.perf_counter()
    results = []
    for root in args.datasets:
        summary, pb = bound(root, args.runs)
        results.append((root.name, summary, pb))
        print(root.name, {k: f"{g:.2f} -> {e:.2f}" for k, (g, e) in summary.items()}, flush=True)
    command = " ".join([".venv/bin/python benchmarks/beacon_bound.py", *map(str, args.datasets), "--runs",
                        str(args.runs)] + (["--out", str(args.out)] if args.out else []))
    text = markdown(results, args.runs, time.perf_counter() - t0, command)
    print(text)
    if args.out:
        from blenav.eval.common import write_text

        write_text(args.out, text)


if __name__ == "__main__":
    main()
