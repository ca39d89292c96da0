"""InertialFeed (issue 31): the bundle's learned odometry made live, every other sample held until the odometry
reaches it; what a phone's stream does to it (IMU gaps, a rotation vector that starts late or never, an app that
pushes its own odometry)."""

from __future__ import annotations

import numpy as np
import pytest

from helpers import RowModel

from blenav.filters.online import EVENT_ORDER
from blenav.runtime.bundle.live_inertial import AUTO_GRACE_S, MAX_HOLD_S, InertialFeed

G = np.array([0.0, 0.0, 9.81])


def _imu(feed, t):
    return feed.imu(("imu", float(t), G + [0.1 * np.sin(t), 0.0, 0.0], np.array([0.0, 0.0, 0.05])))


def _rssi(t):
    return ("rssi", float(t), "b1", -70.0)


def _ordered(events):
    keys = [(e[1], EVENT_ORDER[e[0]]) for e in events]
    return keys == sorted(keys)


def test_an_imu_gap_refuses_samples_without_changing_anything_and_the_imu_resumes_the_stream():
    feed, out = InertialFeed(RowModel("world"), "ahrs"), []
    for k in range(200):  # 2 s at 100 Hz, a packet every 0.1 s
        out += _imu(feed, 0.01 * k)
        if k % 10 == 5:
            out += feed.hold(_rssi(0.01 * k + 0.001))
    accepted = []
    with pytest.raises(ValueError, match="the IMU stopped at 1.990 s: push_imu resumes"):
        for k in range(30):  # packets through a 15 s IMU gap
            t = 2.0 + 0.5 * k
            out += feed.hold(_rssi(t))
            accepted.append(t)
    assert accepted[-1] - 1.99 <= MAX_HOLD_S
    held = len(feed._held)
    with pytest.raises(ValueError, match="IMU stopped"):  # refused again, and nothing changed
        feed.hold(_rssi(accepted[-1] + 0.7))
    assert len(feed._held) == held
    for k in range(100):  # the IMU comes back 15 s later: the gap's odometry and packets go on, in order
        out += _imu(feed, 17.0 + 0.01 * k)
    out += feed.close()
    assert _ordered(out)
    got = [e[1] for e in out if e[0] == "rssi"]
    assert got[-len(accepted):] == accepted
    odo_t = np.array([e[1] for e in out if e[0] == "odo"])
    assert odo_t.max() >= 17.5 and ((odo_t > 2.0) & (odo_t < 17.0)).sum() > 20  # the gap interpolated, as batch does


def test_auto_takes_a_rotation_vector_that_comes_just_after_the_imu_and_the_ahrs_without_one():
    late = InertialFeed(RowModel("world"), "auto")
    _imu(late, 0.0)
    _imu(late, 0.005)
    out = late.orientation(0.005 + 1e-4, [1.0, 0.0, 0.0, 0.0])  # a phone's fused sensor starts 5 ms after its IMU
    assert late.lio.attitude == "orientation" and [e[0] for e in out] == ["odo", "imu"]
    none = InertialFeed(RowModel("world"), "auto")
    for k in range(int(AUTO_GRACE_S / 0.01) + 2):
        _imu(none, 0.01 * k)
    assert none.lio.attitude == "ahrs"


def test_an_orientation_attitude_without_rotation_vector_is_refused_until_one_comes():
    feed = InertialFeed(RowModel("world"), "orientation")
    with pytest.raises(ValueError, match="no rotation vector came with the IMU"):
        for k in range(1200):
            _imu(feed, 0.01 * k)
    out = feed.orientation(0.01 * k, [1.0, 0.0, 0.0, 0.0])  # it comes: the waiting IMU is made into odometry
    assert sum(e[0] == "odo" for e in out) > 15 and _ordered(out)


def test_an_app_that_pushes_its_own_odometry():
    feed = InertialFeed(RowModel("world"), "auto")
    assert feed.orientation(0.0, [1.0, 0.0, 0.0, 0.0]) == [] and feed.hold(_rssi(0.1)) == []
    ev = ("odo", 0.2, np.zeros(2))
    assert feed.odometry(ev) == [_rssi(0.1), ev] and feed.hold(_rssi(0.3)) == [_rssi(0.3)]
    busy = InertialFeed(RowModel("world"), "ahrs")
    _imu(busy, 0.0)
    with pytest.raises(ValueError, match="push one or the other"):
        busy.odometry(ev)
