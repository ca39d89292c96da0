"""Import the Kolakowski BLE RSS radio-map-calibration dataset into dataset format v1.

Source: M. Kolakowski, "BLE RSS dataset for fingerprinting radio map calibration", Zenodo
10.5281/zenodo.5457591 (github marckolak/ble-rss-fingerprints-calib2021, CC BY 4.0), as copied in
``SOURCE.txt`` beside the raw files. The local README names a ``dataset_description`` file that was not
copied; the facts marked *(upstream)* below come from that description
(``description/dataset_description.tex``) and the authors' loader ``src/load_files.py`` in the same
repository, read for this importer. Raw layout (``src`` is the folder holding it)::

    anchors.csv                      id,x,y,z              the 6 fixed anchors (m)
    layout.csv                       x,y                   wall polygon of the flat (m), closed ring
    tests/test_robot_ble.txt         tab-separated system log, one line per anchor report (below)
    tests/test_walk_ble.txt          idem, walking person
    tests/test_robot_df.csv          ,ts,x,heading,y,rssi_1..rssi_6   preprocessed robot test (3 rows/s)
    tests/test_walk_df.csv           ,ts,rssi_1..rssi_6               preprocessed walk test
    tests/path_reference.csv         x0,y0,x1,y1           segments of the walked reference path
    tests/test_robot_motion.txt      unix s, command, 0.15 teleoperation commands of the robot
    calibration/calibration_df.csv   ,ts,x,heading,y,rssi_1..rssi_6   4 robot calibration runs
    calibration/calib_df.csv         ,ts,x,y,rssi_3,rssi_4,rssi_5,rssi_8,rssi_10,rssi_11

Geometry is reversed with respect to the format's phone picture: a mobile BLE **tag transmits** (5
packets/s on the 3 advertising channels *(upstream)*) and the 6 **fixed anchors receive**, each with two
Laird BL652 modules of perpendicular polarisation *(upstream)*. The anchors are written as anchors and
the tag as the session's device (the link is reciprocal to first order). The tag rides at 1.3 m on a
pole in the middle of the robot *(upstream)*; the same tag was worn by the walking person.

Anchor ids
----------
The system logs and ``calib_df.csv`` name anchors by system id 3, 4, 5, 8, 10, 11; ``anchors.csv`` and
the other ``*_df.csv`` files use 1..6. The mapping is by sorted order (3->1, 4->2, 5->3, 8->4, 10->5,
11->6), checked on this copy: the per-second mean RSSI of system id *s* in ``test_*_ble.txt``
correlates best with column ``rssi_<map(s)>`` of the matching ``*_df.csv`` (r = 0.83..0.95; the check is
repeated on every import and its result is in the report notes). ``anchor_id`` is the ``anchors.csv``
id (``"1"``..``"6"``); extra column ``system_id`` keeps the log id.

System log format *(upstream loader)*
-------------------------------------
Tab-separated: ``ts`` (unix ms, arrival at the server), anchor system id, anchor sequence number,
declared payload length, pressure, ``b`` = number of BLE packets, ``u`` = number of UWB packets, then
``b`` groups of 8 (module 1/2, tag id, tag BLE counter, RSSI dBm, pressure, voltage, steps, alert) and
``u`` groups of 4 (UWB, ignored). A line whose field count is not ``7 + 8 b + 4 u`` is malformed. A
line whose declared length is shorter than ``12 b + 8 u + 19`` is a faulty frame that the authors'
loader skips: its packets are dropped and counted. RSSI 0 means "not received" (the loader turns it
into NaN): no row, counted.

What is written
---------------
* One building ``kolakowski_flat``, floor ``0``; ``anchors.csv`` from ``anchors.csv``;
  ``navgraph.geojson`` holds the walked reference path of ``tests/path_reference.csv`` as one
  MultiLineString ``test_walk_reference_path`` of its 8 segments (not one LineString: the 6th segment,
  (3.24, 0.9) -> (4.81, 0.9), is a spur, and the 7th starts again at (3.24, 0.9)).
* ``test_robot`` (robot, labelled): ``rssi.csv`` = one row per BLE packet per receiving module from
  ``test_robot_ble.txt`` (extra columns ``module`` 1/2, ``system_id``, ``tag_counter`` = the tag's BLE
  counter of the packet, ``raw_line``); ``groundtruth.csv``
  = the rows of ``test_robot_df.csv`` (x, y of the robot from the authors' LiDAR SLAM, z = 1.3 m tag
  height, orientation empty, extra column ``heading``). The session clock starts at the first
  ground-truth time; packets before the first or after the last ground-truth time are dropped and
  counted (the robot was already turning 13 s before the first pose, and ground truth is not
  extrapolated). The df's own RSSI columns are not used (they are 1/3 s log-means of the same packets).
* ``test_walk`` (pedestrian, **unlabelled**): ``rssi.csv`` from ``test_walk_ble.txt`` as above. The
  README does not say the reference path is time-aligned to the walk (the path has no times at all),
  so no ground truth is interpolated; the path is in ``navgraph.geojson``.
* ``calibration_run1`` .. ``calibration_run4`` (robot, labelled): ``calibration_df.csv`` holds four
  runs one after the other (its unnamed index restarts and the time jumps by 22-87 min at each
  boundary; split there). They are not static fingerprints at reference points: the robot keeps
  moving with stops (speed between consecutive rows: median 0.07 m/s, 75th percentile 0.38 m/s) and
  each row is the SLAM pose at that time, so they are labelled robot sessions, not ``static`` ones. ``rssi.csv`` = one row per non-empty
  ``rssi_k`` cell (an empty cell = not received: no row, counted); these values are the authors'
  1/3 s log-mean over both modules and all packets in the bin, *not* single packets. ``groundtruth.csv``
  = every row (x, y, z = 1.3 m, ``heading``).
* ``calib_df_unaligned`` (robot, **unlabelled**): ``calib_df.csv`` is an earlier run (2021-06-30; the
  rest is 2021-08-03) whose x, y are in another SLAM frame (x in [-7.3, 0.4] m): a rigid 180 deg
  rotation plus a shift puts all of it inside the flat, but the shift is not determined to better than
  about 0.25 m, so it is not ground truth. Its positions minus the first position are written as
  ``odometry.csv`` (arbitrary frame fixed at the start; only differences meaningful), its RSSI cells
  (system ids, mapped) as ``rssi.csv``.
* Not imported: ``test_robot_motion.txt`` is a teleoperation command log (forward/reverse/left/right/
  stop with a constant 0.15), not odometry (commanded durations x 0.15 do not match the SLAM
  displacement, and the turn rate is not given); ``test_walk_df.csv`` (derived from the walk log).

Units, clock and frames
-----------------------
* World frame: the frame of ``layout.csv``/``anchors.csv`` (metres, flat from (0, 0) to (9.07, 7.1)),
  used unchanged; assumed right-handed with z up (the SLAM ``heading`` is counter-clockwise from +x:
  turning "right" decreases it). Its compass alignment is unknown.
* ``heading`` (rad, unwrapped, CCW from +x) is the SLAM frame's heading of the robot. The robot's
  forward motion points along ``heading + pi`` (median error 0.05-0.1 rad on both robot files), so it is
  the LiDAR's axis, not the driving direction. It is not turned into a quaternion: the tag's own
  orientation is unknown.
* ``*_df.csv`` ``ts`` is unix time in **nanoseconds** (float). The authors' preprocessing rounds arrival
  times to whole seconds and spreads packets over 1/3 s bins, so df times (and thus ground-truth times)
  match the packet arrival times of the logs to within about 1 s.
* ``*_ble.txt`` ``ts`` is unix time in **milliseconds** of arrival at the server (packets of one report
  share it). A few lines (5 in the robot log, 1 in the walk log) are 1 ms earlier than the line
  before; packets are stably sorted by time.
* Each session's ``t`` is seconds since its first row (``test_robot``: first ground-truth row).
* RSSI: dBm. Outside (-150, 0) dBm -> dropped and counted (none in this copy).

Floor plan
----------
``layout.csv`` is one closed ring tracing the inner wall surfaces; interior walls (11-17 cm thick)
appear as narrow notches. It is rasterised at ``RESOLUTION_M`` = 0.05 m: a pixel whose centre is inside
the polygon is FREE; outside the polygon and within ``WALL_M`` = 0.15 m of its boundary OCCUPIED (so
interior walls are solid and outer walls are 15 cm thick); further outside UNKNOWN (not part of the
flat). The image is padded by ``PAD_M``. The fraction of ground-truth positions in FREE pixels is in the
report notes.

Bad input
---------
A line with a wrong field count, a non-numeric, non-integer (log) or non-finite value, an empty
required cell, a wrong header, a df time going backwards, an anchor id missing from ``anchors.csv``, an
invalid layout polygon or a zero-length path segment raise :class:`~blenav.errors.ImportError_`
naming the file and the 1-based line. Nothing is written before all input has been read.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd
import shapely
from shapely.geometry import MultiLineString, Polygon

from blenav.data import FREE, OCCUPIED, UNKNOWN
from blenav.data.building import Building
from blenav.data.writer import write_building, write_dataset_meta, write_session

from . import ImportReport
from ._common import check_out, grid_covering, pixel_centres, source_line, validate_or_raise
from .kolakowski_raw import (
    SYSTEM_IDS,
    Df,
    df_rssi,
    mapping_check,
    packet_rssi,
    read_anchors,
    read_df,
    read_layout,
    read_reference_path,
    read_system_log,
)

BUILDING_ID = "kolakowski_flat"
DEVICE_MODEL = "kolakowski-tag"
#: tag height on the robot's pole (m) (upstream description).
TAG_HEIGHT_M = 1.3
RESOLUTION_M = 0.05
WALL_M = 0.15
PAD_M = 0.3
#: a new calibration run starts where the df index does not increase or time jumps by more than this (s).
RUN_GAP_S = 60.0
CHANNEL_MODEL = ("fixed receiver (two Laird BL652 modules, perpendicular polarisations, averaged in the df files); "
                 "mobile tag transmits (reciprocal link)")
SOURCE_DEFAULT = "Kolakowski, BLE RSS dataset for fingerprinting radio map calibration, Zenodo 10.5281/zenodo.5457591"


# --------------------------------------------------------------------------------------------------
# floor


def rasterise(poly: Polygon) -> tuple[np.ndarray, tuple[float, float]]:
    """Occupancy (H, W) int8, row 0 on top, and the world origin of the lower-left pixel corner."""
    shape, origin = grid_covering(np.reshape(poly.bounds, (2, 2)), RESOLUTION_M, PAD_M)
    gx, gy = pixel_centres(shape, origin, RESOLUTION_M)
    inside = shapely.contains_xy(poly, gx, gy)
    near = shapely.distance(poly.boundary, shapely.points(gx, gy)) <= WALL_M
    occ = np.full(shape, UNKNOWN, dtype=np.int8)
    occ[near & ~inside] = OCCUPIED
    occ[inside] = FREE
    return occ, origin


# --------------------------------------------------------------------------------------------------
# import


def _gt(df: Df, sel: np.ndarray, t0: float) -> pd.DataFrame:
    return pd.DataFrame({"t": df.t_s[sel] - t0, "x": df.cols["x"][sel], "y": df.cols["y"][sel], "z": TAG_HEIGHT_M,
                         "qw": np.nan, "qx": np.nan, "qy": np.nan, "qz": np.nan,
                         "heading": df.cols["heading"][sel], "raw_line": df.lines[sel]})


@dataclass
class _Raw:
    """Every raw input of the import, read and checked (nothing written yet)."""

    anchors: pd.DataFrame        # anchor_id "1".."6", x, y, z (m), system_id
    poly: Polygon                # wall polygon of the flat (m)
    ref_path: MultiLineString    # walked reference path (m)
    robot_pk: pd.DataFrame       # packets of tests/test_robot_ble.txt (see read_system_log)
    walk_pk: pd.DataFrame        # packets of tests/test_walk_ble.txt
    robot_df: Df
    walk_df: Df
    calib: Df                   # calibration/calibration_df.csv (four runs)
    old: Df                     # calibration/calib_df.csv (unaligned frame)


def _read_raw(src: Path, report: ImportReport) -> _Raw:
    """Read all raw files of ``src``; packets dropped while reading the logs are counted in ``report``."""
    return _Raw(
        anchors=read_anchors(src / "anchors.csv"),
        poly=read_layout(src / "layout.csv"),
        ref_path=read_reference_path(src / "tests" / "path_reference.csv"),
        robot_pk=read_system_log(src / "tests" / "test_robot_ble.txt", report),
        walk_pk=read_system_log(src / "tests" / "test_walk_ble.txt", report),
        robot_df=read_df(src / "tests" / "test_robot_df.csv", ("x", "heading", "y")),
        walk_df=read_df(src / "tests" / "test_walk_df.csv", ()),
        calib=read_df(src / "calibration" / "calibration_df.csv", ("x", "heading", "y")),
        old=read_df(src / "calibration" / "calib_df.csv", ("x", "y")),
    )


def _note_mapping_checks(raw: _Raw, report: ImportReport) -> None:
    """Check the system-id -> anchor-id mapping on both tests (see :func:`mapping_check`); note the result."""
    for name, pk, df in (("test_robot", raw.robot_pk, raw.robot_df), ("test_walk", raw.walk_pk, raw.walk_df)):
        ok, worst = mapping_check(pk, df)
        report.notes.append(f"anchor-id mapping {dict(zip(SYSTEM_IDS, range(1, 7)))} checked on {name}: "
                            + (f"every system id correlates best with its mapped df column (r >= {worst:.2f})" if ok
                               else f"WARNING: the mapping does not give the best correlation (smallest r "
                                    f"{worst:.2f})"))


#: a session to write: (id, meta without building/floor/device_model, streams by name)
_Session = tuple[str, dict, dict]


def _robot_test_session(pk: pd.DataFrame, df: Df, report: ImportReport) -> _Session:
    """``test_robot``: packets within the ground-truth time span (t in s since the first ground-truth row)."""
    t0, t1 = df.t_s[0], df.t_s[-1]
    tt = pk["t_s"].to_numpy()
    inside = (tt >= t0) & (tt <= t1)
    report.drop("BLE packets of test_robot_ble.txt outside the ground-truth time span", int((~inside).sum()))
    gt = _gt(df, np.arange(len(df.t_s)), t0)
    gaps = np.diff(df.t_s)
    return ("test_robot", {
        "carrier": "robot", "labelled": True,
        "notes": (f"Kolakowski robot test: rssi = single BLE packets per receiving module from "
                  f"tests/test_robot_ble.txt "
                  f"(t = arrival unix ms / 1000 - first ground-truth time {t0:.3f}); ground truth = LiDAR-SLAM robot "
                  f"positions of tests/test_robot_df.csv (z = tag height 1.3 m; heading = SLAM heading, forward "
                  f"motion is heading + pi); ground-truth times are the authors' 1/3 s bins (about 1 s accuracy); "
                  f"largest ground-truth gap {gaps.max():.1f} s. {int((~inside).sum())} packets outside the "
                  f"ground-truth span dropped. No IMU."),
        "source_file": "tests/test_robot_ble.txt, tests/test_robot_df.csv"},
        {"rssi": packet_rssi(pk[inside], t0), "groundtruth": gt})


def _walk_test_session(pk: pd.DataFrame) -> _Session:
    """``test_walk``: packets only, no time-aligned ground truth (t in s since the first packet)."""
    w0 = float(pk["t_s"].min())
    return ("test_walk", {
        "carrier": "pedestrian", "labelled": False,
        "notes": (f"Kolakowski walk test: rssi = single BLE packets per receiving module from tests/test_walk_ble.txt "
                  f"(t = arrival unix ms / 1000 - {w0:.3f}). The walked path is the MultiLineString "
                  f"'test_walk_reference_path' in the building's navgraph.geojson (tests/path_reference.csv); it has "
                  f"no times, so there is no ground truth. No IMU."),
        "source_file": "tests/test_walk_ble.txt"},
        {"rssi": packet_rssi(pk, w0)})


def _calibration_sessions(calib: Df, report: ImportReport) -> list[_Session]:
    """``calibration_run1``..: ``calibration_df.csv`` split where its index restarts or time jumps (RUN_GAP_S)."""
    new_run = np.r_[True, (np.diff(calib.index) <= 0) | (np.diff(calib.t_s) > RUN_GAP_S)]
    run = np.cumsum(new_run)
    sessions = []
    for k in range(1, int(run.max()) + 1):
        sel = np.flatnonzero(run == k)
        c0 = calib.t_s[sel[0]]
        sessions.append((f"calibration_run{k}", {
            "carrier": "robot", "labelled": True,
            "notes": (f"Kolakowski radio-map calibration run {k} of calibration/calibration_df.csv (lines "
                      f"{calib.lines[sel[0]]}..{calib.lines[sel[-1]]}): the robot drives continuously with stops; "
                      f"rssi = the authors' 1/3 s log-mean over both modules and all packets of each anchor (not "
                      f"single packets), empty cells (not received) have no row; ground truth = LiDAR-SLAM positions, "
                      f"z = tag height 1.3 m, heading = SLAM heading. t = ts (unix ns) / 1e9 - {c0:.3f}. No IMU."),
            "source_file": "calibration/calibration_df.csv"},
            {"rssi": df_rssi(calib, sel, c0, report, "calibration/calibration_df.csv"),
             "groundtruth": _gt(calib, sel, c0)}))
    return sessions


def _unaligned_session(old: Df, report: ImportReport) -> _Session:
    """``calib_df_unaligned``: positions (m) relative to the first one as odometry, not as ground truth."""
    sel = np.arange(len(old.t_s))
    o0 = old.t_s[0]
    odo = pd.DataFrame({"t": old.t_s - o0, "x": old.cols["x"] - old.cols["x"][0],
                        "y": old.cols["y"] - old.cols["y"][0], "raw_line": old.lines})
    return ("calib_df_unaligned", {
        "carrier": "robot", "labelled": False,
        "notes": ("Kolakowski calibration/calib_df.csv, an earlier run (2021-06-30) whose SLAM positions are in an "
                  "unaligned frame (about 180 deg rotated and shifted; the shift is not determined to better than "
                  "~0.25 m): written as odometry.csv (relative to the first position, only differences meaningful), "
                  "not as ground truth. rssi = 1/3 s log-means, columns rssi_<system id> mapped to anchors.csv ids. "
                  f"t = ts (unix ns) / 1e9 - {o0:.3f}. No IMU."),
        "source_file": "calibration/calib_df.csv"},
        {"rssi": df_rssi(old, sel, o0, report, "calibration/calib_df.csv"), "odometry": odo})


def _write(src: Path, out: Path, raw: _Raw, sessions: list[_Session], report: ImportReport) -> Path:
    """Write dataset meta, the building (rasterised layout, anchors, reference path) and every session.

    Returns the building root.
    """
    occ, origin = rasterise(raw.poly)
    write_dataset_meta(out, "kolakowski_ble_calib", "Kolakowski BLE RSS dataset for fingerprinting radio map "
                       "calibration: furnished flat, 6 fixed receivers, 1 mobile tag on a robot or a person",
                       "CC-BY-4.0", source_line(src, SOURCE_DEFAULT))
    anc = raw.anchors.assign(kind="ble", floor=0, tx_power_dbm=np.nan, channel_model=CHANNEL_MODEL)
    nav = [{"id": "test_walk_reference_path", "floor": 0, "geometry": raw.ref_path,
            "properties": {"source": "tests/path_reference.csv", "session": "test_walk"}}]
    broot = write_building(out, BUILDING_ID, "Kolakowski test flat", [{"id": 0, "occupancy": occ,
                           "resolution": RESOLUTION_M, "origin": origin, "z": 0.0}], anc, navgraph=nav,
                           source_layout="layout.csv")
    report.buildings = 1
    for sid, meta, streams in sessions:
        full = {"building": BUILDING_ID, "floor": 0, "device_model": DEVICE_MODEL, **meta}
        write_session(out, sid, full, streams)
        report.sessions += 1
        report.notes.append(f"{sid}: " + ", ".join(f"{len(df)} {name} rows" for name, df in streams.items()))
    return broot


def import_kolakowski_ble_calib(src: Path, out: Path) -> ImportReport:
    """Convert ``src`` (the raw folder described in the module docstring) to a dataset at ``out``."""
    src, out = Path(src), Path(out)
    check_out(out)
    report = ImportReport(out=out)

    raw = _read_raw(src, report)
    _note_mapping_checks(raw, report)
    sessions = [_robot_test_session(raw.robot_pk, raw.robot_df, report), _walk_test_session(raw.walk_pk),
                *_calibration_sessions(raw.calib, report), _unaligned_session(raw.old, report)]
    broot = _write(src, out, raw, sessions, report)

    xy = np.vstack([streams["groundtruth"][["x", "y"]].to_numpy() for _, _, streams in sessions
                    if "groundtruth" in streams])
    floor = Building.load(broot).floor(0)
    free = floor.is_free(xy)
    report.notes.append(f"ground truth in FREE pixels of the rasterised layout: {100 * free.mean():.1f}% "
                        f"({int(free.sum())} of {len(xy)} positions; inside the layout polygon: "
                        f"{100 * shapely.contains_xy(raw.poly, xy[:, 0], xy[:, 1]).mean():.1f}%)")
    report.notes.append("not imported: tests/test_robot_motion.txt (teleoperation commands, not odometry), "
                        "tests/test_walk_df.csv (derived from test_walk_ble.txt)")
    validate_or_raise(out, report)
    return report
