"""The learned inertial odometry of a bundle made live (issue 31), for :class:`blenav.runtime.bundle.live.BundleLocalizer`.

:class:`InertialFeed` runs :class:`blenav.filters.inertial_odometry.StreamingLio` on the pushed IMU and holds every
other sample until the odometry has reached its time, then hands the samples on in the order of
:func:`blenav.filters.online.replay` (time, then mag, odo, rssi, fix, imu): a sample is released once an IMU sample
later than it has been through the network's resampling (every odometry point up to that time is made), i.e. one IMU
period after it arrived. The attitude: ``orientation`` (pushed rotation-vector samples), ``ahrs`` (blenav's AHRS on
the pushed IMU and magnetometer, hard-iron offset ``mag_offset``) or ``auto`` (orientation when a rotation vector
comes before the first IMU sample, else the AHRS). An app that runs the network itself pushes odometry instead:
from its first odometry sample on, nothing is held (one source per stream).

Bounded: samples held for more than :data:`MAX_HOLD_S` (no IMU sample, or no rotation vector for an
``orientation`` attitude) are an error saying what to push, not a queue that grows for the rest of the session.
"""

from __future__ import annotations

import numpy as np

from blenav.filters.inertial_odometry import LIVE_ATTITUDES, StreamingLio
from blenav.filters.online import EVENT_ORDER

__all__ = ["InertialFeed", "MAX_HOLD_S"]

#: the longest a sample waits for the odometry (s of the stream's clock) before the stream is refused
MAX_HOLD_S = 10.0


class InertialFeed:
    """Events in (``imu`` / ``orientation`` / ``hold`` / ``odometry`` / ``close``), the events to push to the filter
    out, in replay's order (module doc). ``model``: the bundle's :class:`blenav.runtime.inertial.InertialModel`."""

    def __init__(self, model, attitude: str = "auto", mag_offset=None):
        if attitude not in LIVE_ATTITUDES + ("auto",):
            raise ValueError(f"attitude must be one of {LIVE_ATTITUDES + ('auto',)}, got {attitude!r}")
        self.model, self.attitude, self.mag_offset = model, attitude, mag_offset
        self.lio: StreamingLio | None = None
        self.source: str | None = None  # "imu": the bundle makes the odometry; "pushed": the app does
        self._held: list[tuple] = []
        self._mags: list[tuple] = []  # magnetometer samples before the AHRS exists
        self._newest = -np.inf

    def _make(self, attitude: str) -> StreamingLio:
        if self.lio is None:
            self.lio = StreamingLio(self.model, attitude, mag_offset=self.mag_offset)
            for t, m in self._mags if attitude == "ahrs" else []:
                self.lio.push_mag(t, m)
            self._mags = []
        return self.lio

    def _add(self, events: list[tuple]) -> None:
        self._held += events
        self._newest = max([self._newest] + [e[1] for e in events])
        if self._held and self._newest - min(e[1] for e in self._held) > MAX_HOLD_S:
            waiting = self.lio is not None and self.lio.attitude == "orientation" and self.lio.horizon is None
            raise ValueError(
                f"samples have waited {MAX_HOLD_S:g} s for the bundle's learned inertial odometry (inertial/): "
                + ("no rotation vector came with the IMU (attitude 'orientation'): push_orientation, or use "
                   "attitude='ahrs'" if waiting else
                   "no IMU sample came: push_imu (with push_mag, or push_orientation), or push the odometry your app "
                   "makes with push_odometry"))

    def _release(self, before: float | None) -> list[tuple]:
        """The held events earlier than ``before`` (all when None), in replay's order."""
        due = [e for e in self._held if before is None or e[1] < before]
        self._held = [e for e in self._held if before is not None and e[1] >= before]
        return sorted(due, key=lambda e: (e[1], EVENT_ORDER[e[0]]))

    def _points(self, pts: list[tuple]) -> list[tuple]:
        self._add([("odo", t, xy, var) for t, xy, var in pts])
        h = self.lio.horizon if self.lio is not None else None
        return self._release(h) if h is not None else []

    def hold(self, ev: tuple) -> list[tuple]:
        """A sample that is not the IMU's (rssi, mag, fix): held until the odometry reaches it."""
        if self.source == "pushed":
            return [ev]
        if ev[0] == "mag":
            if self.lio is None:
                self._mags.append((ev[1], ev[2]))
            else:
                self.lio.push_mag(ev[1], ev[2])
        self._add([ev])
        return []

    def imu(self, ev: tuple) -> list[tuple]:
        if self.source == "pushed":
            return [ev]
        self.source = "imu"
        lio = self._make("ahrs" if self.attitude == "auto" else self.attitude)
        pts = lio.push_imu(ev[1], ev[2], ev[3])
        self._add([ev])
        return self._points(pts)

    def orientation(self, t: float, q) -> list[tuple]:
        if self.source == "pushed":
            return []
        return self._points(self._make("orientation" if self.attitude == "auto" else self.attitude)
                            .push_orientation(t, q))

    def odometry(self, ev: tuple) -> list[tuple]:
        """Odometry the app made: from now on nothing is held (refused once the bundle makes the odometry)."""
        if self.source == "imu":
            raise ValueError("this stream's odometry is made by the bundle's learned inertial odometry from the pushed "
                             "IMU (inertial/): push one or the other, not both")
        self.source = "pushed"
        return self._release(None) + [ev]

    def close(self) -> list[tuple]:
        """Every held sample (the end of the data)."""
        return self._release(None)
