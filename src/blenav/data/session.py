"""Sessions: one recording (or simulation) of one device in one building, with lazy stream access.

Streams are pandas frames with the columns of :data:`blenav.data.schema.STREAMS`; time ``t`` is
seconds since session start (float64), positions metres in the world frame, IMU in the device frame
(accelerometer m/s^2 incl. gravity, gyroscope rad/s), magnetometer microtesla, RSSI dBm.
An absent optional stream reads as an empty frame with the right columns. Each stream is read and checked by
:func:`blenav.data.streams.load_stream`; this module holds the session folder's own rules (session.yaml, which
files, one clock) and :class:`Session`.
"""

from __future__ import annotations

import csv
from dataclasses import dataclass, field, replace
from functools import cached_property
from pathlib import Path

import numpy as np
import pandas as pd

from .building import Building
from .floor import Floor, floor_key
from .issues import Issue, error, raise_or_log
from .schema import CARRIERS, GROUNDTRUTH_KINDS, IMU_MAX_MEAN_DT_S, SESSION_KEYS, STREAMS, T_MAX_S
from .streams import load_stream
from .tables import read_header

#: The files of one session share one clock: a stream whose last time is more than CLOCK_RATIO times another
#: stream's last time is an error ('time-clock'), when both end after CLOCK_MIN_S and have CLOCK_MIN_ROWS rows or
#: more (a short or sparse stream may well stop early). Milliseconds for seconds give a ratio of about 1000.
CLOCK_RATIO = 100.0
CLOCK_MIN_S = 1.0
CLOCK_MIN_ROWS = 10


def check_session_meta(path: Path, doc: dict, buildings: dict) -> list[Issue]:
    """Rules of session.yaml: keys present, carrier known, building and floor exist."""
    issues = []
    missing = [k for k in SESSION_KEYS if k not in doc]
    if missing:
        issues.append(error(path, "session-keys", f"session.yaml lacks key(s) {', '.join(missing)}"))
    if "carrier" in doc and doc["carrier"] not in CARRIERS:
        issues.append(error(path, "session-carrier", f"carrier {doc['carrier']!r} is not one of {CARRIERS}"))
    if "groundtruth_kind" in doc and doc["groundtruth_kind"] not in GROUNDTRUTH_KINDS:
        issues.append(error(path, "session-groundtruth-kind",
                            f"groundtruth_kind {doc['groundtruth_kind']!r} is not one of {GROUNDTRUTH_KINDS}"))
    if "labelled" in doc and not isinstance(doc["labelled"], bool):
        issues.append(error(path, "session-labelled", f"labelled must be true or false, got {doc['labelled']!r}"))
    if "gyro_calibrated" in doc and not isinstance(doc["gyro_calibrated"], bool):
        issues.append(error(path, "session-gyro-calibrated",
                            f"gyro_calibrated must be true or false, got {doc['gyro_calibrated']!r}"))
    b = doc.get("building")
    if b is not None or "building" in doc:
        bld = buildings.get(str(b)) if b is not None else None
        # floors declared in building.yaml count even when one failed to load (reported there, once)
        declared = [] if bld is None else list(bld.floors) + [
            f.get("id") for f in (bld.meta.get("floors") or []) if isinstance(f, dict)]
        if b is None or str(b) not in buildings:
            issues.append(error(path, "session-building", f"building {b!r} is not a folder under buildings/"))
        elif bld is not None and "floor" in doc:
            if floor_key(doc["floor"], declared) is None:
                issues.append(error(path, "session-floor", f"floor {doc['floor']!r} is not a floor of building {b!r}"))
    return issues


def check_session_files(root: Path, meta: dict) -> list[Issue]:
    """Rules on which files a session folder holds: at least one data file; groundtruth.csv when labelled."""
    issues = []
    if not any((root / spec.filename).is_file() for spec in STREAMS.values()):
        issues.append(error(root, "session-empty", "session has no data file besides session.yaml"))
    if meta.get("labelled") is True and not (root / STREAMS["groundtruth"].filename).is_file():
        issues.append(error(root / STREAMS["groundtruth"].filename, "groundtruth-missing",
                            "labelled: true but groundtruth.csv is absent"))
    return issues + check_session_clock(root, meta.get("labelled") is True)


def _stream_end(path: Path) -> tuple[float, int] | None:
    """(last ``t``, number of rows) of a stream file from its header and its last line (the count is estimated
    from the file's size for files over 4 MB); None when either does not parse (reported by the stream's own
    checks)."""
    header = read_header(path)
    if "t" not in header:
        return None
    size = path.stat().st_size
    with open(path, "rb") as f:
        f.seek(max(0, size - 65536))
        tail = f.read()
        if size <= 4 << 20:
            f.seek(0)
            rows = f.read().count(b"\n") - 1
    lines = [ln for ln in tail.decode("utf-8", errors="replace").splitlines() if ln.strip()]
    if not lines:
        return None
    if size > 4 << 20:
        rows = int(size / (len(tail) / max(len(lines), 1)))
    try:
        t = float(next(csv.reader([lines[-1]]))[header.index("t")])
    except (ValueError, IndexError, StopIteration):
        return None
    return (t, rows) if np.isfinite(t) else None


def check_session_clock(root: Path, labelled: bool = True) -> list[Issue]:
    """The session's streams share one clock: the last time of a stream is at most :data:`CLOCK_RATIO` times the
    last time of another (see the constants). Catches one file in milliseconds, or on another clock (absolute
    time with another offset), which the plausible range of ``t`` alone cannot (both stay below ``T_MAX_S``).
    Reads the header and the last line of each stream; the ground truth of an unlabelled session is ignored."""
    ends, rows = {}, {}
    for name, spec in STREAMS.items():
        path = root / spec.filename
        if not path.is_file() or (name == "groundtruth" and not labelled):
            continue
        end = _stream_end(path)
        # a time beyond T_MAX_S is already an error of its own ('time-range')
        if end is not None and CLOCK_MIN_S <= end[0] <= T_MAX_S and end[1] >= CLOCK_MIN_ROWS:
            ends[spec.filename], rows[spec.filename] = end
    if len(ends) < 2:
        return []
    last = max(ends, key=ends.get)
    first = min(ends, key=ends.get)
    if ends[last] <= CLOCK_RATIO * ends[first]:
        return []
    if last == STREAMS["imu"].filename and ends[last] / max(rows[last] - 1, 1) > IMU_MAX_MEAN_DT_S:
        return []  # an IMU that slow is an error of its own ('imu-rate', which says: milliseconds?)
    return [error(root / last, "time-clock", f"{last} runs to t = {ends[last]:g} s, but {first} ends at "
                  f"{ends[first]:g} s ({ends[last] / ends[first]:.0f} times earlier): the files of a session share "
                  f"one clock, in seconds since its start; is {last} in milliseconds, or on another clock?")]


@dataclass
class Session:
    """A session folder. Streams are read, checked and cached on first access.

    Reading a stream that breaks a rule raises :class:`blenav.errors.DatasetError`; warnings (e.g.
    dropped unknown-anchor rows) are logged and kept in :attr:`issues`, and the rows the reader left out
    are counted in :attr:`dropped` (every stream: :meth:`load_all`).
    """

    id: str
    root: Path
    meta: dict
    building: Building
    issues: list[Issue] = field(default_factory=list)

    @property
    def device_model(self) -> str:
        return str(self.meta.get("device_model", ""))

    @property
    def carrier(self) -> str:
        return str(self.meta.get("carrier", ""))

    @property
    def labelled(self) -> bool:
        return bool(self.meta.get("labelled", False))

    @property
    def groundtruth_sparse(self) -> bool:
        """Whether the ground truth is sparse surveyed waypoints (session.yaml ``groundtruth_kind: waypoints``), not
        a trajectory sampled along the walk: consumers that need a position at every instant interpolate between
        them (:meth:`positions_at`) and say so."""
        return self.meta.get("groundtruth_kind", "trajectory") == "waypoints"

    @property
    def gyro_calibrated(self) -> bool:
        """Whether imu.csv's gyroscope has its bias removed (:func:`gyro_calibrated_of` its session.yaml). What
        :func:`blenav.filters.yaw_hold.resolve_yaw` reads."""
        return gyro_calibrated_of(self.meta)

    @property
    def floor(self) -> Floor:
        return self.building.floor(self.meta.get("floor"))

    def with_building(self, building: Building) -> "Session":
        """This session seen in another version of its building (same id and anchors, e.g. a wrong floor
        plan), sharing the streams read so far and those read later."""
        if building.id != self.building.id:
            raise ValueError(f"session {self.id}: building {building.id!r} is not {self.building.id!r}")
        other = replace(self, building=building)
        other.__dict__["_streams"] = self.__dict__.setdefault("_streams", {})
        other.__dict__["_dropped"] = self.__dict__.setdefault("_dropped", {})
        # streams read later are checked against the dataset's own building (its plan), not this version
        other.__dict__["_home"] = self.__dict__.get("_home", self.building)
        return other

    def has(self, name: str) -> bool:
        """Whether the stream has at least one (valid) row."""
        return len(self.stream(name)) > 0

    def stream(self, name: str) -> pd.DataFrame:
        if name not in STREAMS:
            raise KeyError(f"unknown stream {name!r}; streams are {list(STREAMS)}")
        cache = self.__dict__.setdefault("_streams", {})
        if name not in cache:
            home = self.__dict__.get("_home", self.building)
            df, issues, dropped = load_stream(self.root, name, home, self.labelled, self.meta.get("floor"))
            raise_or_log(issues)
            self.issues += issues
            self.__dict__.setdefault("_dropped", {})[name] = dropped
            cache[name] = df
        return cache[name]

    @property
    def dropped(self) -> dict[str, dict[str, int]]:
        """Rows the reader left out of the streams read so far: ``{stream: {reason: rows}}``, only streams
        with at least one dropped row (a copy). Reasons are the rules' names: ``unknown-anchor`` (rssi/rtt
        rows naming an anchor not in anchors.csv), ``duplicate-row`` (rssi/rtt rows equal to an earlier row in
        every column, kept once), ``groundtruth-unlabelled`` (ground truth of a session
        with ``labelled: false``). Every stream's count: :meth:`load_all` first."""
        return {k: dict(v) for k, v in self.__dict__.get("_dropped", {}).items() if v}

    def load_all(self) -> "Session":
        """Read (and check) every stream present; raises :class:`DatasetError` on the first one that breaks a
        rule. Returns the session, so ``s.load_all().dropped`` is the session's full drop count."""
        for name, spec in STREAMS.items():
            if (self.root / spec.filename).is_file() or (name == "groundtruth" and self.labelled):
                self.stream(name)
        return self

    imu = property(lambda self: self.stream("imu"), doc="t, ax, ay, az (m/s^2), gx, gy, gz (rad/s)")
    mag = property(lambda self: self.stream("mag"), doc="t, mx, my, mz (uT)")
    rssi = property(lambda self: self.stream("rssi"), doc="t, anchor_id, rssi (dBm), known anchors only")
    rtt = property(lambda self: self.stream("rtt"), doc="t, anchor_id, range_m, range_std_m (m)")
    visual = property(lambda self: self.stream("visual"), doc="t, x, y, z (m), yaw (rad CCW from +x)")
    odometry = property(lambda self: self.stream("odometry"), doc="t, x, y (m, arbitrary frame)")
    fixes = property(lambda self: self.stream("fixes"), doc="t, x, y, std (m), source")
    wifi = property(lambda self: self.stream("wifi"), doc="t, bssid, rssi_dbm (dBm), freq_mhz (MHz; NaN unknown)")
    orientation = property(lambda self: self.stream("orientation"),
                           doc="t, qw, qx, qy, qz: the phone's own device->world(ish) quaternion, normalised")
    groundtruth = property(lambda self: self.stream("groundtruth"),
                           doc="t, x, y, z (m, world), qw, qx, qy, qz (device->world, NaN when absent)")

    @cached_property
    def duration_s(self) -> float:
        """Largest time stamp over the streams present (s)."""
        ends = [self.stream(n)["t"].max() for n in STREAMS if (self.root / STREAMS[n].filename).is_file()]
        ends = [e for e in ends if np.isfinite(e)]
        return float(max(ends)) if ends else 0.0

    def positions_at(self, t: np.ndarray, with_z: bool = False, device_z: float | None = None) -> np.ndarray:
        """Ground-truth (x, y) interpolated linearly at times ``t`` (s); shape (len(t), 2), or with ``with_z``
        (x, y, z) (len(t), 3): z the fixed height ``device_z`` (m) when given, else the ground truth's, 0 when it
        has no heights (column absent or all NaN)."""
        gt = self.groundtruth
        if len(gt) == 0:
            raise ValueError(f"session {self.id} has no ground truth")
        tt = gt["t"].to_numpy()
        cols = [np.interp(t, tt, gt["x"].to_numpy()), np.interp(t, tt, gt["y"].to_numpy())]
        if with_z and device_z is not None:
            cols.append(np.full(np.shape(t), float(device_z)))
        elif with_z:
            z = gt["z"].to_numpy(float) if "z" in gt and not gt["z"].isna().all() else np.zeros(len(tt))
            cols.append(np.interp(t, tt, z))
        return np.stack(cols, axis=-1)


def gyro_calibrated_of(meta: dict) -> bool:
    """session.yaml ``gyro_calibrated``; absent: true for a session with Android's rotation vector
    (``orientation_frame: enu-magnetic``), whose phone reports the bias-corrected ``TYPE_GYROSCOPE``, else false."""
    v = meta.get("gyro_calibrated")
    if v is None:
        return meta.get("orientation_frame") == "enu-magnetic"
    return bool(v)


def check_session_in_building(session: Session) -> None:
    """Raise :class:`DatasetError` ('groundtruth-off-floor') when a labelled session's ground truth lies mostly
    outside its floor's plan: the session names the wrong building or floor, or the plan's resolution or
    origin is wrong. The rule is applied whenever ground truth is read (:func:`~blenav.data.streams.load_stream`);
    this reads it.
    Unlabelled sessions pass."""
    if session.labelled:
        session.stream("groundtruth")


def sum_dropped(counts) -> dict[str, dict[str, int]]:
    """Add up :attr:`Session.dropped` dicts (e.g. over the sessions of an evaluation): ``{stream: {reason: n}}``."""
    out: dict[str, dict[str, int]] = {}
    for c in counts:
        for stream, reasons in c.items():
            for reason, n in reasons.items():
                out.setdefault(stream, {})[reason] = out.get(stream, {}).get(reason, 0) + int(n)
    return out
