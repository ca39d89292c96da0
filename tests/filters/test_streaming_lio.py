"""The learned inertial odometry one sample at a time (issue 31, the push API): StreamingLio gives lio_odometry's
track, point for point, with either attitude and either input frame."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from helpers import RowModel, as_waypoint_walks, simulate_small

from blenav.data import Dataset
from blenav.filters.attitude import AttitudeConfig
from blenav.filters.inertial_odometry import StreamingLio, lio_odometry
from blenav.filters.runner import hard_iron_offset
from blenav.filters.steps import SessionArrays
from blenav.filters.measurement import AnchorTable


@pytest.fixture(scope="module")
def walk(tmp_path_factory):
    root = as_waypoint_walks(simulate_small(tmp_path_factory.mktemp("slio") / "d", 4, 30, 1))
    ds = Dataset.open(root)
    return ds.session(ds.session_ids[0])


def _stream(walk, model, attitude, mag_offset=None, gyro_calibrated=None):
    lio = StreamingLio(model, attitude, mag_offset=mag_offset, gyro_calibrated=gyro_calibrated)
    ev = [(float(t), 1, np.array(q)) for t, *q in walk.orientation[["t", "qw", "qx", "qy", "qz"]].itertuples(index=False)]
    ev += [(float(t), 0, np.array(m)) for t, *m in walk.mag[["t", "mx", "my", "mz"]].itertuples(index=False)]
    ev += [(float(r.t), 2, np.array([r.ax, r.ay, r.az]), np.array([r.gx, r.gy, r.gz]))
           for r in walk.imu.itertuples(index=False)]
    pts = []
    for e in sorted(ev, key=lambda e: (e[0], e[1])):  # time order: magnetometer, then orientation, then IMU at one time
        if e[1] == 0:
            lio.push_mag(e[0], e[2])
        elif e[1] == 1:
            pts += lio.push_orientation(e[0], e[2])
        else:
            pts += lio.push_imu(e[0], e[2], e[3])
    return np.array([[t, *xy, var] for t, xy, var in pts])


@pytest.mark.parametrize("frame,yaw", [("world", "attitude"), ("heading", "attitude"), ("world", "gyro")])
@pytest.mark.parametrize("attitude", ["orientation", "ahrs"])
def test_streaming_lio_is_the_batch_track(walk, attitude, frame, yaw):
    model = RowModel(frame, yaw)
    ref = lio_odometry(walk, model, attitude)[["t", "x", "y", "var"]].to_numpy()
    off = hard_iron_offset(SessionArrays.from_session(walk, AnchorTable.empty()), AttitudeConfig())
    got = _stream(walk, model, attitude, off)
    assert len(ref) > 40 and got.shape == ref.shape
    np.testing.assert_array_equal(got, ref)


@pytest.mark.parametrize("calibrated", [True, False])
@pytest.mark.parametrize("attitude", ["orientation", "ahrs"])
def test_auto_yaw_follows_the_sessions_gyroscope_live_and_batch(walk, attitude, calibrated):
    """A model trained with ``yaw: auto`` holds the yaw of a session whose gyroscope is calibrated and keeps the
    attitude's of a raw one: batch (session.yaml ``gyro_calibrated``) and live (``gyro_calibrated=``) alike."""
    s = replace(walk, meta={**walk.meta, "gyro_calibrated": calibrated})
    ref = lio_odometry(s, RowModel("world", "auto"), attitude)[["t", "x", "y", "var"]].to_numpy()
    same = lio_odometry(s, RowModel("world", "gyro" if calibrated else "attitude"), attitude)
    other = lio_odometry(s, RowModel("world", "attitude" if calibrated else "gyro"), attitude)
    np.testing.assert_array_equal(same[["t", "x", "y", "var"]].to_numpy(), ref)
    assert np.abs(other[["x", "y"]].to_numpy() - ref[:, 1:3]).max() > 1e-6
    off = hard_iron_offset(SessionArrays.from_session(s, AnchorTable.empty()), AttitudeConfig())
    np.testing.assert_array_equal(_stream(s, RowModel("world", "auto"), attitude, off, calibrated), ref)


def test_streaming_lio_waits_for_its_attitude_and_refuses_bad_input(walk):
    model = RowModel("world")
    lio = StreamingLio(model, "orientation")
    assert lio.push_imu(0.0, [0, 0, 9.8], [0, 0, 0]) == []  # no rotation vector yet: held, not guessed
    assert len(lio.push_orientation(0.01, [1, 0, 0, 0])) == 1  # the origin, once the attitude exists
    with pytest.raises(ValueError, match="backwards"):
        lio.push_imu(-1.0, [0, 0, 9.8], [0, 0, 0])
    with pytest.raises(ValueError, match="attitude must be one of"):
        StreamingLio(model, "groundtruth")


def test_a_repeated_time_stamp_and_a_clock_jump(walk, tmp_path):
    """An IMU row repeated at its time (off the network's grid) gives the batch track (the later sample, as the batch
    interpolation reads it); a jump of the clock by more than MAX_GAP_S is refused at once, not a network run per
    stride of the gap."""
    import shutil

    from blenav.filters.inertial_odometry import MAX_GAP_S

    root = shutil.copytree(walk.root.parent.parent, tmp_path / "dup")
    imu = walk.imu.copy()
    imu["t"] += 0.0011 * (np.arange(len(imu)) % 3)  # jittered, so the network's grid falls between samples
    t = imu["t"].to_numpy()
    g = t[0] + np.arange(int((t[-1] - t[0]) * 50.0)) / 50.0
    inside = np.searchsorted(g, t[:-1], side="right") < np.searchsorted(g, t[1:], side="left")  # a grid time after it
    i = int(np.flatnonzero(inside)[10])
    dup = imu.iloc[[i]].copy()
    dup[["ax", "gy"]] += [0.7, 0.2]
    imu2 = __import__("pandas").concat([imu.iloc[: i + 1], dup, imu.iloc[i + 1:]], ignore_index=True)
    imu2.to_csv(root / "sessions" / walk.id / "imu.csv", index=False, float_format="%.17g")
    w2 = Dataset.open(root).session(walk.id)
    for dup_after in (False, True):  # a grid time after the repeated row, and one just before it
        if dup_after:
            j = int(np.flatnonzero(inside)[20]) + 1
            imu3 = __import__("pandas").concat([imu.iloc[: j + 1], imu.iloc[[j]], imu.iloc[j + 1:]], ignore_index=True)
            imu3.loc[j + 1, ["ax", "gz"]] += [0.7, 0.3]
            imu3.to_csv(root / "sessions" / walk.id / "imu.csv", index=False, float_format="%.17g")
            w2 = Dataset.open(root).session(walk.id)
        for yaw in ("attitude", "gyro"):  # the held yaw gives each repeated row its own attitude, as live
            model = RowModel("world", yaw)
            ref = lio_odometry(w2, model, "orientation")[["t", "x", "y", "var"]].to_numpy()
            np.testing.assert_array_equal(_stream(w2, model, "orientation"), ref)
    model = RowModel("world")
    lio = StreamingLio(model, "ahrs")
    lio.push_imu(0.0, [0, 0, 9.8], [0, 0, 0])
    with pytest.raises(ValueError, match="time jumps from 0.000 s to"):
        lio.push_imu(MAX_GAP_S + 1.0, [0, 0, 9.8], [0, 0, 0])
