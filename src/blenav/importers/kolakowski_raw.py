"""The raw files of M. Kolakowski's BLE RSS radio-map-calibration dataset, read and checked: anchors, the flat's
wall layout, the walked reference path, the tab-separated system logs of anchor reports and the preprocessed
``*_df.csv`` tables (:class:`Df`), with their RSSI as per-packet rows; and the check that a log and its table
describe the same packets (:func:`mapping_check`). Units, columns and upstream facts: the docstring of
:mod:`blenav.importers.kolakowski_ble_calib`, which writes the dataset. A malformed value raises
:class:`blenav.errors.ImportError_` naming file and line.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd
from shapely.geometry import MultiLineString, Polygon

from blenav.data.schema import RSSI_MAX_DBM, RSSI_MIN_DBM
from blenav.errors import ImportError_

from . import ImportReport
from ._common import (
    FAR_TIME,
    drop_rssi,
    first_true,
    parse_numbers,
    raise_at,
    raise_far,
    read_cells,
    read_lines,
    split_cells,
)

__all__ = ["SYSTEM_IDS", "TAG_ID", "NOT_RECEIVED", "Df", "read_anchors", "read_layout", "read_reference_path",
           "read_system_log", "read_df", "df_rssi", "packet_rssi", "mapping_check"]

#: system ids of the anchors in the logs, in the order of anchors.csv ids 1..6.
SYSTEM_IDS = (3, 4, 5, 8, 10, 11)
TAG_ID = 1
NOT_RECEIVED = 0
_RANGE = f"(outside ({RSSI_MIN_DBM:g}, {RSSI_MAX_DBM:g}) dBm)"



def read_anchors(path: Path) -> pd.DataFrame:
    cells, first = read_cells(path, 4, header=("id", "x", "y", "z"), require_rows=True)
    ids = parse_numbers(path, cells[:, :1], first, ("id",), integer=True)[:, 0].astype(np.int64)
    raise_at(path, pd.Series(ids).duplicated().to_numpy(bool), first,
             lambda r, c: f"anchor id {ids[r]} appears twice")
    raise_at(path, (ids < 1) | (ids > len(SYSTEM_IDS)), first,
             lambda r, c: f"anchor id {ids[r]} is not in 1..{len(SYSTEM_IDS)} (the ids mapped to system ids "
                          f"{SYSTEM_IDS})")
    if len(ids) != len(SYSTEM_IDS):
        raise ImportError_(path, None, f"{len(ids)} anchors, expected {len(SYSTEM_IDS)}")
    xyz = parse_numbers(path, cells[:, 1:], first, ("x", "y", "z"))
    return pd.DataFrame({"anchor_id": ids.astype(str), "x": xyz[:, 0], "y": xyz[:, 1], "z": xyz[:, 2],
                         "system_id": np.asarray(SYSTEM_IDS)[ids - 1]})


def read_layout(path: Path) -> Polygon:
    cells, first = read_cells(path, 2, header=("x", "y"), require_rows=True)
    xy = parse_numbers(path, cells, first, ("x", "y"))
    raise_far(path, xy, first, ("column 'x'", "column 'y'"))
    poly = Polygon(xy)
    if len(xy) < 4 or not poly.is_valid or poly.area <= 0:
        raise ImportError_(path, None, "the wall vertices do not form a valid polygon")
    return poly


def read_reference_path(path: Path) -> MultiLineString:
    """The walked reference path: one 2-point LineString per row, in file order (m)."""
    cells, first = read_cells(path, 4, header=("x0", "y0", "x1", "y1"), require_rows=True)
    v = parse_numbers(path, cells, first, ("x0", "y0", "x1", "y1"))
    raise_at(path, np.hypot(v[:, 2] - v[:, 0], v[:, 3] - v[:, 1]) <= 0, first, lambda r, c: "segment has zero length")
    return MultiLineString([[(a, b), (c, d)] for a, b, c, d in v])


def read_system_log(path: Path, report: ImportReport) -> pd.DataFrame:
    """BLE packets of a ``*_ble.txt`` log: t_s (unix s), system_id, module, tag, tag_counter, rssi, raw_line.

    File order, then packet order within the line. Faulty frames, other tags and RSSI 0 are dropped
    and counted in ``report``.
    """
    lines = read_lines(path)
    if not lines:
        raise ImportError_(path, None, "file is empty")
    s = pd.Series(lines, dtype=object)
    blank = s.str.strip().eq("").to_numpy(bool)
    bad = first_true(blank)
    if bad is not None:
        raise ImportError_(path, bad + 1, "blank line")
    tok = s.str.split("\t", expand=True)
    ntok = tok.notna().sum(axis=1).to_numpy(np.int64)
    bad = first_true(ntok < 7)
    if bad is not None:
        raise ImportError_(path, bad + 1, f"{ntok[bad]} tab-separated fields, expected at least 7")
    num = pd.DataFrame({c: pd.to_numeric(tok[c].str.strip(), errors="coerce") for c in tok.columns}).to_numpy(float)
    badcell = tok.notna().to_numpy() & ~(np.isfinite(num) & (num == np.round(num)))
    r = first_true(badcell.any(axis=1))
    if r is not None:
        c = int(np.flatnonzero(badcell[r])[0])
        raise ImportError_(path, r + 1, f"field {c + 1}: {tok.iat[r, c]!r} is not an integer")
    raise_far(path, num[:, :1] / 1000.0, 1, ("field 1 (ts, unix ms / 1000)",), **FAR_TIME)
    b, u = num[:, 5].astype(np.int64), num[:, 6].astype(np.int64)
    expected = 7 + 8 * b + 4 * u
    bad = first_true((b < 0) | (u < 0) | (ntok != expected))
    if bad is not None:
        raise ImportError_(path, bad + 1, f"{ntok[bad]} fields, but the line announces {b[bad]} BLE and {u[bad]} "
                           f"UWB packets ({expected[bad]} fields)")
    faulty = num[:, 3] < 12 * b + 8 * u + 19
    report.drop(f"BLE packets in frames the authors' loader flags as faulty (declared length too short) "
                f"in {path.name}", int(b[faulty].sum()))
    parts = []
    for k in range(int(b.max(initial=0))):
        rows = np.flatnonzero((b > k) & ~faulty)
        c0 = 7 + 8 * k
        parts.append(pd.DataFrame({"raw_line": rows + 1, "k": k, "t_s": num[rows, 0] / 1000.0,
                                   "system_id": num[rows, 1].astype(np.int64),
                                   "module": num[rows, c0].astype(np.int64), "tag": num[rows, c0 + 1].astype(np.int64),
                                   "tag_counter": num[rows, c0 + 2].astype(np.int64), "rssi": num[rows, c0 + 3]}))
    if not parts:
        raise ImportError_(path, None, "no BLE packets")
    pk = pd.concat(parts).sort_values(["raw_line", "k"], kind="stable").reset_index(drop=True)
    other = (pk["tag"] != TAG_ID).to_numpy()
    report.drop(f"BLE packets of a tag other than {TAG_ID} in {path.name}", int(other.sum()))
    pk = pk[~other]
    unknown = ~pk["system_id"].isin(SYSTEM_IDS).to_numpy()
    if unknown.any():
        r = int(pk["raw_line"].to_numpy()[unknown][0])
        raise ImportError_(path, r, f"anchor system id {int(pk['system_id'].to_numpy()[unknown][0])} is not one of "
                           f"{SYSTEM_IDS}")
    rssi = pk["rssi"].to_numpy()
    keep = drop_rssi(report, rssi, rssi == NOT_RECEIVED, f"BLE packets with RSSI 0 (not received) in {path.name}",
                     f"BLE packets with an invalid RSSI {_RANGE} in {path.name}")
    pk = pk[keep]
    return pk.iloc[np.argsort(pk["t_s"].to_numpy(), kind="stable")].reset_index(drop=True)


@dataclass
class Df:
    path: Path
    index: np.ndarray        # the unnamed first column
    t_s: np.ndarray          # unix s
    cols: dict               # x, y, heading -> float arrays (present ones)
    rssi: pd.DataFrame       # columns = anchors.csv ids "1".."6", NaN = not received
    lines: np.ndarray        # 1-based file lines


def read_df(path: Path, position: tuple[str, ...]) -> Df:
    """A preprocessed ``*_df.csv``: unnamed index, ``ts`` (unix ns), ``position`` columns, ``rssi_<id>``."""
    lines = read_lines(path)
    if not lines:
        raise ImportError_(path, None, "file is empty")
    names = [c.strip() for c in lines[0].split(",")]  # any header; the columns are looked up by name
    if len(lines) == 1:
        raise ImportError_(path, None, "file has a header but no rows")
    cells = split_cells(path, lines[1:], 2, len(names))
    if names[0] != "" or "ts" not in names:
        raise ImportError_(path, 1, "expected an unnamed first (index) column and a 'ts' column")
    missing = [c for c in position if c not in names]
    if missing:
        raise ImportError_(path, 1, f"header lacks column(s) {', '.join(missing)}")
    rcols = [n for n in names if n.startswith("rssi_")]
    try:
        suffix = [int(n[5:]) for n in rcols]
    except ValueError:
        raise ImportError_(path, 1, f"rssi columns must be rssi_<integer id>, got {rcols}") from None
    if set(suffix) == set(SYSTEM_IDS):
        ids = [str(SYSTEM_IDS.index(s) + 1) for s in suffix]
    elif suffix and set(suffix) <= set(range(1, len(SYSTEM_IDS) + 1)):
        ids = [str(s) for s in suffix]
    else:
        raise ImportError_(path, 1, f"rssi columns {rcols} name neither anchors 1..6 nor system ids {SYSTEM_IDS}")
    col = {n: k for k, n in enumerate(names)}
    index = parse_numbers(path, cells[:, :1], 2, ("(index)",), integer=True)[:, 0]
    ts = parse_numbers(path, cells[:, [col["ts"]]], 2, ("ts",))[:, 0]
    raise_far(path, ts / 1e9, 2, ("column 'ts' (unix ns / 1e9)",), **FAR_TIME)
    raise_at(path, np.diff(ts) < 0, 3, lambda r, c: "'ts' goes backwards (earlier than the line before)")
    pv = parse_numbers(path, cells[:, [col[c] for c in position]], 2, position)
    pos = {c: pv[:, k] for k, c in enumerate(position)}
    rv = parse_numbers(path, cells[:, [col[n] for n in rcols]], 2, rcols, nullable=True)
    rssi = pd.DataFrame({i: rv[:, k] for k, i in enumerate(ids)})
    return Df(path, index, ts / 1e9, pos, rssi, np.arange(2, len(cells) + 2))


def df_rssi(df: Df, sel: np.ndarray, t0: float, report: ImportReport, what: str) -> pd.DataFrame:
    """Long rssi rows (t, anchor_id, rssi, raw_line) of the df rows ``sel``; empty cells are not rows."""
    r = df.rssi.iloc[sel]
    long = pd.DataFrame({
        "t": np.repeat(df.t_s[sel] - t0, r.shape[1]),
        "anchor_id": np.tile(np.asarray(r.columns, dtype=object), len(r)),
        "rssi": r.to_numpy().ravel(),
        "raw_line": np.repeat(df.lines[sel], r.shape[1]),
    })
    v = long["rssi"].to_numpy()
    keep = drop_rssi(report, v, np.isnan(v), f"empty rssi cells (not received; no row) in {what}",
                     f"rssi cells with an invalid RSSI {_RANGE} in {what}")
    return long[keep].reset_index(drop=True)


def packet_rssi(pk: pd.DataFrame, t0: float) -> pd.DataFrame:
    return pd.DataFrame({"t": pk["t_s"].to_numpy() - t0,
                         "anchor_id": (np.searchsorted(SYSTEM_IDS, pk["system_id"].to_numpy()) + 1).astype(str),
                         "rssi": pk["rssi"].to_numpy().astype(np.int64),
                         "module": pk["module"].to_numpy(), "system_id": pk["system_id"].to_numpy(),
                         "tag_counter": pk["tag_counter"].to_numpy(), "raw_line": pk["raw_line"].to_numpy()})


def mapping_check(pk: pd.DataFrame, df: Df) -> tuple[bool, float]:
    """Whether each system id's per-second mean RSSI correlates best with the df column it maps to.

    Returns ``(all_match, smallest matching correlation)``.
    """
    m = pk.assign(sec=np.floor(pk["t_s"]).astype(np.int64)).groupby(["sec", "system_id"])["rssi"].mean().unstack()
    d = df.rssi.assign(sec=np.floor(df.t_s).astype(np.int64)).groupby("sec").mean()
    j = m.join(d, how="inner")
    ok, worst = True, 1.0
    for s in m.columns:
        corr = {a: j[s].corr(j[a]) for a in d.columns}
        want = str(SYSTEM_IDS.index(s) + 1)
        ok &= max(corr, key=lambda a: -np.inf if np.isnan(corr[a]) else corr[a]) == want
        worst = min(worst, corr[want])
    return bool(ok), float(worst)
