"""``blenav-map DATASET --sessions ID,ID --out DIR``: beacon positions from labelled walks (issue 14, sec. 3).

Estimates every BLE beacon's position and RSSI at 1 m from the named labelled sessions (default: every labelled
session) with :func:`blenav.backend.mapping.map_beacons`, and writes DIR: a copy of the dataset with those
sessions and their buildings, whose ``anchors.csv`` holds the estimated positions (``x, y, z``), their
horizontal std (``std_m``, m per axis), the RSSI at 1 m (``tx_power_dbm``, its std ``tx_power_std_db``), the
input positions (``x_prior, y_prior, z_prior``) and ``map_status``. Beacons it could not place (heard too
little, bad geometry) are reported and left out of anchors.csv (``--keep-unplaced``: kept at their input
position with an empty ``std_m`` and the reason in ``map_status``); nothing is invented. DIR passes
``blenav-validate``; ``DIR/mapping_report.json`` records the settings, the fit and every beacon's outcome
(with its error against ``x_true, y_true`` when the dataset knows them).

Settings: ``conf/backend/default.yaml``, node ``mapping`` (``--set min_readings=50 --set walls=false``).
"""

from __future__ import annotations

import json
import shutil
import sys
from pathlib import Path

from .args import ArgumentParser
from .common import run_main

PROG = "blenav-map"


def _parse(argv):
    p = ArgumentParser(prog=PROG, description=__doc__.splitlines()[0])
    p.add_argument("dataset", help="dataset folder (contains dataset.yaml)")
    p.add_argument("--sessions", default=None, help="comma-separated labelled session ids (default: every labelled one)")
    p.add_argument("--out", required=True, help="output dataset folder (must not exist, or be empty)")
    p.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                   help="a mapping setting of conf/backend/default.yaml (repeatable), e.g. min_readings=50")
    p.add_argument("--keep-unplaced", action="store_true",
                   help="keep beacons that could not be placed, at their input position with an empty std_m")
    return p.parse_args(argv)


def _main(argv) -> int:
    args = _parse(argv)
    import yaml

    from blenav.backend.config import load_backend_config
    from blenav.backend.mapping import map_beacons
    from blenav.data import Dataset, validate

    out = Path(args.out)
    if out.exists() and (not out.is_dir() or any(out.iterdir())):
        raise ValueError(f"--out {out} exists and is not empty: give a new folder")
    over = [s if s.startswith("mapping.") else f"mapping.{s}" for s in args.set]
    cfg = load_backend_config(overrides=over).mapping
    ds = Dataset.open(args.dataset)
    ids = [s.strip() for s in args.sessions.split(",") if s.strip()] if args.sessions else None
    sessions = list(ds.sessions(ids, labelled=None if ids else True))
    unlabelled = [s.id for s in sessions if not s.labelled]
    if unlabelled:
        raise ValueError(f"sessions {unlabelled} are not labelled: mapping needs ground-truth poses")
    if not sessions:
        raise ValueError(f"{args.dataset} has no labelled session to map beacons from")
    by_building: dict[str, list] = {}
    for s in sessions:
        by_building.setdefault(s.building.id, []).append(s)

    results = {}
    for bid, sess in by_building.items():
        res = map_beacons(sess, ds.building(bid).anchors, cfg)
        if not res.beacons["placed"].any() and not args.keep_unplaced:
            why = "; ".join(f"{r.anchor_id}: {r.status}" for r in res.beacons.itertuples())[:400]
            raise ValueError(f"building {bid}: no beacon could be placed from sessions "
                             f"{[s.id for s in sess]} ({why}); nothing written")
        results[bid] = (sess, res)

    out.mkdir(parents=True, exist_ok=True)
    meta = dict(ds.meta)
    used = [s.id for s in sessions]
    meta["description"] = (f"{meta.get('description', '')} -- beacon map estimated by blenav-map from sessions "
                           f"{', '.join(used)}").strip(" -")
    (out / "dataset.yaml").write_text(yaml.safe_dump(meta, sort_keys=False), encoding="utf-8")
    report = {"dataset": str(Path(args.dataset).resolve()), "sessions": used, "settings": _plain(cfg),
              "buildings": {}}
    for bid, (sess, res) in results.items():
        report["buildings"][bid] = _write_building(ds, out, bid, sess, res, args.keep_unplaced)
    (out / "mapping_report.json").write_text(json.dumps(report, indent=1, default=str) + "\n", encoding="utf-8")
    errors = [i for i in validate(out) if i.is_error]
    if errors:  # a bug of this command, never the user's: say so
        raise RuntimeError(f"{PROG} wrote an invalid dataset {out}: {errors[0]}")
    print(f"wrote {out} (blenav-validate: OK)")
    return 0


def _write_building(ds, out: Path, bid: str, sess: list, res, keep_unplaced: bool) -> dict:
    """Writes building ``bid`` of ``ds`` (its anchors.csv with the estimates ``res``, a MappingResult) and its
    mapped sessions ``sess`` into the output dataset ``out``, prints the outcome (with the errors against
    ``x_true, y_true``, m, when anchors.csv has them) and returns the building's entry of mapping_report.json."""
    import numpy as np

    from blenav.data.writer import write_csv

    src = ds.root / "buildings" / bid
    shutil.copytree(src, out / "buildings" / bid)
    anchors = ds.building(bid).anchors
    table = _anchors_table(anchors, res.beacons, keep_unplaced)
    write_csv(out / "buildings" / bid / "anchors.csv", table)
    for s in sess:
        shutil.copytree(s.root, out / "sessions" / s.id)
    rows = res.beacons.copy()
    a = anchors.set_index("anchor_id")
    truth = all(c in a.columns for c in ("x_true", "y_true"))
    if truth:
        tr = a.loc[rows["anchor_id"]]
        rows["error_m"] = np.where(rows["placed"], np.hypot(rows["x"].to_numpy() - tr["x_true"].to_numpy(float),
                                                            rows["y"].to_numpy() - tr["y_true"].to_numpy(float)),
                                   np.nan)
    entry = {
        "gamma": res.gamma, "gamma_std": res.gamma_std, "reference_session": res.reference_session,
        "receiver_offsets_db": res.offsets_db, "residual_std_db": res.residual_std_db, "notes": res.notes,
        "wall_s": res.wall_s,
        "beacons": json.loads(rows.to_json(orient="records")),
    }
    placed = rows[rows["placed"]]
    print(f"{bid}: placed {len(placed)} of {len(rows)} beacons from {len(sess)} session(s) in {res.wall_s:.1f} s; "
          f"gamma {res.gamma:.2f}, residual std {res.residual_std_db:.1f} dB")
    if truth and len(placed):
        e = placed["error_m"].to_numpy(float)
        print(f"  error against the true positions: mean {e.mean():.2f} m, median {np.median(e):.2f} m, max "
              f"{e.max():.2f} m; median error / std_m {np.median(e / placed['std_m'].to_numpy(float)):.2f}")
    for r in rows[~rows["placed"]].itertuples():
        print(f"  not placed: {r.anchor_id}: {r.status}")
    return entry


def _plain(cfg) -> dict:
    from dataclasses import asdict

    return {k: (str(v) if hasattr(v, "value") else v) for k, v in asdict(cfg).items()}


def _anchors_table(anchors, beacons, keep_unplaced: bool):
    """anchors.csv of the output: every non-BLE row unchanged; BLE rows with the estimates (placed), or kept at
    the input (``keep_unplaced``), or left out."""
    import numpy as np
    import pandas as pd

    est = beacons.set_index("anchor_id")
    rows = anchors.copy()
    for c in ("x", "y", "z"):
        rows[f"{c}_prior"] = rows[c]
    for c in ("std_m", "tx_power_std_db"):
        rows[c] = np.nan
    rows["map_status"] = ""
    is_ble = rows["kind"] == "ble"
    keep = np.ones(len(rows), bool)
    for i in np.flatnonzero(is_ble.to_numpy()):
        aid = str(rows.iloc[i]["anchor_id"])
        if aid not in est.index:
            continue
        e = est.loc[aid]
        rows.iloc[i, rows.columns.get_loc("map_status")] = e["status"]
        if e["placed"]:
            for c in ("x", "y", "z", "std_m", "tx_power_dbm", "tx_power_std_db"):
                rows.iloc[i, rows.columns.get_loc(c)] = float(e[c])
        elif not keep_unplaced:
            keep[i] = False
    return pd.DataFrame(rows[keep]).reset_index(drop=True)


def main(argv: list[str] | None = None) -> int:
    """``blenav-map``: errors the user can fix print one line and exit 1 (``--debug``: with the traceback)."""
    return run_main(PROG, _main, argv)


if __name__ == "__main__":
    sys.exit(main())
