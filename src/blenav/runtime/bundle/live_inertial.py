"""The learned inertial odometry of a bundle made live (issue 31), for :class:`blenav.runtime.bundle.live.BundleLocalizer`.

:class:`InertialFeed` runs :class:`blenav.filters.inertial_odometry.StreamingLio` on the pushed IMU and holds every
other sample until the odometry has reached its time, then hands the samples on in the order of
:func:`blenav.filters.online.replay` (time, then mag, odo, rssi, fix, imu): a sample is released once an IMU sample
later than it has been through the network's resampling (every odometry point up to that time is made), i.e. one IMU
period after it arrived. The attitude: ``orientation`` (pushed rotation-vector samples), ``ahrs`` (blenav's AHRS on
the pushed IMU and magnetometer, hard-iron offset ``mag_offset``) or ``auto`` (orientation when a rotation vector
comes within :data:`AUTO_GRACE_S` of the first IMU sample, as a phone's fused sensor starts a little after its IMU;
else the AHRS; apps that know which they push pass it). An app that runs the network itself pushes odometry instead:
from its first odometry sample on, nothing is held (one source per stream).

Bounded: a sample that would wait more than :data:`MAX_HOLD_S` (no IMU sample, the IMU stopped, or no rotation
vector for an ``orientation`` attitude) is refused with what to push, not queued for the rest of the session; the
refusal changes nothing, so the stream goes on once the IMU (or the rotation vector) comes.
"""

from __future__ import annotations

from blenav.filters.inertial_odometry import MAX_GAP_S, StreamingLio
from blenav.filters.pdr_odometry import HEADING_SOURCES
from blenav.filters.online import EVENT_ORDER

__all__ = ["InertialFeed", "MAX_HOLD_S", "AUTO_GRACE_S"]

#: the longest a sample waits for the odometry (s of the stream's clock): a later sample is refused, not queued
MAX_HOLD_S = 10.0
#: ``auto``: how long the IMU waits for a rotation vector before the AHRS is chosen (s of the IMU's clock)
AUTO_GRACE_S = 1.0


class InertialFeed:
    """Events in (``imu`` / ``orientation`` / ``hold`` / ``odometry`` / ``close``), the events to push to the filter
    out, in replay's order (module doc). ``model``: the bundle's :class:`blenav.runtime.inertial.InertialModel`.

    A refused sample (ValueError) changes nothing: the stream goes on when what was missing comes (an IMU sample after
    a gap of up to :data:`~blenav.filters.inertial_odometry.MAX_GAP_S`, a rotation vector). A sample older than the
    odometry already handed on (pushed late) is handed on at once and joins the filter's current step (:attr:`late`
    counts them)."""

    def __init__(self, model, attitude: str = "auto", mag_offset=None, gyro_calibrated: bool | None = None):
        if attitude not in HEADING_SOURCES:
            raise ValueError(f"attitude must be one of {HEADING_SOURCES}, got {attitude!r}")
        self.model, self.attitude, self.mag_offset = model, attitude, mag_offset
        self.gyro_calibrated = gyro_calibrated  # StreamingLio's: whether the pushed gyroscope is bias-corrected
        self.lio: StreamingLio | None = None
        self.source: str | None = None  # "imu": the bundle makes the odometry; "pushed": the app does
        self.late = 0
        self._held: list[tuple] = []
        self._mags: list[tuple] = []  # magnetometer samples before the AHRS exists
        self._early: list[tuple] = []  # auto: IMU samples before the attitude is chosen

    def _make(self, attitude: str) -> None:
        """Start the odometry in ``attitude`` (the magnetometer samples so far queued for its AHRS)."""
        self.lio = StreamingLio(self.model, attitude, mag_offset=self.mag_offset, gyro_calibrated=self.gyro_calibrated)
        for t, m in self._mags if attitude == "ahrs" else []:
            self.lio.push_mag(t, m)
        self._mags = []

    def _feed_early(self) -> list[tuple]:
        pts, early, self._early = [], self._early, []
        for ev in early:
            pts += self.lio.push_imu(ev[1], ev[2], ev[3])
        return pts

    def _refuse_if_stale(self, t: float) -> None:
        """ValueError (nothing changed) when the oldest held sample would wait more than MAX_HOLD_S at time ``t``."""
        if not self._held:
            return
        oldest = min(e[1] for e in self._held)
        if t - oldest <= MAX_HOLD_S:
            return
        h = self.lio.horizon if self.lio is not None else None
        if self.lio is not None and self.lio.attitude == "orientation" and h is None:
            why = ("no rotation vector came with the IMU (attitude 'orientation'): push_orientation, or open the "
                   "localizer with attitude='ahrs'")
        elif self.source == "imu":
            why = (f"the IMU stopped at {h if h is not None else oldest:.3f} s: push_imu resumes the stream (a gap of up "
                   f"to {MAX_GAP_S:g} s), else open a new localizer")
        else:
            why = ("no IMU sample came: push_imu (with push_mag, or push_orientation), or push the odometry your app "
                   "makes with push_odometry")
        raise ValueError(f"a sample at {t:.3f} s would wait more than {MAX_HOLD_S:g} s for the bundle's learned "
                         f"inertial odometry (inertial/), which has its samples up to {oldest:.3f} s: {why}")

    def _release(self, before: float | None) -> list[tuple]:
        """The held events earlier than ``before`` (all when None), in replay's order."""
        due = [e for e in self._held if before is None or e[1] < before]
        self._held = [e for e in self._held if before is not None and e[1] >= before]
        return sorted(due, key=lambda e: (e[1], EVENT_ORDER[e[0]]))

    def _points(self, pts: list[tuple]) -> list[tuple]:
        self._held += [("odo", t, xy, var) for t, xy, var in pts]
        h = self.lio.horizon if self.lio is not None else None
        return self._release(h) if h is not None else []

    def hold(self, ev: tuple) -> list[tuple]:
        """A sample that is not the IMU's (rssi, mag, fix): held until the odometry reaches it."""
        if self.source == "pushed":
            return [ev]
        h = self.lio.horizon if self.lio is not None else None
        if h is not None and ev[1] < h:  # late: the odometry up to it is handed on already
            self.late += 1
            if ev[0] == "mag":
                self.lio.push_mag(ev[1], ev[2])
            return [ev]
        self._refuse_if_stale(ev[1])
        if ev[0] == "mag":
            if self.lio is None:
                self._mags.append((ev[1], ev[2]))
            else:
                self.lio.push_mag(ev[1], ev[2])
        self._held.append(ev)
        return []

    def imu(self, ev: tuple) -> list[tuple]:
        if self.source == "pushed":
            return [ev]
        if self.lio is None or self.lio.horizon is None:  # the odometry has not started: the IMU waits too, bounded
            self._refuse_if_stale(ev[1])
        self.source = "imu"
        if self.lio is None and self.attitude == "auto":
            self._early.append(ev)
            self._held.append(ev)
            if ev[1] - self._early[0][1] < AUTO_GRACE_S:
                return []
            self._make("ahrs")  # no rotation vector within the grace: the AHRS
            return self._points(self._feed_early())
        if self.lio is None:
            self._make(self.attitude)
        pts = self.lio.push_imu(ev[1], ev[2], ev[3])
        self._held.append(ev)
        return self._points(pts)

    def orientation(self, t: float, q) -> list[tuple]:
        if self.source == "pushed":
            return []
        if self.lio is None:
            self._make("orientation" if self.attitude == "auto" else self.attitude)
        pts = self.lio.push_orientation(t, q)
        return self._points(pts + self._feed_early())

    def odometry(self, ev: tuple) -> list[tuple]:
        """Odometry the app made: from now on nothing is held (refused once the bundle makes the odometry)."""
        if self.source == "imu":
            raise ValueError("this stream's odometry is made by the bundle's learned inertial odometry from the pushed "
                             "IMU (inertial/): push one or the other, not both")
        self.source, self._mags = "pushed", []
        return self._release(None) + [ev]

    def close(self) -> list[tuple]:
        """Every held sample (the end of the data)."""
        return self._release(None)
