"""Motion models (proposals) of the particle filter, acting on all runs and particles at once.

State of a particle (shape (R, N, D), R runs, N particles): ``x[..., 0:2]`` position (m, world x/y),
``x[..., 2:4]`` velocity (m/s, world), and for :class:`OdometryIncrement` ``x[..., 4]`` the rotation
(rad) from the odometry frame to the world frame. The filter is planar: floor plans and anchors fix the
height, so 000's 3-D state (p, p_dot) in R^6 is used with its horizontal components (the vertical axis is
not observable from ceiling-height beacons and the device stays on one floor).

Per-step controls (built from the sensors by :mod:`blenav.filters.steps`):

* ``acc_w`` (2,): gravity-compensated world acceleration, horizontal, mean over the step (m/s^2);
* ``heading`` (rad, CCW from +x): AHRS heading of the device's forward (+y) axis at the step's end;
* ``steps`` (int): steps detected by PDR in the step window;
* ``odo`` (2,): inertial-odometry displacement over the step, in the odometry frame (m).

Parameters default to Table I of Ghaffari Jadidi et al. (RW, DR, IMU) and to Roy's section 3.2
(odometry increment).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from . import motion_kernels as K


class MotionModel:
    """Base: ``propagate(x, ctrl, dt, rng) -> x_new``; ``state_dim``; ``init_state(xy, rng)``."""

    state_dim = 4
    #: which per-step controls the model reads (the step builder computes only what is needed)
    needs: tuple[str, ...] = ()
    #: state column of an odometry-to-world frame angle, None when the state has none
    frame_angle_col: int | None = None

    def init_state(self, xy: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        """Full state (R, N, D) from positions (R, N, 2): zero velocity."""
        x = np.zeros(xy.shape[:-1] + (self.state_dim,))
        x[..., :2] = xy
        return x

    def propagate(self, x: np.ndarray, ctrl: dict, dt: float, rng: np.random.Generator) -> np.ndarray:
        raise NotImplementedError


@dataclass
class RandomWalk(MotionModel):
    """Constant velocity with random input (000, ref. [9]): v' = v + nu, p' = p + dt v' + eps.

    nu ~ N(0, sigma_v^2 I) (m/s), eps ~ N(0, sigma_p^2 I) (m). Table I of Ghaffari Jadidi et al.:
    sigma_p = 0.1 m, sigma_v = 0.05 m/s.
    """

    sigma_p: float = 0.1
    sigma_v: float = 0.05
    max_speed: float = 3.0

    def propagate(self, x, ctrl, dt, rng):
        e = rng.standard_normal(x.shape[:-1] + (4,))  # one draw: (nu, eps)
        # compiled (motion_kernels.random_walk: one pass, the numbers of v' = clip(v + sigma_v nu),
        # p' = p + dt v' + sigma_p eps as numpy computed them)
        D = x.shape[-1]
        return K.random_walk(x.reshape(-1, D), e.reshape(-1, 4), float(dt), float(self.sigma_v), float(self.sigma_p),
                             float(self.max_speed)).reshape(x.shape)


class _HeadingOffset(MotionModel):
    """Models that walk along the AHRS heading carry a per-particle heading offset in state column 4.

    Indoors the magnetometer is disturbed by steel and wiring, so an AHRS heading is typically off by
    tens of degrees, and slowly varying. Each particle holds its own offset (rad), drawn from
    N(0, heading_offset_std^2) at start and random-walking by ``heading_offset_rw`` rad per sqrt(s); the
    measurements select the offsets that fit. heading_offset_std = 0 gives the model of the paper.
    """

    state_dim = 5
    heading_offset_std: float = 0.0
    heading_offset_rw: float = 0.0

    def init_state(self, xy, rng):
        x = super().init_state(xy, rng)
        x[..., 4] = self.heading_offset_std * rng.standard_normal(xy.shape[:-1])
        return x

    def _heading(self, x, ctrl, dt, rng):
        off = x[..., 4]
        if self.heading_offset_rw > 0:
            off = off + self.heading_offset_rw * np.sqrt(dt) * rng.standard_normal(off.shape)
        return ctrl["heading"] + off, off


@dataclass
class DeadReckoning(_HeadingOffset):
    """Constant increment along the AHRS heading plus velocity noise (000, section VI.B).

    p' = p + delta [cos psi, sin psi] + dt nu, nu ~ N(0, sigma_v^2 I), psi = AHRS heading + the
    particle's heading offset (see :class:`_HeadingOffset`; 0 in the paper). Table I: delta = 0.075 m
    per step, sigma_v = 0.03 m/s. The velocity columns hold the increment rate.
    """

    increment_m: float = 0.075
    sigma_v: float = 0.03
    heading_offset_std: float = 0.0
    heading_offset_rw: float = 0.0
    needs = ("heading",)

    def propagate(self, x, ctrl, dt, rng):
        psi, off = self._heading(x, ctrl, dt, rng)
        step = self.increment_m * np.stack([np.cos(psi), np.sin(psi)], axis=-1)
        noise = dt * self.sigma_v * rng.standard_normal(x.shape[:-1] + (2,))
        return _moved(x, step + noise, dt, off)


@dataclass
class ImuProposal(MotionModel):
    """The probabilistic IMU motion model of Ghaffari Jadidi et al., eqs. 4-7.

    x_bar' = F x_bar + G u with x_bar = (p, p_dot), F = [[I, t_s I], [0, I]],
    G = [[t_s^2/2 I, t_s I], [t_s I, I]] (eq. 5) and u = (zeta a_hat, nu), where
    a_hat = a_tilde / ||a_tilde|| is the direction of the gravity-compensated world acceleration
    a_tilde = R a + g (eqs. 6-7; zero when ||a_tilde|| < ``min_acc``), zeta ~ N(0, sigma_a^2) one scalar
    per particle, nu ~ N(0, sigma_v^2 I). Expanded:

        p' = p + t_s p_dot + t_s^2/2 zeta a_hat + t_s nu
        p_dot' = p_dot + t_s zeta a_hat + nu

    Table I: sigma_a = 1.5 m/s^2, sigma_v = 0.005 m/s. ``max_speed`` caps |p_dot| (a walking person or
    an indoor robot) so that a long run of same-sign draws cannot fling a particle across the building.
    """

    sigma_a: float = 1.5
    sigma_v: float = 0.005
    min_acc: float = 0.05
    max_speed: float = 2.5
    needs = ("acc_w",)

    def propagate(self, x, ctrl, dt, rng):
        a = np.asarray(ctrl["acc_w"], dtype=float)[:2]
        na = np.hypot(a[0], a[1])
        a_hat = a / na if na >= self.min_acc else np.zeros(2)  # eq. 7
        shape = x.shape[:-1]
        z = rng.standard_normal(shape + (1,))  # zeta / sigma_a
        n = rng.standard_normal(shape + (2,))  # nu / sigma_v
        # compiled (motion_kernels.imu_proposal): per particle, u = zeta a_hat,
        #   p' = p + dt p_dot + dt^2/2 u + dt nu, p_dot' = p_dot + dt u + nu (eqs. 4-5), then the speed cap
        D = x.shape[-1]
        return K.imu_proposal(x.reshape(-1, D), z.reshape(-1), n.reshape(-1, 2), float(a_hat[0]), float(a_hat[1]),
                              float(dt), float(self.sigma_a), float(self.sigma_v),
                              float(self.max_speed)).reshape(x.shape)


@dataclass
class OdometryIncrement(MotionModel):
    """Roy, eq. 3.7: x' = x + R(theta) delta_o + eta, eta ~ N(0, Sigma), Sigma = sigma^2 I.

    delta_o is the inertial-odometry displacement over the step in the odometry frame (arbitrary,
    fixed at session start), rotated into the world by the particle's own theta (state column 4): theta
    starts uniform in [-pi, pi) (or at ``theta0`` when the alignment is known) and random-walks with
    ``sigma_theta`` rad per step. Roy writes Sigma = 0.1 I "m" at 1 Hz; we read 0.1 as the covariance
    in m^2 per 1 s step and scale it with the step length (sigma = sqrt(0.1 dt)).

    ``odo_var_scale`` (issue 31): Sigma = odo_var_scale x the odometry's own variance growth over the step (control
    ``odo_var``, m^2 per axis: the learned inertial odometry's covariance head, TLIO-style) where the track states one,
    Roy's 0.1 dt elsewhere (a track without variance, a step where it did not grow); None: always Roy's.
    """

    sigma2_per_s: float = 0.1
    sigma_theta: float = 0.01
    theta0: float | None = None
    odo_var_scale: float | None = None
    state_dim = 5

    def __post_init__(self):
        if self.odo_var_scale is not None and not (np.isfinite(self.odo_var_scale) and self.odo_var_scale > 0):
            raise ValueError(f"motion.odo_var_scale must be a positive number or null, got {self.odo_var_scale!r}")
    needs = ("odo",)
    #: state column of the odometry-to-world frame angle (read by the map prior's heading bins and set by an
    #: oracle start, see :class:`blenav.filters.method.MapSpec` ``heading``)
    frame_angle_col = 4

    def init_state(self, xy, rng):
        x = super().init_state(xy, rng)
        x[..., 4] = self.theta0 if self.theta0 is not None else rng.uniform(-np.pi, np.pi, xy.shape[:-1])
        return x

    def propagate(self, x, ctrl, dt, rng):
        d = np.asarray(ctrl["odo"], dtype=float)
        th = x[..., 4] + self.sigma_theta * rng.standard_normal(x.shape[:-1])
        c, s = np.cos(th), np.sin(th)
        step = np.stack([c * d[0] - s * d[1], s * d[0] + c * d[1]], axis=-1)
        var = self.sigma2_per_s * dt
        if self.odo_var_scale is not None:
            g = float(ctrl.get("odo_var", 0.0))
            if np.isfinite(g) and g > 0.0:
                var = self.odo_var_scale * g
        eta = np.sqrt(var) * rng.standard_normal(x.shape[:-1] + (2,))
        return _moved(x, step + eta, dt, th)


@dataclass
class Pdr(_HeadingOffset):
    """Step-detection pedestrian dead reckoning: each detected step moves step_length along the heading.

    p' = p + n (L + N(0, sigma_L^2)) [cos(psi + dpsi), sin(psi + dpsi)] + N(0, sigma_p^2 I), with
    psi = AHRS heading + the particle's heading offset (:class:`_HeadingOffset`), dpsi ~ N(0,
    sigma_heading^2) per step; n = steps detected in the window (:class:`blenav.filters.steps.StepDetector`).
    """

    step_length: float = 0.7
    sigma_length: float = 0.1
    sigma_heading: float = 0.1
    sigma_p: float = 0.02
    heading_offset_std: float = 0.5
    heading_offset_rw: float = 0.02
    needs = ("heading", "steps")

    def propagate(self, x, ctrl, dt, rng):
        n = float(ctrl["steps"])
        shape = x.shape[:-1]
        psi0, off = self._heading(x, ctrl, dt, rng)
        move = np.zeros(shape + (2,))
        if n > 0:
            L = n * (self.step_length + self.sigma_length * rng.standard_normal(shape))
            psi = psi0 + self.sigma_heading * rng.standard_normal(shape)
            move = np.stack([L * np.cos(psi), L * np.sin(psi)], axis=-1)
        return _moved(x, move + self.sigma_p * rng.standard_normal(shape + (2,)), dt, off)


def _moved(x: np.ndarray, move: np.ndarray, dt: float, col4: np.ndarray) -> np.ndarray:
    """New state: position += move (R, N, 2), velocity = move / dt, column 4 = col4."""
    out = x.copy()
    out[..., :2] = x[..., :2] + move
    out[..., 2:4] = move / dt
    out[..., 4] = col4
    return out
