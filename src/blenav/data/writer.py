"""Writing format-v1 datasets (used by the simulator and the importers).

All writers take world-frame metres and seconds; they never write a sentinel for a missing value
(an empty cell instead), and round floats to a fixed number of decimals so that the same input gives
the same bytes.
"""

from __future__ import annotations

import json
import os
from pathlib import Path

import numpy as np
import pandas as pd
import yaml
from PIL import Image
from shapely.geometry import mapping

from blenav.errors import DatasetError

from .floor import FREE, OCCUPIED
from .schema import ANCHOR_COLUMNS, FORMAT, STREAMS
from .tables import read_stream

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


def write_fixes(session_dir: Path, t, xy, std=None, *, source: str) -> Path:
    """Write position fixes of one ``source`` into ``<session_dir>/fixes.csv``; returns the file's path.

    ``t`` (F,) s since session start, ``xy`` (F, 2) world metres, ``std`` None (unknown: empty cells),
    a scalar or (F,) metres (NaN = unknown on that row), ``source`` a non-empty name of what produced
    the fixes (e.g. ``"locnet-4beacons"``; surrounding spaces are stripped).

    Merging: rows of *other* sources already in the file (including rows with an empty source) are
    kept, with any extra columns; rows of the same source are replaced. The result is sorted by t
    (stable: at equal t, kept rows come before new ones, and each keeps its own order), written to a
    temporary file and moved into place, so a failure leaves the old file intact.

    Invalid input raises ``ValueError`` and writes nothing: a NaN or infinite position or time (the
    message says how many rows; a localizer that has no fix for a window should leave that row out,
    never write NaN), a negative or infinite std, mismatched lengths. An existing fixes.csv that
    does not pass the format's checks raises :class:`~blenav.errors.DatasetError` instead of being
    overwritten. An open :class:`~blenav.data.Session` caches its streams: reopen it to see the new rows.
    """
    session_dir = Path(session_dir)
    if not session_dir.is_dir():
        raise FileNotFoundError(f"session folder {session_dir} does not exist")
    src = str(source).strip() if source is not None else ""
    if not src or "\n" in src or "\r" in src:
        raise ValueError(f"source must be a non-empty one-line name, got {source!r}")
    t = np.asarray(t, dtype=float).reshape(-1)
    xy = np.asarray(xy, dtype=float)
    if xy.ndim != 2 or xy.shape[1] != 2 or len(xy) != len(t):
        raise ValueError(f"xy must have shape (len(t), 2) = ({len(t)}, 2), got {xy.shape}")
    sd = np.full(len(t), np.nan) if std is None else np.broadcast_to(np.asarray(std, dtype=float), t.shape).copy()
    bad_xy = ~np.isfinite(xy).all(axis=1)
    if bad_xy.any():
        raise ValueError(f"{int(bad_xy.sum())} of {len(t)} fixes have a NaN or infinite position (first at row "
                         f"{int(np.argmax(bad_xy))}); leave windows without a fix out instead of writing NaN")
    bad_t = ~np.isfinite(t)
    if bad_t.any():
        raise ValueError(f"{int(bad_t.sum())} of {len(t)} fixes have a NaN or infinite time")
    bad_sd = np.isinf(sd) | (sd < 0)
    if bad_sd.any():
        raise ValueError(f"{int(bad_sd.sum())} of {len(t)} fixes have a negative or infinite std (NaN means unknown)")

    spec = STREAMS["fixes"]
    path = session_dir / spec.filename
    new = pd.DataFrame({"t": t, "x": xy[:, 0], "y": xy[:, 1], "std": sd, "source": src})
    frames = []
    if path.is_file():
        old, issues = read_stream(path, spec)
        errors = [i for i in issues if i.is_error]
        if old is None or errors:  # do not overwrite rows we could not read
            raise DatasetError(errors)
        keep = old["source"].fillna("").astype(str).str.strip() != src
        frames.append(old[keep.to_numpy()])
    frames.append(new)
    out = pd.concat([f for f in frames if len(f)] or [new], ignore_index=True)
    out = out.sort_values("t", kind="stable").reset_index(drop=True)
    cols = list(spec.columns) + [c for c in out.columns if c not in spec.columns]
    tmp = path.with_name(f".{spec.filename}.tmp")
    write_csv(tmp, out[cols])
    os.replace(tmp, path)
    return path


def write_tum(path: Path, t, xy, z=None, q_xyzw=None) -> Path:
    """A trajectory in the TUM RGB-D format that ``evo`` reads (``evo_ape tum ref.tum est.tum``): one line per
    pose, ``timestamp tx ty tz qx qy qz qw`` (s, m; quaternion x, y, z, w). ``xy`` (K, 2) world m; ``z`` (K,) m
    (default 0); ``q_xyzw`` (K, 4) (default identity: a 2-D track carries no orientation). Rows with a
    non-finite value are left out."""
    t = np.asarray(t, float)
    xy = np.asarray(xy, float).reshape(len(t), 2)
    zz = np.zeros(len(t)) if z is None else np.asarray(z, float).reshape(len(t))
    q = np.tile([0.0, 0.0, 0.0, 1.0], (len(t), 1)) if q_xyzw is None else np.asarray(q_xyzw, float).reshape(len(t), 4)
    rows = np.column_stack([t, xy, zz, q])
    rows = rows[np.isfinite(rows).all(axis=1)]
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    np.savetxt(path, rows, fmt="%.6f", delimiter=" ")
    return path
