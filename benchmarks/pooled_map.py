"""Issue 32: a wrong beacon map corrected by pooling every walk's RSSI in one mapping graph, against one walk alone.

The back-end moves a 3 m map's beacons 1-4 % closer to the truth (docs/results-000-002.md), and
``benchmarks/beacon_bound.py`` shows that one walk's ranges cannot do much better even on its true track. This
measures the other way that page names: several walks in one graph. The walks' positions are their front-end's
tracks on the wrong map (no ground truth), the estimator ``blenav map``'s RSSI-domain one
(:func:`blenav.backend.mapping.map_beacons`, each beacon's prior centred on the wrong map: ``use_map_prior``,
``prior_sigma_m``). Three steps, the front-end run as a user runs it:

    .venv/bin/python benchmarks/pooled_map.py perturb DATASET WRONG [--noise-m 3] [--seed 0]
    .venv/bin/blenav-eval experiment=backend_000 data=WRONG runs=1 "only=[F-end]" beacon_map.source=given out=OUT
    .venv/bin/python benchmarks/pooled_map.py map WRONG --eval OUT [--prior-sigma-m 3]

and a fourth, to see what the pooled map is worth for localization: ``write WRONG POOLED --eval OUT`` (or
``--truth``: pooled on the walks' true tracks, an oracle) writes a copy of WRONG whose BLE anchors are the pooled
estimate (x_true / y_true kept), on which ``blenav-eval experiment=backend_000 data=POOLED beacon_map.source=given``
runs F-end and B-end as on WRONG.

``perturb``: a copy of DATASET whose BLE anchors are moved by N(0, noise^2) per horizontal axis, **one draw for
every walk** (:func:`blenav.eval.beacon_map.perturb` with ``per_walk: false``: run 0's draw of
``experiment=mapnoise_pooled``), anchors.csv's x_true / y_true kept to score it. ``beacon_map.source=given`` makes the
front-end run on that wrong map (backend_000's default, ``true``, reads x_true / y_true where a dataset has
them). ``map``: the map estimated from every walk pooled, from each walk alone (the mean of their errors), and from
every walk pooled on its true track; printed: the mean horizontal error of the given and the estimated maps over
every BLE beacon (a beacon the estimator does not place stays where the given map put it) and how much closer the
estimate is. The evaluation's own version of the pooled step, followed by the closed loop on the pooled map: rows
``F-end+pool`` / ``B-end+pool`` of ``experiment=mapnoise_pooled`` (:mod:`blenav.backend.pooled`).
"""

from __future__ import annotations

import argparse
import shutil
from pathlib import Path

import numpy as np
import pandas as pd

from blenav.backend.config import load_backend_config
from blenav.backend.mapping import map_beacons
from blenav.backend.pooled import along_track
from blenav.data import Dataset
from blenav.data.session import Session
from blenav.eval.beacon_map import BeaconMapConfig, perturb


def tracked(sess: Session, tum: Path) -> Session:
    """``sess`` seen along the TUM trajectory ``tum`` (t x y z qx qy qz qw; x, y taken) at the session's own heights
    interpolated at those times (:func:`blenav.backend.pooled.along_track`)."""
    tr = np.loadtxt(tum, ndmin=2)
    gt = sess.groundtruth
    z = np.interp(tr[:, 0], gt["t"].to_numpy(float), gt["z"].to_numpy(float)) if "z" in gt else 0.0
    return along_track(sess, tr[:, 0], tr[:, 1:3], z)


def map_error(beacons: pd.DataFrame, anchors: pd.DataFrame) -> float:
    """Mean horizontal distance (m) of the BLE beacons of ``beacons`` (anchor_id, x, y) from anchors.csv's
    x_true / y_true."""
    ble = anchors[anchors["kind"] == "ble"].set_index("anchor_id")
    b = beacons.set_index("anchor_id").loc[ble.index]
    return float(np.hypot(b["x"] - ble["x_true"], b["y"] - ble["y_true"]).mean())


def cmd_perturb(args) -> None:
    shutil.copytree(args.dataset, args.out)
    ds = Dataset.open(args.out)
    cfg = BeaconMapConfig(source="true", noise_m=args.noise_m, vertical=False, per_walk=False, seed=args.seed)
    for bid in ds.building_ids:
        b = perturb(ds.building(bid), cfg, 0, 0)  # run 0's draw, the same for every walk
        path = Path(args.out) / "buildings" / bid / "anchors.csv"
        b.anchors.to_csv(path, index=False)
        print(f"{path}: BLE anchors moved, mean error {map_error(b.anchors, b.anchors):.2f} m")


def _buildings(args):
    """(the estimator's settings with ``--prior-sigma-m`` around the given map, [(building id, anchors.csv rows, its
    labelled walks)] of ``args.dataset``)."""
    ds = Dataset.open(args.dataset)
    cfg = load_backend_config(overrides=["mapping.use_map_prior=true",
                                         f"mapping.prior_sigma_m={args.prior_sigma_m}"]).mapping
    return cfg, [(bid, ds.building(bid).anchors, [s for s in ds.sessions(None, labelled=True) if s.building.id == bid])
                 for bid in ds.building_ids]


def cmd_map(args) -> None:
    cfg, buildings = _buildings(args)
    for bid, anchors, sessions in buildings:
        if not sessions:
            print(f"building {bid}: no labelled walk, skipped")
            continue
        front = [tracked(s, args.eval / s.id / "trajectories" / f"{args.row}.tum") for s in sessions]
        given = map_error(anchors, anchors)
        rows = [("every walk pooled, front-end tracks", map_error(map_beacons(front, anchors, cfg).beacons, anchors)),
                ("each walk alone, front-end track (mean)",
                 float(np.mean([map_error(map_beacons([s], anchors, cfg).beacons, anchors) for s in front]))),
                ("every walk pooled, their true tracks",
                 map_error(map_beacons(sessions, anchors, cfg).beacons, anchors))]
        print(f"building {bid}: {len(sessions)} walks, {int((anchors['kind'] == 'ble').sum())} BLE beacons, given map "
              f"{given:.2f} m off; prior_sigma_m {args.prior_sigma_m:g}, tracks: {args.row} of {args.eval}")
        for name, err in rows:
            print(f"  {name:42s} {err:5.2f} m  closer by {100.0 * (1.0 - err / given):5.1f} %")


def cmd_write(args) -> None:
    if (args.eval is None) == (not args.truth):
        raise SystemExit("write: give --eval OUT (the row's tracks) or --truth (the true tracks), one of them")
    shutil.copytree(args.dataset, args.out)
    cfg, buildings = _buildings(args)
    for bid, anchors, sessions in buildings:
        if not sessions:
            continue
        walks = sessions if args.truth else [tracked(s, args.eval / s.id / "trajectories" / f"{args.row}.tum")
                                             for s in sessions]
        est = map_beacons(walks, anchors, cfg).beacons.set_index("anchor_id")
        a = anchors.copy()
        hit = a["anchor_id"].astype(str).isin(est.index[est["placed"]]).to_numpy()
        a.loc[hit, ["x", "y"]] = est.loc[a.loc[hit, "anchor_id"].astype(str), ["x", "y"]].to_numpy(float)
        path = Path(args.out) / "buildings" / bid / "anchors.csv"
        a.to_csv(path, index=False)
        src = "true tracks" if args.truth else f"{args.row} of {args.eval}"
        print(f"{path}: {int(hit.sum())} BLE anchors from {len(walks)} walks ({src}), map "
              f"{map_error(anchors, anchors):.2f} -> {map_error(a, a):.2f} m off")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    sub = ap.add_subparsers(dest="cmd", required=True)
    p = sub.add_parser("perturb", help="a copy of the dataset with one wrong map for every walk")
    p.add_argument("dataset", type=Path)
    p.add_argument("out", type=Path)
    p.add_argument("--noise-m", type=float, default=3.0)
    p.add_argument("--seed", type=int, default=0)
    m = sub.add_parser("map", help="the map estimated from the walks' front-end tracks")
    m.add_argument("dataset", type=Path)
    m.add_argument("--eval", type=Path, required=True, help="an evaluation of the dataset (its trajectories/)")
    m.add_argument("--row", default="F-end", help="the row whose trajectories place the readings")
    m.add_argument("--prior-sigma-m", type=float, default=3.0)
    w = sub.add_parser("write", help="a copy of the dataset whose beacon map is the pooled estimate")
    w.add_argument("dataset", type=Path)
    w.add_argument("out", type=Path)
    w.add_argument("--eval", type=Path, help="an evaluation of the dataset (its trajectories/)")
    w.add_argument("--truth", action="store_true", help="pool on the walks' true tracks (an oracle)")
    w.add_argument("--row", default="F-end", help="the row whose trajectories place the readings")
    w.add_argument("--prior-sigma-m", type=float, default=3.0)
    args = ap.parse_args()
    {"perturb": cmd_perturb, "map": cmd_map, "write": cmd_write}[args.cmd](args)


if __name__ == "__main__":
    main()
