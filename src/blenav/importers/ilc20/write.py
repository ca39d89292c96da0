"""Session folders of the ILC 2.0 import: session.yaml and one CSV per stream from columns of text cells."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from blenav.data.schema import STREAMS
from blenav.data.writer import write_session

PHONE_HEIGHT_M = 1.2


def num_text(v: np.ndarray, decimals: int) -> np.ndarray:
    """Numbers as CSV text rounded to ``decimals`` (NaN -> empty cell)."""
    fmt = f"%.{decimals}f"
    return np.array(["" if x != x else (fmt % x).rstrip("0").rstrip(".") if decimals else "%d" % x
                     for x in np.asarray(v, dtype=float).tolist()], dtype=object)


def write_streams(root: Path, sid: str, meta: dict, streams: dict[str, dict[str, np.ndarray]]) -> None:
    """session.yaml (blenav's writer) and one CSV per stream from columns of text cells (spec columns first)."""
    write_session(root, sid, meta, {})
    for name, cols in streams.items():
        _write_stream(root, sid, name, cols)


def _write_stream(root: Path, sid: str, name: str, cols: dict[str, np.ndarray]) -> None:
    """One stream's CSV of session ``sid`` (its folder written by :func:`write_streams`) from columns of text
    cells (spec columns first)."""
    spec = STREAMS[name]
    missing = [c for c in spec.columns if c not in cols]
    if missing:
        raise ValueError(f"stream {name} for session {sid} lacks columns {missing}")
    order = list(spec.columns) + [c for c in cols if c not in spec.columns]
    body = "\n".join(map(",".join, zip(*(cols[c] for c in order))))
    (root / "sessions" / sid / spec.filename).write_text(",".join(order) + "\n" + body + ("\n" if body else ""),
                                                         encoding="utf-8")


def write_groundtruth(root: Path, pending: list, floor_z: float) -> None:
    """groundtruth.csv of a floor's sessions, written once: ``pending`` [(session id, columns)] from the walk pass
    (z left None there: the floor's level may come from its GeoJSON, read later); z = ``floor_z`` (m) +
    ``PHONE_HEIGHT_M``."""
    for sid, cols in pending:
        cols = {**cols, "z": num_text(np.full(len(cols["t"]), floor_z + PHONE_HEIGHT_M), 3)}
        _write_stream(root, sid, "groundtruth", cols)
