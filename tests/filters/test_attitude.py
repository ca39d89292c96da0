"""AHRS front-end (blenav.filters.attitude): accuracy on simulated sessions, streaming == batch, biases,
helpers (gravity compensation, heading, misalignment), hard-iron fit, configuration errors.

Accuracy is checked on the ``small`` preset with a calibrated magnetometer in a clean field
(``mag.hard_iron_std_ut=0``, ``mag.disturbance_ut=0``): this isolates the filters and the frame
conventions from the simulator's indoor magnetic disturbances (8 uT per axis against a 22 uT horizontal
field), which by themselves put the compass 5-20 deg off. The default preset (hard-iron offset fitted
with ``estimate_hard_iron``, disturbances on) is checked with loose bounds in ``test_default_preset``.
"""

from __future__ import annotations

import functools

import numpy as np
import pytest
from blenav.configs import compose

from blenav.data import Dataset
from blenav.filters.attitude import (
    FILTERS,
    AttitudeConfig,
    StreamingAttitude,
    estimate_attitude,
    estimate_hard_iron,
    gravity_compensated_acc,
    misalignment_deg,
    yaw_of_device_forward,
)
from blenav.filters.median import CausalMedian, causal_median
from blenav.filters.quaternions import quat_to_matrix
from blenav.sim.config import make_sim_config
from blenav.sim.world import simulate

SETTLE_S = 5.0


def compose_sim(*overrides: str):
    return compose("sim", *overrides)


def load(ds: Dataset, carrier: str, index: int = 0) -> dict:
    sid = [s for s in ds.session_ids if s.endswith(carrier)][index]
    s = ds.session(sid)
    imu, mag, gt = s.imu, s.mag, s.groundtruth
    d = {"t": imu.t.to_numpy(), "acc": imu[["ax", "ay", "az"]].to_numpy(), "gyr": imu[["gx", "gy", "gz"]].to_numpy(),
         "mag_t": mag.t.to_numpy(), "mag": mag[["mx", "my", "mz"]].to_numpy(),
         "t_gt": gt.t.to_numpy(), "xyz": gt[["x", "y", "z"]].to_numpy(),
         "q_gt": gt[["qw", "qx", "qy", "qz"]].to_numpy()}
    d["gi"] = np.searchsorted(d["t"], d["t_gt"] - 1e-9)  # ground truth is sampled at IMU times
    assert np.allclose(d["t"][d["gi"]], d["t_gt"])
    # evaluation mask: after SETTLE_S, and for a survey also SETTLE_S after each jump between points
    jump = np.r_[True, misalignment_deg(d["q_gt"][1:], d["q_gt"][:-1]) > 1.0]
    last_jump = np.maximum.accumulate(np.where(jump, d["t_gt"], -np.inf))
    d["eval"] = (d["t_gt"] >= SETTLE_S) & (d["t_gt"] - last_jump >= SETTLE_S)
    return d


def cfg_for(name: str, carrier: str) -> AttitudeConfig:
    # a survey moves the device between points off the clock (no gyro signal): reset on
    if carrier == "static":
        return AttitudeConfig(filter=name, reset_deg=20.0, reset_s=0.5)
    return AttitudeConfig(filter=name)


def wrap_deg(a):
    return np.degrees(np.angle(np.exp(1j * np.asarray(a))))


@pytest.fixture(scope="module")
def clean_ds(tmp_path_factory):
    out = tmp_path_factory.mktemp("att") / "clean"
    cfg = make_sim_config(compose_sim("sim=small", "sim.mag.hard_iron_std_ut=0", "sim.mag.disturbance_ut=0").sim)
    simulate(cfg, 0, out, 60.0, 4)  # sessions: pedestrian, pedestrian, robot, static
    return Dataset.open(out)


@pytest.fixture(scope="module")
def clean_run(clean_ds):
    """(filter, carrier) -> (session dict, quaternions at IMU rate), computed once per module."""

    @functools.cache
    def run(name: str, carrier: str):
        d = load(clean_ds, carrier)
        return d, estimate_attitude(d["t"], d["acc"], d["gyr"], d["mag_t"], d["mag"], cfg_for(name, carrier))

    return run


# Measured on seed 0 (60 s, calibrated magnetometer; median over the ground-truth samples after
# settling), deg:
#                    misalignment            |heading error|
#                 madgwick mahony  ekf     madgwick mahony  ekf
#   pedestrian      1.66   1.32   2.30       0.36   0.86   1.76
#   robot           0.55   0.56   3.11       0.30   0.47   3.08
#   static          0.45   1.06   4.93       0.38   1.00   4.65
# (ahrs' EKF has no gyro-bias state: the simulated ~0.01-0.02 rad/s bias costs it 2-5 deg, up to 8 deg
# on the survey of seed 2.) Tolerance: twice the measured value, at least 2 deg.
MEASURED = {  # (filter, carrier): (misalignment, heading error)
    ("madgwick", "pedestrian"): (1.66, 0.36), ("madgwick", "robot"): (0.55, 0.30), ("madgwick", "static"): (0.45, 0.38),
    ("mahony", "pedestrian"): (1.32, 0.86), ("mahony", "robot"): (0.56, 0.47), ("mahony", "static"): (1.06, 1.00),
    ("ekf", "pedestrian"): (2.30, 1.76), ("ekf", "robot"): (3.11, 3.08), ("ekf", "static"): (4.93, 4.65),
}


def tolerance(measured: float) -> float:
    return max(2.0 * measured, 2.0)


@pytest.mark.parametrize("carrier", ["pedestrian", "robot", "static"])
@pytest.mark.parametrize("name", FILTERS)
def test_accuracy_against_ground_truth(clean_run, name, carrier):
    d, q = clean_run(name, carrier)
    assert q.shape == (len(d["t"]), 4)
    assert np.allclose(np.linalg.norm(q, axis=1), 1.0)
    ev = d["eval"]
    mis = misalignment_deg(q[d["gi"]], d["q_gt"])[ev]
    yaw_err = np.abs(wrap_deg(yaw_of_device_forward(q[d["gi"]]) - yaw_of_device_forward(d["q_gt"])))[ev]
    print(f"{name} {carrier}: misalignment median {np.median(mis):.2f} p90 {np.percentile(mis, 90):.2f}, "
          f"|heading error| median {np.median(yaw_err):.2f} deg")
    mis_ref, yaw_ref = MEASURED[name, carrier]
    assert np.median(mis) < tolerance(mis_ref)
    assert np.median(yaw_err) < tolerance(yaw_ref)
    assert np.percentile(mis, 90) < 3 * tolerance(mis_ref)


def test_default_preset(tmp_path):
    """Default magnetic environment (hard iron ~15 uT/axis, fitted; indoor disturbances 8 uT/axis),
    one pedestrian session. Measured on seed 0: misalignment median madgwick 16.6, mahony 16.2,
    ekf 15.3 deg (other seeds and sessions: 7-30 deg); the compass alone (true tilt, hard-iron offset
    from the ground truth) is 15 deg off in the median on this session. Bound: about twice the
    measured value; a frame error gives 90-180 deg."""
    cfg = make_sim_config(compose_sim("sim=small").sim)
    simulate(cfg, 0, tmp_path / "d", 60.0, 1)
    d = load(Dataset.open(tmp_path / "d"), "pedestrian")
    offset = estimate_hard_iron(d["mag"])
    for name in FILTERS:
        q = estimate_attitude(d["t"], d["acc"], d["gyr"], d["mag_t"], d["mag"], AttitudeConfig(filter=name),
                              mag_offset=offset)
        mis = misalignment_deg(q[d["gi"]], d["q_gt"])[d["eval"]]
        print(f"default preset {name}: misalignment median {np.median(mis):.1f} deg")
        assert np.median(mis) < 35.0


def test_initial_orientation_from_accelerometer_and_magnetometer(clean_run):
    d, q = clean_run("madgwick", "robot")
    # flat device, clean field: the first sample alone gives the orientation to about a degree
    assert misalignment_deg(q[0], d["q_gt"][0]) < 3.0


@pytest.mark.parametrize("name", FILTERS)
def test_streaming_equals_batch(clean_ds, name):
    d = load(clean_ds, "pedestrian")
    n = 1600  # 8 s
    t, acc, gyr = d["t"][:n], d["acc"][:n], d["gyr"][:n]
    keep = (d["mag_t"] >= 2.0) & (d["mag_t"] <= t[-1])  # magnetometer starts late: heading alignment path
    mag_t, mag = d["mag_t"][keep], d["mag"][keep]
    rng = np.random.default_rng(1)
    gb = 0.01 * rng.standard_normal((n, 3))  # per-sample gyro bias
    ab = np.array([0.05, -0.02, 0.03])
    off = np.array([1.0, -2.0, 0.5])
    cfg = AttitudeConfig(filter=name, reset_deg=10.0, reset_s=0.2, median_window=4)
    q_batch = estimate_attitude(t, acc, gyr, mag_t, mag, cfg, gyro_bias=gb, acc_bias=ab, mag_offset=off)
    s = StreamingAttitude(cfg, acc_bias=ab, mag_offset=off)
    j = 0
    q_stream = np.empty_like(q_batch)
    for k in range(n):
        # the magnetometer may run ahead: update() only consumes samples with time <= t
        while j < len(mag_t) and mag_t[j] <= t[k] + 0.05:
            s.update_mag(mag_t[j], mag[j])
            j += 1
        q_stream[k] = s.update(t[k], acc[k], gyr[k], gyro_bias=gb[k])
    assert np.array_equal(q_stream, q_batch)


def test_causal_median_batch_and_streaming():
    x = np.random.default_rng(0).standard_normal((50, 3))
    for w in (1, 2, 5):
        batch = causal_median(x, w)
        cm = CausalMedian(w)
        stream = np.array([cm(row) for row in x])
        assert np.array_equal(batch, stream)
        assert np.array_equal(batch[10], np.median(x[10 - w + 1:11], axis=0))  # causal: samples <= k
    x2 = x.copy()
    x2[30:] += 100.0
    assert np.array_equal(causal_median(x2, 5)[:30], causal_median(x, 5)[:30])  # no look-ahead


@pytest.mark.parametrize("name", ["madgwick", "mahony"])
def test_gyro_and_acc_bias_are_subtracted(clean_ds, name):
    d = load(clean_ds, "pedestrian")
    n = 2000
    t, acc, gyr = d["t"][:n], d["acc"][:n], d["gyr"][:n]
    mk = d["mag_t"] <= t[-1]
    cfg = AttitudeConfig(filter=name)
    ref = estimate_attitude(t, acc, gyr, d["mag_t"][mk], d["mag"][mk], cfg)
    b = np.array([0.02, -0.01, 0.03])
    q = estimate_attitude(t, acc, gyr + b, d["mag_t"][mk], d["mag"][mk], cfg, gyro_bias=b)
    assert np.allclose(q, ref, atol=1e-9)
    ramp = np.linspace(0, 0.05, n)[:, None] * np.array([1.0, -1.0, 0.5])  # per-sample (T, 3) biases
    q = estimate_attitude(t, acc + ramp, gyr + ramp, d["mag_t"][mk], d["mag"][mk], cfg, gyro_bias=ramp, acc_bias=ramp)
    assert np.allclose(q, ref, atol=1e-9)
    q_biased = estimate_attitude(t, acc, gyr + b, d["mag_t"][mk], d["mag"][mk], cfg)
    assert np.max(misalignment_deg(q_biased, ref)) > 0.5  # the bias does matter when not removed


def test_gravity_compensated_acc_static(clean_run):
    d, q = clean_run("madgwick", "static")
    a = gravity_compensated_acc(q, d["acc"])
    assert a.shape == d["acc"].shape
    norm = np.linalg.norm(a, axis=1)
    print(f"static: mean |a~| {norm.mean():.3f} m/s^2, |mean a~| {np.linalg.norm(a.mean(0)):.3f}")
    assert norm.mean() < 0.2


def test_gravity_compensated_acc_pedestrian(clean_run):
    """Horizontal world acceleration against the second difference of the 10 Hz ground-truth positions.
    The second difference with step h equals the true acceleration smoothed by a triangle of half-width
    h, so the estimate is smoothed by the same triangle before sampling at the ground-truth times."""
    d, q = clean_run("madgwick", "pedestrian")
    a = gravity_compensated_acc(q, d["acc"])
    h = float(np.median(np.diff(d["t_gt"])))
    dt = float(np.median(np.diff(d["t"])))
    m = int(round(h / dt))
    tri = np.r_[np.arange(1, m + 1), np.arange(m - 1, 0, -1)].astype(float)
    tri /= tri.sum()
    a_s = np.stack([np.convolve(a[:, i], tri, mode="same") for i in range(3)], axis=1)[d["gi"]]
    a_gt = np.full_like(d["xyz"], np.nan)
    a_gt[1:-1] = (d["xyz"][2:] - 2 * d["xyz"][1:-1] + d["xyz"][:-2]) / h**2
    ok = d["eval"] & np.isfinite(a_gt[:, 0])
    ok[:1] = ok[-1:] = False
    corr = [np.corrcoef(a_s[ok, i], a_gt[ok, i])[0, 1] for i in range(2)]
    rms = np.sqrt(np.mean((a_s[ok, :2] - a_gt[ok, :2]) ** 2))
    print(f"pedestrian: horizontal correlation x {corr[0]:.3f} y {corr[1]:.3f}, rms error {rms:.3f} m/s^2, "
          f"gt rms {np.sqrt(np.mean(a_gt[ok, :2] ** 2)):.3f}")
    # measured (seed 0, Madgwick): correlation x 0.970, y 0.981; rms error 0.21 of 1.08 m/s^2
    assert min(corr) > 0.85
    assert rms < 0.45
    still = gravity_compensated_acc(np.array([1.0, 0, 0, 0]), np.array([[0.0, 0.0, 9.80665]]))
    assert np.allclose(still, 0.0)


def test_misalignment_deg():
    rng = np.random.default_rng(0)
    q = rng.standard_normal((20, 4))
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    assert np.allclose(misalignment_deg(q, q), 0.0, atol=1e-6)
    assert np.allclose(misalignment_deg(-q, q), 0.0, atol=1e-6)  # q and -q are the same rotation
    qz90 = np.array([np.cos(np.pi / 4), 0.0, 0.0, np.sin(np.pi / 4)])
    assert np.isclose(misalignment_deg(qz90, np.array([1.0, 0, 0, 0])), 90.0)
    # right-multiplied error (R_est = R_gt R_x(90)) and any R_gt: still 90
    qx90 = np.array([np.cos(np.pi / 4), np.sin(np.pi / 4), 0.0, 0.0])
    w, x, y, z = q.T
    a, b = qx90[0], qx90[1]
    q_est = np.stack([w * a - x * b, w * b + x * a, y * a + z * b, z * a - y * b], axis=1)
    assert np.allclose(misalignment_deg(q_est, q), 90.0)
    assert np.allclose(quat_to_matrix(q_est), quat_to_matrix(q) @ quat_to_matrix(qx90))


def test_yaw_of_device_forward():
    # identity: device +y (top of the screen) points north = 90 deg CCW from east
    assert np.isclose(yaw_of_device_forward(np.array([[1.0, 0, 0, 0]]))[0], np.pi / 2)
    # turned 90 deg CCW about up: the top points west
    qz90 = np.array([[np.cos(np.pi / 4), 0.0, 0.0, np.sin(np.pi / 4)]])
    assert np.isclose(abs(yaw_of_device_forward(qz90)[0]), np.pi)


def test_estimate_hard_iron():
    from scipy.spatial.transform import Rotation

    rot = Rotation.random(400, random_state=0)
    offset = np.array([12.0, -20.0, 7.0])
    m = rot.inv().apply([0.0, 22.0, -42.0]) + offset + 0.3 * np.random.default_rng(0).standard_normal((400, 3))
    assert np.allclose(estimate_hard_iron(m), offset, atol=0.5)


def test_unknown_filter_name():
    with pytest.raises(ValueError, match="madgwick"):
        AttitudeConfig(filter="kalman")
    cfg = AttitudeConfig()
    cfg.filter = "complementary"
    with pytest.raises(ValueError, match="choose one of"):
        estimate_attitude(np.arange(3) * 0.01, np.tile([0, 0, 9.8], (3, 1)), np.zeros((3, 3)), cfg=cfg)


def test_a_resumed_run_is_the_whole_run_to_the_bit():
    """attitude_states resumed at a sample from a run on the same inputs before it (a bias correction from there on)
    gives the whole run's states; settings whose state is more than the quaternion are refused."""
    from blenav.filters.attitude import AttitudeConfig, attitude_states, estimate_attitude, to_world

    rng = np.random.default_rng(3)
    n = 2000
    t = np.cumsum(0.01 + 0.002 * rng.random(n))
    acc = np.array([0.0, 0.0, 9.81]) + 0.3 * rng.standard_normal((n, 3))
    gyr = 0.2 * rng.standard_normal((n, 3)) + np.array([0.0, 0.0, 0.3])
    mag_t = t[5::2] + 0.001  # the magnetometer starts late: the heading aligns at its first sample
    mag = np.array([0.0, 22.0, -40.0]) + rng.standard_normal((len(mag_t), 3))
    cfg = AttitudeConfig()
    first = attitude_states(t, acc, gyr, mag_t, mag, cfg)
    for start in (3, 7, 1234):  # before the first magnetometer sample, right after it, and later
        gyr2 = gyr.copy()
        gyr2[start:] -= np.array([0.01, -0.02, 0.005])
        whole = attitude_states(t, acc, gyr2, mag_t, mag, cfg)
        resumed = attitude_states(t, acc, gyr2, mag_t, mag, cfg, start=start, prev=first)
        np.testing.assert_array_equal(resumed, whole)
        assert np.abs(whole[start:] - first[start:]).max() > 0  # the correction changed what follows
    np.testing.assert_array_equal(to_world(first, cfg), estimate_attitude(t, acc, gyr, mag_t, mag, cfg))
    with pytest.raises(ValueError, match="cannot be resumed"):
        attitude_states(t, acc, gyr, mag_t, mag, AttitudeConfig(filter="mahony"), start=10, prev=first)
