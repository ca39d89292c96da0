"""Import Indoor Location Competition 2.0 recordings (and the 2021 Kaggle challenge layout) into dataset format v1.

Source: XYZ10, Inc., Indoor Location Competition 2.0 sample data, GitHub
location-competition/indoor-location-competition-20 (MIT licence; see ``SOURCE.txt`` beside the raw copy).
The 2021 "Indoor Location & Navigation" challenge (204 buildings) uses the same path-file format.

Input (``src``)
---------------
* a floor folder ``<site>/<floor>/{floor_info.json, geojson_map.json, floor_image.png, path_data_files/*.txt}``,
  a site folder holding floor folders, or any folder above them (repository layout);
* the challenge layout ``train/<site>/<floor>/*.txt`` with ``metadata/<site>/<floor>/{floor_info.json,
  geojson_map.json}`` (``src`` may be the folder holding both, or ``train`` itself when ``metadata`` is its
  sibling);
* a ``.tar.gz`` / ``.tgz`` / ``.tar`` or ``.zip`` of either, read member by member (tar: one streaming pass)
  without unpacking to disk. Each member's declared size is checked before it is read (at most
  ``BLENAV_MAX_ARCHIVE_MEMBER_MB``, default 256 MiB; the largest path file of the sample is 4.1 MB), and so is
  the archive's expansion (at most ``BLENAV_MAX_ARCHIVE_RATIO``, default 200, times its size plus 64 MiB; the
  sample's archives expand about 5.5 times): a member over either is refused naming it. Links and special
  members are not read; the report counts them. Nothing is written under a member's name.

``floors`` (``--floors SITE/FLOOR,...``) keeps only those floors; a name that matches no floor is an error
listing the floors found. Site and floor names are the folder names (``site1``, ``F1``).

What is written
---------------
* One building per site (folder name, e.g. ``site1``; ``name`` = the path files' ``SiteName``), one floor per
  floor folder, floor id = the folder name (``B1``, ``F1``, a string). Floor ``z`` = level x
  ``FLOOR_HEIGHT_M`` (5 m, **assumed**; level from the name: ``F<k>``/``L<k>``/``<k>F`` -> k - 1,
  ``B<k>`` -> -k, else the GeoJSON outline's ``floor_num`` - 1, else 0).
* **Frames.** Every floor keeps the upstream floor frame, the frame of its waypoints: x east, y north, metres,
  origin at the south-west corner of the bounding box of the floor outline. The outline's longitude/latitude
  bounding box maps linearly onto ``[0, width] x [0, height]`` (``floor_info.json`` ``map_info``), the
  alignment described in SOURCE.txt. Floors of one site therefore have slightly different origins (format v1
  wants one origin per building): building.yaml ``floor_frames`` gives each floor's bounding box in
  longitude/latitude and the shift (m) of its origin from the first floor's, for consumers that move between
  floors. The alignment is checked per floor against the waypoints (below).
* **Occupancy grid** at ``RESOLUTION_M`` = 0.1 m/px covering ``[0, width] x [0, height]``, origin (0, 0):
  a pixel is FREE (walkable) when its centre lies inside the floor outline (holes excluded) and outside every
  unit polygon; inside a unit it is UNKNOWN (grey, 205): shops are entered through doors the plan does not
  draw, and surveyors did walk into them (one B1 walk has 3 of its 5 waypoints inside units), so a unit is
  "not known to be free", not a wall; outside the outline it is OCCUPIED. Rasterised with PIL's polygon fill
  (exact to about one pixel at edges); holes of unit polygons are not cut out (none in the sample data).
  ``floor_image.png`` is not used.
* **Rooms**: every unit (shop) polygon becomes a ``rooms.geojson`` feature in floor metres, ``id`` = the
  unit's GeoJSON id (else ``<floor>-unit<i>``), ``name`` = its name. An invalid polygon is repaired with
  shapely's ``make_valid`` (counted in the report); empty ones are dropped (counted).
* **Alignment check** (per floor, in the report and in building.yaml ``alignment``): the share of all
  waypoints of the floor inside the outline, on FREE cells of the grid, and inside a unit; plus the ratio of
  ``floor_info`` width/height to the outline's geodesic size (1.0 = the same scale). A floor with under half
  of its waypoints on FREE cells would fail the validator's ``groundtruth-in-obstacles`` rule.
* ``anchors.csv``: one ``kind: ble`` row per iBeacon transmitter heard, **position unknown** (x, y, z empty:
  the data gives none; ``blenav-map`` estimates them). ``anchor_id`` = ``UUID:major:minor:MAC`` (upper case):
  in this data the iBeacon triple alone does not identify a beacon: over the three floors 327 MACs advertise
  ``9195B3AD-A9D0-4500-85FF-9FB0F65A5201:0:0`` (the mall's beacons, almost all rows from MACs E0:78:A3:...),
  and another triple is advertised by 113 MACs (devices with rotating addresses). ``beacon_id="triple"``
  writes ``UUID:major:minor`` instead. ``floor`` = the floor where it was heard most often (a guess: heard
  on several floors, see ``floors_heard``); ``tx_power_dbm`` = the median advertised measured power (RSSI at
  1 m) when it lies in (-150, 0) dBm, else empty. Extra columns: ``uuid, major, minor, mac, n_rows,
  floors_heard``.
* One session per path file, id ``<site>_<floor>_<path id>``: ``carrier: pedestrian``, ``device_model`` =
  ``<Brand> <Model>`` from the header (``unknown`` when absent), ``receiver_brand``, ``android``,
  ``groundtruth_kind: waypoints``, ``orientation_frame``, the upstream ``site_id``/``floor_id``/``path_id``,
  ``start_unix_ms``, ``sensor_time_offset_s``, ``records`` (rows per record type read).

  - ``imu.csv``: TYPE_ACCELEROMETER (m/s^2 incl. gravity) and TYPE_GYROSCOPE (rad/s), Android device frame
    (the format's frame; no conversion). **Time alignment**: when both streams have the same timestamps (all
    walks of the sample: the app logs them together) rows are paired; otherwise the gyroscope is linearly
    interpolated at the accelerometer times and accelerometer samples outside the gyroscope's time span are
    dropped (counted).
  - ``mag.csv``: TYPE_MAGNETIC_FIELD (calibrated, microtesla). The ``*_UNCALIBRATED`` streams are not imported.
  - ``orientation.csv`` (format extension): TYPE_ROTATION_VECTOR as a unit quaternion ``qw, qx, qy, qz``
    (``qw = sqrt(1 - x^2 - y^2 - z^2)``, Android's ``getQuaternionFromVector``) rotating device-frame vectors
    into Android's East-North-Up frame, whose y axis points to *magnetic* north (session.yaml
    ``orientation_frame: enu-magnetic``); the floor frame's y is geographic north of the map, so they differ
    by the magnetic declination (about -5 deg at the ILC mall) plus the map's own error.
  - ``rssi.csv``: TYPE_BEACON rows, ``t`` = the row's time, ``rssi`` dBm. Readings not in (-150, 0) dBm are
    dropped and counted.
  - ``wifi.csv`` (format extension): TYPE_WIFI rows: ``t`` = the scan's row time, ``bssid`` (lower case),
    ``rssi_dbm``, ``freq_mhz``; extra ``ssid`` and ``t_seen`` (the AP's ``last_seen`` time on the session
    clock, s; it can precede the scan by tens of seconds, and the session's start: a cached reading).
    Readings not in (-150, 0) dBm are dropped and counted; a frequency outside 2000..8000 MHz is left empty.
  - ``groundtruth.csv``: the surveyed TYPE_WAYPOINT rows only (x, y in floor metres; z = floor z +
    ``PHONE_HEIGHT_M`` 1.2 m, assumed; orientation empty; extra ``raw_line``). Nothing is interpolated:
    consumers that need denser labels interpolate between waypoints and say so. A walk with fewer than two
    waypoints is written ``labelled: false`` without groundtruth.csv (its waypoint, if any, in session.yaml
    ``waypoints``).

Time
----
Every row carries a Unix time in ms. The session clock is ``t = (unix_ms - t0) / 1000`` s with ``t0`` the
header's ``startTime`` (the first row's time when the header lacks it, or the earliest row when a row precedes
it). Rows of each stream are sorted by time (stable): waypoints, for one, are logged out of file order.
**Sensor vs system time**: sensor rows (accelerometer, gyroscope, magnetometer, rotation vector) carry the
SensorEvent time aligned to Unix time by the recording app, other rows the system time. In the 365 walks
of the sample the sensor rows start 106..189 ms after ``startTime`` and end at most 11 ms after ``endTime``,
so no offset is applied. When the sensor times of a walk lie more than ``SENSOR_CLOCK_TOL_S`` (10 s) outside
the walk's system-time span (an app that did not align the SensorEvent clock: boot time), the sensor streams
are shifted so that their first sample falls at the walk's start, and the shift is written as
``sensor_time_offset_s`` (0.0 otherwise) and counted in the report.

Bad input
---------
A line that does not parse (too few or too many tab-separated fields for its record type, a time that is
not an integer, a value that is not a finite number, a blank line inside the file, bytes that are not
UTF-8) or a file that does not end with a newline (its last line may be cut) raises
:class:`~blenav.errors.ImportError_` naming the file (``archive:member`` inside an archive) and the
1-based line. Record types the format does not document are counted per type and reported, never fatal;
documented types that are not imported (uncalibrated streams, TYPE_BLUE/BLU4/DIST1/DIST2, accuracy changes)
are counted as ignored. A walk without an ``endTime`` header line (possibly cut exactly at a line end) is
imported and counted. Output goes to a temporary folder beside ``out`` that is renamed to ``out`` only when
everything parsed, so a parse error leaves nothing behind; the validator then checks ``out`` (a dataset it
refuses stays there for inspection, and the import raises its errors).
"""

from __future__ import annotations

import csv
import io
import json
import math
import os
import re
import shutil
import tarfile
import zipfile
from collections import Counter, defaultdict
from dataclasses import dataclass, field
from pathlib import Path
from typing import Iterator

import numpy as np
import pandas as pd
import shapely
from PIL import Image, ImageDraw
from shapely.geometry import MultiPolygon, Polygon, shape

from blenav.data.building import FREE, OCCUPIED, UNKNOWN
from blenav.data.schema import STREAMS
from blenav.data.writer import write_building, write_dataset_meta, write_session
from blenav.limits import MIB, max_member_bytes

from blenav.errors import ImportError_

from . import ImportReport
from ._common import check_out, grid_lookup, iter_tar, iter_zip, rssi_in_range, skipped_note, validate_or_raise

RESOLUTION_M = 0.1
FLOOR_HEIGHT_M = 5.0
PHONE_HEIGHT_M = 1.2
SENSOR_CLOCK_TOL_S = 10.0
WIFI_FREQ_MHZ = (2000.0, 8000.0)
#: metres per degree of latitude, and of longitude at the equator (WGS84 mean values, for the scale check only)
M_PER_DEG_LAT = 110_574.0
M_PER_DEG_LON = 111_320.0

SENSOR_TYPES = ("TYPE_ACCELEROMETER", "TYPE_GYROSCOPE", "TYPE_MAGNETIC_FIELD", "TYPE_ROTATION_VECTOR")
#: record type -> (allowed numbers of tab-separated fields, names of the fields after time and type)
USED = {
    **{t: ((5, 6), ("x", "y", "z", "accuracy")) for t in SENSOR_TYPES},
    "TYPE_WAYPOINT": ((4,), ("x", "y")),
    "TYPE_WIFI": ((7,), ("ssid", "bssid", "rssi", "frequency", "last_seen")),
    "TYPE_BEACON": ((10,), ("uuid", "major", "minor", "tx_power", "rssi", "distance", "mac", "unix_ms")),
}
IGNORED = ("TYPE_ACCELEROMETER_UNCALIBRATED", "TYPE_GYROSCOPE_UNCALIBRATED", "TYPE_MAGNETIC_FIELD_UNCALIBRATED",
           "TYPE_BLUE", "TYPE_BLU4", "TYPE_DIST1", "TYPE_DIST2")
_IGNORED_RE = re.compile(r"^TYPE_SENSOR_[A-Z_]+_ACCURACY_CHANGED$")

_REPO_RE = re.compile(r"^(?:.*/)?([^/]+)/([^/]+)/path_data_files/([^/]+)\.txt$")
_CHALLENGE_RE = re.compile(r"^(?:.*/)?train/([^/]+)/([^/]+)/([^/]+)\.txt$")
_META_RE = re.compile(r"^(?:.*/)?([^/]+)/([^/]+)/(floor_info|geojson_map)\.json$")
_SESSION_ID_RE = re.compile(r"[^A-Za-z0-9_.-]+")


# --------------------------------------------------------------------------------------------------
# sources: folder, tar, zip


@dataclass
class _Entry:
    vpath: str        # posix path used for layout matching
    display: str      # what error messages name
    data: bytes


def _classify(vpath: str) -> tuple[str, tuple[str, str], str] | None:
    """('walk' | 'meta', (site, floor), stem or meta name) for a relevant path, else None."""
    name = vpath.rsplit("/", 1)[-1]
    if name.startswith("._") or "__MACOSX/" in vpath:
        return None
    m = _REPO_RE.match(vpath)
    if m:
        return "walk", (m.group(1), m.group(2)), m.group(3)
    m = _CHALLENGE_RE.match(vpath)
    if m:
        return "walk", (m.group(1), m.group(2)), m.group(3)
    m = _META_RE.match(vpath)
    if m:
        return "meta", (m.group(1), m.group(2)), m.group(3)
    return None


def _iter_source(src: Path, want, report: ImportReport | None = None) -> Iterator[_Entry]:
    """Relevant files of ``src`` (folder, tar or zip) in storage order; ``want(vpath)`` filters before reading.
    Every file is bounded before it is read (:class:`~blenav.importers._common.ArchiveBudget`: member size, and an
    archive's expansion ratio); archive members that are links or special files are not read and are counted in
    ``report``'s notes."""
    name = src.name.lower()
    skipped: list[str] = []
    if src.is_dir():
        base = src.resolve()
        max_file = max_member_bytes()
        for root, dirs, files in os.walk(base):
            dirs.sort()
            for f in sorted(files):
                p = Path(root) / f
                vpath = p.as_posix().lstrip("/")
                if want(vpath):
                    if p.stat().st_size > max_file:
                        raise ImportError_(p, None, f"file of {p.stat().st_size / MIB:,.1f} MiB, larger than the "
                                           f"{max_file / MIB:g} MiB a file may have (BLENAV_MAX_ARCHIVE_MEMBER_MB)")
                    yield _Entry(vpath, str(p), p.read_bytes())
        # challenge layout given as its train/ folder: the metadata/ sibling
        if base.name == "train" and (base.parent / "metadata").is_dir():
            yield from _iter_source(base.parent / "metadata", want, report)
        return
    if name.endswith((".tar.gz", ".tgz", ".tar")):
        members, errors, what = iter_tar, (tarfile.TarError, EOFError, OSError), "tar"
    elif name.endswith(".zip"):
        members, errors, what = iter_zip, (zipfile.BadZipFile, EOFError, OSError), "zip"
    else:
        raise ImportError_(src, None, "expected a folder, a .tar.gz/.tgz/.tar or a .zip archive")
    try:
        for vpath, data in members(src, want, skipped):
            yield _Entry(vpath, f"{src}:{vpath}", data)
    except errors as exc:
        raise ImportError_(src, None, f"not a readable {what} archive ({exc})") from None
    note = skipped_note(skipped)
    if note and report is not None:
        report.notes.append(note)


# --------------------------------------------------------------------------------------------------
# path files


#: tab-separated fields read per line at least (the widest documented record, TYPE_BEACON, has 10)
MAX_FIELDS = 12


@dataclass
class _Walk:
    header: dict[str, str]
    start_line: dict[str, int]
    cells: pd.DataFrame           # str cells, row r = file line r + 1, columns 0, 1, ... ('' when absent)
    nfields: np.ndarray           # (lines,) tab-separated fields per line
    kinds: np.ndarray             # (lines,) record type ('' on header lines)
    counts: Counter
    unknown: Counter
    ignored: Counter


def _parse_lines(display: str, data: bytes) -> _Walk:
    """Split a path file into cells (pandas' C parser; one row per physical line) and check the line structure."""
    try:
        data.decode("utf-8")
    except UnicodeDecodeError as exc:
        raise ImportError_(display, data[: exc.start].count(b"\n") + 1, f"not UTF-8 text ({exc.reason})") from None
    if data.startswith(b"\xef\xbb\xbf"):
        data = data[3:]
    if not data:
        raise ImportError_(display, None, "file is empty")
    if not data.endswith(b"\n"):
        raise ImportError_(display, data.count(b"\n") + 1, "the file does not end with a newline, so its last "
                           "line may be cut short (a number missing digits): was the walk cut while it was written "
                           "or copied?")
    a = np.frombuffer(data, dtype=np.uint8)
    ends = np.flatnonzero(a == 10)
    starts = np.concatenate([[0], ends[:-1] + 1])
    tabs = np.flatnonzero(a == 9)
    nfields = np.searchsorted(tabs, ends) - np.searchsorted(tabs, starts) + 1
    blank = (ends == starts) | ((ends - starts == 1) & (a[np.maximum(ends - 1, 0)] == 13))
    if blank.any():
        raise ImportError_(display, int(np.argmax(blank)) + 1, "blank line inside the file")
    # as many columns as the widest line (a header line may be wider; a data line too wide for its record type
    # is reported by _table, naming its line)
    ncols = max(MAX_FIELDS, int(nfields.max()))
    try:
        cells = pd.read_csv(io.BytesIO(data), sep="\t", header=None, names=range(ncols), dtype=object,
                            quoting=csv.QUOTE_NONE, keep_default_na=False, skip_blank_lines=False, engine="c")
    except (ValueError, pd.errors.ParserError) as exc:  # not expected after the checks above
        m = re.search(r"line (\d+)", str(exc))
        raise ImportError_(display, int(m.group(1)) if m else None, f"unreadable line ({exc})") from None
    if len(cells) != len(ends):
        raise ImportError_(display, None, f"{len(cells)} rows read from {len(ends)} lines (a stray carriage return?)")
    first = cells[0].to_numpy(dtype=object)
    is_header = a[starts] == ord("#")
    header: dict[str, str] = {}
    start_line: dict[str, int] = {}
    for r in np.flatnonzero(is_header):
        items = [first[r][1:]] + [str(x) for x in cells.iloc[r, 1:nfields[r]]]
        for item in items:
            k, sep, v = item.partition(":")
            if sep and k.strip():
                header[k.strip()] = v.strip()
                start_line[k.strip()] = int(r) + 1
    short = ~is_header & (nfields < 2)
    if short.any():
        r = int(np.argmax(short))
        raise ImportError_(display, r + 1, f"1 field, expected 'unix_time_ms<TAB>TYPE<TAB>values' ({first[r][:60]!r})")
    kinds = np.where(is_header, "", cells[1].to_numpy(dtype=object)).astype(object)
    vc = Counter(pd.Series(kinds[~is_header]).value_counts().to_dict())
    counts, unknown, ignored = Counter(), Counter(), Counter()
    for k, n in vc.items():
        if k in USED:
            counts[k] = n
        elif k in IGNORED or _IGNORED_RE.match(k):
            ignored[k] = n
        else:
            unknown[k or "(empty type)"] = n
    return _Walk(header, start_line, cells, nfields, kinds, counts, unknown, ignored)


def _floats(cells: np.ndarray) -> np.ndarray:
    """float64 of text cells (numpy's conversion, fast); cells that are not numbers become NaN."""
    try:
        return cells.astype(np.float64)
    except (ValueError, TypeError):
        return pd.to_numeric(pd.Series(cells, dtype=object), errors="coerce").to_numpy(dtype=float)


def _table(display: str, walk: _Walk, kind: str, numeric: tuple[int, ...]
           ) -> tuple[np.ndarray, np.ndarray, np.ndarray, pd.DataFrame]:
    """(lines (n,), unix ms (n,) int64, numbers (n, len(numeric)) float64, str cells (n, MAX_FIELDS)) of the rows
    of ``kind``, in file order. ``numeric`` indexes the fields after time and type (cell column 2 + i). Raises
    naming the line of the first bad row (field count, time, number)."""
    rows = np.flatnonzero(walk.kinds == kind)
    allowed, names = USED[kind]
    n = len(rows)
    if n == 0:
        return np.empty(0, np.int64), np.empty(0, np.int64), np.empty((0, len(numeric))), walk.cells.iloc[:0]
    lens = walk.nfields[rows]
    bad = ~np.isin(lens, allowed)
    if bad.any():
        r = int(rows[np.argmax(bad)])
        want = " or ".join(str(a) for a in allowed)
        raise ImportError_(display, r + 1, f"{kind}: {walk.nfields[r]} tab-separated fields, expected {want} "
                           f"(time, type, {', '.join(names)})")
    sub = walk.cells.iloc[rows]
    tf = _floats(sub[0].to_numpy(dtype=object))
    with np.errstate(invalid="ignore"):
        isint = np.isfinite(tf) & (tf == np.round(tf)) & (np.abs(tf) < 2 ** 53)
    if not isint.all():
        r = int(rows[np.argmax(~isint)])
        raise ImportError_(display, r + 1, f"time {walk.cells.iat[r, 0]!r} is not an integer (Unix ms)")
    t = tf.astype(np.int64)
    v = np.empty((n, len(numeric)))
    for k, c in enumerate(numeric):
        col = _floats(sub[2 + c].to_numpy(dtype=object))
        bad = ~np.isfinite(col)
        if bad.any():
            r = int(rows[np.argmax(bad)])
            raise ImportError_(display, r + 1, f"{kind} field {names[c]!r}: {walk.cells.iat[r, 2 + c]!r} is not a "
                               "finite number")
        v[:, k] = col
    return rows + 1, t, v, sub


# --------------------------------------------------------------------------------------------------
# one walk -> one session


@dataclass
class _FloorAcc:
    """What the sessions of one floor contribute to its building."""

    waypoints: list = field(default_factory=list)           # (n, 2) arrays
    walks: int = 0
    site_name: str = ""
    site_id: str = ""
    floor_id: str = ""


def _stable_sort(t: np.ndarray) -> np.ndarray:
    return np.argsort(t, kind="stable")


def _num_text(v: np.ndarray, decimals: int) -> np.ndarray:
    """Numbers as CSV text rounded to ``decimals`` (NaN -> empty cell)."""
    fmt = f"%.{decimals}f"
    return np.array(["" if x != x else (fmt % x).rstrip("0").rstrip(".") if decimals else "%d" % x
                     for x in np.asarray(v, dtype=float).tolist()], dtype=object)


def _quote(v: np.ndarray) -> np.ndarray:
    """Text cells quoted as RFC 4180 wants where they hold a comma, a quote or a line end."""
    if not any(c in "".join(v) for c in ',"\r\n') and not any(x[:1].isspace() or x[-1:].isspace() for x in v):
        return v
    s = pd.Series(v, dtype=object).fillna("").astype(str)
    need = s.str.contains(r'[,"\r\n]|^\s|\s$', regex=True).to_numpy(dtype=bool)
    if need.any():
        s[need] = '"' + s[need].str.replace('"', '""') + '"'
    return s.to_numpy(dtype=object)


def _write_streams(root: Path, sid: str, meta: dict, streams: dict[str, dict[str, np.ndarray]]) -> None:
    """session.yaml (blenav's writer) and one CSV per stream from columns of text cells (spec columns first)."""
    write_session(root, sid, meta, {})
    for name, cols in streams.items():
        _write_stream(root, sid, name, cols)


def _write_stream(root: Path, sid: str, name: str, cols: dict[str, np.ndarray]) -> None:
    """One stream's CSV of session ``sid`` (its folder written by :func:`_write_streams`) from columns of text
    cells (spec columns first)."""
    spec = STREAMS[name]
    missing = [c for c in spec.columns if c not in cols]
    if missing:
        raise ValueError(f"stream {name} for session {sid} lacks columns {missing}")
    order = list(spec.columns) + [c for c in cols if c not in spec.columns]
    body = "\n".join(map(",".join, zip(*(cols[c] for c in order))))
    (root / "sessions" / sid / spec.filename).write_text(",".join(order) + "\n" + body + ("\n" if body else ""),
                                                         encoding="utf-8")


def _convert_walk(display: str, data: bytes, site: str, floor: str, stem: str, beacon_id: str,
                  report: ImportReport, events: Counter, beacons: dict, bssids: set
                  ) -> tuple[str, dict, dict, np.ndarray, dict]:
    """Parse one path file; returns (session id, session.yaml, streams, waypoints (n, 2) m, header).

    ``beacons`` (anchor id -> what was heard) and ``bssids`` are updated; rows left out are counted in
    ``report.dropped``, walk-level events in ``events``."""
    w = _parse_lines(display, data)
    for k in ("startTime", "endTime"):
        if k in w.header and not re.fullmatch(r"-?\d+", w.header[k]):
            raise ImportError_(display, w.start_line[k], f"header {k}: {w.header[k]!r} is not an integer (Unix ms)")
    _, acc_t, acc, acc_c = _table(display, w, "TYPE_ACCELEROMETER", (0, 1, 2))
    _, gyr_t, gyr, gyr_c = _table(display, w, "TYPE_GYROSCOPE", (0, 1, 2))
    _, mag_t, mag, mag_c = _table(display, w, "TYPE_MAGNETIC_FIELD", (0, 1, 2))
    _, rot_t, rot, rot_c = _table(display, w, "TYPE_ROTATION_VECTOR", (0, 1, 2))
    wp_l, wp_t, wp, _ = _table(display, w, "TYPE_WAYPOINT", (0, 1))
    _, wf_t, wf, wf_c = _table(display, w, "TYPE_WIFI", (2, 3))
    _, bc_t, bc, bc_c = _table(display, w, "TYPE_BEACON", (1, 2, 3, 4))

    t0, offset_ms, (acc_t, gyr_t, mag_t, rot_t), all_t = _walk_clock(
        display, w.header, (acc_t, gyr_t, mag_t, rot_t), (wf_t, bc_t, wp_t), report, events)
    sec = _time_text(all_t, t0)
    streams: dict[str, dict[str, np.ndarray]] = {}   # name -> column -> text cells
    imu = _imu_stream(acc_t, acc_c, gyr_t, gyr, gyr_c, sec, report, events)
    if imu is not None:
        streams["imu"] = imu
    if len(mag_t):
        o = _stable_sort(mag_t)
        streams["mag"] = {"t": sec(mag_t[o]), **{c: _raw(mag_c, o, k) for k, c in enumerate(("mx", "my", "mz"))}}
    if len(rot_t):
        streams["orientation"] = _orientation_stream(rot_t, rot, rot_c, sec)
    if len(bc_t):
        streams["rssi"] = _beacon_stream(bc_t, bc, bc_c, sec, floor, beacon_id, report, beacons)
    if len(wf_t):
        streams["wifi"] = _wifi_stream(wf_t, wf, wf_c, sec, t0, report, bssids)
    o = _stable_sort(wp_t)
    wp_xy = wp[o]
    labelled = len(wp_t) >= 2
    if labelled:
        empty = np.full(len(o), "", dtype=object)
        streams["groundtruth"] = {"t": sec(wp_t[o]), "x": _num_text(wp_xy[:, 0], 6), "y": _num_text(wp_xy[:, 1], 6),
                                  "z": None, "qw": empty,  # z: the floor's, known at _write_site
                                  "qx": empty, "qy": empty, "qz": empty, "raw_line": _num_text(wp_l[o], 0)}
    else:
        events["walks with fewer than two waypoints (written as unlabelled sessions)"] += 1
    sid, meta = _walk_meta(w, site, floor, stem, labelled, wp_t[o], wp_xy, sec, t0, offset_ms)
    for k, v in w.unknown.items():
        report.drop(f"rows of undocumented record type {k} (not imported)", v)
    for k, v in w.ignored.items():
        report.drop(f"rows of {k} (documented, not imported)", v)
    return sid, meta, streams, wp_xy, w.header


def _walk_clock(display: str, header: dict, sensor_t: tuple, sys_t: tuple, report: ImportReport, events: Counter):
    """The session clock of one walk: (t0 Unix ms the session's zero, offset_ms subtracted from the sensor
    times, the sensor times (4 arrays (n,) int64 Unix ms, accelerometer, gyroscope, magnetometer, rotation
    vector) shifted by it, every non-empty time array (sensors shifted, then WiFi, beacon, waypoint)).

    ``sys_t`` (WiFi, beacon, waypoint) are on the system clock with the header's startTime/endTime; sensor
    times more than SENSOR_CLOCK_TOL_S outside that span are on another clock and are shifted so their first
    sample is at the system clock's first time. t0 = startTime, or the earliest row when one precedes it."""
    sys_times = [a for a in sys_t if len(a)]
    sensor_times = [a for a in sensor_t if len(a)]
    start = int(header["startTime"]) if "startTime" in header else None
    end = int(header["endTime"]) if "endTime" in header else None
    if end is None:
        events["walks without an endTime header line (imported; possibly cut at a line end)"] += 1
    lo = ([start] if start is not None else []) + [int(a.min()) for a in sys_times]
    sys_lo = min(lo) if lo else 0
    sys_hi = max(([end] if end is not None else []) + [int(a.max()) for a in sys_times] + [sys_lo])
    offset_ms = 0
    if sensor_times and (start is not None or sys_times):
        s_lo = min(int(a.min()) for a in sensor_times)
        s_hi = max(int(a.max()) for a in sensor_times)
        tol = SENSOR_CLOCK_TOL_S * 1000
        if s_lo < sys_lo - tol or s_hi > sys_hi + tol:
            offset_ms = s_lo - sys_lo
            events["walks whose sensor clock was shifted onto the system clock (sensor_time_offset_s)"] += 1
    sensor_t = tuple(a - offset_ms for a in sensor_t)
    all_t = [a for a in sensor_t + tuple(sys_t) if len(a)]
    first = min(int(a.min()) for a in all_t) if all_t else 0
    t0 = start if start is not None else first
    if first < t0:
        report.notes.append(f"{display}: rows precede startTime by {(t0 - first) / 1000:g} s; the session starts "
                            "at the earliest row")
        t0 = first
    return t0, offset_ms, sensor_t, all_t


def _time_text(all_t: list, t0: int):
    """A function from Unix ms times (n,) int (each one of ``all_t``'s) to session times as text (n,) object,
    seconds since ``t0`` with exactly the millisecond resolution of the raw times.

    Each distinct time is formatted once (the sensor streams share their times, the rows of a WiFi scan
    theirs)."""
    uniq = np.unique(np.concatenate(all_t)) if all_t else np.empty(0, np.int64)
    uniq_text = np.array(["%.3f" % x for x in ((uniq - t0) / 1000.0).tolist()], dtype=object)

    def sec(t_ms):
        return uniq_text[np.searchsorted(uniq, np.asarray(t_ms, dtype=np.int64))]

    return sec


def _raw(cells: pd.DataFrame, order: np.ndarray, field_: int) -> np.ndarray:
    """The raw text (n,) of a numeric field (checked finite by _table) of the rows ``order`` (n,), written as
    read: no float formatting."""
    return cells[2 + field_].to_numpy(dtype=object)[order]


def _imu_stream(acc_t: np.ndarray, acc_c: pd.DataFrame, gyr_t: np.ndarray, gyr: np.ndarray, gyr_c: pd.DataFrame,
                sec, report: ImportReport, events: Counter) -> dict | None:
    """imu.csv columns (text cells) from accelerometer and gyroscope rows (times (n,) Unix ms, m/s^2, rad/s):
    rows paired on equal times, else the gyroscope interpolated at the accelerometer's times (those outside
    its span dropped). None when either sensor is missing or no row remains."""
    if len(acc_t) and len(gyr_t):
        ia, ig = _stable_sort(acc_t), _stable_sort(gyr_t)
        at, gt = acc_t[ia], gyr_t[ig]
        if len(at) == len(gt) and np.array_equal(at, gt):
            imu = {"t": sec(at), **{c: _raw(acc_c, ia, k) for k, c in enumerate(("ax", "ay", "az"))},
                   **{c: _raw(gyr_c, ig, k) for k, c in enumerate(("gx", "gy", "gz"))}}
        else:
            inside = (at >= gt[0]) & (at <= gt[-1])
            report.drop("accelerometer samples outside the gyroscope's time span", int((~inside).sum()))
            ia, at = ia[inside], at[inside]
            g = gyr[ig]
            imu = {"t": sec(at), **{c: _raw(acc_c, ia, k) for k, c in enumerate(("ax", "ay", "az"))},
                   **{c: _num_text(np.interp(at, gt, g[:, k]), 7) for k, c in enumerate(("gx", "gy", "gz"))}}
        if len(at):
            return imu
    elif len(acc_t) or len(gyr_t):
        events["walks with an accelerometer or a gyroscope but not both (no imu.csv)"] += 1
    return None


def _orientation_stream(rot_t: np.ndarray, rot: np.ndarray, rot_c: pd.DataFrame, sec) -> dict:
    """orientation.csv columns (text cells) from rotation vector rows (times (n,) Unix ms, (n, 3) x, y, z):
    qw = sqrt(1 - |v|^2) rounded to 7 decimals, qx..qz as read."""
    o = _stable_sort(rot_t)
    n2 = (rot[o] ** 2).sum(axis=1)
    # |v| <= 1 for a rotation vector; a larger one (rounding) gets qw = 0 and is normalised by the readers
    qw = np.round(np.sqrt(np.clip(1.0 - n2, 0.0, None)), 7)
    return {"t": sec(rot_t[o]), "qw": _num_text(qw, 7), **{c: _raw(rot_c, o, k) for k, c in
                                                           enumerate(("qx", "qy", "qz"))}}


def _beacon_stream(bc_t: np.ndarray, bc: np.ndarray, bc_c: pd.DataFrame, sec, floor: str, beacon_id: str,
                   report: ImportReport, beacons: dict) -> dict:
    """rssi.csv columns (text cells) from iBeacon rows (times (n,) Unix ms, (n, 4) major, minor, tx power dBm,
    RSSI dBm); readings outside (-150, 0) dBm dropped. ``beacons`` (anchor id -> uuid, major, minor, mac,
    rows per floor, up to 200 tx powers) is updated."""
    o = _stable_sort(bc_t)
    rssi = bc[o, 3]
    keep = rssi_in_range(rssi)
    report.drop("iBeacon readings outside (-150, 0) dBm", int((~keep).sum()))
    o = o[keep]
    uuid = np.array([x.strip().upper() for x in bc_c[2].to_numpy(dtype=object)[o]], dtype=object)
    mac = np.array([x.strip().upper() for x in bc_c[8].to_numpy(dtype=object)[o]], dtype=object)
    major, minor = bc[o, 0].astype(np.int64), bc[o, 1].astype(np.int64)
    triple = uuid + ":" + major.astype(str).astype(object) + ":" + minor.astype(str).astype(object)
    ids = triple + ":" + mac if beacon_id == "mac" else triple
    heard = pd.DataFrame({"id": ids, "uuid": uuid, "major": major, "minor": minor, "mac": mac, "tx": bc[o, 2]})
    for aid, g in heard.groupby("id", sort=False):
        b = beacons.get(aid)
        if b is None:
            r0 = g.iloc[0]
            b = beacons[aid] = {"uuid": r0["uuid"], "major": int(r0["major"]), "minor": int(r0["minor"]),
                                "mac": r0["mac"] if beacon_id == "mac" else "", "floors": Counter(), "tx": []}
        b["floors"][floor] += len(g)
        if len(b["tx"]) < 200:
            b["tx"] += g["tx"].tolist()[:200]
    return {"t": sec(bc_t[o]), "anchor_id": ids, "rssi": _raw(bc_c, o, 4)}


def _wifi_stream(wf_t: np.ndarray, wf: np.ndarray, wf_c: pd.DataFrame, sec, t0: int, report: ImportReport,
                 bssids: set) -> dict:
    """wifi.csv columns (text cells) from WiFi rows (times (n,) Unix ms, (n, 2) RSSI dBm, frequency MHz);
    readings outside (-150, 0) dBm dropped, frequencies outside WIFI_FREQ_MHZ written empty, ``t_seen`` s since
    ``t0`` (Unix ms). ``bssids`` gets the (lower-case) BSSIDs heard."""
    o = _stable_sort(wf_t)
    keep = rssi_in_range(wf[o, 0])
    report.drop("WiFi readings outside (-150, 0) dBm", int((~keep).sum()))
    o = o[keep]
    freq = wf[o, 1].copy()
    bad_f = (freq < WIFI_FREQ_MHZ[0]) | (freq > WIFI_FREQ_MHZ[1])
    report.drop("WiFi frequencies outside 2000..8000 MHz (written empty)", int(bad_f.sum()))
    freq[bad_f] = np.nan
    bssid = np.array([x.strip().lower() for x in wf_c[3].to_numpy(dtype=object)[o]], dtype=object)
    seen = _floats(wf_c[6].to_numpy(dtype=object))[o]
    bssids.update(bssid)
    return {"t": sec(wf_t[o]), "bssid": bssid, "rssi_dbm": _raw(wf_c, o, 2),
            "freq_mhz": _num_text(freq, 0), "ssid": _quote(wf_c[2].to_numpy(dtype=object)[o]),
            "t_seen": _num_text((seen - t0) / 1000.0, 3)}


def _walk_meta(w: _Walk, site: str, floor: str, stem: str, labelled: bool, wp_t: np.ndarray, wp_xy: np.ndarray,
               sec, t0: int, offset_ms: int) -> tuple[str, dict]:
    """(session id, session.yaml dict) of one walk; ``wp_t`` (n,) Unix ms and ``wp_xy`` (n, 2) m its waypoints
    in time order (kept in the yaml when fewer than two, i.e. unlabelled), t0 Unix ms its zero, offset_ms the
    shift applied to its sensor clock."""
    h = w.header
    brand, model = h.get("Brand", "").strip(), h.get("Model", "").strip()
    sid = _SESSION_ID_RE.sub("-", f"{site}_{floor}_{stem}")
    meta = {"building": site, "floor": floor, "device_model": f"{brand} {model}".strip() or "unknown",
            "carrier": "pedestrian", "labelled": labelled, "groundtruth_kind": "waypoints",
            "orientation_frame": "enu-magnetic",
            "notes": ("Indoor Location Competition 2.0 walk; ground truth = surveyed waypoints only"
                      + ("" if labelled else f"; {len(wp_t)} waypoint(s), fewer than two: unlabelled")),
            "receiver_brand": brand, "android": h.get("AndroidName", ""),
            "site_id": h.get("SiteID", ""), "floor_id": h.get("FloorId", ""), "path_id": stem,
            "start_unix_ms": int(t0), "sensor_time_offset_s": offset_ms / 1000.0,
            "records": {k: int(v) for k, v in sorted((w.counts + w.ignored + w.unknown).items())}}
    if not labelled and len(wp_t):
        meta["waypoints"] = [[float(a), float(b), float(c)] for a, (b, c) in zip(sec(wp_t), wp_xy)]
    return sid, meta

# --------------------------------------------------------------------------------------------------
# floor plans


def _floor_level(name: str, floor_num) -> int:
    m = re.fullmatch(r"(?:F|L)(\d+)|(\d+)F", name, flags=re.I)
    if m:
        return int(m.group(1) or m.group(2)) - 1
    m = re.fullmatch(r"B(\d+)|(\d+)B", name, flags=re.I)
    if m:
        return -int(m.group(1) or m.group(2))
    try:
        return int(floor_num) - 1
    except (TypeError, ValueError):
        return 0


def _json(display: str, data: bytes):
    try:
        return json.loads(data.decode("utf-8-sig"))
    except UnicodeDecodeError as exc:
        raise ImportError_(display, data[: exc.start].count(b"\n") + 1, f"not UTF-8 text ({exc.reason})") from None
    except json.JSONDecodeError as exc:
        raise ImportError_(display, exc.lineno, f"not valid JSON ({exc.msg})") from None
    except RecursionError:
        raise ImportError_(display, None, "JSON nested too deeply") from None


@dataclass
class _Plan:
    occupancy: np.ndarray
    outline: shapely.Geometry
    units: list                     # (id, name, geometry in metres)
    width: float
    height: float
    lonlat_box: tuple[float, float, float, float]
    scale_ratio: tuple[float, float]
    floor_num: object


def _polygons(g) -> list[Polygon]:
    if isinstance(g, Polygon):
        return [g]
    if isinstance(g, MultiPolygon):
        return list(g.geoms)
    if hasattr(g, "geoms"):
        return [p for x in g.geoms for p in _polygons(x)]
    return []


def _read_plan(info_display: str, info_data: bytes, geo_display: str, geo_data: bytes, floor: str,
               report: ImportReport) -> _Plan:
    """The floor plan of one floor from its floor_info.json (size in m) and geojson_map.json (outline and
    unit polygons in longitude/latitude): units in metres of the upstream floor frame and the occupancy
    raster at RESOLUTION_M m/px."""
    width, height = _plan_size(info_display, info_data)
    geoms, props, k = _plan_features(geo_display, geo_data)
    outline_ll = geoms[k]
    lon0, lat0, lon1, lat1 = outline_ll.bounds
    if not (lon1 > lon0 and lat1 > lat0):
        raise ImportError_(geo_display, None, f"features[{k}]: the floor outline has an empty bounding box")

    def to_m(g):
        return shapely.transform(g, lambda c: np.column_stack([(c[:, 0] - lon0) / (lon1 - lon0) * width,
                                                               (c[:, 1] - lat0) / (lat1 - lat0) * height]))

    outline = shapely.make_valid(to_m(outline_ll))
    lat_mid = math.radians((lat0 + lat1) / 2)
    scale = (width / ((lon1 - lon0) * M_PER_DEG_LON * math.cos(lat_mid)), height / ((lat1 - lat0) * M_PER_DEG_LAT))
    units = _plan_units(geoms, props, k, to_m, floor, report)
    occ = _plan_occupancy(outline, units, width, height)
    return _Plan(occ, outline, units, width, height, (lon0, lat0, lon1, lat1), scale,
                 props[k].get("floor_num"))


def _plan_size(info_display: str, info_data: bytes) -> tuple[float, float]:
    """(width, height) m of a floor from floor_info.json ``map_info``, each in (0, 2000]."""
    info = _json(info_display, info_data)
    try:
        width = float(info["map_info"]["width"])
        height = float(info["map_info"]["height"])
    except (KeyError, TypeError, ValueError):
        raise ImportError_(info_display, None, "expected {'map_info': {'width': metres, 'height': metres}}") from None
    if not (math.isfinite(width) and math.isfinite(height) and 0 < width <= 2000 and 0 < height <= 2000):
        raise ImportError_(info_display, None, f"map_info width {width:g} x height {height:g} m is not a floor size")
    return width, height


def _plan_features(geo_display: str, geo_data: bytes) -> tuple[list, list[dict], int]:
    """(geometries (F,) in longitude/latitude, properties (F,), index of the floor outline: the first feature of
    type "floor", else 0) of a geojson_map.json FeatureCollection; every coordinate finite."""
    doc = _json(geo_display, geo_data)
    feats = doc.get("features") if isinstance(doc, dict) else None
    if not isinstance(feats, list) or not feats:
        raise ImportError_(geo_display, None, "expected a GeoJSON FeatureCollection with the floor outline first")
    geoms = []
    for i, f in enumerate(feats):
        try:
            g = shape(f["geometry"])
        except Exception as exc:  # shapely raises several types for malformed coordinates
            raise ImportError_(geo_display, None, f"features[{i}]: malformed geometry ({exc})") from None
        if not np.isfinite(shapely.get_coordinates(g)).all():
            raise ImportError_(geo_display, None, f"features[{i}]: a coordinate is not a finite number")
        geoms.append(g)
    props = [f.get("properties") or {} for f in feats]
    k = next((i for i, p in enumerate(props) if p.get("type") == "floor"), 0)
    return geoms, props, k


def _plan_units(geoms: list, props: list[dict], k: int, to_m, floor: str, report: ImportReport) -> list:
    """The unit polygons (id, name, geometry in m) of a floor: every feature but the outline ``k``, mapped by
    ``to_m`` (longitude/latitude -> m), repaired when invalid; non-polygons and empty ones dropped (counted in
    ``report``). Ids are the features' ``id`` (else ``<floor>-unit<i>``), made unique with trailing '_'."""
    units, used_ids = [], set()
    for i, (g, p) in enumerate(zip(geoms, props)):
        if i == k:
            continue
        polys = _polygons(g)
        if not polys:
            report.drop(f"GeoJSON features that are not polygons (floor {floor})")
            continue
        gm = to_m(g)
        if not gm.is_valid:
            gm = shapely.make_valid(gm)
            report.drop(f"unit polygons repaired with make_valid (floor {floor})")
            parts = _polygons(gm)
            gm = parts[0] if len(parts) == 1 else MultiPolygon(parts) if parts else None
        if gm is None or gm.is_empty or gm.area <= 0:
            report.drop(f"empty unit polygons (floor {floor})")
            continue
        uid = str(p.get("id") or f"{floor}-unit{i}")
        while uid in used_ids:
            uid += "_"
        used_ids.add(uid)
        units.append((uid, str(p.get("name") or p.get("display") or ""), gm))
    return units


def _plan_occupancy(outline, units: list, width: float, height: float) -> np.ndarray:
    """Occupancy (H, W) int8 at RESOLUTION_M m/px (row 0 at the top) of a ``width`` x ``height`` m floor:
    FREE inside the outline (m) and outside every unit, UNKNOWN inside a unit, OCCUPIED outside the outline."""
    # rasterise: pixel centre (col + 0.5, row + 0.5) in PIL coordinates -> integer PIL coordinates
    w_px, h_px = int(math.ceil(width / RESOLUTION_M - 1e-9)), int(math.ceil(height / RESOLUTION_M - 1e-9))
    inside = _raster(_polygons(outline), True, w_px, h_px)
    in_unit = _raster([p for _, _, g in units for p in _polygons(g)], False, w_px, h_px)
    return np.where(inside, np.where(in_unit, UNKNOWN, FREE), OCCUPIED).astype(np.int8)


def _ring_px(ring, h_px: int) -> list[tuple[float, float]]:
    """A ring's vertices (m) as PIL pixel coordinates (x right, y down) of an image ``h_px`` pixels high."""
    c = np.asarray(ring.coords)
    px = c[:, 0] / RESOLUTION_M - 0.5
    py = h_px - c[:, 1] / RESOLUTION_M - 0.5
    return list(zip(px.tolist(), py.tolist()))


def _raster(polys: list[Polygon], holes: bool, w_px: int, h_px: int) -> np.ndarray:
    """(h_px, w_px) bool: pixels inside one of ``polys`` (m), minus their interior rings when ``holes``."""
    im = Image.new("1", (w_px, h_px), 0)
    d = ImageDraw.Draw(im)
    for poly in polys:
        d.polygon(_ring_px(poly.exterior, h_px), fill=1)
        if holes:
            for r in poly.interiors:
                d.polygon(_ring_px(r, h_px), fill=0)
    return np.asarray(im, dtype=bool)

# --------------------------------------------------------------------------------------------------
# the import


def _floor_list(floors) -> list[tuple[str, str]] | None:
    if floors is None:
        return None
    items = floors.split(",") if isinstance(floors, str) else list(floors)
    out = []
    for it in items:
        it = str(it).strip().strip("/")
        if not it:
            continue
        site, sep, fl = it.partition("/")
        if not sep or not site or not fl or "/" in fl:
            raise ImportError_("--floors", None, f"{it!r} is not SITE/FLOOR (e.g. site1/F1)")
        out.append((site, fl))
    return out


def import_ilc20(src: Path, out: Path, floors=None, beacon_id: str = "mac") -> ImportReport:
    """Convert the ILC 2.0 / challenge recordings at ``src`` (folder or archive) into dataset ``out``.

    ``floors``: ``"site1/F1,site1/F2"`` or a list of such names (default: every floor found). ``beacon_id``:
    ``"mac"`` (``UUID:major:minor:MAC``, default) or ``"triple"`` (``UUID:major:minor``). See the module doc.
    """
    src, out = Path(src), Path(out)
    if beacon_id not in ("mac", "triple"):
        raise ValueError(f"beacon_id must be 'mac' or 'triple', got {beacon_id!r}")
    if not src.exists():
        raise ImportError_(src, None, "source does not exist")
    check_out(out)
    selected = _floor_list(floors)
    sel = set(selected) if selected is not None else None
    seen_floors: set[tuple[str, str]] = set()

    def want(vpath: str) -> bool:
        c = _classify(vpath)
        if c is None:
            return False
        seen_floors.add(c[1])
        return sel is None or c[1] in sel

    tmp = out.parent / f".{out.name}.partial-{os.getpid()}"
    if tmp.exists():
        shutil.rmtree(tmp)
    report = ImportReport(out=out)
    try:
        _import(src, tmp, want, sel, seen_floors, beacon_id, report)
        if out.exists():
            out.rmdir()  # empty (check_out refused a dataset); a non-empty folder raises OSError
        os.replace(tmp, out)
    except OSError as exc:
        shutil.rmtree(tmp, ignore_errors=True)
        raise ImportError_(out, None, f"cannot write the dataset here ({exc})") from None
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    report.out = out
    validate_or_raise(out, report)
    return report


def _import(src: Path, tmp: Path, want, sel, seen_floors, beacon_id: str, report: ImportReport) -> None:
    """Write the selected walks, one building per site and dataset.yaml into ``tmp``."""
    got = _import_walks(src, tmp, want, beacon_id, report)
    if sel is not None:
        missing = sorted(sel - set(got.acc))
        if missing:
            found = ", ".join(f"{s}/{f}" for s, f in sorted(seen_floors)) or "none"
            raise ImportError_(src, None, f"--floors names {', '.join(f'{s}/{f}' for s, f in missing)}, not found "
                               f"with walks in the source (floors found: {found})")
    if not got.acc:
        raise ImportError_(src, None, "no path files found: expected <site>/<floor>/path_data_files/*.txt or "
                           "train/<site>/<floor>/*.txt (in a folder, .tar.gz or .zip)")

    by_site: dict[str, list[str]] = defaultdict(list)
    for site, floor in sorted(got.acc):
        by_site[site].append(floor)
    for site, floor_names in by_site.items():
        _write_site(src, tmp, site, floor_names, got, report)
    report.notes.append(f"{got.labelled} of {report.sessions} sessions labelled (>= 2 waypoints)")
    report.notes += [f"{n} {what}" for what, n in sorted(got.events.items())]
    write_dataset_meta(
        tmp, "ilc20", "Indoor Location Competition 2.0 walks: IMU, magnetometer, rotation vector, WiFi and iBeacon "
        "RSSI, surveyed waypoints, floor plans (beacon and AP positions not given)", "MIT",
        "XYZ10, Inc., location-competition/indoor-location-competition-20 (data/); same format as the 2021 Indoor "
        "Location & Navigation challenge", importer="blenav.importers.ilc20", source_path=str(src),
        beacon_id="UUID:major:minor:MAC" if beacon_id == "mac" else "UUID:major:minor")


@dataclass
class _WalkPass:
    """What the pass over the source's walks gathered for the buildings."""

    meta_files: dict            # ((site, floor), "floor_info" | "geojson_map") -> (display name, bytes)
    acc: dict                   # (site, floor) -> _FloorAcc, floors with at least one written session
    beacons: dict               # anchor id -> what was heard (see _beacon_stream)
    bssids: dict                # site -> set of BSSIDs heard
    pending_gt: dict            # (site, floor) -> [(session id, groundtruth columns)], written by _write_site
    events: Counter             # walk-level events -> count
    labelled: int               # sessions with >= 2 waypoints


def _import_walks(src: Path, tmp: Path, want, beacon_id: str, report: ImportReport) -> _WalkPass:
    """One pass over the source: every selected walk converted and written as a session into ``tmp``, the
    floors' metadata files kept for the buildings."""
    meta_files: dict[tuple[tuple[str, str], str], tuple[str, bytes]] = {}
    acc: dict[tuple[str, str], _FloorAcc] = defaultdict(_FloorAcc)
    beacons: dict[str, dict] = {}
    bssids: dict[str, set] = defaultdict(set)
    sessions: set[str] = set()
    pending_gt: dict[tuple[str, str], list] = defaultdict(list)
    events: Counter = Counter()
    labelled = 0
    for e in _iter_source(src, want, report):
        kind, key, name = _classify(e.vpath)
        if kind == "meta":
            meta_files[(key, name)] = (e.display, e.data)
            continue
        site, floor = key
        sid, meta, streams, wp_xy, header = _convert_walk(e.display, e.data, site, floor, name, beacon_id, report,
                                                          events, beacons, bssids[site])
        if sid in sessions:
            raise ImportError_(e.display, None, f"a second walk with session id {sid!r} (the same path file twice?)")
        if not streams:
            events["walks without any data row (no session written)"] += 1
            continue
        sessions.add(sid)
        if "groundtruth" in streams:  # written once the floor's z is known (the GeoJSON may come later)
            pending_gt[key].append((sid, streams.pop("groundtruth")))
        _write_streams(tmp, sid, meta, streams)
        report.sessions += 1
        labelled += bool(meta["labelled"])
        a = acc[key]
        a.walks += 1
        if len(wp_xy):
            a.waypoints.append(wp_xy)
        a.site_name = a.site_name or header.get("SiteName", "")
        a.site_id = a.site_id or header.get("SiteID", "")
        a.floor_id = a.floor_id or header.get("FloorId", "")
    return _WalkPass(meta_files, acc, beacons, bssids, pending_gt, events, labelled)


def _write_site(src: Path, tmp: Path, site: str, floor_names: list[str], w: _WalkPass, report: ImportReport) -> None:
    """building.yaml, floor images, rooms and anchors of one site into ``tmp``: its floors' plans (in the
    upstream floor frames; ``floor_frames`` relates them to the first floor's), the waypoints' alignment with
    each plan, and its BLE anchors (positions unknown)."""
    floors, rooms, frames, alignment = [], [], {}, {}
    ref = None
    for floor in floor_names:
        key = (site, floor)
        info = w.meta_files.get((key, "floor_info"))
        geo = w.meta_files.get((key, "geojson_map"))
        if info is None or geo is None:
            lack = " and ".join(n for n, v in (("floor_info.json", info), ("geojson_map.json", geo)) if v is None)
            raise ImportError_(src, None, f"floor {site}/{floor} has walks but no {lack} (repository layout: "
                               f"beside path_data_files/; challenge layout: metadata/{site}/{floor}/)")
        plan = _read_plan(*info, *geo, floor, report)
        level = _floor_level(floor, plan.floor_num)
        z = level * FLOOR_HEIGHT_M
        _write_groundtruth(tmp, w.pending_gt.get(key, []), z)
        floors.append({"id": floor, "occupancy": plan.occupancy, "resolution": RESOLUTION_M, "origin": (0.0, 0.0),
                       "z": z, "filename": f"floor_{floor}.png"})
        rooms += [{"id": uid, "floor": floor, "geometry": g, "properties": {"name": nm}}
                  for uid, nm, g in plan.units]
        if ref is None:
            ref = plan
        frames[floor] = _floor_frame(plan, ref)
        alignment[floor] = _floor_alignment(plan, w.acc[key], f"{site}/{floor}", report)
    rows = _site_anchor_rows(w.beacons, floor_names)
    anchors = pd.DataFrame(rows) if rows else None
    a0 = w.acc[(site, floor_names[0])]
    write_building(tmp, site, a0.site_name or site, floors, anchors, rooms=rooms,
                   site_id=a0.site_id, floor_frames=frames, alignment=alignment,
                   floor_plan=(f"rasterised from geojson_map.json at {RESOLUTION_M} m/px: walkable = inside the "
                               "floor outline and outside every unit polygon; each floor in its upstream frame "
                               "(outline bounding box -> [0, width] x [0, height] m)"),
                   assumptions=[f"floor z = level x {FLOOR_HEIGHT_M} m", f"phone height {PHONE_HEIGHT_M} m",
                                "anchor positions unknown"])
    report.buildings += 1
    report.notes.append(f"site {site}: {len(rows)} BLE anchors (position unknown), {len(w.bssids[site])} WiFi "
                        "access points (BSSIDs) heard")


def _floor_frame(plan: _Plan, ref: _Plan) -> dict:
    """building.yaml ``floor_frames`` entry of a floor: its outline's lon/lat bounding box, size (m), the shift
    (m) of its origin in the frame of the site's first floor ``ref``, and floor_info / geodesic size ratios."""
    lon0, lat0, lon1, lat1 = plan.lonlat_box
    r0 = ref.lonlat_box
    shift = ((lon0 - r0[0]) / (r0[2] - r0[0]) * ref.width, (lat0 - r0[1]) / (r0[3] - r0[1]) * ref.height)
    return {"lonlat_bbox": [lon0, lat0, lon1, lat1], "size_m": [plan.width, plan.height],
            "origin_shift_m": [round(shift[0], 3), round(shift[1], 3)],
            "scale_vs_geodesic": [round(plan.scale_ratio[0], 4), round(plan.scale_ratio[1], 4)]}


def _floor_alignment(plan: _Plan, fa: _FloorAcc, name: str, report: ImportReport) -> dict:
    """building.yaml ``alignment`` entry of floor ``name`` (SITE/FLOOR): how its walks' waypoints (m) sit on the
    plan (shares inside the outline, on walkable cells, inside a unit; walks mostly off walkable cells), also
    written as a report note."""
    wps = np.vstack(fa.waypoints) if fa.waypoints else np.empty((0, 2))
    n = len(wps)
    in_outline = float(shapely.contains_xy(plan.outline, wps[:, 0], wps[:, 1]).mean()) if n else float("nan")
    on_free = float((grid_lookup(plan.occupancy, (0.0, 0.0), wps, RESOLUTION_M, OCCUPIED) == FREE).mean()) \
        if n else float("nan")
    if n and plan.units:
        u = shapely.union_all([g for _, _, g in plan.units])
        in_unit = float(shapely.contains_xy(u, wps[:, 0], wps[:, 1]).mean())
    else:
        in_unit = float("nan") if not n else 0.0
    # walks whose waypoints lie mostly off walkable cells (inside shops, or a misaligned plan)
    off = sum(float(np.mean(grid_lookup(plan.occupancy, (0.0, 0.0), w_, RESOLUTION_M, OCCUPIED) != FREE)) > 0.5
              for w_ in fa.waypoints)
    report.notes.append(
        f"floor {name}: {fa.walks} walks, {n} waypoints: {in_outline:.1%} inside the outline, "
        f"{on_free:.1%} on walkable cells, {in_unit:.1%} inside a unit ({off} walks with most waypoints off "
        f"walkable cells); plan {plan.width:.1f} x "
        f"{plan.height:.1f} m, floor_info / geodesic size x {plan.scale_ratio[0]:.3f}, "
        f"y {plan.scale_ratio[1]:.3f}; {len(plan.units)} units")
    return {"waypoints": n, "walks": fa.walks, "inside_outline": round(in_outline, 4),
            "on_walkable": round(on_free, 4), "inside_unit": round(in_unit, 4),
            "walks_mostly_off_walkable": int(off),
            "free_share_of_plan": round(float((plan.occupancy == FREE).mean()), 4)}


def _site_anchor_rows(beacons: dict, floor_names: list[str]) -> list[dict]:
    """anchors.csv rows of the iBeacons heard on the site's floors, by anchor id: position unknown (NaN),
    floor = where heard most, tx power = the median advertised (NaN when outside (-150, 0) dBm)."""
    site_b = {k: v for k, v in beacons.items() if any(f in floor_names for f in v["floors"])}
    rows = []
    for aid, b in sorted(site_b.items()):
        tx = np.asarray(b["tx"], dtype=float)
        med = float(np.median(tx)) if len(tx) else float("nan")
        fl = b["floors"].most_common(1)[0][0]
        rows.append({"anchor_id": aid, "kind": "ble", "x": np.nan, "y": np.nan, "z": np.nan, "floor": fl,
                     "tx_power_dbm": med if rssi_in_range(np.array([med]))[0] else np.nan,
                     "channel_model": "iBeacon; position unknown (not in the ILC data)",
                     "uuid": b["uuid"], "major": b["major"], "minor": b["minor"], "mac": b["mac"],
                     "n_rows": int(sum(b["floors"].values())),
                     "floors_heard": ";".join(sorted(b["floors"]))})
    return rows


def _write_groundtruth(root: Path, pending: list, floor_z: float) -> None:
    """groundtruth.csv of a floor's sessions, written once: ``pending`` [(session id, columns)] from the walk pass
    (z left None there: the floor's level may come from its GeoJSON, read later); z = ``floor_z`` (m) +
    ``PHONE_HEIGHT_M``."""
    for sid, cols in pending:
        cols = {**cols, "z": _num_text(np.full(len(cols["t"]), floor_z + PHONE_HEIGHT_M), 3)}
        _write_stream(root, sid, "groundtruth", cols)
