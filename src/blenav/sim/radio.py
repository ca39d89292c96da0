"""Radio channel: BLE RSSI and WiFi RTT ranges between anchors and a moving receiver.

BLE, per advertisement k of beacon b received at world position p (metres, 3-D distance d):

    rssi = P_b - 10 n log10(d) - W min(walls(b, p), W_max) + S_b(p) + F_k - body(b, p)   (channel, dBm)
    reported = profile.offset(kappa) + ref + gain (rssi - ref) + N(0, profile.std(kappa)^2), quantised

with ``P_b`` the beacon's true 1 m level (nominal + N(0, sigma_tx)), ``n`` the path-loss exponent,
``walls`` the number of free->occupied transitions along the 2-D line of sight on the occupancy grid,
``S_b`` a spatially correlated Gaussian shadowing field (std ``shadow_std_db``, Gaussian correlation
length ``shadow_corr_m``), ``F_k`` Rician fading in dB with K-factor falling with distance and walls
(Rayleigh-like in deep NLOS), ``body`` up to ``body_db`` when the carrier's body is between phone and
beacon (phone held in front: beacons behind the walker are shadowed). A packet is lost by the scan duty
cycle (``scan_prob``: 10 Hz advertising seen at about 7 Hz), below the receiver's sensitivity, or by the
receiver's own dropout; kappa in [0, 1] is the interference level: the number of beacons audible at the
receiver's position (mean level above sensitivity) over ``interference_ref``.

Walls and shadowing are precomputed per anchor on an analysis grid (``grid_m``) and bilinearly
interpolated per packet, so a packet costs O(1); the distance term is exact.

RTT: range = d + offset_a + NLOS bias (exponential, mean ``nlos_bias_m`` per wall) + N(0, sigma(d)^2),
with sigma(d) = ``std_m`` + ``std_per_m`` d and a reported std that is sigma times U(0.7, 1.3).
Each kept ranging exchange also reports the AP's WiFi RSSI (the optional ``rssi`` column of rtt.csv, used
by the -65 dBm rule of Duembgen et al. 004 sec. V-A), a log-distance model with wall loss
(:func:`rtt_wifi_rssi`)::

    rssi = P_ap - 10 n_w log10(d) - W_w min(walls, W_max) + N(0, sigma_w^2), rounded to 1 dBm

with ``P_ap`` the AP's 1 m level in this session (``rssi_1m_dbm`` + N(0, ``rssi_tx_spread_db``), drawn per
session: it includes the phone's receive gain). Its draws come from a
random stream of their own, so every other output of a seed is unchanged by it.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.ndimage import map_coordinates

from blenav.data.floor import OCCUPIED

from .receivers import TABLE_REF_1M_DBM, ReceiverProfile


@dataclass
class BleConfig:
    path_loss_exponent: float = 2.25  # gamma, Patel et al. Table I
    tx_power_dbm: float = -60.0  # nominal RSSI at 1 m (alpha_X, Patel et al. Table I)
    tx_spread_db: float = 2.0  # per-beacon deviation of the true 1 m level
    wall_db: float = 3.5
    walls_max: int = 5
    shadow_std_db: float = 3.5
    shadow_corr_m: float = 3.0
    k_factor_1m_db: float = 20.0  # Rician K at 1 m, line of sight (Table 3.2 variances as low as 0.4 dB^2 leave little room)
    k_factor_slope_db: float = 10.0  # K falls by this per decade of distance
    k_factor_per_wall_db: float = 6.0
    body_db: float = 6.0
    adv_rate_hz: float = 10.0
    scan_prob: float = 0.7
    interference_ref: float = 8.0
    grid_m: float = 0.5
    max_range_m: float = 40.0


@dataclass
class RttConfig:
    rate_hz: float = 3.0
    offset_mean_m: float = 0.3
    offset_std_m: float = 0.5
    nlos_bias_m: float = 0.8
    std_m: float = 0.3
    std_per_m: float = 0.02
    loss_prob: float = 0.05
    loss_prob_per_wall: float = 0.08
    max_range_m: float = 35.0
    # WiFi RSSI reported with each range (rtt.csv `rssi`; 004 sec. V-A drops ranges below -65 dBm). -30 dBm at
    # 1 m: a 20 dBm EIRP AP minus 46 dB free-space loss at 5 GHz and some phone antenna loss. A line-of-sight AP
    # falls below -65 dBm at about 20 m, one behind two walls at about 10 m.
    write_rssi: bool = True
    rssi_1m_dbm: float = -30.0
    rssi_tx_spread_db: float = 2.0
    rssi_exponent: float = 2.7
    rssi_wall_db: float = 4.0
    rssi_walls_max: int = 5
    rssi_std_db: float = 3.0


def gaussian_field(rng: np.random.Generator, shape: tuple[int, ...], corr_px: float) -> np.ndarray:
    """Zero-mean unit-variance Gaussian random fields with correlation exp(-r^2 / (2 corr_px^2)).

    ``shape`` = (..., H, W): independent fields over the leading axes; ``corr_px`` correlation length in
    grid cells. White noise filtered by a Gaussian kernel of std corr_px / sqrt(2) (whose
    autocorrelation has std corr_px), via FFT; padding avoids wrap-around correlation across edges.
    """
    pad = int(np.ceil(2 * corr_px))
    h, w = shape[-2] + 2 * pad, shape[-1] + 2 * pad
    noise = rng.standard_normal(shape[:-2] + (h, w))
    fy = np.fft.fftfreq(h)[:, None]
    fx = np.fft.rfftfreq(w)[None, :]
    kernel = np.exp(-((np.pi * corr_px) ** 2) * (fx**2 + fy**2))
    f = np.fft.irfft2(np.fft.rfft2(noise) * kernel, s=(h, w))[..., pad:-pad or None, pad:-pad or None]
    std = f.std(axis=(-2, -1), keepdims=True)
    return f / np.where(std > 0, std, 1.0)


class AnchorMaps:
    """Per-anchor wall counts and shadowing on an analysis grid over the floor.

    ``occupancy``: int8 (H, W) image order; ``resolution`` m/px; anchors ``xy`` (A, 2) m.
    Grid cell (i, j) is at world (x0 + j g, y0 + i g) with g = ``grid_m`` (row 0 at the *bottom*).
    """

    def __init__(self, occupancy: np.ndarray, resolution: float, origin: tuple[float, float], xy: np.ndarray,
                 grid_m: float, max_range_m: float, rng: np.random.Generator | None = None, corr_m: float = 3.0):
        self.occ = occupancy == OCCUPIED
        self.res, self.origin, self.g = resolution, origin, grid_m
        h, w = occupancy.shape
        self.nx = int(np.ceil(w * resolution / grid_m)) + 1
        self.ny = int(np.ceil(h * resolution / grid_m)) + 1
        gx, gy = np.meshgrid(origin[0] + np.arange(self.nx) * grid_m, origin[1] + np.arange(self.ny) * grid_m)
        targets = np.stack([gx.ravel(), gy.ravel()], axis=1)
        self.walls = np.stack([self._crossings(a, targets, max_range_m) for a in np.asarray(xy, float)])
        self.walls = self.walls.reshape(len(xy), self.ny, self.nx).astype(np.float32)
        self.shadow = None
        if rng is not None:
            self.shadow = gaussian_field(rng, (len(xy), self.ny, self.nx), corr_m / grid_m).astype(np.float32)

    def _crossings(self, src: np.ndarray, targets: np.ndarray, max_range: float) -> np.ndarray:
        """Number of free->occupied transitions on segments src -> targets (sampled at half a pixel)."""
        step = self.res * 0.5
        d = np.linalg.norm(targets - src, axis=1)
        dmax = min(float(d.max()), max_range)
        s = np.arange(0.0, dmax + step, step)
        out = np.zeros(len(targets), np.int16)
        h, w = self.occ.shape
        for lo in range(0, len(targets), 4096):  # chunks bound the (M, K) sample array to a few MB
            tg, dd = targets[lo:lo + 4096], d[lo:lo + 4096]
            u = (tg - src) / np.maximum(dd, 1e-9)[:, None]
            px = src[0] + u[:, :1] * s[None, :]
            py = src[1] + u[:, 1:] * s[None, :]
            col = np.clip(((px - self.origin[0]) / self.res).astype(np.int32), 0, w - 1)
            row = np.clip(h - 1 - ((py - self.origin[1]) / self.res).astype(np.int32), 0, h - 1)
            occ = self.occ[row, col] & (s[None, :] <= dd[:, None])
            out[lo:lo + 4096] = np.count_nonzero(occ[:, 1:] & ~occ[:, :-1], axis=1) + occ[:, 0]
        return out

    def sample(self, field: np.ndarray, anchor: np.ndarray, xy: np.ndarray) -> np.ndarray:
        """Bilinear value of per-anchor ``field`` (A, ny, nx) for anchor index ``anchor`` (N,) at xy (N, 2)."""
        fi = (xy[:, 1] - self.origin[1]) / self.g
        fj = (xy[:, 0] - self.origin[0]) / self.g
        return map_coordinates(field, np.stack([anchor.astype(float), fi, fj]), order=1, mode="nearest")


def rician_db(rng: np.random.Generator, k_lin: np.ndarray) -> np.ndarray:
    """Fading gain in dB of a Rician channel with K-factor ``k_lin`` (linear), unit mean power."""
    los = np.sqrt(k_lin / (k_lin + 1.0))
    sc = np.sqrt(1.0 / (2.0 * (k_lin + 1.0)))
    re = los + sc * rng.standard_normal(k_lin.shape)
    im = sc * rng.standard_normal(k_lin.shape)
    return 10.0 * np.log10(re * re + im * im + 1e-12)


def fading_moments_db(k_lin: float, order: int = 60) -> tuple[float, float]:
    """Mean and variance (dB, dB^2) of :func:`rician_db` at K-factor ``k_lin``, by Gauss-Hermite quadrature."""
    z, w = np.polynomial.hermite_e.hermegauss(order)
    w = w / w.sum()
    los = np.sqrt(k_lin / (k_lin + 1.0))
    sc = np.sqrt(1.0 / (2.0 * (k_lin + 1.0)))
    re, im = los + sc * z[:, None], sc * z[None, :]
    g = 10.0 * np.log10(re * re + im * im + 1e-300)
    ww = w[:, None] * w[None, :]
    m = float((ww * g).sum())
    return m, float((ww * (g - m) ** 2).sum())


def k_factor(cfg: BleConfig, d: np.ndarray, walls: np.ndarray) -> np.ndarray:
    k_db = cfg.k_factor_1m_db - cfg.k_factor_slope_db * np.log10(np.maximum(d, 1.0)) - cfg.k_factor_per_wall_db * walls
    return 10.0 ** (np.maximum(k_db, -10.0) / 10.0)


def channel_mean_db(cfg: BleConfig, p1m: np.ndarray, d: np.ndarray, walls: np.ndarray) -> np.ndarray:
    """Large-scale mean level (dBm) without shadowing, fading, body or receiver effects."""
    return p1m - 10.0 * cfg.path_loss_exponent * np.log10(np.maximum(d, 0.1)) - cfg.wall_db * np.minimum(walls, cfg.walls_max)


def receive(rng: np.random.Generator, profile: ReceiverProfile, channel_dbm: np.ndarray, kappa: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Apply a receiver profile to channel levels: returns (reported dBm, kept mask)."""
    off, std, q = profile.at(kappa)
    level = TABLE_REF_1M_DBM + profile.gain * (channel_dbm - TABLE_REF_1M_DBM) + off
    level = level + std * rng.standard_normal(channel_dbm.shape)
    level = np.round(level / profile.quant_db) * profile.quant_db
    kept = (level >= profile.sensitivity_dbm) & (rng.random(channel_dbm.shape) >= q) & (level < -1.0)
    return level, kept


def simulate_ble(rng: np.random.Generator, cfg: BleConfig, profile: ReceiverProfile, maps: AnchorMaps,
                 anchor_xyz: np.ndarray, p1m: np.ndarray, traj_t: np.ndarray, traj_xyz: np.ndarray,
                 traj_heading: np.ndarray, body_db: float, duration_s: float):
    """All BLE packets of one session. Returns (t, anchor index, rssi dBm), sorted by time.

    ``anchor_xyz`` (A, 3) true positions; ``p1m`` (A,) true 1 m levels; trajectory at times ``traj_t``
    (T,) with positions (T, 3) m and walking heading (T,) rad (direction the body faces).
    """
    A = len(anchor_xyz)
    period = 1.0 / cfg.adv_rate_hz
    n_adv = int(np.ceil(duration_s / period)) + 1
    # BLE advertising: interval + advDelay U(0, 10 ms), random phase per beacon
    gaps = period + rng.uniform(0.0, 0.01, (A, n_adv))
    t = rng.uniform(0, period, (A, 1)) + np.cumsum(gaps, axis=1) - gaps[:, :1]
    aid = np.broadcast_to(np.arange(A)[:, None], t.shape)
    keep = (t < duration_s) & (rng.random(t.shape) < cfg.scan_prob)
    t, aid = t[keep], aid[keep]
    order = np.argsort(t, kind="stable")
    t, aid = t[order], aid[order]

    pos = np.stack([np.interp(t, traj_t, traj_xyz[:, k]) for k in range(3)], axis=1)
    head = np.interp(t, traj_t, np.unwrap(traj_heading))
    delta = anchor_xyz[aid] - pos
    d = np.linalg.norm(delta, axis=1)
    walls = maps.sample(maps.walls, aid, pos[:, :2])
    level = channel_mean_db(cfg, p1m[aid], d, walls)
    if maps.shadow is not None:
        level += cfg.shadow_std_db * maps.sample(maps.shadow, aid, pos[:, :2])
    level += rician_db(rng, k_factor(cfg, d, walls))
    if body_db > 0:
        cosang = (np.cos(head) * delta[:, 0] + np.sin(head) * delta[:, 1]) / np.maximum(np.hypot(delta[:, 0], delta[:, 1]), 1e-6)
        level -= body_db * 0.5 * (1.0 - cosang)
    kappa = interference(cfg, profile, maps, anchor_xyz, p1m, t, pos)
    rssi, kept = receive(rng, profile, level, kappa)
    return t[kept], aid[kept], rssi[kept]


def interference(cfg: BleConfig, profile: ReceiverProfile, maps: AnchorMaps, anchor_xyz: np.ndarray,
                 p1m: np.ndarray, t: np.ndarray, pos: np.ndarray) -> np.ndarray:
    """kappa per packet: audible beacons (mean level above sensitivity) at the receiver / interference_ref.

    Evaluated once per second of the session and interpolated (the count changes slowly)."""
    if len(t) == 0:
        return np.zeros(0)
    tk = np.arange(0.0, t[-1] + 1.0, 1.0)
    pk = np.stack([np.interp(tk, t, pos[:, k]) for k in range(3)], axis=1)
    A = len(anchor_xyz)
    aid = np.repeat(np.arange(A)[None, :], len(tk), axis=0).ravel()
    pp = np.repeat(pk, A, axis=0)
    d = np.linalg.norm(anchor_xyz[aid] - pp, axis=1)
    lvl = channel_mean_db(cfg, p1m[aid], d, maps.sample(maps.walls, aid, pp[:, :2]))
    n = (lvl > profile.sensitivity_dbm).reshape(len(tk), A).sum(axis=1)
    return np.interp(t, tk, np.clip((n - 1) / cfg.interference_ref, 0.0, 1.0))


def simulate_rtt(rng: np.random.Generator, cfg: RttConfig, maps: AnchorMaps, ap_xyz: np.ndarray,
                 ap_offset: np.ndarray, traj_t: np.ndarray, traj_xyz: np.ndarray, duration_s: float):
    """WiFi RTT ranging rounds to every AP at ``rate_hz``. Returns (t, ap index, range_m, std_m)."""
    A = len(ap_xyz)
    if A == 0:
        return np.zeros(0), np.zeros(0, int), np.zeros(0), np.zeros(0)
    rounds = np.arange(rng.uniform(0, 1 / cfg.rate_hz), duration_s, 1 / cfg.rate_hz)
    t = (rounds[:, None] + 0.005 * np.arange(A)[None, :]).ravel()  # APs ranged one after another
    aid = np.tile(np.arange(A), len(rounds))
    pos = np.stack([np.interp(t, traj_t, traj_xyz[:, k]) for k in range(3)], axis=1)
    d = np.linalg.norm(ap_xyz[aid] - pos, axis=1)
    walls = np.round(maps.sample(maps.walls, aid, pos[:, :2]))
    sigma = cfg.std_m + cfg.std_per_m * d
    nlos = rng.exponential(cfg.nlos_bias_m, d.shape) * walls
    rng_m = d + ap_offset[aid] + nlos + sigma * rng.standard_normal(d.shape)
    std = sigma * rng.uniform(0.7, 1.3, d.shape)
    lost = rng.random(d.shape) < cfg.loss_prob + cfg.loss_prob_per_wall * walls
    keep = ~lost & (d < cfg.max_range_m)
    return t[keep], aid[keep], rng_m[keep], std[keep]


def rtt_wifi_rssi(rng: np.random.Generator, cfg: RttConfig, maps: AnchorMaps, ap_xyz: np.ndarray, t: np.ndarray,
                  aid: np.ndarray, traj_t: np.ndarray, traj_xyz: np.ndarray) -> np.ndarray:
    """The AP's WiFi RSSI (dBm, (N,), integers as float) reported with each ranging exchange ``t`` (N,) s to AP
    ``aid`` (N,) of :func:`simulate_rtt` (see the module docstring for the model).

    ``rng`` must be a stream of its own (not the one of :func:`simulate_rtt`), so that the other outputs of a
    seed stay bit-identical; the APs' 1 m levels are its first draws. Values are clipped to [-100, -1] dBm."""
    p1m = cfg.rssi_1m_dbm + cfg.rssi_tx_spread_db * rng.standard_normal(len(ap_xyz))
    if len(t) == 0:
        return np.zeros(0)
    pos = np.stack([np.interp(t, traj_t, traj_xyz[:, k]) for k in range(3)], axis=1)
    d = np.linalg.norm(ap_xyz[aid] - pos, axis=1)
    walls = np.round(maps.sample(maps.walls, aid, pos[:, :2]))
    level = (p1m[aid] - 10.0 * cfg.rssi_exponent * np.log10(np.maximum(d, 0.1))
             - cfg.rssi_wall_db * np.minimum(walls, cfg.rssi_walls_max) + cfg.rssi_std_db * rng.standard_normal(len(t)))
    return np.clip(np.round(level), -100.0, -1.0)
