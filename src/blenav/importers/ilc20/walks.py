"""One ILC 2.0 path file -> one session: the walk's clock, its streams as columns of text cells (IMU,
magnetometer, orientation, iBeacon RSSI, WiFi, waypoints) and its session.yaml."""

from __future__ import annotations

import re
from collections import Counter

import numpy as np
import pandas as pd

from blenav.errors import ImportError_

from .. import ImportReport
from .._common import rssi_in_range
from .parse import Walk, floats, parse_lines, table
from .write import num_text

SENSOR_CLOCK_TOL_S = 10.0
WIFI_FREQ_MHZ = (2000.0, 8000.0)
_SESSION_ID_RE = re.compile(r"[^A-Za-z0-9_.-]+")


def _stable_sort(t: np.ndarray) -> np.ndarray:
    return np.argsort(t, kind="stable")


def _quote(v: np.ndarray) -> np.ndarray:
    """Text cells quoted as RFC 4180 wants where they hold a comma, a quote or a line end."""
    if not any(c in "".join(v) for c in ',"\r\n') and not any(x[:1].isspace() or x[-1:].isspace() for x in v):
        return v
    s = pd.Series(v, dtype=object).fillna("").astype(str)
    need = s.str.contains(r'[,"\r\n]|^\s|\s$', regex=True).to_numpy(dtype=bool)
    if need.any():
        s[need] = '"' + s[need].str.replace('"', '""') + '"'
    return s.to_numpy(dtype=object)


def convert_walk(display: str, data: bytes, site: str, floor: str, stem: str, beacon_id: str,
                 report: ImportReport, events: Counter, beacons: dict, bssids: set
                  ) -> tuple[str, dict, dict, np.ndarray, dict]:
    """Parse one path file; returns (session id, session.yaml, streams, waypoints (n, 2) m, header).

    ``beacons`` (anchor id -> what was heard) and ``bssids`` are updated; rows left out are counted in
    ``report.dropped``, walk-level events in ``events``."""
    w = parse_lines(display, data)
    for k in ("startTime", "endTime"):
        if k in w.header and not re.fullmatch(r"-?\d+", w.header[k]):
            raise ImportError_(display, w.start_line[k], f"header {k}: {w.header[k]!r} is not an integer (Unix ms)")
    _, acc_t, acc, acc_c = table(display, w, "TYPE_ACCELEROMETER", (0, 1, 2))
    _, gyr_t, gyr, gyr_c = table(display, w, "TYPE_GYROSCOPE", (0, 1, 2))
    _, mag_t, mag, mag_c = table(display, w, "TYPE_MAGNETIC_FIELD", (0, 1, 2))
    _, rot_t, rot, rot_c = table(display, w, "TYPE_ROTATION_VECTOR", (0, 1, 2))
    wp_l, wp_t, wp, _ = table(display, w, "TYPE_WAYPOINT", (0, 1))
    _, wf_t, wf, wf_c = table(display, w, "TYPE_WIFI", (2, 3))
    _, bc_t, bc, bc_c = table(display, w, "TYPE_BEACON", (1, 2, 3, 4))

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
        streams["groundtruth"] = {"t": sec(wp_t[o]), "x": num_text(wp_xy[:, 0], 6), "y": num_text(wp_xy[:, 1], 6),
                                  "z": None, "qw": empty,  # z: the floor's, known at run._write_site
                                  "qx": empty, "qy": empty, "qz": empty, "raw_line": num_text(wp_l[o], 0)}
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
    """The raw text (n,) of a numeric field (checked finite by :func:`~.parse.table`) of the rows ``order``
    (n,), written as read: no float formatting."""
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
                   **{c: num_text(np.interp(at, gt, g[:, k]), 7) for k, c in enumerate(("gx", "gy", "gz"))}}
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
    return {"t": sec(rot_t[o]), "qw": num_text(qw, 7), **{c: _raw(rot_c, o, k) for k, c in
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
    seen = floats(wf_c[6].to_numpy(dtype=object))[o]
    bssids.update(bssid)
    return {"t": sec(wf_t[o]), "bssid": bssid, "rssi_dbm": _raw(wf_c, o, 2),
            "freq_mhz": num_text(freq, 0), "ssid": _quote(wf_c[2].to_numpy(dtype=object)[o]),
            "t_seen": num_text((seen - t0) / 1000.0, 3)}


def _walk_meta(w: Walk, site: str, floor: str, stem: str, labelled: bool, wp_t: np.ndarray, wp_xy: np.ndarray,
               sec, t0: int, offset_ms: int) -> tuple[str, dict]:
    """(session id, session.yaml dict) of one walk; ``wp_t`` (n,) Unix ms and ``wp_xy`` (n, 2) m its waypoints
    in time order (kept in the yaml when fewer than two, i.e. unlabelled), t0 Unix ms its zero, offset_ms the
    shift applied to its sensor clock."""
    h = w.header
    brand, model = h.get("Brand", "").strip(), h.get("Model", "").strip()
    sid = _SESSION_ID_RE.sub("-", f"{site}_{floor}_{stem}")
    meta = {"building": site, "floor": floor, "device_model": f"{brand} {model}".strip() or "unknown",
            "carrier": "pedestrian", "labelled": labelled, "groundtruth_kind": "waypoints",
            "orientation_frame": "enu-magnetic", "gyro_calibrated": True,  # TYPE_GYROSCOPE: bias removed by Android
            "notes": ("Indoor Location Competition 2.0 walk; ground truth = surveyed waypoints only"
                      + ("" if labelled else f"; {len(wp_t)} waypoint(s), fewer than two: unlabelled")),
            "receiver_brand": brand, "android": h.get("AndroidName", ""),
            "site_id": h.get("SiteID", ""), "floor_id": h.get("FloorId", ""), "path_id": stem,
            "start_unix_ms": int(t0), "sensor_time_offset_s": offset_ms / 1000.0,
            "records": {k: int(v) for k, v in sorted((w.counts + w.ignored + w.unknown).items())}}
    if not labelled and len(wp_t):
        meta["waypoints"] = [[float(a), float(b), float(c)] for a, (b, c) in zip(sec(wp_t), wp_xy)]
    return sid, meta
