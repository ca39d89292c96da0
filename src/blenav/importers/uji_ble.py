"""Import the UJI BLE RSS fingerprint database (cross-phone set) into dataset format v1.

Source: Mendoza-Silva, Matey-Sanz, Torres-Sospedra, Huerta, "BLE RSS measurements database and
supporting materials", Universitat Jaume I, 2018, Zenodo DOI 10.5281/zenodo.1618692 (CC BY 4.0),
as copied in ``SOURCE.txt`` beside the raw files. Raw layout (``src`` is the folder holding it)::

    dep/{lib,geo}.csv                   id,x,y        beacon positions; row k <-> RSS column k
    obs/{lib,geo}.csv                   id,x,y,type   obstacle outline points (shelves, pillars)
    rss/{lib,geo}_{rss,tms,crd,ids}.csv no header     row i of each file = fingerprint i

What is written
---------------
* Two buildings, one per zone: ``lib`` (library, among bookshelves) and ``geo`` (Geotec lab/office).
  The zones share no beacon and no frame. Each has one floor, ``0`` (floor z = 0 m).
* ``anchors.csv``: one row per line of ``dep/<zone>.csv``; ``anchor_id`` is the raw id (``23``..``46``
  in lib, ``B1``..``B22`` in geo), ``kind: ble``. ``tx_power_dbm`` (calibrated RSSI at 1 m) is empty:
  it is not in the raw data. The configured *transmission* power (lib -12 dBm; geo -4/-12/-20 dBm
  depending on the session) is not an RSSI at 1 m; it is written as ``beacon_tx_power_dbm`` in each
  ``session.yaml`` instead.
* One session per (zone, phone code P, TX-power code W, campaign code C) of the 8-digit fingerprint id
  ``PWCNNNSS``: lib 3 phones x 1 power x 2 campaigns = 6 sessions, geo 1 phone x 3 powers x 1
  campaign = 3 sessions. Session id ``<zone>_<phone>_<campaign>_txm<|power|>``, e.g.
  ``lib_bq_c4_txm12``. ``carrier: static``, ``labelled: true``, ``device_model`` = the authors' phone
  name (``A5``, ``Bq``, ``S6``; from their ``getFilterDefs.m``). Campaign names follow the authors'
  loaders: lib code 2 = ``c1``, lib code 3 = ``c4``, geo code 1 = ``c1``.
* ``rssi.csv``: one row per (fingerprint, detected beacon). RSS ``100`` means "not detected": no row
  is written (counted in the report as dropped cells, never written as a sentinel). Extra columns:
  ``t_rx`` (s, the beacon's own reading time from ``*_tms.csv`` on the same session clock) and
  ``raw_line`` (1-based line of the fingerprint in the rss/tms/crd/ids files).
* ``groundtruth.csv``: one row per fingerprint (including fingerprints in which no beacon was
  detected), at the fingerprint's time, giving the surveyed point from ``*_crd.csv``. Orientation
  columns are empty (the raw data has no orientation). Extra columns: ``point`` (NNN, the raw point
  number), ``sample`` (SS), ``raw_line``, ``t_interpolated`` (1 when the time was interpolated, see
  below).

Units and frames
----------------
* x, y: metres, the authors' local frame of each zone, copied unchanged. Its axes are not known to be
  aligned with east/north; it is used as the building's world frame as is (assumed right-handed, x to
  the right and y up on the authors' plots).
* z: the heights of the beacons and of the phone are not in the raw data. The phone is assumed held
  at ``PHONE_HEIGHT_M`` = 1.2 m above the floor and the beacons are written at the same height, so
  that 3-D and horizontal beacon-phone distances agree; **both heights are assumptions**.
* RSS: dBm as recorded (integers). Values other than 100 must lie in (-150, 0) dBm, else the import
  fails.
* Time: ``*_tms.csv`` holds one time per (fingerprint, beacon), 0 when not detected. ``SOURCE.txt``
  calls it a "ms counter", but the values (about 8e12) step by about 1e9 between consecutive
  fingerprints and the authors' ``timeDiffMilli.m`` divides them by 1e6 to get milliseconds: they are
  **nanoseconds** on a per-phone monotonic counter with an undocumented epoch. The session clock is
  therefore ``t = (ns - first reading of the session in ns) / 1e9`` seconds. A fingerprint's time is
  its latest beacon reading (the moment its scan window was complete); all its ``rssi.csv`` rows and
  its ``groundtruth.csv`` row carry that time, so a fingerprint is exactly the set of rows at one
  ``t``. In the raw data these times are non-decreasing in file order within every session (checked;
  a violation fails the import). A fingerprint with no detected beacon has no time of its own: its
  time is interpolated linearly over file order between the neighbouring timed fingerprints (held
  constant before the first / after the last one) and flagged ``t_interpolated = 1``.

Floor plan
----------
The raw data holds **no walls and no floor image**. The floor is an occupancy grid at
``RESOLUTION_M`` = 0.1 m/px covering the bounding box of beacons, surveyed points and obstacle
outlines plus ``MARGIN_M`` = 1.0 m on every side. Obstacles (``obs/<zone>.csv``, polygon = convex hull
of each id's points, per the authors' documentation; type code undocumented, all rasterised alike) are
occupied (pixels whose centre lies in a polygon); everything else is free. Room walls are therefore
missing: the free area is an over-approximation of the walkable space.

Raw-data facts a user should know (checked on the copy described in SOURCE.txt)
-----------------------------------------------------------------------------
* Each surveyed location has two point numbers (the walk visits every location twice, e.g. lib c1
  points 1..24 and 25..48 share 24 locations), so ``point`` is not a location id: use x, y.
* In lib, phone Bq campaign c1, points 17 and 31 were recorded twice (same ``PWCNNNSS`` ids, different
  readings some seconds apart): both recordings are kept.

Bad input
---------
Any malformed line (wrong column count, blank line, non-numeric or non-finite value, RSS neither 100
nor in (-150, 0) dBm, a position more than 2 km from the others, a time of 0 where an RSS was
recorded or vice versa, an id that does not decode to a known phone/power/campaign, a time going
backwards inside a session, a header that is not the expected one) or different row counts between
the rss/tms/crd/ids files raises :class:`~blenav.errors.ImportError_` naming the file and the 1-based
line. Nothing is written unless the whole source parses.

The strict CSV helpers, :func:`~blenav.importers._common.occupancy_grid` and the output checks are
shared by all importers (:mod:`blenav.importers._common`).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd
from shapely.geometry import MultiPoint, Polygon

from blenav.data import OCCUPIED
from blenav.data.writer import write_building, write_dataset_meta, write_session

from blenav.errors import ImportError_

from . import ImportReport
from ._common import (
    check_out,
    grid_lookup,
    occupancy_grid,
    parse_numbers,
    raise_at,
    raise_bad_rssi,
    raise_far,
    read_cells,
    validate_or_raise,
)

#: RSS value meaning "beacon not detected" in *_rss.csv.
NOT_DETECTED = 100.0
#: assumed height of the phone above the floor (m); beacons are written at the same height.
PHONE_HEIGHT_M = 1.2
ANCHOR_Z_M = PHONE_HEIGHT_M
#: occupancy-grid resolution (m/px) and margin around all known geometry (m).
RESOLUTION_M = 0.1
MARGIN_M = 1.0
#: ns per second for *_tms.csv.
NS_PER_S = 1e9

#: Code tables from SOURCE.txt and the authors' getFilterDefs.m.
ZONES = {
    "lib": {"name": "UJI library, bookshelf area", "phones": {1: "A5", 2: "Bq", 3: "S6"},
            "powers": {2: -12}, "campaigns": {2: "c1", 3: "c4"}},
    "geo": {"name": "UJI Geotec lab/office", "phones": {1: "A5"},
            "powers": {1: -4, 2: -12, 3: -20}, "campaigns": {1: "c1"}},
}

CHANNEL_MODEL = ("BLE beacon (iBKS 105, advertising every 200 ms per the data paper); no calibrated RSSI at 1 m "
                 "in the raw data; configured TX power per session in session.yaml beacon_tx_power_dbm; "
                 "z assumed (= phone height, not surveyed)")


# --------------------------------------------------------------------------------------------------
# UJI zone reading


@dataclass
class _Zone:
    zone: str
    beacon_ids: np.ndarray        # (B,) str
    beacon_xy: np.ndarray         # (B, 2) m
    obstacles: list[Polygon]
    obstacle_xy: np.ndarray       # (M, 2) m, all outline points
    rss: np.ndarray               # (N, B) dBm, NOT_DETECTED where not detected
    tms: np.ndarray               # (N, B) int64 ns, 0 where not detected
    crd: np.ndarray               # (N, 2) m
    codes: dict                   # P, W, C, N, S: (N,) int64 each
    rss_path: Path


def _read_zone(src: Path, zone: str) -> _Zone:
    spec = ZONES[zone]
    dep_path = src / "dep" / f"{zone}.csv"
    cells, first = read_cells(dep_path, 3, header=("id", "x", "y"))
    if len(cells) == 0:
        raise ImportError_(dep_path, None, "no beacon rows")
    bid = cells[:, 0]
    raise_at(dep_path, bid == "", first, lambda r, c: "empty beacon id")
    dup = pd.Series(bid).duplicated().to_numpy()
    raise_at(dep_path, dup, first, lambda r, c: f"beacon id {bid[r]!r} appears twice")
    bxy = parse_numbers(dep_path, cells[:, 1:], first, ("x", "y"))
    raise_far(dep_path, bxy, first, ("column 'x'", "column 'y'"))
    nb = len(bid)
    per_beacon = f" (one per beacon row of {dep_path.parent.name}/{dep_path.name})"

    rdir = src / "rss"
    rss_path, tms_path, crd_path, ids_path = (rdir / f"{zone}_{k}.csv" for k in ("rss", "tms", "crd", "ids"))
    names = [f"beacon {b}" for b in bid]
    c, f = read_cells(rss_path, nb, what=per_beacon)
    rss = parse_numbers(rss_path, c, f, names)
    c, f = read_cells(tms_path, nb, what=per_beacon)
    tms_f = parse_numbers(tms_path, c, f, names, integer=True)
    c, f = read_cells(crd_path, 2)
    crd = parse_numbers(crd_path, c, f, ("x", "y"))
    raise_far(crd_path, crd, f, ("x", "y"))
    c, f = read_cells(ids_path, 1)
    ids = parse_numbers(ids_path, c, f, ("id",), integer=True)[:, 0]
    n = len(rss)
    if n == 0:
        raise ImportError_(rss_path, None, "no fingerprint rows")
    for path, arr in ((tms_path, tms_f), (crd_path, crd), (ids_path, ids)):
        if len(arr) != n:
            raise ImportError_(path, min(len(arr), n) + 1,
                               f"file has {len(arr)} rows but {rss_path.name} has {n}: row i of the "
                               f"rss/tms/crd/ids files must describe the same fingerprint i")

    missing = rss == NOT_DETECTED
    raise_bad_rssi(rss_path, rss, 1, NOT_DETECTED, lambda c: f"beacon {bid[c]}: RSS", "not-detected code 100")
    raise_at(tms_path, tms_f < 0, 1, lambda r, c: f"beacon {bid[c]}: negative time {tms_f[r, c]:.0f}")
    raise_at(tms_path, (tms_f == 0) != missing, 1,
             lambda r, c: f"beacon {bid[c]}: time {tms_f[r, c]:.0f} does not agree with RSS {rss[r, c]:g} "
                          f"in {rss_path.name} (time is 0 exactly when RSS is 100, not detected)")
    tms = tms_f.astype(np.int64)

    ids = ids.astype(np.int64)
    raise_at(ids_path, (ids < 10_000_000) | (ids > 99_999_999), 1,
             lambda r, c: f"id {ids[r]} is not an 8-digit PWCNNNSS fingerprint id")
    codes = {"P": ids // 10_000_000, "W": ids // 1_000_000 % 10, "C": ids // 100_000 % 10,
             "N": ids // 100 % 1000, "S": ids % 100}
    for key, table, label in (("P", "phones", "phone"), ("W", "powers", "TX-power"), ("C", "campaigns", "campaign")):
        known = np.isin(codes[key], list(spec[table]))
        raise_at(ids_path, ~known, 1, lambda r, c, key=key, table=table, label=label:
                 f"id {ids[r]}: {label} code {codes[key][r]} is not one of {sorted(spec[table])} for zone {zone}")

    obstacles, obs_xy = _read_obstacles(src / "obs" / f"{zone}.csv")
    return _Zone(zone, bid, bxy, obstacles, obs_xy, rss, tms, crd, codes, rss_path)


def _read_obstacles(path: Path) -> tuple[list[Polygon], np.ndarray]:
    cells, first = read_cells(path, 4, header=("id", "x", "y", "type"))
    if len(cells) == 0:
        return [], np.empty((0, 2))
    v = parse_numbers(path, cells, first, ("id", "x", "y", "type"))
    raise_far(path, v[:, 1:3], first, ("column 'x'", "column 'y'"))
    oid = v[:, 0]
    polys = []
    for k in pd.unique(oid):  # one iteration per obstacle (tens), not per row
        rows = np.flatnonzero(oid == k)
        hull = MultiPoint(v[rows, 1:3]).convex_hull
        if not isinstance(hull, Polygon) or hull.area <= 0:
            raise ImportError_(path, int(rows[0]) + first,
                               f"obstacle id {k:g}: its points enclose no area (need 3 non-collinear points)")
        polys.append(hull)
    return polys, v[:, 1:3]


def _session_clock(z: _Zone, idx: np.ndarray, tms_path: Path) -> tuple[np.ndarray, np.ndarray, int]:
    """Scan times (s) of fingerprints ``idx`` (file order), interpolated flags, and t0 (ns)."""
    tms = z.tms[idx]
    det = tms > 0
    timed = det.any(axis=1)
    scan_ns = np.where(det, tms, np.iinfo(np.int64).min).max(axis=1)
    if not timed.any():
        # no beacon heard in the whole session: no clock at all; one fingerprint per second
        return np.arange(len(idx), dtype=float), np.ones(len(idx), dtype=bool), 0
    t0 = int(tms[det].min())
    pos = np.flatnonzero(timed)
    back = np.flatnonzero(np.diff(scan_ns[pos]) < 0)
    if back.size:
        r = int(idx[pos[back[0] + 1]])
        raise ImportError_(tms_path, r + 1, f"fingerprint time goes backwards within session (its latest reading "
                           f"is earlier than that of line {int(idx[pos[back[0]]]) + 1})")
    t_timed = (scan_ns[pos] - t0) / NS_PER_S
    t = np.interp(np.arange(len(idx)), pos, t_timed)
    return t, ~timed, t0


def import_uji_ble(src: Path, out: Path) -> ImportReport:
    """Convert the UJI BLE cross-phone fingerprint set at ``src`` into dataset ``out`` (see module doc)."""
    src, out = Path(src), Path(out)
    check_out(out)
    zones = {z: _read_zone(src, z) for z in ZONES}  # parse everything before writing anything
    report = ImportReport(out=out)
    write_dataset_meta(
        out, "uji_ble", "UJI BLE RSS fingerprints (library: 3 phones; Geotec: 1 phone, 3 TX powers), static survey",
        "CC BY 4.0 (data), Universitat Jaume I", "Mendoza-Silva et al., Zenodo 10.5281/zenodo.1618692; copy: "
        "Kassiopeia14/IndoorPositioning@ea387895 UJI_BLE_DB/data", importer="blenav.importers.uji_ble",
        assumptions=[f"phone and beacon height {PHONE_HEIGHT_M} m (not in raw data)",
                     "*_tms.csv read as nanoseconds (authors' timeDiffMilli.m divides by 1e6 for ms)",
                     "floor plan = obstacles only (shelves/pillars); walls are not in the raw data"])
    total_cells = 0
    for zname, z in zones.items():
        spec = ZONES[zname]
        tms_path = z.rss_path.with_name(f"{zname}_tms.csv")
        occ, origin = occupancy_grid(np.vstack([z.beacon_xy, z.crd, z.obstacle_xy]), z.obstacles, RESOLUTION_M,
                                     MARGIN_M)
        anchors = pd.DataFrame({"anchor_id": z.beacon_ids, "kind": "ble", "x": z.beacon_xy[:, 0],
                                "y": z.beacon_xy[:, 1], "z": ANCHOR_Z_M, "floor": 0, "tx_power_dbm": np.nan,
                                "channel_model": CHANNEL_MODEL})
        write_building(out, zname, spec["name"], [{"id": 0, "occupancy": occ, "resolution": RESOLUTION_M,
                                                   "origin": origin, "z": 0.0}], anchors,
                       source="UJI BLE RSS database, dep/ and obs/ files",
                       floor_plan=(f"no walls in the raw data: free grid over the bounding box of beacons, points and "
                                   f"obstacles + {MARGIN_M} m; obstacles (convex hull of each obs id) occupied"))
        report.buildings += 1
        in_obstacle = int((grid_lookup(occ, origin, z.crd, RESOLUTION_M) == OCCUPIED).sum())
        if in_obstacle:
            report.notes.append(f"{zname}: {in_obstacle} fingerprints lie in an obstacle pixel of the grid (kept)")

        c = z.codes
        key = c["P"] * 100 + c["W"] * 10 + c["C"]
        for k in pd.unique(key):  # one iteration per session (9)
            idx = np.flatnonzero(key == k)
            p, w, camp = int(c["P"][idx[0]]), int(c["W"][idx[0]]), int(c["C"][idx[0]])
            phone, power, cname = spec["phones"][p], spec["powers"][w], spec["campaigns"][camp]
            sid = f"{zname}_{phone.lower()}_{cname}_txm{abs(power):02d}"
            t, interp, t0 = _session_clock(z, idx, tms_path)

            rss, tms = z.rss[idx], z.tms[idx]
            r, col = np.nonzero(rss != NOT_DETECTED)
            rssi = pd.DataFrame({"t": t[r], "anchor_id": z.beacon_ids[col], "rssi": rss[r, col],
                                 "t_rx": (tms[r, col] - t0) / NS_PER_S, "raw_line": idx[r] + 1})
            gt = pd.DataFrame({"t": t, "x": z.crd[idx, 0], "y": z.crd[idx, 1], "z": PHONE_HEIGHT_M,
                               "qw": np.nan, "qx": np.nan, "qy": np.nan, "qz": np.nan,
                               "point": c["N"][idx], "sample": c["S"][idx], "raw_line": idx + 1,
                               "t_interpolated": interp.astype(np.int8)})
            meta = {"building": zname, "floor": 0, "device_model": phone, "carrier": "static", "labelled": True,
                    "notes": (f"UJI BLE fingerprint survey, zone {zname}, phone {phone}, campaign {cname}, beacons "
                              f"at {power} dBm TX power; t = latest beacon reading of each fingerprint (tms ns) "
                              f"since the session's first reading; no IMU"),
                    "zone": zname, "campaign": cname, "beacon_tx_power_dbm": power,
                    "raw_codes": {"phone": p, "power": w, "campaign": camp}}
            write_session(out, sid, meta, {"rssi": rssi, "groundtruth": gt})
            report.sessions += 1
            n_miss = int(rss.size - len(rssi))
            total_cells += rss.size
            report.drop(f"RSS cells = 100 (beacon not detected; no row written) in {zname}", n_miss)
            if interp.any():
                report.notes.append(f"{sid}: {int(interp.sum())} of {len(idx)} fingerprints detected no beacon; "
                                    "their time is interpolated (t_interpolated = 1), no rssi rows")
    report.notes.append(f"{sum(len(z.rss) for z in zones.values())} fingerprints, {total_cells} RSS cells read")
    validate_or_raise(out, report)
    return report

