"""The streaming API: one method on a live stream of samples, pushed in time order (:class:`OnlineLocalizer`), and
a recorded session as such a stream (:func:`replay`). For the same seed it reproduces
:func:`blenav.filters.runner.run_session` exactly.
"""

from __future__ import annotations

import numpy as np

from blenav.data import Session

from .method import Method, require_models
from .runner import build_filter
from .steps import StepStream

__all__ = ["OnlineLocalizer", "replay", "EVENT_ORDER"]


class OnlineLocalizer:
    """Streaming API: push sensor samples in time order; each closed step yields estimates.

    For a given seed it reproduces :func:`run_session` exactly when fed the same session through
    :func:`replay` (magnetometer samples before IMU samples of the same time stamp).
    """

    def __init__(self, method: Method, session_meta_building: Session, n_runs: int, seed: int,
                 t_start: float = 0.0, imu_rate_hz: float = 200.0, mag_offset: np.ndarray | None = None,
                 start_xy: np.ndarray | None = None, start_theta: float | None = None):
        """``start_xy`` (2,) world m / ``start_theta`` rad: the known start for ``map.init`` 'fix' or
        'groundtruth' and ``map.heading`` 'groundtruth' (a live localizer gets them from its caller)."""
        self.method = method
        require_models(method)
        rng = np.random.default_rng(seed)
        self.pf, anchors, self.geom = build_filter(method, session_meta_building, n_runs, rng)
        self.pf.initializer.start_xy, self.pf.initializer.start_theta = start_xy, start_theta
        self.stream = StepStream(anchors, method.filter.rate_hz, method.attitude, method.steps, t_start, imu_rate_hz,
                                 method.needs_imu, mag_offset)
        self.pf.initialize(t_start)

    def _run(self, steps):
        return [self.pf.step(t, c, o) for t, c, o in steps]

    def push_imu(self, t, acc, gyr):
        return self._run(self.stream.push_imu(t, acc, gyr))

    def push_mag(self, t, mag):
        return self._run(self.stream.push_mag(t, mag))

    def push_rssi(self, t, anchor_id, rssi):
        return self._run(self.stream.push_rssi(t, anchor_id, rssi))

    def push_odometry(self, t, xy, var=None):
        """An odometry position (m) and its cumulative variance (m^2 per axis; None when the track states none)."""
        return self._run(self.stream.push_odometry(t, xy, var))

    def push_fix(self, t, x, y, std=None, source=None):
        """A position fix from another localizer: world x, y (m), std (m, None when unknown), source name.

        A :class:`~blenav.filters.measurement.FixLikelihood` with ``source`` set uses only fixes pushed
        with that source; with ``source=None`` it uses every fix."""
        return self._run(self.stream.push_fix(t, x, y, std, source))

    def push_event(self, e: tuple):
        """Push one event of :func:`replay` (dispatch on its kind)."""
        kind = e[0]
        if kind == "imu":
            return self.push_imu(e[1], e[2], e[3])
        if kind == "mag":
            return self.push_mag(e[1], e[2])
        if kind == "rssi":
            return self.push_rssi(e[1], e[2], e[3])
        if kind == "odo":
            return self.push_odometry(e[1], e[2], e[3] if len(e) > 3 else None)
        if kind == "fix":
            return self.push_fix(e[1], e[2], e[3], e[4], e[5])
        raise ValueError(f"unknown event kind {kind!r}")

    def close(self, t_end):
        return self._run(self.stream.close(t_end))


#: the order of :func:`replay`'s events at one time
EVENT_ORDER = {"mag": 0, "odo": 1, "rssi": 2, "fix": 3, "imu": 4}


def replay(session: Session, odometry=None):
    """The session's samples as one time-ordered event list (kind, t, payload...).

    Kinds: ('mag', t, m), ('odo', t, xy) or ('odo', t, xy, var) where the track has the column ``var``, ('rssi', t, anchor_id, rssi), ('fix', t, x, y, std | None,
    source | None), ('imu', t, acc, gyr); :meth:`OnlineLocalizer.push_event` dispatches them. ``odometry``
    (DataFrame t, x, y): the odometry events' track in place of the session's odometry.csv (e.g. the learned inertial
    odometry of a bundle).
    """
    ev = []
    imu, mag, r, fx = session.imu, session.mag, session.rssi, session.fixes
    odo = session.odometry if odometry is None else odometry
    for row in mag.itertuples(index=False):
        ev.append(("mag", row.t, np.array([row.mx, row.my, row.mz])))
    if "var" in odo.columns:  # the learned inertial odometry's variance (issue 31: odo_var_scale), as the batch reads it
        for t, x, y, v in zip(*(odo[c].to_numpy(float) for c in ("t", "x", "y", "var"))):
            ev.append(("odo", t, np.array([x, y]), float(v)))
    else:
        for row in odo.itertuples(index=False):
            ev.append(("odo", row.t, np.array([row.x, row.y])))
    for row in r.itertuples(index=False):
        ev.append(("rssi", row.t, str(row.anchor_id), float(row.rssi)))
    for t, x, y, std, src in zip(fx["t"].to_numpy(float), fx["x"].to_numpy(float), fx["y"].to_numpy(float),
                                 fx["std"].to_numpy(float), fx["source"].to_numpy(object)):
        ev.append(("fix", float(t), float(x), float(y), None if np.isnan(std) else float(std),
                   None if not isinstance(src, str) else src))
    for row in imu.itertuples(index=False):
        ev.append(("imu", row.t, np.array([row.ax, row.ay, row.az]), np.array([row.gx, row.gy, row.gz])))
    ev.sort(key=lambda e: (e[1], EVENT_ORDER[e[0]]))
    return ev
