"""The push API of a bundle: live samples in, track points out (:class:`BundleLocalizer`,
``Bundle.open(dir).localizer(building)``).

``push_rssi``, ``push_odometry``, ``push_imu``, ``push_mag``, ``close`` in time order; each returns the track points
(:class:`TrackPoint`: t, x, y, std) of the filter steps the sample closed. RSSI packets become the localizer's fixes
(:class:`blenav.runtime.bundle.windows.WindowFixer`), which weigh a particle filter of the bundle's settings
(:func:`blenav.runtime.bundle.settings.build_method`). With ``map.init: fix`` the filter starts around the first fix:
samples before it are kept and replayed then, so the first estimates come H steps after the first packet (as the
batch filter, which starts at the session's first sample). :meth:`Bundle.run_session` replays a recorded session
through it and gives exactly what :func:`blenav.filters.runner.run_session` gives with the same fixes and seed.
"""

from __future__ import annotations

from collections import deque
from types import SimpleNamespace
from typing import NamedTuple

import numpy as np

from blenav.filters.online import EVENT_ORDER

from .format import FIX_SOURCE
from .windows import WindowFixer


class TrackPoint(NamedTuple):
    """One filter step of the live track (one run): t (s, the session's clock), x, y (m, the building's world frame),
    std (m): the RMS of the per-axis standard deviations of the particle cloud, sqrt((var_x + var_y) / 2). Offline,
    R runs of K steps are one :class:`blenav.filters.estimate.Estimate`."""

    t: float
    x: float
    y: float
    std: float


class BundleLocalizer:
    """Live localization with a bundle: push samples in time order, get :class:`TrackPoint` rows as steps close.

    ``bundle``: an opened :class:`blenav.runtime.bundle.Bundle` (this module does not import it: it imports this);
    ``building``: a :class:`blenav.data.Building` (checked against the bundle); ``floor``: its floor id (default:
    the first); ``seed``: the filter's random generator; ``start_xy`` / ``start_theta``: a known start for
    ``map.init: groundtruth`` / ``map.heading: groundtruth`` settings; ``t_start``: the clock time the filter
    starts at (default: the first IMU, RSSI or odometry sample pushed); ``mag_offset``: the magnetometer's
    hard-iron offset (uT) for settings whose motion model runs an AHRS; ``keep_fixes``: how many of the latest
    fixes :attr:`fixes` holds, (t, x, y) each (None: every fix, as :meth:`Bundle.run_session` keeps for parity; a
    live app keeps memory flat with the default, benchmarks/soak.py); ``method``: a fresh ``bundle.method()`` to run
    (default: one built here).

    A bundle with a learned inertial odometry (``inertial/``) whose settings read odometry runs it live
    (:class:`blenav.runtime.bundle.live_inertial.InertialFeed`) once the app pushes IMU samples, with magnetometer
    samples (blenav's AHRS, hard-iron offset ``mag_offset``) or its rotation vector (:meth:`push_orientation`);
    ``attitude``: ``orientation``, ``ahrs`` or ``auto`` (default: the model's own; ``auto``: the rotation vector when
    one comes before the first IMU sample); ``gyro_calibrated``: whether the pushed gyroscope has its bias removed
    (Android's ``TYPE_GYROSCOPE``: true), which decides the yaw of a model trained with ``data.yaw: auto`` as
    ``session.yaml gyro_calibrated`` does in batch (default: true with the rotation vector, else false). An app that
    runs the model itself pushes the track with :meth:`push_odometry` instead (one or the other per stream). Until the stream shows which, and while the bundle
    makes the odometry, the other samples wait until a later IMU sample has made the odometry up to them (one IMU
    period; at most ``MAX_HOLD_S`` = 10 s, then an error saying what to push), so the filter sees every stream in
    replay's order and gives :meth:`Bundle.run_session`'s rows."""

    def __init__(self, bundle, building, floor=None, seed: int = 0, start_xy=None, start_theta=None,
                 t_start: float | None = None, mag_offset=None, keep_fixes: int | None = 1000, method=None,
                 attitude: str | None = None, gyro_calibrated: bool | None = None):
        bundle.check_building(building)
        fid = floor if floor is not None else next(iter(building.floors))
        self._ctx = SimpleNamespace(id="live", building=building, meta={"floor": fid}, floor=building.floor(fid))
        self.bundle, self.seed = bundle, int(seed)
        self.method = bundle.method() if method is None else method
        self.fixer = WindowFixer(bundle.graph)
        self.fixes: deque[tuple] = deque(maxlen=keep_fixes)
        self._online = None
        self._pending: list[tuple] = []
        self._t_start = t_start
        self._start_xy = None if start_xy is None else np.asarray(start_xy, float)
        self._start_theta, self._mag_offset = start_theta, mag_offset
        self._init = str(self.method.map.init)
        self._rssi_models = bool(self.method.measurements_needing("rssi"))
        self._lio = None  # the live learned odometry (InertialFeed), where the bundle has one its settings read
        if bundle.inertial is not None and self.method.needs_odometry:
            from .live_inertial import InertialFeed

            self._lio = InertialFeed(bundle.inertial, attitude or bundle.inertial.attitude, mag_offset, gyro_calibrated)
        elif attitude is not None or gyro_calibrated is not None:
            raise ValueError("attitude= and gyro_calibrated= are settings of a bundle's learned inertial odometry "
                             "(inertial/, with settings that read odometry): this bundle runs none")
        if self._init == "groundtruth" and self._start_xy is None:
            raise ValueError("the bundle's settings start at a known position (map.init: groundtruth): pass start_xy")

    @property
    def started(self) -> bool:
        return self._online is not None

    def _start(self) -> list[TrackPoint]:
        from blenav.filters.online import OnlineLocalizer

        self._online = OnlineLocalizer(self.method, self._ctx, 1, self.seed, t_start=float(self._t_start),
                                       mag_offset=self._mag_offset, start_xy=self._start_xy,
                                       start_theta=self._start_theta)
        out: list[TrackPoint] = []
        pending, self._pending = self._pending, []
        for ev in pending:
            out += self._rows(self._online.push_event(ev))
        return out

    @staticmethod
    def _rows(results) -> list[TrackPoint]:
        out = []
        for r in results:
            c = r.cov[0]
            out.append(TrackPoint(float(r.t), float(r.position[0, 0]), float(r.position[0, 1]),
                                float(np.sqrt(max(0.0, (c[0, 0] + c[1, 1]) / 2.0)))))
        return out

    def _feed(self, ev: tuple) -> list[TrackPoint]:
        if ev[0] == "rssi" and not self._rssi_models:
            return []  # the filter weighs the bundle's fixes, not packets: they only feed the localizer's windows
        if self._online is not None:
            return self._rows(self._online.push_event(ev))
        self._pending.append(ev)
        if self._init == "fix" and ev[0] == "fix":
            self._start_xy = np.array([ev[2], ev[3]], float)
        if self._init != "fix" or self._start_xy is not None:
            return self._start()
        return []

    def _push(self, ev: tuple) -> list[TrackPoint]:
        t = float(ev[1])
        if ev[0] != "mag" and self._t_start is None:
            self._t_start = t
        out = []
        for tf, x, y, sd in self.fixer.advance(t):
            self.fixes.append((tf, x, y))
            out += self._feed(("fix", tf, x, y, sd, FIX_SOURCE))
        if ev[0] == "rssi":
            self.fixer.add(t, ev[2], ev[3])
        return out + self._feed(ev)

    def _all(self, events: list[tuple]) -> list[TrackPoint]:
        out = []
        for ev in events:
            out += self._push(ev)
        return out

    def push_rssi(self, t: float, anchor_id: str, rssi: float) -> list[TrackPoint]:
        """One BLE packet: time (s), anchor id, RSSI (dBm)."""
        ev = ("rssi", float(t), str(anchor_id), float(rssi))
        return self._push(ev) if self._lio is None else self._all(self._lio.hold(ev))

    def push_odometry(self, t: float, xy, var: float | None = None) -> list[TrackPoint]:
        """Inertial odometry position (m, the odometry's own frame, as odometry.csv) and, where the odometry states
        one, its cumulative position variance (m^2 per axis, odometry.csv's optional ``var``: settings with
        ``motion.odo_var_scale`` weigh each step by its growth)."""
        ev = ("odo", float(t), np.asarray(xy, float))
        ev = ev if var is None else ev + (float(var),)
        return self._push(ev) if self._lio is None else self._all(self._lio.odometry(ev))

    def push_imu(self, t: float, acc, gyr) -> list[TrackPoint]:
        """Accelerometer (m/s^2) and gyroscope (rad/s), phone frame (used by settings with an IMU motion model, and by
        the bundle's learned inertial odometry)."""
        ev = ("imu", float(t), np.asarray(acc, float), np.asarray(gyr, float))
        return self._push(ev) if self._lio is None else self._all(self._lio.imu(ev))

    def push_orientation(self, t: float, q) -> list[TrackPoint]:
        """The phone's rotation vector (device -> world quaternion w, x, y, z): the learned inertial odometry's attitude
        with ``attitude="orientation"``; nothing else reads it."""
        return [] if self._lio is None else self._all(self._lio.orientation(float(t), q))

    def push_mag(self, t: float, mag) -> list[TrackPoint]:
        """Magnetometer (uT), phone frame."""
        ev = ("mag", float(t), np.asarray(mag, float))
        return self._push(ev) if self._lio is None else self._all(self._lio.hold(ev))

    def push_event(self, ev: tuple) -> list[TrackPoint]:
        """One event of :func:`blenav.filters.online.replay` (fix events are not taken: the bundle makes its own)."""
        if ev[0] == "fix":
            return []
        if ev[0] not in EVENT_ORDER:
            raise ValueError(f"unknown event kind {ev[0]!r} (one of {sorted(EVENT_ORDER)})")
        if ev[0] == "imu":
            return self.push_imu(ev[1], ev[2], ev[3])
        if ev[0] == "mag":
            return self.push_mag(ev[1], ev[2])
        if ev[0] == "odo":
            return self.push_odometry(ev[1], ev[2], ev[3] if len(ev) > 3 else None)
        return self.push_rssi(ev[1], ev[2], ev[3])

    def close(self, t_end: float) -> list[TrackPoint]:
        """End of the data at ``t_end``: the last fix, then every step that ends by then (or by that fix)."""
        out = self._all(self._lio.close()) if self._lio is not None else []
        for tf, x, y, sd in self.fixer.flush():
            self.fixes.append((tf, x, y))
            out += self._feed(("fix", tf, x, y, sd, FIX_SOURCE))
            t_end = max(t_end, tf)
        if self._online is None:
            if not self._pending:
                return out
            if self._init == "fix":
                raise ValueError("no fix was made (no window with a beacon of the bundle heard): the filter never "
                                 "started")
            out += self._start()
        return out + self._rows(self._online.close(float(t_end)))
