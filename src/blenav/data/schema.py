"""Static description of dataset format v1 (``docs/dataset-format.md``).

Every reader, writer and the validator take the file names, columns and enumerations from here, so
the contract lives in one place.

A :class:`StreamSpec` describes one per-session CSV stream:

* ``required``: columns that must exist and hold a finite value on every row;
* ``nullable``: columns that must exist but may be empty on a row (e.g. ``fixes.std``);
* ``string``: columns read as text (anchor ids, fix sources), never parsed as numbers.
"""

from __future__ import annotations

from dataclasses import dataclass

FORMAT = "blenav/1"

CARRIERS = ("pedestrian", "robot", "static")
ANCHOR_KINDS = ("ble", "wifi_rtt")

#: ROS map_server defaults for building.yaml floors.
DEFAULT_OCCUPIED_THRESH = 0.65
DEFAULT_FREE_THRESH = 0.196

#: RSSI outside (RSSI_MIN_DBM, RSSI_MAX_DBM) is a sentinel or a corrupt value, never a reading.
RSSI_MIN_DBM = -150.0
RSSI_MAX_DBM = 0.0

#: Quaternions with a norm below this are rejected; others are normalised on read.
QUAT_MIN_NORM = 0.5


@dataclass(frozen=True)
class StreamSpec:
    """Columns of one session stream file (all times in seconds since session start)."""

    name: str
    required: tuple[str, ...]
    nullable: tuple[str, ...] = ()
    string: tuple[str, ...] = ()

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
        # range and reported std, metres
        StreamSpec("rtt", ("t", "anchor_id", "range_m"), ("range_std_m",), string=("anchor_id",)),
        # sparse visual pose fixes, world frame, yaw rad CCW from +x
        StreamSpec("visual", ("t", "x", "y", "z", "yaw")),
        # inertial odometry, arbitrary frame fixed at session start, metres
        StreamSpec("odometry", ("t", "x", "y")),
        # absolute fixes in the world frame from another localizer, metres
        StreamSpec("fixes", ("t", "x", "y"), ("std", "source"), string=("source",)),
        # world-frame position (m) and device-to-world quaternion (w first, may be empty)
        StreamSpec("groundtruth", ("t", "x", "y", "z"), ("qw", "qx", "qy", "qz")),
    )
}

#: Streams that need the building's anchors.
ANCHORED_STREAMS = ("rssi", "rtt")

ANCHOR_COLUMNS = ("anchor_id", "kind", "x", "y", "z", "floor", "tx_power_dbm", "channel_model")
ANCHOR_TRUE_COLUMNS = ("x_true", "y_true", "z_true")

FLOOR_KEYS = ("id", "image", "resolution", "origin")
SESSION_KEYS = ("building", "floor", "device_model", "carrier", "labelled")
