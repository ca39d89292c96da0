"""Inertial and magnetic sensors, and an inertial-odometry stream, from a :class:`Trajectory`.

Accelerometer (device frame, m/s^2, incl. gravity): f = R^T (a_world + [0, 0, g]) + b_a + n_a, with
a_world the second derivative of the true position (so gait bounce and sway are consistent with the
ground truth) and b_a a bias random walk. Gyroscope (device frame, rad/s): the body rate from
consecutive orientations, omega = log(R_{k-1}^T R_{k+1}) / (2 dt), + b_g + n_g.
Magnetometer (device frame, uT, at ``mag_rate_hz``): m = R^T (B_earth + D(p)) + h + n, with D a
smooth indoor disturbance field (per component Gaussian random field) and h the device's hard-iron
offset. Odometry (arbitrary frame, m, at ``odo_rate_hz``): the true velocity scaled by (1 + s),
rotated by a heading error that drifts linearly plus a random walk, plus (``vel_noise_mps`` > 0) a
velocity error that is AR(1) in time with correlation time ``vel_noise_tau_s`` -- the seconds-long
over- and under-shoots of a learned inertial-odometry network, which the other terms lack -- integrated,
in a frame rotated and shifted at random.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.signal import lfilter
from scipy.spatial.transform import Rotation

from .motion import Trajectory
from .radio import gaussian_field

GRAVITY = 9.80665


@dataclass
class ImuConfig:
    acc_noise: float = 0.05  # m/s^2 per sample
    gyro_noise: float = 0.004  # rad/s per sample
    acc_bias_std: float = 0.05  # m/s^2 initial
    gyro_bias_std: float = 0.01  # rad/s initial
    acc_bias_rw: float = 0.001  # m/s^2 / sqrt(s)
    gyro_bias_rw: float = 0.0002  # rad/s / sqrt(s)
    hand_tremor: float = 0.15  # m/s^2, carried in hand (pedestrian only)


@dataclass
class MagConfig:
    rate_hz: float = 50.0
    earth_ut: tuple[float, float, float] = (0.0, 22.0, -42.0)  # x east, y north, z up
    disturbance_ut: float = 8.0
    disturbance_corr_m: float = 1.5
    hard_iron_std_ut: float = 15.0
    noise_ut: float = 0.6


@dataclass
class OdometryConfig:
    rate_hz: float = 5.0
    scale_std: float = 0.05
    drift_deg_per_min_std: float = 1.5
    heading_rw_deg: float = 0.3  # deg / sqrt(s)
    noise_m: float = 0.02
    vel_noise_mps: float = 0.0  # std of the AR(1) velocity error per axis while moving (0: off, no draws)
    vel_noise_tau_s: float = 3.0  # its correlation time


def _random_walk(rng, n: int, dt: float, std0: float, rw: float, dims: int = 3) -> np.ndarray:
    return std0 * rng.standard_normal(dims) + np.cumsum(rng.standard_normal((n, dims)) * rw * np.sqrt(dt), axis=0)


def simulate_imu(rng: np.random.Generator, cfg: ImuConfig, traj: Trajectory, hand: bool) -> np.ndarray:
    """(T, 6) accelerometer (m/s^2) and gyroscope (rad/s) at the trajectory's times."""
    dt = float(traj.t[1] - traj.t[0])
    acc_w = np.zeros_like(traj.xyz)
    omega = np.zeros_like(traj.xyz)
    for seg in traj.segments():  # derivatives never straddle a jump of the trajectory
        if seg.stop - seg.start < 3:
            continue
        acc_w[seg] = np.gradient(np.gradient(traj.xyz[seg], dt, axis=0), dt, axis=0)
        q = traj.rot[seg]
        m = seg.stop - seg.start
        prev = np.concatenate([[0], np.arange(m - 1)])
        nxt = np.concatenate([np.arange(1, m), [m - 1]])
        omega[seg] = (q[prev].inv() * q[nxt]).as_rotvec() / ((nxt - prev) * dt)[:, None]
    acc_w[:, 2] += GRAVITY
    f = traj.rot.inv().apply(acc_w)
    n = len(traj.t)
    f += _random_walk(rng, n, dt, cfg.acc_bias_std, cfg.acc_bias_rw) + cfg.acc_noise * rng.standard_normal((n, 3))
    if hand:
        f += cfg.hand_tremor * rng.standard_normal((n, 3))
    omega += _random_walk(rng, n, dt, cfg.gyro_bias_std, cfg.gyro_bias_rw) + cfg.gyro_noise * rng.standard_normal((n, 3))
    return np.hstack([f, omega])


class DisturbanceField:
    """Indoor magnetic disturbance D(x, y) (uT), three smooth Gaussian random fields on a 0.25 m grid."""

    def __init__(self, rng, cfg: MagConfig, width_m: float, height_m: float, grid_m: float = 0.25):
        self.g = grid_m
        self.f = cfg.disturbance_ut * gaussian_field(
            rng, (3, int(height_m / grid_m) + 2, int(width_m / grid_m) + 2), cfg.disturbance_corr_m / grid_m)

    def __call__(self, xy: np.ndarray) -> np.ndarray:
        from scipy.ndimage import map_coordinates

        fi, fj = xy[:, 1] / self.g, xy[:, 0] / self.g
        return np.stack([map_coordinates(self.f[k], [fi, fj], order=1, mode="nearest") for k in range(3)], axis=1)


def simulate_mag(rng, cfg: MagConfig, traj: Trajectory, field: DisturbanceField) -> tuple[np.ndarray, np.ndarray]:
    """(t, (N, 3) uT) magnetometer samples at cfg.rate_hz."""
    step = max(1, int(round((1.0 / cfg.rate_hz) / (traj.t[1] - traj.t[0]))))
    idx = np.arange(0, len(traj.t), step)
    b_w = np.asarray(cfg.earth_ut)[None, :] + field(traj.xyz[idx, :2])
    hard = cfg.hard_iron_std_ut * rng.standard_normal(3)
    m = traj.rot[idx].inv().apply(b_w) + hard + cfg.noise_ut * rng.standard_normal((len(idx), 3))
    return traj.t[idx], m


def ar1_noise(rng, n: int, dt: float, std: float, tau_s: float, dims: int = 2) -> np.ndarray:
    """(n, dims) stationary AR(1) noise with standard deviation ``std`` and correlation time ``tau_s`` s
    at step ``dt`` s: e_k = a e_(k-1) + sqrt(1 - a^2) std w_k, a = exp(-dt / tau_s), e_0 ~ N(0, std^2)."""
    a = float(np.exp(-dt / tau_s)) if tau_s > 0 else 0.0
    w = rng.standard_normal((n, dims)) * std
    w[1:] *= np.sqrt(1.0 - a * a)
    return lfilter([1.0], [1.0, -a], w, axis=0)


def simulate_odometry(rng, cfg: OdometryConfig, traj: Trajectory) -> tuple[np.ndarray, np.ndarray]:
    """(t, (N, 2) m) inertial-odometry positions in an arbitrary frame fixed at session start."""
    step = max(1, int(round((1.0 / cfg.rate_hz) / (traj.t[1] - traj.t[0]))))
    idx = np.arange(0, len(traj.t), step)
    t = traj.t[idx]
    xy = traj.xyz[idx, :2]
    v = np.diff(xy, axis=0)
    dt = np.diff(t)
    scale = 1.0 + cfg.scale_std * rng.standard_normal()
    drift = np.radians(cfg.drift_deg_per_min_std * rng.standard_normal()) / 60.0
    err = drift * t[1:] + np.cumsum(np.radians(cfg.heading_rw_deg) * np.sqrt(dt) * rng.standard_normal(len(dt)))
    c, s = np.cos(err), np.sin(err)
    vo = scale * np.stack([c * v[:, 0] - s * v[:, 1], s * v[:, 0] + c * v[:, 1]], axis=1)
    moving = np.linalg.norm(v, axis=1, keepdims=True) > 1e-4
    vo += cfg.noise_m * rng.standard_normal(vo.shape) * moving
    if cfg.vel_noise_mps > 0:  # drawn only when on, so datasets simulated without it are unchanged
        vo += ar1_noise(rng, len(dt), float(np.median(dt)), cfg.vel_noise_mps, cfg.vel_noise_tau_s) * dt[:, None] * moving
    pos = np.vstack([[0.0, 0.0], np.cumsum(vo, axis=0)])
    frame = Rotation.from_euler("z", rng.uniform(-np.pi, np.pi)).as_matrix()[:2, :2]
    return t, pos @ frame.T
