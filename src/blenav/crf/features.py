"""Feature functions of the CRF (Duembgen et al., 004, sec. IV-A), in log space, on the grid's cells.

Every unary feature returns (N,) log values over the N cells of a :class:`~blenav.crf.grid.CrfGrid`;
:func:`normalise_log` makes them sum to one on the grid ("all features are normalized such that their sum
on the considered grid equals one", 004 sec. IV-A). The pairwise IMU features (eqs. 13-14) are evaluated on
the grid's transition edges; :func:`imu_edge_log` is the numpy reference of what the Viterbi kernel
computes per edge (:mod:`blenav.crf.viterbi`), normalised per source cell (a transition kernel).

Distances are 3-D (anchors at their height, cells at the device height ``device_z``), in metres; RSSI in
dBm; angles in rad counter-clockwise from world +x.
"""

from __future__ import annotations

import numpy as np

__all__ = ["LOG_SQRT_2PI", "normalise_log", "logsumexp", "cell_anchor_distances", "rtt_log_feature",
           "rssi_log_feature", "imu_edge_log", "visual_log_feature", "wrap_angle"]

LOG_SQRT_2PI = 0.5 * np.log(2.0 * np.pi)


def logsumexp(x: np.ndarray) -> float:
    m = float(np.max(x)) if x.size else -np.inf
    if not np.isfinite(m):
        return m
    return m + float(np.log(np.sum(np.exp(x - m))))


def normalise_log(logf: np.ndarray) -> np.ndarray:
    """``logf`` shifted so that exp(logf) sums to one over the grid (all -inf stays all -inf)."""
    z = logsumexp(logf)
    return logf - z if np.isfinite(z) else logf


def wrap_angle(a):
    """Angle(s) wrapped to [-pi, pi) (the Delta operator of 004 eq. 14)."""
    return (np.asarray(a, float) + np.pi) % (2.0 * np.pi) - np.pi


def cell_anchor_distances(cell_xy: np.ndarray, device_z: float, anchor_xyz: np.ndarray) -> np.ndarray:
    """(N, A) 3-D distance (m) from cells (N, 2) at height ``device_z`` to anchors (A, 3), at least 1 cm."""
    d = np.sqrt(((cell_xy[:, None, :] - anchor_xyz[None, :, :2]) ** 2).sum(-1) + (anchor_xyz[None, :, 2] - device_z) ** 2)
    return np.maximum(d, 0.01)


def rtt_log_feature(dist: np.ndarray, ranges: np.ndarray, sigma) -> np.ndarray:
    """Eq. 6 (004): sum over APs of ln(1 / (sigma_m sqrt(2 pi))) - (d_m - d*_m)^2 / (2 sigma_m^2), (N,).

    dist (N, A) m: cell-to-AP distances d*; ranges (A,) m: measured (calibrated) ranges d_m, NaN where the AP
    gave none (left out); sigma scalar or (A,) m."""
    ranges = np.asarray(ranges, float)
    ok = np.isfinite(ranges)
    if not ok.any():
        return np.zeros(dist.shape[0])
    s = np.broadcast_to(np.asarray(sigma, float), ranges.shape)[ok]
    r = (ranges[ok][None, :] - dist[:, ok]) / s[None, :]
    return (-np.log(s) - LOG_SQRT_2PI).sum() - 0.5 * (r * r).sum(axis=1)


def rssi_log_feature(log_dist: np.ndarray, rssi: np.ndarray, tx_dbm: np.ndarray, n: float, sigma_db,
                     mode_correction: bool = True) -> np.ndarray:
    """Eqs. 8-12 (004): log-normal distance feature of BLE RSSI, (N,).

    log_dist (N, A): ln d*_m of every cell to every beacon; rssi (A,) dBm (NaN: not heard, left out);
    tx_dbm (A,) dBm: T_m, the RSSI at 1 m; n: path-loss exponent; sigma_db: RSSI std (dBm), scalar or (A,).
    The measured distance is d_m = 10^((T_m - P_m) / (10 n)) (eq. 8); ln d_m ~ N(ln d*_m, sigma_d^2) with
    sigma_d = ln(10) / (10 n) sigma (eq. 9; S_m = ln d*_m under eq. 7). ``mode_correction`` (eq. 11): the
    density is scaled by the distance, which removes the 1 / d factor of the log-normal density (eq. 10) so
    that the feature peaks where ||a_m - y|| = d_m rather than at d_m exp(-sigma_d^2); without it the
    -ln d*_m term of eq. 10 is kept (the log-normal density over the cell's distance)."""
    rssi = np.asarray(rssi, float)
    ok = np.isfinite(rssi) & np.isfinite(tx_dbm)
    if not ok.any():
        return np.zeros(log_dist.shape[0])
    sd = np.log(10.0) / (10.0 * n) * np.broadcast_to(np.asarray(sigma_db, float), rssi.shape)[ok]
    log_dm = np.log(10.0) * (np.asarray(tx_dbm, float)[ok] - rssi[ok]) / (10.0 * n)  # ln d_m, eq. 8
    ld = log_dist[:, ok]
    r = (log_dm[None, :] - ld) / sd[None, :]
    out = (-np.log(sd) - LOG_SQRT_2PI).sum() - 0.5 * (r * r).sum(axis=1)
    if not mode_correction:
        out = out - ld.sum(axis=1)
    return out


def imu_edge_log(length: float, heading: float, edge_dist: np.ndarray, edge_angle: np.ndarray, sigma_l: float,
                 sigma_theta: float, use_heading: bool = True) -> np.ndarray:
    """Eqs. 13-14 (004) on transition edges (E,): ln N(l_IMU; ||y_i - y_k||, sigma_l) plus, when
    ``use_heading`` (a step was detected), ln N(Delta(theta_IMU, theta(y_i, y_k)); 0, sigma_theta).

    edge_dist (E,) m and edge_angle (E,) rad from source y_k to target y_i; a self edge (distance 0) has no
    direction: its heading term is that of Delta = pi (staying put contradicts a detected step)."""
    r = (length - edge_dist) / sigma_l
    out = -np.log(sigma_l) - LOG_SQRT_2PI - 0.5 * r * r
    if use_heading:
        delta = np.where(edge_dist > 0, wrap_angle(heading - edge_angle), np.pi)
        out = out - np.log(sigma_theta) - LOG_SQRT_2PI - 0.5 * (delta / sigma_theta) ** 2
    return out


def visual_log_feature(cell_xy: np.ndarray, v_xy: np.ndarray, sigma_v: float = 0.05) -> np.ndarray:
    """Eq. 15 (004): the reset map ln N(||y_i - v||; 0, sigma_v) over the cells (N,), before normalisation."""
    d2 = ((cell_xy - np.asarray(v_xy, float)[None, :2]) ** 2).sum(axis=1)
    return -np.log(sigma_v) - LOG_SQRT_2PI - 0.5 * d2 / sigma_v**2
