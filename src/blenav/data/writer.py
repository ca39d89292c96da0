"""Writing format-v1 datasets (used by the simulator and the importers).

All writers take world-frame metres and seconds; they never write a sentinel for a missing value
(an empty cell instead), and round floats to a fixed number of decimals so that the same input gives
the same bytes.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pandas as pd
import yaml
from PIL import Image
from shapely.geometry import mapping

from .building import FREE, OCCUPIED
from .schema import ANCHOR_COLUMNS, FORMAT, STREAMS

#: decimals written per column (others: 6)
DECIMALS = {"t": 4, "rssi": 2, "range_m": 3, "range_std_m": 3, "x": 4, "y": 4, "z": 4}


def _dump_yaml(path: Path, doc: dict) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(yaml.safe_dump(doc, sort_keys=False), encoding="utf-8")


def write_dataset_meta(root: Path, name: str, description: str = "", licence: str = "", source: str = "",
                       **extra) -> None:
    _dump_yaml(Path(root) / "dataset.yaml", {"format": FORMAT, "name": name, "description": description,
                                             "licence": licence, "source": source, **extra})


def occupancy_to_image(occ: np.ndarray) -> np.ndarray:
    """int8 occupancy (FREE 0 / OCCUPIED 1 / UNKNOWN -1) -> uint8 map_server pixels (254 / 0 / 205)."""
    img = np.full(occ.shape, 205, dtype=np.uint8)
    img[occ == FREE] = 254
    img[occ == OCCUPIED] = 0
    return img


def write_building(root: Path, building_id: str, name: str, floors: list[dict], anchors: pd.DataFrame | None = None,
                   rooms: list[dict] | None = None, navgraph: list[dict] | None = None, **extra) -> Path:
    """Write ``buildings/<building_id>/``.

    ``floors``: dicts with id, image (uint8 array, row 0 on top, or an occupancy int8 array under
    ``occupancy``), resolution (m/px), origin (x, y) m, z m. ``rooms``/``navgraph``: dicts with id,
    floor and a shapely ``geometry`` in world metres.
    """
    broot = Path(root) / "buildings" / building_id
    broot.mkdir(parents=True, exist_ok=True)
    fdocs = []
    for f in floors:
        img = f["image"] if "image" in f else occupancy_to_image(f["occupancy"])
        fname = f.get("filename", f"floor_{f['id']}.png")
        Image.fromarray(np.asarray(img, dtype=np.uint8), mode="L").save(broot / fname)
        fdocs.append({"id": f["id"], "image": fname, "resolution": float(f["resolution"]),
                      "origin": [float(f["origin"][0]), float(f["origin"][1]), 0.0], "z": float(f.get("z", 0.0)),
                      "occupied_thresh": 0.65, "free_thresh": 0.196})
    _dump_yaml(broot / "building.yaml", {"name": name, "floors": fdocs, **extra})
    if anchors is not None and len(anchors):
        cols = list(ANCHOR_COLUMNS) + [c for c in anchors.columns if c not in ANCHOR_COLUMNS]
        a = anchors.reindex(columns=cols)
        write_csv(broot / "anchors.csv", a)
    for fname, feats in (("rooms.geojson", rooms), ("navgraph.geojson", navgraph)):
        if feats:
            fc = {"type": "FeatureCollection", "features": [
                {"type": "Feature", "properties": {"id": str(r["id"]), "floor": r["floor"],
                                                   **r.get("properties", {})},
                 "geometry": mapping(r["geometry"])} for r in feats]}
            (broot / fname).write_text(json.dumps(fc, indent=1), encoding="utf-8")
    return broot


def write_csv(path: Path, df: pd.DataFrame) -> None:
    """Write a frame with per-column rounding; NaN becomes an empty cell."""
    out = df.copy()
    for c in out.columns:
        if pd.api.types.is_float_dtype(out[c]):
            out[c] = out[c].round(DECIMALS.get(c, 6))
    path.parent.mkdir(parents=True, exist_ok=True)
    out.to_csv(path, index=False, na_rep="", lineterminator="\n")


def write_session(root: Path, session_id: str, meta: dict, streams: dict[str, pd.DataFrame]) -> Path:
    """Write ``sessions/<session_id>/``: ``session.yaml`` plus one CSV per stream in ``streams``.

    Streams must carry the columns of :data:`blenav.data.schema.STREAMS` (extra columns are kept).
    """
    sroot = Path(root) / "sessions" / session_id
    sroot.mkdir(parents=True, exist_ok=True)
    _dump_yaml(sroot / "session.yaml", meta)
    for name, df in streams.items():
        spec = STREAMS[name]
        missing = [c for c in spec.columns if c not in df.columns]
        if missing:
            raise ValueError(f"stream {name} for session {session_id} lacks columns {missing}")
        cols = list(spec.columns) + [c for c in df.columns if c not in spec.columns]
        write_csv(sroot / spec.filename, df[cols])
    return sroot
