"""Static description of dataset format v1 (``docs/dataset-format.md``).

Every reader, writer and the validator take the file names, columns and enumerations from here, so
the contract lives in one place.

A :class:`StreamSpec` describes one per-session CSV stream:

* ``required``: columns that must exist and hold a finite value on every row;
* ``nullable``: columns that must exist but may be empty on a row (e.g. ``fixes.std``);
* ``string``: columns read as text (anchor ids, fix sources), never parsed as numbers;
* ``optional``: numeric columns a file may have or lack (a compatible extension, e.g. ``rtt.rssi``); when
  present they are read and checked like ``nullable`` ones, when absent the frame has no such column.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

FORMAT = "blenav/1"

CARRIERS = ("pedestrian", "robot", "static")
ANCHOR_KINDS = ("ble", "wifi_rtt")

#: ROS map_server defaults for building.yaml floors.
DEFAULT_OCCUPIED_THRESH = 0.65
DEFAULT_FREE_THRESH = 0.196

#: RSSI outside (RSSI_MIN_DBM, RSSI_MAX_DBM) is a sentinel or a corrupt value, never a reading.
RSSI_MIN_DBM = -150.0
RSSI_MAX_DBM = 0.0

#: Largest time stamp (s since the session's start) a reader accepts: about 11.6 days. Larger values are
#: milliseconds written as seconds, or absolute (Unix) times (docs/dataset-format.md, "Plausible ranges").
T_MAX_S = 1e6

#: An imu.csv with at least IMU_RATE_MIN_ROWS rows whose mean interval exceeds IMU_MAX_MEAN_DT_S is refused:
#: no inertial sensor samples below 1 Hz; 100 Hz samples with t in milliseconds look like this.
IMU_MAX_MEAN_DT_S = 1.0
IMU_RATE_MIN_ROWS = 10
#: ... and one whose mean interval is below IMU_MIN_MEAN_DT_S (faster than 10 kHz; phones sample at most ~500 Hz):
#: its times do not advance (all one value), or are in hours.
IMU_MIN_MEAN_DT_S = 1e-4


@dataclass(frozen=True)
class Plausible:
    """Values a receiver or sensor can report for one column; a value outside is an error naming its line.

    ``lo``/``hi`` are inclusive unless ``open_`` (then both bounds are excluded); ``hint`` says what a value
    outside usually means. Empty cells of nullable columns are not checked.
    """

    lo: float
    hi: float
    unit: str
    rule: str
    hint: str
    open_: bool = False

    def outside(self, v):
        """Bool mask of values outside the range (NaN -> False: reported by the finiteness checks)."""
        v = np.asarray(v, dtype=float)
        with np.errstate(invalid="ignore"):
            bad = (v <= self.lo) | (v >= self.hi) if self.open_ else (v < self.lo) | (v > self.hi)
        return bad & ~np.isnan(v)

    def describe(self) -> str:
        lo, hi = ("(", ")") if self.open_ else ("[", "]")
        return f"{lo}{self.lo:g}, {self.hi:g}{hi} {self.unit}".rstrip()


_ACC = Plausible(-160.0, 160.0, "m/s^2", "imu-range",
                 "beyond 16 g, a phone accelerometer's full scale: is it in m/s^2 (not mg or cm/s^2)?")
_GYR = Plausible(-35.0, 35.0, "rad/s", "imu-range",
                 "beyond 2000 deg/s, a phone gyroscope's full scale: is it in rad/s (not deg/s)?")
_MAG = Plausible(-5000.0, 5000.0, "uT", "mag-range",
                 "beyond a phone magnetometer's full scale (about 4900 uT): is it in microtesla (not nT)?")
_T = Plausible(0.0, T_MAX_S, "s", "time-range",
               "t is seconds since the session's start: a negative time is before the start, a time above "
               f"{T_MAX_S:g} s ({T_MAX_S / 86400:.1f} days) is milliseconds or an absolute (Unix) time")

#: Plausible ranges per (stream, column); every stream's ``t`` is checked against ``_T`` as well.
PLAUSIBLE: dict[tuple[str, str], Plausible] = {
    **{("imu", c): _ACC for c in ("ax", "ay", "az")},
    **{("imu", c): _GYR for c in ("gx", "gy", "gz")},
    **{("mag", c): _MAG for c in ("mx", "my", "mz")},
    ("rssi", "rssi"): Plausible(RSSI_MIN_DBM, RSSI_MAX_DBM, "dBm", "rssi-range",
                                "a sentinel or corrupt value (a beacon not heard has no row)", open_=True),
    ("wifi", "rssi_dbm"): Plausible(RSSI_MIN_DBM, RSSI_MAX_DBM, "dBm", "rssi-range",
                                    "a sentinel or corrupt value (an access point not heard has no row)", open_=True),
    ("wifi", "freq_mhz"): Plausible(2000.0, 8000.0, "MHz", "wifi-range",
                                    "WiFi channels lie between 2.4 and 7.1 GHz: is it in MHz (not GHz or a channel number)?"),
    ("rtt", "range_m"): Plausible(-50.0, 1000.0, "m", "rtt-range",
                                  "is it in metres (not mm or cm)? (Android reports small negative ranges)"),
    ("rtt", "range_std_m"): Plausible(0.0, 1000.0, "m", "rtt-range", "a standard deviation in metres"),
    # the optional WiFi RSSI of the ranged AP (004 sec. V-A: ranges below -65 dBm are dropped); empty when unknown
    ("rtt", "rssi"): Plausible(RSSI_MIN_DBM, RSSI_MAX_DBM, "dBm", "rssi-range",
                               "the AP's WiFi RSSI in dBm: a sentinel or corrupt value (empty when unknown)", open_=True),
    ("fixes", "std"): Plausible(0.0, float("inf"), "m", "fixes-range",
                                "a standard deviation is >= 0 (empty when unknown)"),
    # anchors.csv: the calibrated RSSI at 1 m is an RSSI (empty when unknown)
    ("anchors", "tx_power_dbm"): Plausible(RSSI_MIN_DBM, RSSI_MAX_DBM, "dBm", "anchor-range",
                                           "tx_power_dbm is the RSSI at 1 m in dBm (a transmitter's output power "
                                           "such as +4 dBm, or a sentinel, is not): empty when unknown", open_=True),
}


def plausible(stream: str, column: str) -> Plausible | None:
    """The plausible range of ``column`` of ``stream`` (``t`` of every stream: :data:`T_MAX_S`), or None."""
    if column == "t":
        return _T
    return PLAUSIBLE.get((stream, column))

#: Quaternions with a norm below this are rejected; others are normalised on read.
QUAT_MIN_NORM = 0.5


@dataclass(frozen=True)
class StreamSpec:
    """Columns of one session stream file (all times in seconds since session start)."""

    name: str
    required: tuple[str, ...]
    nullable: tuple[str, ...] = ()
    string: tuple[str, ...] = ()
    optional: tuple[str, ...] = ()

    def present(self, columns) -> tuple[str, ...]:
        """:attr:`columns` plus the optional columns found among ``columns`` (a header or a frame's columns)."""
        return self.columns + tuple(c for c in self.optional if c in columns)

    @property
    def filename(self) -> str:
        return f"{self.name}.csv"

    @property
    def columns(self) -> tuple[str, ...]:
        return self.required + self.nullable


STREAMS: dict[str, StreamSpec] = {
    s.name: s
    for s in (
        # accelerometer m/s^2 incl. gravity, gyroscope rad/s, device frame (Android convention)
        StreamSpec("imu", ("t", "ax", "ay", "az", "gx", "gy", "gz")),
        # magnetometer, microtesla, device frame
        StreamSpec("mag", ("t", "mx", "my", "mz")),
        # one row per received advertisement, dBm
        StreamSpec("rssi", ("t", "anchor_id", "rssi"), string=("anchor_id",)),
        # range and reported std, metres; optional: the AP's WiFi RSSI (dBm) of the ranging exchange
        StreamSpec("rtt", ("t", "anchor_id", "range_m"), ("range_std_m",), string=("anchor_id",), optional=("rssi",)),
        # sparse visual pose fixes, world frame, yaw rad CCW from +x
        StreamSpec("visual", ("t", "x", "y", "z", "yaw")),
        # inertial odometry, arbitrary frame fixed at session start, metres
        StreamSpec("odometry", ("t", "x", "y")),
        # absolute fixes in the world frame from another localizer, metres
        StreamSpec("fixes", ("t", "x", "y"), ("std", "source"), string=("source",)),
        # world-frame position (m) and device-to-world quaternion (w first, may be empty)
        StreamSpec("groundtruth", ("t", "x", "y", "z"), ("qw", "qx", "qy", "qz")),
        # WiFi RSS scans (optional extension): one row per access point per scan, dBm, MHz; not anchored
        StreamSpec("wifi", ("t", "bssid", "rssi_dbm"), ("freq_mhz",), string=("bssid",)),
        # the phone's own orientation estimate (optional extension, e.g. Android's rotation vector): unit
        # quaternion, w first, device frame -> the frame named in session.yaml `orientation_frame`
        StreamSpec("orientation", ("t", "qw", "qx", "qy", "qz")),
    )
}

#: Streams that need the building's anchors.
ANCHORED_STREAMS = ("rssi", "rtt")

ANCHOR_COLUMNS = ("anchor_id", "kind", "x", "y", "z", "floor", "tx_power_dbm", "channel_model")
#: Anchor columns that may be empty together on a row: the anchor's position is unknown (docs/dataset-format.md,
#: "Anchors whose position is unknown"); one or two of them empty is an error ('non-finite').
ANCHOR_POSITION_COLUMNS = ("x", "y", "z")

#: session.yaml `groundtruth_kind`: `trajectory` (default: ground truth sampled along the walk) or `waypoints`
#: (sparse surveyed points only; consumers that need denser labels interpolate and say so).
GROUNDTRUTH_KINDS = ("trajectory", "waypoints")
ANCHOR_TRUE_COLUMNS = ("x_true", "y_true", "z_true")

FLOOR_KEYS = ("id", "image", "resolution", "origin")
SESSION_KEYS = ("building", "floor", "device_model", "carrier", "labelled")
