"""The gyroscope's yaw held to the attitude's running mean (blenav.filters.yaw_hold, issue 31)."""

from __future__ import annotations

import numpy as np
import pytest

from blenav.filters.quaternions import qmul, quat_to_matrix
from blenav.filters.yaw_hold import StreamingYawHold, hold_yaw, resolve_yaw


def _quat(yaw, pitch, roll):
    """(T, 4) device -> world: Rz(yaw) Ry(pitch) Rx(roll)."""
    def axis(a, k):
        q = np.zeros((len(a), 4))
        q[:, 0], q[:, k] = np.cos(a / 2), np.sin(a / 2)
        return q
    return qmul(axis(yaw, 3), qmul(axis(pitch, 2), axis(roll, 1)))


def _walk(pitch_deg=10.0, n=3000, dt=0.02, seed=0):
    """A phone turning about the vertical (true yaw psi), held at a pitch, and its exact gyroscope (device frame)."""
    rng = np.random.default_rng(seed)
    t = np.arange(n) * dt + 0.003 * rng.random(n)
    t.sort()
    psi = 0.8 * np.sin(0.11 * t) + 0.3 * t / t[-1]
    pitch = np.full(n, np.radians(pitch_deg))
    roll = 0.05 * np.sin(0.7 * t)
    q = _quat(psi, pitch, roll)
    # world angular velocity of the product Rz(psi) Ry(pitch) Rx(roll): psi' about world z, roll' about the device x
    R = quat_to_matrix(q)
    dpsi = np.gradient(psi, t)
    droll = np.gradient(roll, t)
    w_world = np.stack([np.zeros(n), np.zeros(n), dpsi], 1) + R[:, :, 0] * droll[:, None]
    gyr = np.einsum("tji,tj->ti", R, w_world)  # R^T w
    # the gyro taken as constant over [t_i, t_i+1): the rate integrated exactly over each interval instead
    return t, gyr, psi, pitch, roll


def _yaw(q):
    R = quat_to_matrix(q)
    return np.unwrap(np.arctan2(R[:, 1, 0], R[:, 0, 0]))


def test_streaming_is_the_batch_to_the_bit():
    t, gyr, psi, pitch, roll = _walk()
    q = _quat(psi + np.radians(8) * np.sin(0.05 * t), pitch, roll)
    ref = hold_yaw(t, gyr, q)
    h = StreamingYawHold()
    got = np.array([h.update(t[i], gyr[i], q[i]) for i in range(len(t))])
    np.testing.assert_array_equal(got, ref)


@pytest.mark.parametrize("pitch_deg", [10.0, 80.0])
def test_a_wandering_magnetic_heading_is_held_and_tilt_kept(pitch_deg):
    """The attitude's yaw = the truth + a wandering error (zero mean over the walk, 10 deg): the held yaw follows the
    truth to well under the error; the tilt (the device's z axis in the world) is the attitude's."""
    t, gyr, psi, pitch, roll = _walk(pitch_deg)
    err = np.radians(10.0) * np.sin(2 * np.pi * t / 20.0)
    q_att = _quat(psi + err, pitch, roll)
    held = hold_yaw(t, gyr, q_att)
    # the device x axis' yaw is not defined near upright: compare the rotation about world z that takes the truth
    # to each track (the twist of q_track conj(q_true))
    from blenav.filters.quaternions import qconj
    from blenav.filters.yaw_hold import _twist_z

    q_true = _quat(psi, pitch, roll)
    e_att = _twist_z(qmul(q_att, qconj(q_true)))
    e_held = _twist_z(qmul(held, qconj(q_true)))
    late = t > 20.0  # after one period of the error, its running mean is near zero
    assert np.degrees(np.sqrt(np.mean(e_att[late] ** 2))) > 6.5
    assert np.degrees(np.sqrt(np.mean(e_held[late] ** 2))) < 2.0
    np.testing.assert_allclose(quat_to_matrix(held)[:, 2], quat_to_matrix(q_att)[:, 2], atol=1e-12)
    np.testing.assert_allclose(np.linalg.norm(held, axis=1), 1.0, atol=1e-12)


def test_a_constant_offset_stays_and_a_right_attitude_is_unchanged():
    """The held yaw has the attitude's mean: a constant offset is the attitude's, kept (the gyroscope has no north);
    with no error the held track is the attitude (to the gyroscope's integration error)."""
    t, gyr, psi, pitch, roll = _walk()
    q = _quat(psi + np.radians(7.0), pitch, roll)
    held = hold_yaw(t, gyr, q)
    np.testing.assert_allclose(_yaw(held), _yaw(q), atol=np.radians(0.3))
    assert hold_yaw(t[:1], gyr[:1], q[:1]).shape == (1, 4)


def test_the_window_bounds_a_gyro_bias_and_streams_to_the_bit():
    """A gyroscope biased by b about the vertical: the held yaw lags the attitude's mean by about b W / 2 over a window
    of W seconds, not b t / 2 as a mean over the whole session would; live and batch agree with a window shorter than
    the walk."""
    t, gyr, psi, pitch, roll = _walk(n=6000)  # 120 s
    q = _quat(psi, pitch, roll)
    b = 0.002  # rad/s about the device z, which the 10 deg pitch keeps near the vertical
    biased = gyr + np.array([0.0, 0.0, b])
    from blenav.filters.quaternions import qconj
    from blenav.filters.yaw_hold import _twist_z

    for window in (10.0, 30.0):
        held = hold_yaw(t, biased, q, window)
        err = np.degrees(np.abs(_twist_z(qmul(held, qconj(q)))))
        assert err[t > 2 * window].max() < np.degrees(b * window / 2) * 1.3 + 0.1
        h = StreamingYawHold(window)
        got = np.array([h.update(t[i], biased[i], q[i]) for i in range(len(t))])
        np.testing.assert_array_equal(got, held)
    whole = np.degrees(np.abs(_twist_z(qmul(hold_yaw(t, biased, q, 1e9), qconj(q)))))
    assert whole[-1] > np.degrees(b * t[-1] / 2) * 0.8  # the mean over everything lags ever more


def test_auto_holds_only_a_calibrated_gyroscope():
    """``auto``: the gyroscope's yaw where it is calibrated, the attitude's own for a raw (biased) one; an explicit
    source is kept whatever the gyroscope; anything else is refused."""
    assert resolve_yaw("auto", True) == "gyro" and resolve_yaw("auto", False) == "attitude"
    assert resolve_yaw("gyro", False) == "gyro" and resolve_yaw("attitude", True) == "attitude"
    with pytest.raises(ValueError, match="yaw must be one of"):
        resolve_yaw("compass", True)
