"""Import the Danis et al. position-annotated BLE RSSI tracks into dataset format v1.

Source: F. S. Danis, A. T. Naskali, A. T. Cemgil, C. Ersoy, "Position Annotated BLE RSSI Dataset for
Indoor Localization" (github philotuxo/Position-Annotated-BLE-RSSI-Dataset, CC0 1.0), as copied in
``SOURCE.txt`` beside the raw files. Raw layout (``src`` is the folder holding it)::

    trk/<track>_all_sensors.mbd   no header, 16 columns, one row per received BLE packet:
                                  unix time (s), receiver MAC, transmitter MAC, RSSI (dBm),
                                  x, y, z (m), 3x3 orientation matrix (9 values)
    cnf/tetam.dev                 "Dongles:{MAC: [[x, y, z], colour, alias], ...}" and "Beacons:{...}"
    occ/tetam_0.1.occ             header "[[xmin, ymin], [xmax, ymax]]::cell"; lines "[x, y]::value"

Geometry is reversed with respect to the format's phone-receives-from-anchors picture: **one moving BLE
transmitter** (the beacon in ``Beacons``, ``e78f135624ce``) is carried along 9 tracks and **12 fixed
receivers** (``Dongles``) log its packets. The receivers are written as the anchors and the moving
beacon as the session's device; since the RSSI of a link is (to first order) reciprocal, the data
reads like a device hearing 12 anchors.

What is written
---------------
* One building ``tetam``, floor ``0`` (z = 0 m).
* ``anchors.csv``: one row per receiver of ``cnf/tetam.dev`` (12 rows). ``anchor_id`` = receiver MAC
  (lower-case hex, no colons, as in the track files), ``kind: ble``, x, y, z from the file (m),
  ``tx_power_dbm`` empty (unknown), ``channel_model`` = "fixed receiver; moving transmitter (reciprocal
  link)". Extra column ``alias`` (``sensor10`` ...). (Four receivers have Raspberry Pi MACs
  ``b827eb...`` and sit at 1.22 m, the other eight have placeholder MACs ``000000000xyz`` and sit at
  2.30 m; the hardware is not documented further.)
* One session per track file, id = the file name without ``_all_sensors.mbd`` (e.g. ``straight_05``):
  ``carrier: pedestrian`` (``SOURCE.txt`` and the authors' README describe a "navigable setup of
  cameras and a BLE beacon" moved through the area; no robot is mentioned), ``device_model:
  danis-beacon``, ``labelled: true``. No ``imu.csv`` (the raw data has no inertial data).
* ``rssi.csv``: one row per packet: ``t``, ``anchor_id`` = receiver MAC, ``rssi`` (integer dBm).
* ``groundtruth.csv``: one row per distinct packet time ``t`` (the raw position is per packet; of rows
  with the same ``t`` only the first in time order is kept; the raw positions are interpolated per
  packet, so merged rows differ by well under 1 mm -- the notes count any that differ by more), x, y, z
  of the beacon (m). Ground-truth times are therefore strictly increasing. **Orientation
  columns are empty on every row**; see below.

Units, clock and frames
-----------------------
* Time: ``t = unix - (earliest unix time of the track)`` seconds, rounded to the writer's 0.1 ms (two
  packets closer than that share a ``t``). The merged track files are not
  strictly time-ordered (about one pair per track is swapped, by < 1 ms); rows are stably sorted by
  time before writing, so every file is non-decreasing. The number of reordered rows is in the notes.
* Positions: metres in the authors' world frame (the frame of the AR markers, receivers, occupancy
  grid and ``tetam.par`` limits ``[0, 0, 20.66, 17.64]``), used unchanged as the building frame. It is
  taken as right-handed, x east-ish, y north-ish, z up (z of the beacon is 1.5..2.0 m; receivers at
  1.22/2.30 m); its true compass alignment is unknown.
* RSSI: dBm as logged. A value >= 0 dBm (straight_05 has one +42) or <= -150 dBm is not a reading: the
  row is dropped from ``rssi.csv`` and counted in the report (its position still enters the ground
  truth: the annotation comes from the cameras, not from the radio).

Orientation (why the quaternion columns are empty)
--------------------------------------------------
The 9 values are read row-major, ``M[i, j] = v[3 i + j]``. They are the orientation of the carried
camera/beacon rig estimated by the AR-marker system -- the *rig's (beacon's)* orientation, not a
phone's, and in a camera body frame, not the Android device frame. Checked on this copy:

* Only 20-71 % of the rows per track are proper rotations (all singular values within 5 % of 1 and
  det > 0); the rest have singular values down to ~0 (e.g. straight_05 line 20: rows 2 and 3 have norm
  0.31). They are element-wise interpolations between two orientations 180 deg apart.
* Between proper rows, the relative rotation ``M(t)^T M(t0)`` is about the world vertical axis (for the
  transposed product ``M(t) M(t0)^T`` the axis is horizontal): so ``M`` maps world to body
  (``M^T`` is body-to-world) and the jumps are 180 deg *yaw* flips -- present even on the tracks named
  ``*_without_rotation``, where the rig did not turn. This is the front/back ambiguity of the camera
  pose, not motion.

Converting these to quaternions would write wrong orientation as ground truth for most rows, and the
format allows orientation only on every row or on none. The quaternion columns are therefore left
empty (position-only ground truth, allowed by the format); the per-track fraction of proper rotations
is in the session notes.

Floor plan
----------
``occ/tetam_0.1.occ`` (0.1 m cells, the finest) is converted to the floor image. Each line's ``[x, y]``
is a **cell centre** in world metres (on the 1.0 m grid, ground truth agrees with centre cells far
better than with lower-left-corner cells), so the grid's lower-left corner is ``(xmin - cell/2,
ymin - cell/2)`` and ``y`` grows upwards (image row 0 is the largest y). Cells missing from the file
would be UNKNOWN (none are missing). The grid is padded by ``PAD_M`` of UNKNOWN on every side because a
few ground-truth positions lie just outside the authors' limits (straight_03 starts at y = -0.14 m).

**Value convention.** The authors' occ/README says 1 = traversable, 0 = occupied. On this copy the
ground truth lies in cells of value **0** for 98.7 % of all packets (0.3 % in value-1 cells, 1.0 %
just off the grid), and of the upstream fingerprint points (``fpt/`` file names, not copied) 15 of the 18
surveyed at an elevated height (z > 1.85 m, i.e. standing on furniture) fall in value-1 cells against 6
of the 40 at 1.85 m: the file marks *occupied* (desk blocks) with 1. The importer decides the convention from
the data -- the value that holds the majority of ground-truth positions is FREE, the other OCCUPIED --
and states the decision and both fractions in the report notes. The resulting free fraction is
measured on the written floor (through :class:`blenav.data.Floor`, so the orientation is checked end to
end) and reported.

Bad input
---------
A track line without exactly 16 comma-separated fields, a non-numeric or non-finite number, an empty
MAC, a malformed occupancy line or header, an occupancy value other than 0/1, a cell off the grid or
listed twice, or an unparsable ``tetam.dev`` raises :class:`~blenav.errors.ImportError_` naming the
file and the 1-based line. Rows from another transmitter or from a receiver missing in ``tetam.dev``
are dropped and counted (none in this copy). Nothing is written before all input has been read.
"""

from __future__ import annotations

import json
import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd

from blenav.data import FREE, OCCUPIED, UNKNOWN
from blenav.data.building import Building
from blenav.data.schema import RSSI_MAX_DBM, RSSI_MIN_DBM
from blenav.data.writer import write_building, write_dataset_meta, write_session

from blenav.errors import ImportError_

from . import ImportReport
from ._common import (
    FAR_TIME,
    check_out,
    drop_rssi,
    first_true,
    grid_lookup,
    parse_numbers,
    raise_far,
    read_cells,
    read_lines,
    source_line,
    validate_or_raise,
)

BUILDING_ID = "tetam"
DEVICE_MODEL = "danis-beacon"
TRACK_GLOB = "*_all_sensors.mbd"
OCC_FILE = "tetam_0.1.occ"
#: UNKNOWN margin around the occupancy grid (m).
PAD_M = 0.5
#: rows merged into one ground-truth time whose positions differ by more than this (m) are counted.
SAME_POSITION_M = 1e-3
#: tolerance for a proper rotation: singular values within this of 1, det > 0.
ROTATION_TOL = 0.05
CHANNEL_MODEL = "fixed receiver; moving transmitter (reciprocal link)"
SOURCE_DEFAULT = "github philotuxo/Position-Annotated-BLE-RSSI-Dataset"
TRACK_COLUMNS = ("unix_s", "receiver", "transmitter", "rssi", "x", "y", "z",
                 "m00", "m01", "m02", "m10", "m11", "m12", "m20", "m21", "m22")
_NUM = r"[-+]?(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?"
_PAIR = rf"\[\s*({_NUM})\s*,\s*({_NUM})\s*\]"
_OCC_HEADER = re.compile(rf"^\[\s*{_PAIR}\s*,\s*{_PAIR}\s*\]::\s*({_NUM})$")
_OCC_LINE = rf"^{_PAIR}::\s*({_NUM})$"


# --------------------------------------------------------------------------------------------------
# reading


@dataclass
class _Receivers:
    table: pd.DataFrame   # anchor_id, x, y, z, alias
    beacons: list[str]


def read_devices(path: Path) -> _Receivers:
    """``cnf/tetam.dev``: receivers ("Dongles") with positions (m) and the transmitter MACs ("Beacons")."""
    found: dict[str, tuple[int, dict]] = {}
    for i, line in enumerate(read_lines(path), start=1):
        if not line.strip():
            continue
        key, sep, rest = line.partition(":")
        if not sep or key.strip() not in ("Dongles", "Beacons"):
            raise ImportError_(path, i, f"expected 'Dongles:{{...}}' or 'Beacons:{{...}}', got {line[:40]!r}")
        try:
            doc = json.loads(rest)
        except json.JSONDecodeError as exc:
            raise ImportError_(path, i, f"{key.strip()}: not a JSON object ({exc.msg})") from None
        if not isinstance(doc, dict):
            raise ImportError_(path, i, f"{key.strip()}: not a JSON object")
        found[key.strip()] = (i, doc)
    for key in ("Dongles", "Beacons"):
        if key not in found:
            raise ImportError_(path, None, f"no '{key}:' line")
    line, dongles = found["Dongles"]
    rows = []
    for mac, val in dongles.items():
        try:
            xyz = [float(v) for v in val[0]]
            alias = str(val[2])
        except (TypeError, ValueError, IndexError, KeyError):
            raise ImportError_(path, line, f"receiver {mac!r}: expected [[x, y, z], colour, alias]") from None
        if len(xyz) != 3 or not np.all(np.isfinite(xyz)):
            raise ImportError_(path, line, f"receiver {mac!r}: position must be 3 finite numbers (m)")
        rows.append((str(mac).strip().lower(), *xyz, alias))
    if not rows:
        raise ImportError_(path, line, "no receivers")
    table = pd.DataFrame(rows, columns=["anchor_id", "x", "y", "z", "alias"])
    beacons = [str(m).strip().lower() for m in found["Beacons"][1]]
    if len(beacons) != 1:
        raise ImportError_(path, found["Beacons"][0], f"expected exactly one beacon (the moving transmitter), "
                           f"got {len(beacons)}")
    return _Receivers(table, beacons)


def read_track(path: Path) -> pd.DataFrame:
    """One ``trk/*.mbd`` file as a frame with :data:`TRACK_COLUMNS` plus ``line`` (1-based), file order."""
    cells, first = read_cells(path, len(TRACK_COLUMNS), require_rows=True)
    df = pd.DataFrame({"line": np.arange(first, len(cells) + first)})
    for c in ("receiver", "transmitter"):
        v = np.char.lower(cells[:, TRACK_COLUMNS.index(c)])
        bad = first_true(v == "")
        if bad is not None:
            raise ImportError_(path, bad + first, f"column {c!r} (MAC) is empty")
        df[c] = v.astype(object)
    numeric = [k for k, c in enumerate(TRACK_COLUMNS) if c not in ("receiver", "transmitter")]
    v = parse_numbers(path, cells[:, numeric], first, [TRACK_COLUMNS[k] for k in numeric])
    raise_far(path, v[:, :1], first, ("column 'unix_s'",), **FAR_TIME)
    for j, k in enumerate(numeric):
        df[TRACK_COLUMNS[k]] = v[:, j]
    return df


@dataclass
class _OccGrid:
    values: np.ndarray       # int8 (nx, ny): raw value per cell, -1 where the file lists no cell
    cell: float              # m
    lower_left: tuple[float, float]   # world (x, y) of the lower-left corner of cell (0, 0)


def read_occupancy(path: Path) -> _OccGrid:
    """``occ/tetam_<cell>.occ`` as a grid indexed ``[ix, iy]`` (x east, y up); raw values 0/1."""
    lines = read_lines(path)
    if not lines:
        raise ImportError_(path, None, "file is empty")
    m = _OCC_HEADER.match(lines[0].strip())
    if m is None:
        raise ImportError_(path, 1, "header must be '[[xmin, ymin], [xmax, ymax]]::cell_size'")
    xmin, ymin, xmax, ymax, cell = (float(g) for g in m.groups())
    if not (cell > 0 and xmax > xmin and ymax > ymin):
        raise ImportError_(path, 1, "need cell_size > 0, xmax > xmin and ymax > ymin")
    parts = pd.Series(lines[1:], dtype=object).str.strip().str.extract(_OCC_LINE)
    bad = first_true(parts[0].isna().to_numpy(bool))
    if bad is not None:
        raise ImportError_(path, bad + 2, "expected '[x, y]::value'")
    v = parts.astype(float).to_numpy()
    bad = first_true(~np.isin(v[:, 2], (0.0, 1.0)))
    if bad is not None:
        raise ImportError_(path, bad + 2, f"occupancy value {v[bad, 2]:g} is not 0 or 1")
    fx, fy = (v[:, 0] - xmin) / cell, (v[:, 1] - ymin) / cell
    ix, iy = np.rint(fx).astype(np.int64), np.rint(fy).astype(np.int64)
    bad = first_true((np.abs(fx - ix) > 1e-6) | (np.abs(fy - iy) > 1e-6) | (ix < 0) | (iy < 0))
    if bad is not None:
        raise ImportError_(path, bad + 2, f"cell [{v[bad, 0]:g}, {v[bad, 1]:g}] is not on the {cell:g} m grid "
                           f"starting at [{xmin:g}, {ymin:g}]")
    key = ix * (iy.max() + 1) + iy
    bad = first_true(pd.Series(key).duplicated().to_numpy(bool))
    if bad is not None:
        raise ImportError_(path, bad + 2, f"cell [{v[bad, 0]:g}, {v[bad, 1]:g}] is listed twice")
    grid = np.full((ix.max() + 1, iy.max() + 1), -1, dtype=np.int8)
    grid[ix, iy] = v[:, 2].astype(np.int8)
    return _OccGrid(grid, cell, (xmin - cell / 2, ymin - cell / 2))


def _raw_values_at(grid: _OccGrid, xy: np.ndarray) -> np.ndarray:
    """Raw occupancy value (0/1, -1 off the grid or unlisted) at world points (N, 2)."""
    return grid_lookup(grid.values.T[::-1], grid.lower_left, xy, grid.cell, outside=-1)


def floor_image(grid: _OccGrid, free_value: int) -> tuple[np.ndarray, tuple[float, float]]:
    """(occupancy int8 (H, W) with row 0 on top, world origin of the lower-left pixel), padded by PAD_M."""
    occ_xy = np.full(grid.values.shape, UNKNOWN, dtype=np.int8)
    occ_xy[grid.values == free_value] = FREE
    occ_xy[grid.values == 1 - free_value] = OCCUPIED
    pad = int(round(PAD_M / grid.cell))
    occ_xy = np.pad(occ_xy, pad, constant_values=UNKNOWN)
    img = occ_xy.T[::-1].copy()      # [ix, iy] -> [row, col], row 0 = largest y
    origin = (grid.lower_left[0] - pad * grid.cell, grid.lower_left[1] - pad * grid.cell)
    return img, (round(origin[0], 9), round(origin[1], 9))


def proper_rotation_mask(m: np.ndarray) -> np.ndarray:
    """(N,) whether each 3x3 matrix in ``m`` (N, 3, 3) is a rotation within :data:`ROTATION_TOL`."""
    sv = np.linalg.svd(m, compute_uv=False)
    return (np.abs(sv - 1.0).max(axis=1) <= ROTATION_TOL) & (np.linalg.det(m) > 0)


# --------------------------------------------------------------------------------------------------
# import


@dataclass
class _Session:
    """One converted track, ready to write."""

    sid: str
    meta: dict
    rssi: pd.DataFrame       # t (s), anchor_id (receiver MAC), rssi (dBm)
    gt: pd.DataFrame         # t (s), x, y, z (m), qw..qz (empty)
    n_raw: int               # rows in the raw track file
    proper: float            # fraction of ground-truth rows whose 3x3 matrix is a proper rotation


def _time_sorted(raw: pd.DataFrame, beacon: str, report: ImportReport) -> tuple[pd.DataFrame, int, float]:
    """Rows of ``beacon`` only, stably sorted by unix time.

    Returns ``(rows, number of rows that moved, largest step back in time in the file (ms))``.
    """
    other_tx = (raw["transmitter"] != beacon).to_numpy()
    report.drop("rows from a transmitter other than the beacon in cnf/tetam.dev", int(other_tx.sum()))
    raw = raw[~other_tx]
    unix = raw["unix_s"].to_numpy()
    order = np.argsort(unix, kind="stable")
    n_moved = int((order != np.arange(len(order))).sum())
    back_ms = 1000 * max(0.0, float(-np.diff(unix).min(initial=0.0)))
    return raw.iloc[order].reset_index(drop=True), n_moved, back_ms


def _track_rssi(raw: pd.DataFrame, t: np.ndarray, receivers: set[str], sid: str,
                report: ImportReport) -> pd.DataFrame:
    """``rssi.csv`` rows (t (s), anchor_id, rssi (dBm)) of a time-sorted track; ``t`` (N,) per raw row.

    Rows from unknown receivers and invalid RSSI values are dropped and counted in ``report``.
    """
    unknown_rx = ~raw["receiver"].isin(receivers).to_numpy()
    rssi_v = raw["rssi"].to_numpy()
    keep = drop_rssi(report, rssi_v, unknown_rx, "rssi rows from a receiver not in cnf/tetam.dev",
                     f"rssi rows with an invalid RSSI (>= {RSSI_MAX_DBM:g} dBm or <= {RSSI_MIN_DBM:g} dBm)")
    invalid = ~unknown_rx & ~keep
    rssi_out = rssi_v[keep]
    if np.all(rssi_out == np.round(rssi_out)):
        rssi_out = rssi_out.astype(np.int64)  # integer dBm as logged
    rssi = pd.DataFrame({"t": t[keep], "anchor_id": raw["receiver"].to_numpy()[keep], "rssi": rssi_out})
    if invalid.any():
        bad = ", ".join(f"{int(r)} dBm at line {int(ln)}" for r, ln in
                        zip(rssi_v[invalid][:5], raw["line"].to_numpy()[invalid][:5]))
        report.notes.append(f"{sid}: dropped invalid RSSI {bad}")
    return rssi


def _track_groundtruth(raw: pd.DataFrame, t: np.ndarray) -> tuple[pd.DataFrame, np.ndarray, float, int]:
    """Ground truth of a time-sorted track: the first row of each distinct ``t`` (N,) (s).

    Returns ``(groundtruth frame (t, x, y, z in m, empty quaternion), (N,) mask of the kept rows,
    fraction of kept rows with a proper rotation matrix, number of merged rows whose position differs
    from the kept one by more than SAME_POSITION_M)``.
    """
    first = ~pd.Series(t).duplicated().to_numpy()
    g = raw[first]
    gt = pd.DataFrame({"t": t[first], "x": g["x"].to_numpy(), "y": g["y"].to_numpy(), "z": g["z"].to_numpy(),
                       "qw": np.nan, "qx": np.nan, "qy": np.nan, "qz": np.nan})
    m = g[list(TRACK_COLUMNS[7:])].to_numpy().reshape(-1, 3, 3)
    proper = float(proper_rotation_mask(m).mean())
    same_t = raw[~first]
    prev = raw.loc[first].set_index(pd.Series(t[first]))
    conflict = 0
    if len(same_t):
        ref = prev.loc[t[~first], ["x", "y", "z"]].to_numpy()
        conflict = int((np.abs(ref - same_t[["x", "y", "z"]].to_numpy()).max(axis=1) > SAME_POSITION_M).sum())
    return gt, first, proper, conflict


def _convert_track(path: Path, beacon: str, receivers: set[str], report: ImportReport) -> _Session:
    """One ``trk/*_all_sensors.mbd`` file as a session (rssi + position-only ground truth, t in s)."""
    raw = read_track(path)
    sid = path.name[: -len("_all_sensors.mbd")]
    n_raw = len(raw)
    raw, n_moved, back_ms = _time_sorted(raw, beacon, report)
    # seconds since the first packet, on the writer's 0.1 ms grid (so "distinct time" means distinct on disk)
    t = np.round(raw["unix_s"].to_numpy() - raw["unix_s"].min(), 4)
    rssi = _track_rssi(raw, t, receivers, sid, report)
    gt, first, proper, conflict = _track_groundtruth(raw, t)
    notes = (f"Danis et al. track {path.name}: one BLE beacon ({beacon}) carried on a camera rig and "
             f"heard by {len(receivers)} fixed receivers (the anchors; reciprocal link). t = unix time - first "
             f"packet ({raw['unix_s'].min():.6f}); {n_moved} rows were out of time order in the raw file (by "
             f"up to {back_ms:.2f} ms) and were sorted. Ground truth: AR-marker camera positions, one row per "
             f"distinct packet time ({int((~first).sum())} same-time rows merged, {conflict} of them > 1 mm "
             f"from the kept position). Orientation left empty: only {100 * proper:.0f}% of the raw 3x3 "
             f"matrices are proper rotations, the rest are blends of two orientations 180 deg apart in yaw "
             f"(see importer docstring). No IMU.")
    meta = {"building": BUILDING_ID, "floor": 0, "device_model": DEVICE_MODEL, "carrier": "pedestrian",
            "labelled": True, "notes": notes, "source_file": f"trk/{path.name}", "beacon_mac": beacon}
    return _Session(sid, meta, rssi, gt, n_raw, proper)


def _free_value_convention(grid: _OccGrid, xy: np.ndarray, report: ImportReport) -> int:
    """The raw occupancy value (0 or 1) that means FREE: the one holding most ground-truth points (N, 2) (m).

    The decision and both fractions are noted in ``report``.
    """
    raw_at = _raw_values_at(grid, xy)
    frac1, frac0 = float((raw_at == 1).mean()), float((raw_at == 0).mean())
    free_value = 1 if frac1 >= frac0 else 0
    report.notes.append(
        f"occupancy {OCC_FILE}: ground-truth positions lie in value-1 cells {100 * frac1:.1f}%, value-0 cells "
        f"{100 * frac0:.1f}%, off the grid {100 * (1 - frac0 - frac1):.1f}%; the authors' README says 1 = "
        f"traversable; this import treats {free_value} as FREE and {1 - free_value} as OCCUPIED"
        + ("" if free_value == 1 else " (the data contradicts the README)"))
    return free_value


def _write(src: Path, out: Path, dev: _Receivers, grid: _OccGrid, free_value: int, sessions: list[_Session],
           report: ImportReport) -> Path:
    """Write dataset meta, the building (floor image, anchors) and every session; return the building root."""
    occ, origin = floor_image(grid, free_value)
    anchors = dev.table.assign(kind="ble", floor=0, tx_power_dbm=np.nan, channel_model=CHANNEL_MODEL)
    write_dataset_meta(out, "danis_ble_tracks", "Danis et al. position-annotated BLE RSSI tracks (TETAM area, "
                       f"Bogazici University): 1 moving beacon, {dev.table['anchor_id'].nunique()} fixed receivers, "
                       f"{len(sessions)} tracks",
                       "CC0-1.0", source_line(src, SOURCE_DEFAULT))
    broot = write_building(out, BUILDING_ID, "TETAM test area (Danis et al.)",
                           [{"id": 0, "occupancy": occ, "resolution": grid.cell, "origin": origin, "z": 0.0}],
                           anchors, source_occupancy=f"occ/{OCC_FILE}", occupancy_free_value=free_value)
    for s in sessions:
        write_session(out, s.sid, s.meta, {"rssi": s.rssi, "groundtruth": s.gt})
        report.sessions += 1
        report.notes.append(f"{s.sid}: {s.n_raw} raw rows -> {len(s.rssi)} rssi rows, {len(s.gt)} ground-truth rows; "
                            f"{100 * s.proper:.0f}% proper rotation matrices")
    report.buildings = 1
    return broot


def import_danis_ble_tracks(src: Path, out: Path) -> ImportReport:
    """Convert ``src`` (the raw folder described in the module docstring) to a dataset at ``out``."""
    src, out = Path(src), Path(out)
    check_out(out)
    report = ImportReport(out=out)

    dev = read_devices(src / "cnf" / "tetam.dev")
    receivers = set(dev.table["anchor_id"])
    grid = read_occupancy(src / "occ" / OCC_FILE)
    track_paths = sorted((src / "trk").glob(TRACK_GLOB))
    if not track_paths:
        raise ImportError_(src / "trk", None, f"no track files matching {TRACK_GLOB}")
    sessions = [_convert_track(path, dev.beacons[0], receivers, report) for path in track_paths]

    # floor: decide the value convention from where the ground truth lies
    xy = np.vstack([s.gt[["x", "y"]].to_numpy() for s in sessions])
    free_value = _free_value_convention(grid, xy, report)
    broot = _write(src, out, dev, grid, free_value, sessions, report)

    floor = Building.load(broot).floor(0)
    free = floor.is_free(xy)
    report.notes.append(f"ground truth in FREE cells of the written floor: {100 * free.mean():.1f}% "
                        f"({int(free.sum())} of {len(xy)} positions)")
    validate_or_raise(out, report)
    return report
