"""The RSSI factor of the beacon mapping (:mod:`blenav.backend.mapping`): the log-distance path-loss prediction
with body shadow, wall loss and receiver offset, its whitened residuals made robust as GTSAM's M-estimators
weigh them (r = sign(u) sqrt(2 rho(u)), so that 0.5 ||r||^2 = sum rho(u)), and their Jacobians; numpy only,
the error function of a ``gtsam.CustomFactor``.
"""

from __future__ import annotations

import numpy as np

from .config import RobustKernel, mapping_kernel
from .mapping_readings import Readings

__all__ = ["LN10", "D_MIN", "robust_sqrt", "rssi_error", "residual_db"]

LN10 = np.log(10.0)
D_MIN = 0.5  # m: distances below are floored (the model is not meant for the near field)


def robust_sqrt(u: np.ndarray, kernel: RobustKernel, k: float) -> tuple[np.ndarray, np.ndarray]:
    """(r, dr/du) with r = sign(u) sqrt(2 rho(u)) for GTSAM's M-estimators (``noiseModel.mEstimator``):
    Huber rho = u^2/2 (|u| <= k), k|u| - k^2/2; Cauchy rho = k^2/2 log(1 + u^2/k^2); none: r = u."""
    u = np.asarray(u, float)
    kernel = mapping_kernel(kernel)
    if kernel == RobustKernel.none:
        return u.copy(), np.ones_like(u)
    a = np.abs(u)
    if kernel == RobustKernel.huber:
        rho = np.where(a <= k, 0.5 * u * u, k * a - 0.5 * k * k)
        psi = np.where(a <= k, u, k * np.sign(u))
    else:
        rho = 0.5 * k * k * np.log1p((u / k) ** 2)
        psi = u / (1.0 + (u / k) ** 2)
    r = np.sign(u) * np.sqrt(2.0 * rho)
    small = a < 1e-9
    drdu = np.where(small, 1.0, psi / np.where(small, 1.0, r))
    return np.where(small, u, r), drdu


def rssi_error(P: np.ndarray, rssi: np.ndarray, heading: np.ndarray | None, walls: np.ndarray | None,
               sigma_db: float, kernel: RobustKernel, k: float, gamma_fixed: float | None, has_body: bool,
               has_offset: bool, this, values, H) -> np.ndarray:
    """Stacked robust residuals (n,) of n readings ``rssi`` (n,) dBm taken at positions P (n, 3) world m.

    ``heading`` (n, 2): unit walking direction (world x, y) per reading, zero when not walking; with
    ``has_body`` the body's shadow is W * (1 - cos theta) / 2, theta between the walking direction and the
    direction to the beacon (W / 2 when not walking), W a variable (dB). ``walls`` (n,): walls crossed by each
    line of sight (held fixed: counted at the previous estimate), times a per-wall loss M (dB, a variable).
    Keys of ``this``: L(j) (Point3), A(j) (1-D dBm), then G (1-D, when ``gamma_fixed`` is None), then W (1-D
    dB, when ``has_body``), then M (1-D dB, when ``walls`` is given), then O(s) (1-D dB, when ``has_offset``).
    Jacobians, when ``H`` is given, in that order."""
    keys = this.keys()
    l = values.atPoint3(keys[0])
    a = values.atVector(keys[1])[0]
    i = 2
    i_gamma = i_body = None
    if gamma_fixed is None:
        gam, i_gamma, i = values.atVector(keys[i])[0], i, i + 1
    else:
        gam = gamma_fixed
    if has_body:
        w, i_body, i = values.atVector(keys[i])[0], i, i + 1
    i_wall = None
    if walls is not None:
        m_wall, i_wall, i = values.atVector(keys[i])[0], i, i + 1
    off = values.atVector(keys[i])[0] if has_offset else 0.0
    diff = l - P  # (n, 3)
    d_raw = np.sqrt(np.einsum("ij,ij->i", diff, diff))
    d = np.maximum(d_raw, D_MIN)
    log_d = np.log10(d)
    pred = a + off - 10.0 * gam * log_d
    if has_body:
        rho_h = np.maximum(np.hypot(diff[:, 0], diff[:, 1]), 1e-6)
        cos_t = np.einsum("ij,ij->i", heading, diff[:, :2]) / rho_h  # 0 when not walking (heading 0)
        shadow = 0.5 * (1.0 - cos_t)
        pred = pred - w * shadow
    if walls is not None:
        pred = pred - m_wall * walls
    u = (pred - rssi) / sigma_db
    r, drdu = robust_sqrt(u, kernel, k)
    if H is not None:
        s = drdu / sigma_db  # (n,)
        near = d_raw > D_MIN
        dl = -(10.0 * gam / LN10) * diff / (d * d)[:, None] * near[:, None]  # d prediction / d l
        if has_body:  # + w/2 d cos / d l, horizontal only
            ux, uy = diff[:, 0] / rho_h, diff[:, 1] / rho_h
            dl[:, 0] += 0.5 * w * (heading[:, 0] - cos_t * ux) / rho_h
            dl[:, 1] += 0.5 * w * (heading[:, 1] - cos_t * uy) / rho_h
        H[0] = s[:, None] * dl
        H[1] = s[:, None]
        if i_gamma is not None:
            H[i_gamma] = (s * (-10.0 * log_d))[:, None]
        if i_body is not None:
            H[i_body] = (s * -shadow)[:, None]
        if i_wall is not None:
            H[i_wall] = (s * -walls)[:, None]
        if has_offset:
            H[i] = s[:, None]
    return r


def residual_db(p: Readings, l: np.ndarray, a: float, gamma: float, offset: float, body_db: float) -> np.ndarray:
    """Prediction - reading (dB) of one pair's readings at the estimate."""
    diff = l - p.P
    d = np.maximum(np.linalg.norm(diff, axis=-1), D_MIN)
    cos_t = np.einsum("ij,ij->i", p.heading, diff[:, :2]) / np.maximum(np.hypot(diff[:, 0], diff[:, 1]), 1e-6)
    return a + offset - 10.0 * gamma * np.log10(d) - body_db * 0.5 * (1.0 - cos_t) - p.rssi
