"""Import the Feng et al. WiFi RTT + RSS fingerprint dataset into dataset format v1.

Source: Feng, Nguyen, Luo, "WiFi RSS & RTT dataset with different LOS conditions for indoor
positioning", Zenodo DOI 10.5281/zenodo.11558792 (MIT licence), GitHub copy
Fx386483710/WiFi_RSS_RTT_Dataset_for_Model_Selection (see ``SOURCE.txt``). Raw layout (``src``)::

    data/database_<env>_<split>.csv     env: lecture_theatre | office | corridor; split: train | test
        X,Y,AP1 RTT(mm)..AP5 RTT(mm),AP1 RSS(dBm)..AP5 RSS(dBm),LOS APs
    data/lecture theatre+office+corridor_AP_position.txt
        per environment: a name line, "AP X: x1,x2,..", "AP Y: y1,y2,.."

What is written
---------------
* Three buildings, one per environment: ``lecture_theatre``, ``office``, ``corridor`` (one floor ``0``,
  floor z = 0 m). They share nothing (separate frames).
* ``anchors.csv``: one ``kind: wifi_rtt`` row per AP with a position; ``anchor_id`` = ``AP<k>`` where
  ``k`` is the AP number of the data columns. ``tx_power_dbm`` empty (not reported).
  **The corridor** has 4 positions but 5 AP column pairs, and its ``AP1`` columns never hold a reading
  (all 100000 mm / -200 dBm): its 4 positions are mapped, in order, to ``AP2``..``AP5``. Evidence: the
  per-point median RTT correlates with the distance to the mapped position at r >= 0.98 for each of
  AP2..AP5. Readings in an AP column without a position would be dropped and counted (none occur).
* Six sessions ``<env>_<split>`` (e.g. ``office_test``): ``carrier: static``, ``labelled: true``,
  ``device_model: unknown`` (the README does not name the phone). The train/test split is the
  authors'; points do not overlap between them.
* ``rtt.csv``: one row per (scan, AP) with an RTT reading: ``range_m`` = RTT column (mm) / 1000,
  ``range_std_m`` empty (not reported). 100000 mm means "not received": no row. Ranges are kept as
  the phone reported them, including negative ones (Android reports a negative distance when the
  measured round trip is shorter than its calibration offset; 567 readings, down to -10.6 m in
  office_test) and NLOS ranges longer than the floor's diagonal (corridor, up to 41.7 m). Optional column
  ``rssi`` (docs/dataset-format.md): the same scan's RSS of that AP (dBm), empty where its RSS cell is -200
  (not received); Duembgen et al.'s -65 dBm rule (004 sec. V-A) reads it.
* ``rssi.csv``: **WiFi RSS** (dBm) of the same APs, same ``anchor_id``; it is not BLE. -200 dBm means
  "not heard": no row. Other values must lie in (-150, 0) dBm. (The anchors' ``channel_model`` says so.)
* ``groundtruth.csv``: one row per scan (raw row) with the reference point. Orientation columns are
  empty. Extra columns: ``grid_x``, ``grid_y`` (raw X, Y), ``los_aps`` (raw "LOS APs" text: the AP
  numbers with line of sight, space-separated; empty where the raw cell is empty, e.g. all of the
  corridor, which the README describes as entirely NLOS), ``raw_line`` (1-based line in the raw file).
* Not-received cells are counted in the report's ``dropped``.

Units and frames
----------------
* X, Y are grid indices (integers in the data). The README states a 0.6 m x 0.6 m grid ("Grid size:
  0.6 x 0.6 m2" for every environment); the index extents times 0.6 m (lecture theatre 19 x 24 cells
  = 11.4 x 14.4 m, office 28 x 8 = 16.8 x 4.8 m, corridor 57 x 2 = 34.2 x 1.2 m) fit inside the stated
  testbed areas (15 x 14.5, 18 x 5.5, 35 x 6 m2). World position: ``x = 0.6 X``, ``y = 0.6 Y`` metres,
  origin at grid index (0, 0). The frame's orientation to north is unknown (x east / y north is not
  guaranteed); it is assumed right-handed as plotted in the README.
* The AP position file gives **grid units too**, not metres: with ``0.6 * AP`` the per-point median RTT
  is a near-linear function of distance (slope 0.94..1.29, r 0.94..0.995 for every AP of every
  environment), while reading the file as metres gives r as low as 0.12 and distances beyond the
  testbed (e.g. corridor AP at x = 48). AP positions may be fractional (18.8, 7.5).
* z: neither AP nor phone heights are given. The phone is assumed at ``PHONE_HEIGHT_M`` = 1.2 m and the
  APs are written at the same height (3-D range = horizontal distance); **both are assumptions**.
* Time: the raw files have no timestamps. Session clock: raw rows in file order, one scan per
  ``SCAN_PERIOD_S`` = 1 s (``t = 0, 1, 2, ...``). The spacing is synthetic; only the order (each
  point's 60 scans are contiguous in the files) is real.

Floor plan
----------
The raw data has no floor plan (the README's layout pictures are external images). The floor is an
all-free occupancy grid at 0.1 m/px covering the bounding box of the reference points of both splits
and of the APs plus 1.0 m on every side. It encodes no walls.

Raw-data facts a user should know
---------------------------------
* Row counts differ from the README's feature tables for two environments: lecture theatre train/test
  5280/1920 rows (88/32 points; README 5400/1800), corridor train 5100 rows (85 points; README 5130).
  Totals (7200, 6840) match. The data files are imported as they are.
* The README's feature tables label the corridor "mixed LOS-NLOS" and the office "entirely NLOS", the
  reverse of its layout descriptions; the ``LOS APs`` column agrees with the layout descriptions
  (corridor: empty everywhere; office: some LOS APs per point).

Bad input
---------
A malformed line (wrong column count, blank line, non-numeric or non-finite number, RSS neither -200
nor in (-150, 0) dBm, malformed ``LOS APs``), a header other than the expected one, or a malformed AP
position file raises :class:`~blenav.errors.ImportError_` naming the file and the 1-based line.
Nothing is written unless the whole source parses.
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd

from blenav.data.writer import write_building, write_dataset_meta, write_session

from blenav.errors import ImportError_

from . import ImportReport
from ._common import (
    check_out,
    occupancy_grid,
    parse_numbers,
    raise_at,
    raise_bad_rssi,
    raise_far,
    read_cells,
    read_lines,
    validate_or_raise,
)

GRID_M = 0.6
PHONE_HEIGHT_M = 1.2
ANCHOR_Z_M = PHONE_HEIGHT_M
SCAN_PERIOD_S = 1.0
#: floor grid resolution (m/px) and margin around points and APs (m).
RESOLUTION_M = 0.1
MARGIN_M = 1.0
RTT_NOT_RECEIVED_MM = 100000.0
RSS_NOT_RECEIVED_DBM = -200.0
N_AP_COLUMNS = 5
SPLITS = ("train", "test")
AP_FILE = "lecture theatre+office+corridor_AP_position.txt"

HEADER = (["X", "Y"] + [f"AP{k} RTT(mm)" for k in range(1, N_AP_COLUMNS + 1)]
          + [f"AP{k} RSS(dBm)" for k in range(1, N_AP_COLUMNS + 1)] + ["LOS APs"])

#: environment -> (name, LOS description from the README layout section, AP numbers of the positions in order)
ENVIRONMENTS = {
    "lecture_theatre": ("Lecture theatre (Feng et al.)", "entirely LOS", (1, 2, 3, 4, 5)),
    "office": ("Office (Feng et al.)", "mixed LOS/NLOS, at least one NLOS AP per point", (1, 2, 3, 4, 5)),
    "corridor": ("Corridor (Feng et al.)", "entirely NLOS", (2, 3, 4, 5)),
}

_LOS_RE = re.compile(r"^\d+( +\d+)*$")
_AP_LINE_RE = re.compile(r"^AP\s*([XY])\s*:(.*)$")


@dataclass
class _Split:
    path: Path
    grid: np.ndarray    # (N, 2) raw X, Y
    rtt: np.ndarray     # (N, 5) mm
    rss: np.ndarray     # (N, 5) dBm
    los: np.ndarray     # (N,) str, "" when empty


def _read_ap_positions(path: Path) -> dict[str, tuple[np.ndarray, int]]:
    """env -> (positions (n, 2) in grid units, line of its 'AP X' line)."""
    lines = read_lines(path)
    out: dict[str, tuple[np.ndarray, int]] = {}
    env, xy = None, {}

    def close(line_no: int) -> None:
        if env is None:
            return
        if set(xy) != {"X", "Y"}:
            raise ImportError_(path, line_no, f"environment {env!r} lacks an 'AP X:' or 'AP Y:' line")
        (x, lx), (y, ly) = xy["X"], xy["Y"]
        if len(x) != len(y):
            raise ImportError_(path, max(lx, ly), f"{env}: {len(x)} AP X values but {len(y)} AP Y values")
        want = len(ENVIRONMENTS[env][2])
        if len(x) != want:
            raise ImportError_(path, lx, f"{env}: {len(x)} AP positions, expected {want}")
        raise_far(path, np.column_stack([x, y]) * GRID_M, lambda r, c: (lx, ly)[c],
                  (f"{env}: AP X (x {GRID_M} m)", f"{env}: AP Y (x {GRID_M} m)"))
        out[env] = (np.column_stack([x, y]), lx)

    for i, raw in enumerate(lines, start=1):  # a dozen lines
        s = raw.strip()
        if not s:
            continue
        m = _AP_LINE_RE.match(s)
        if m is None:
            close(i)
            env = s.lower().replace(" ", "_")
            if env not in ENVIRONMENTS:
                raise ImportError_(path, i, f"unknown environment {s!r}; expected one of "
                                   f"{', '.join(e.replace('_', ' ') for e in ENVIRONMENTS)}")
            if env in out:
                raise ImportError_(path, i, f"environment {s!r} appears twice")
            xy = {}
            continue
        if env is None:
            raise ImportError_(path, i, "AP coordinates before any environment name")
        axis, vals = m.group(1), [v.strip() for v in m.group(2).split(",")]
        cells = np.array(vals, dtype=str)[None, :]
        v = parse_numbers(path, cells, i, [f"AP {axis} #{k + 1}" for k in range(len(vals))])[0]
        if axis in xy:
            raise ImportError_(path, i, f"{env}: second 'AP {axis}:' line")
        xy[axis] = (v, i)
    close(len(lines) + 1)
    for env in ENVIRONMENTS:
        if env not in out:
            raise ImportError_(path, None, f"no AP positions for environment {env.replace('_', ' ')!r}")
    return out


def _read_split(path: Path) -> _Split:
    cells, first = read_cells(path, len(HEADER), header=HEADER, require_rows=True)
    v = parse_numbers(path, cells[:, :-1], first, HEADER[:-1])
    raise_far(path, v[:, :2] * GRID_M, first, (f"column 'X' (x {GRID_M} m)", f"column 'Y' (x {GRID_M} m)"))
    rtt, rss = v[:, 2:2 + N_AP_COLUMNS], v[:, 2 + N_AP_COLUMNS:]
    raise_bad_rssi(path, rss, first, RSS_NOT_RECEIVED_DBM, lambda c: f"column {HEADER[2 + N_AP_COLUMNS + c]!r}:",
                   "not-received code -200")
    los = cells[:, -1]
    bad_los = (los != "") & ~pd.Series(los, dtype=object).str.match(_LOS_RE).to_numpy(dtype=bool)
    raise_at(path, bad_los, first, lambda r, c: f"column 'LOS APs': {los[r]!r} is not a space-separated list of "
                                                "AP numbers")
    tokens = pd.Series(los, dtype=object).str.split().explode().dropna()  # AP numbers, index = row
    out_of_range = np.zeros(len(los), dtype=bool)
    if len(tokens):
        nums = pd.to_numeric(tokens).to_numpy()
        out_of_range[tokens.index.to_numpy()[(nums < 1) | (nums > N_AP_COLUMNS)]] = True
    raise_at(path, out_of_range, first, lambda r, c: f"column 'LOS APs': {los[r]!r} names an AP outside "
                                                     f"1..{N_AP_COLUMNS}")
    return _Split(path, v[:, :2], rtt, rss, los)


def import_feng_wifi_rtt(src: Path, out: Path) -> ImportReport:
    """Convert the Feng et al. WiFi RTT/RSS fingerprints at ``src`` into dataset ``out`` (see module doc)."""
    src, out = Path(src), Path(out)
    check_out(out)
    ddir = src / "data"
    aps = _read_ap_positions(ddir / AP_FILE)
    data = {env: {sp: _read_split(ddir / f"database_{env}_{sp}.csv") for sp in SPLITS} for env in ENVIRONMENTS}

    report = ImportReport(out=out)
    write_dataset_meta(
        out, "feng_wifi_rtt", "WiFi RTT + RSS static fingerprints in a lecture theatre, an office and a corridor "
        "(Feng et al. 2024); rssi.csv holds WiFi RSS", "MIT", "Feng, Nguyen, Luo, Zenodo 10.5281/zenodo.11558792; "
        "copy: Fx386483710/WiFi_RSS_RTT_Dataset_for_Model_Selection@48e41763",
        importer="blenav.importers.feng_wifi_rtt",
        assumptions=[f"grid index * {GRID_M} m for points and AP positions", f"phone and AP height {PHONE_HEIGHT_M} m",
                     f"synthetic clock: one scan per {SCAN_PERIOD_S:g} s in file order",
                     "floor plan: free space only, no walls in the raw data"])
    n_neg = 0
    for env, (name, los_desc, ap_numbers) in ENVIRONMENTS.items():
        pos_grid, _ = aps[env]
        ap_xy = pos_grid * GRID_M
        ap_ids = np.array([f"AP{k}" for k in ap_numbers])
        cols = np.array(ap_numbers) - 1
        pts = np.vstack([data[env][sp].grid for sp in SPLITS]) * GRID_M
        occ, origin = occupancy_grid(np.vstack([pts, ap_xy]), (), RESOLUTION_M, MARGIN_M)
        anchors = pd.DataFrame({
            "anchor_id": ap_ids, "kind": "wifi_rtt", "x": ap_xy[:, 0], "y": ap_xy[:, 1], "z": ANCHOR_Z_M, "floor": 0,
            "tx_power_dbm": np.nan,
            "channel_model": (f"WiFi RTT (IEEE 802.11mc FTM) access point, {los_desc}; rssi.csv rows for this id are "
                              "its WiFi RSS (not BLE); z assumed (= phone height)")})
        write_building(out, env, name, [{"id": 0, "occupancy": occ, "resolution": RESOLUTION_M, "origin": origin,
                                         "z": 0.0}], anchors,
                       source=f"{AP_FILE} (grid units * {GRID_M} m)",
                       floor_plan=("no plan in the raw data: all-free grid over the bounding box of points and "
                                   f"APs + {MARGIN_M} m; no walls"))
        report.buildings += 1
        for sp in SPLITS:
            d = data[env][sp]
            n = len(d.grid)
            t = np.arange(n) * SCAN_PERIOD_S
            rtt, rss = d.rtt[:, cols], d.rss[:, cols]
            # readings in AP columns that have no position (none in the published data)
            other = np.setdiff1d(np.arange(N_AP_COLUMNS), cols)
            n_orphan = (d.rtt[:, other] != RTT_NOT_RECEIVED_MM).sum() + (d.rss[:, other] != RSS_NOT_RECEIVED_DBM).sum()
            report.drop(f"RTT/RSS readings of an AP column without a position ({env})", int(n_orphan))
            r, c = np.nonzero(rtt != RTT_NOT_RECEIVED_MM)
            rtt_df = pd.DataFrame({"t": t[r], "anchor_id": ap_ids[c], "range_m": rtt[r, c] / 1000.0,
                                   "range_std_m": np.nan,
                                   "rssi": np.where(rss[r, c] != RSS_NOT_RECEIVED_DBM, rss[r, c], np.nan)})
            r2, c2 = np.nonzero(rss != RSS_NOT_RECEIVED_DBM)
            rssi_df = pd.DataFrame({"t": t[r2], "anchor_id": ap_ids[c2], "rssi": rss[r2, c2]})
            los = pd.Series(d.los, dtype=object).replace("", np.nan)
            grid = d.grid.astype(np.int64) if np.all(d.grid == np.round(d.grid)) else d.grid
            gt = pd.DataFrame({"t": t, "x": d.grid[:, 0] * GRID_M, "y": d.grid[:, 1] * GRID_M, "z": PHONE_HEIGHT_M,
                               "qw": np.nan, "qx": np.nan, "qy": np.nan, "qz": np.nan,
                               "grid_x": grid[:, 0], "grid_y": grid[:, 1], "los_aps": los,
                               "raw_line": np.arange(n) + 2})
            sid = f"{env}_{sp}"
            meta = {"building": env, "floor": 0, "device_model": "unknown", "carrier": "static", "labelled": True,
                    "notes": (f"Feng et al. WiFi RTT/RSS fingerprints, {env.replace('_', ' ')}, {sp} split; "
                              f"synthetic clock (one raw row per {SCAN_PERIOD_S:g} s in file order); rssi.csv is "
                              "WiFi RSS; no IMU"),
                    "split": sp}
            write_session(out, sid, meta, {"rtt": rtt_df, "rssi": rssi_df, "groundtruth": gt})
            report.sessions += 1
            report.drop(f"RTT cells = 100000 mm (not received; no row written) in {env}",
                        int((d.rtt == RTT_NOT_RECEIVED_MM).sum()))
            report.drop(f"RSS cells = -200 dBm (not received; no row written) in {env}",
                        int((d.rss == RSS_NOT_RECEIVED_DBM).sum()))
            n_neg += int((rtt_df["range_m"] < 0).sum())
    if n_neg:
        report.notes.append(f"{n_neg} RTT ranges are negative as reported by the phone (kept unchanged)")
    validate_or_raise(out, report)
    return report
