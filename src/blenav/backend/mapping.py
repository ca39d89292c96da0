"""Beacon maps from labelled walks (issue 14, sec. 3): each BLE beacon's position and RSSI at 1 m from readings
taken at known (ground-truth) poses, on GTSAM.

Model (log-distance path loss with log-normal shadowing, the form PF-PS uses, Patel et al. eq. 1 with d0 = 1 m;
000's future work: "joint state and parameters estimation of radio signal measurements (RSSI factors)"):

    rssi_i = A_j + o_s - 10 gamma log10(max(||p_i - l_j||, d_min) / 1 m) - W b_i - M n_ij + eps_i,
    eps_i ~ N(0, sigma_db^2)

with p_i the receiver's ground-truth position (world m) at the reading's time, and unknowns

* ``L(j)``: beacon j's position (Point3, world m);
* ``A(j)``: beacon j's RSSI at 1 m (1-D, dBm): its transmit power as the mapping receivers read it. The
  transmit power is a variable of the graph rather than a per-beacon least-squares fit on the residuals
  afterwards: position and power are estimated jointly, and their correlation enters the position's std.
  A deployment's beacons share a model and setting, so A_j = A_common + delta_j with delta_j ~ N(0,
  ``a_x_spread_db``^2) (``A(n_beacons)`` is the common level, broad prior), which narrows the "weak
  beacon near the path" vs "strong beacon far away" ambiguity that independent broad priors leave (on the
  simulated office it changed little: beacons heard only from afar stay badly placed, see below);
* ``G(0)``: one path-loss exponent shared by all beacons (1-D; ``mapping.estimate_gamma``, else fixed);
* ``W(0)``, ``M(0)``: body shadow and per-wall loss (1-D, dB), see below;
* ``O(s)``: the receiver offset of session s (1-D, dB; the first session's is held at 0 so that A_j is the
  RSSI at 1 m as *its* receiver reads it): sessions recorded with different phones stay consistent.

Factors: one ``gtsam.CustomFactor`` per (beacon, session) whose error is the stacked vector of that pair's
readings (vectorised numpy; one Python call per pair instead of per reading), each element the robust
"square-rooted" residual r = sign(u) sqrt(2 rho(u)) of the whitened residual u = (prediction - rssi) / sigma_db,
so that 0.5 ||r||^2 is exactly sum_i rho(u_i) for GTSAM's Huber or Cauchy rho (tested against per-reading
``CustomFactor``s with ``noiseModel.Robust``); broad priors on every variable (``L``: ``mapping.prior_sigma_m``
around the strongest readings' positions, or the map's; height ``mapping.height_sigma_m`` around anchors.csv's
z, which a walk on one floor cannot see; ``A``: ``a_x_prior_sigma_db``).

Two further terms of the mean level, both physical and both estimated (one value shared by all beacons):
the carrier's body shadow ``W (1 - cos theta) / 2`` (theta between the walking direction, from the ground
truth, and the direction to the beacon) and the multi-wall loss ``M n_walls`` (Motley-Keenan / COST 231:
n_walls the free -> occupied transitions of the floor plan on the line of sight, at most ``max_walls``,
counted at the previous estimate and held fixed during one solve; ``wall_passes`` solves). On the simulated
384 s office they cut the error of the beacons the walk passes within 2 m from 2.2 m to 1.2 m.

Readings weaker than ``mapping.min_rssi_dbm`` can be left out (default: none). Near the receiver's sensitivity
only the readings that came out strong are reported, which flattens the fitted exponent; a fixed threshold,
though, ignores each receiver's own level and selects on the noise (worse on the simulated office).

A beacon is *placed* only when it was heard ``min_readings`` times from positions whose minor-axis spread is
at least ``min_spread_m`` (a straight walk past a beacon leaves it mirror-ambiguous) and its estimated
horizontal std is at most ``max_std_m``; otherwise it is reported with the reason and not invented. Its std is
the marginal covariance (``sqrt(trace(Sigma_xy) / 2)``, per axis) scaled by the a-posteriori variance factor
of its own residuals (robust: 1.4826 MAD / sigma_db, never below 1), by the design effect of the shadowing
shared within ``shadow_corr_m`` cells (1 + (m - 1) rho, rho the intra-cell correlation of the residuals, m
readings per cell), and by ``std_scale``: on five simulated datasets (the small office, 2 x 240 s with two
phones, seeds 11-13, and 3 x 300 s; the 384 s office walk) the errors of placed beacons were still 1.3-2.7 times
the model's std in the median, so the default states 2.5 times the model's std. With it the median |error| /
std_m was 0.75, 2.15, 1.88, 1.68 and 1.12 (a Rayleigh's is 1.18) and the 90th percentile 1.2-4.7: a beacon
the walks only pass at a distance, behind walls, can still be placed metres off with a std of 1-2 m
(on the office walk: 33 of 79 placed, mean error 2.8 m; 19 of them were passed within 2 m). Measured, not
derived: set it to 1 to get the model's own.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from functools import partial

import numpy as np
import pandas as pd

from .config import MappingConfig, RobustKernel

__all__ = ["MappingResult", "robust_sqrt", "rssi_error", "collect_readings", "map_beacons", "mean_map"]

LN10 = np.log(10.0)
D_MIN = 0.5  # m: distances below are floored (the model is not meant for the near field)


# ------------------------------------------------------------------------------------------- robust residuals
def robust_sqrt(u: np.ndarray, kernel: RobustKernel, k: float) -> tuple[np.ndarray, np.ndarray]:
    """(r, dr/du) with r = sign(u) sqrt(2 rho(u)) for GTSAM's M-estimators (``noiseModel.mEstimator``):
    Huber rho = u^2/2 (|u| <= k), k|u| - k^2/2; Cauchy rho = k^2/2 log(1 + u^2/k^2); none: r = u."""
    u = np.asarray(u, float)
    kernel = RobustKernel(kernel)
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


# ------------------------------------------------------------------------------------------- data
@dataclass
class _Pair:
    """The readings of one beacon (row j of the BLE anchors) in one session (index s): P (n, 3) m, rssi (n,) dBm,
    heading (n, 2) unit walking direction (0 when not walking)."""

    j: int
    s: int
    P: np.ndarray
    rssi: np.ndarray
    heading: np.ndarray


def collect_readings(sessions, ids: np.ndarray, cfg: MappingConfig) -> tuple[list[_Pair], list[str]]:
    """(beacon, session) pairs of readings at ground-truth positions (linear interpolation; readings outside the
    ground truth's time span are left out), readings below ``min_rssi_dbm`` dropped. Returns (pairs, notes)."""
    pairs, notes = [], []
    index = {str(a): j for j, a in enumerate(ids)}
    for s, sess in enumerate(sessions):
        if not sess.labelled:
            raise ValueError(f"session {sess.id} is not labelled: mapping needs its ground-truth poses")
        gt, r = sess.groundtruth, sess.rssi
        if not len(gt) or not len(r):
            notes.append(f"session {sess.id}: no {'ground truth' if not len(gt) else 'RSSI'}; skipped")
            continue
        tg = gt["t"].to_numpy(float)
        t = r["t"].to_numpy(float)
        j = np.array([index.get(str(a), -1) for a in r["anchor_id"].astype(str)], dtype=int)
        y = r["rssi"].to_numpy(float)
        keep = (t >= tg[0]) & (t <= tg[-1]) & (j >= 0)
        floor_db = None
        if cfg.censor_margin_db is not None and keep.any():  # the receiver's own sensitivity: its weakest readings
            floor_db = float(np.percentile(y[keep], 0.5)) + cfg.censor_margin_db
        threshold = max([v for v in (cfg.min_rssi_dbm, floor_db) if v is not None], default=None)
        if threshold is not None:
            weak = keep & (y < threshold)
            if weak.any():
                notes.append(f"session {sess.id}: {np.count_nonzero(weak)} of {np.count_nonzero(keep)} readings below "
                             f"{threshold:.1f} dBm left out")
            keep &= ~weak
        t, j, y = t[keep], j[keep], y[keep]
        P = sess.positions_at(t, with_z=True, device_z=cfg.device_z)
        hd = _walking_direction(tg, gt["x"].to_numpy(float), gt["y"].to_numpy(float), t)
        order = np.argsort(j, kind="stable")
        j, P, y, hd = j[order], P[order], y[order], hd[order]
        for jj, lo, hi in _runs(j):
            pairs.append(_Pair(int(jj), s, P[lo:hi], y[lo:hi], hd[lo:hi]))
    return pairs, notes


def count_walls(floor, src_xy: np.ndarray, targets: np.ndarray, cap: int | None = None) -> np.ndarray:
    """(n,) number of free -> occupied transitions on the floor plan along the segments ``src_xy`` (2,) ->
    ``targets`` (n, 2) (world m), sampled every half pixel (the multi-wall count of Motley-Keenan / COST 231);
    capped at ``cap``."""
    from blenav.data import OCCUPIED

    targets = np.asarray(targets, float)
    out = np.zeros(len(targets))
    if not len(targets):
        return out
    occ = floor.occupancy == OCCUPIED
    step = 0.5 * floor.resolution
    d = np.linalg.norm(targets - src_xy, axis=1)
    s = np.arange(0.0, float(d.max()) + step, step)
    for lo in range(0, len(targets), 2048):  # chunks bound the (n, K) samples to a few MB
        tg, dd = targets[lo:lo + 2048], d[lo:lo + 2048]
        u = (tg - src_xy) / np.maximum(dd, 1e-9)[:, None]
        pts = src_xy + u[:, None, :] * s[None, :, None]  # (m, K, 2)
        row, col = floor.world_to_pixel(pts)
        inside = (row >= 0) & (row < occ.shape[0]) & (col >= 0) & (col < occ.shape[1])
        hit = np.zeros(row.shape, bool)
        hit[inside] = occ[row[inside], col[inside]]
        hit &= s[None, :] <= dd[:, None]
        out[lo:lo + 2048] = np.count_nonzero(hit[:, 1:] & ~hit[:, :-1], axis=1) + hit[:, 0]
    return np.minimum(out, cap) if cap is not None else out


WALL_CELL_M = 0.25  # m: readings' positions snapped to this grid for the wall count (one ray per cell)


def _walls_on_cells(floor, src_xy: np.ndarray, P: np.ndarray, cap: int | None) -> np.ndarray:
    """:func:`count_walls` from ``src_xy`` to positions P (n, 2), one ray per ``WALL_CELL_M`` cell they fall in
    (a receiver reports ~20 readings per second from nearly one place: 30x fewer rays on a walk)."""
    cells = np.round(P / WALL_CELL_M).astype(np.int64)
    uniq, inv = np.unique(cells, axis=0, return_inverse=True)
    return count_walls(floor, src_xy, uniq * WALL_CELL_M, cap)[inv.ravel()]


def _walking_direction(tg: np.ndarray, x: np.ndarray, y: np.ndarray, t: np.ndarray, span_s: float = 1.0,
                       min_speed: float = 0.3) -> np.ndarray:
    """(n, 2) unit direction of travel at times t from the ground truth (central differences over ``span_s``);
    zero where slower than ``min_speed`` m/s (standing: the body's facing is unknown)."""
    lo, hi = np.clip(t - span_s / 2, tg[0], tg[-1]), np.clip(t + span_s / 2, tg[0], tg[-1])
    dx, dy = np.interp(hi, tg, x) - np.interp(lo, tg, x), np.interp(hi, tg, y) - np.interp(lo, tg, y)
    dist = np.hypot(dx, dy)
    moving = dist > min_speed * np.maximum(hi - lo, 1e-9)
    out = np.zeros((len(t), 2))
    out[moving] = np.column_stack([dx, dy])[moving] / dist[moving, None]
    return out


def _runs(sorted_ids: np.ndarray):
    """(value, start, stop) of each run of equal values in a sorted array."""
    if not len(sorted_ids):
        return
    cut = np.flatnonzero(np.diff(sorted_ids)) + 1
    starts = np.r_[0, cut]
    stops = np.r_[cut, len(sorted_ids)]
    for a, b in zip(starts, stops):
        yield sorted_ids[a], a, b


def _spread(P: np.ndarray) -> float:
    """Minor-axis std (m) of horizontal positions P (n, >= 2): sqrt of the smaller eigenvalue of their covariance."""
    if len(P) < 3:
        return 0.0
    return float(np.sqrt(max(np.linalg.eigvalsh(np.cov(P[:, :2].T))[0], 0.0)))


def _initial_xy(P: np.ndarray, rssi: np.ndarray) -> np.ndarray:
    """Mean horizontal position of the strongest tenth of the readings (at least 5)."""
    n = max(5, len(rssi) // 10)
    top = np.argsort(-rssi, kind="stable")[:n]
    return P[top, :2].mean(axis=0)


# ------------------------------------------------------------------------------------------- result
@dataclass
class MappingResult:
    """``beacons``: one row per BLE anchor of the building: anchor_id, x, y, z (m, estimate; the input's for
    beacons not placed), std_m (horizontal, per axis, m), tx_power_dbm (A_j, dBm at 1 m as the reference
    session's receiver reads it), tx_power_std_db, n_readings, spread_m (minor-axis std of the hearing
    positions), placed (bool), status ('placed' or why not). ``gamma`` (and its std, 0 when fixed), ``offsets_db``
    {session id: receiver offset}, ``reference_session``, ``residual_std_db`` (robust, all readings), notes,
    wall_s."""

    beacons: pd.DataFrame
    gamma: float
    gamma_std: float
    offsets_db: dict
    reference_session: str
    residual_std_db: float
    notes: list[str] = field(default_factory=list)
    wall_s: float = 0.0

    @property
    def placed(self) -> pd.DataFrame:
        return self.beacons[self.beacons["placed"]]

    @property
    def unplaced(self) -> pd.DataFrame:
        return self.beacons[~self.beacons["placed"]]


# ------------------------------------------------------------------------------------------- the graph
@dataclass
class _Screening:
    """The beacons' readings and the checks before the solve (nb BLE anchors).

    ``n_read`` (nb,) readings per beacon; ``P_all`` {j: (n_j, 3) world m} and ``y_all`` {j: (n_j,) dBm}: the
    positions and RSSI of every reading of each beacon heard (in the order of the pairs); ``spread`` (nb,) m:
    minor-axis std of its hearing positions; ``status`` (nb,) object: 'placed' or why not (updated by the solve
    and the std check); ``active``: indices of the beacons that passed the checks; ``used``: their (beacon,
    session) pairs; ``sess_used``: the sessions those come from (sorted indices), ``ref`` the reference one."""

    n_read: np.ndarray
    P_all: dict
    y_all: dict
    spread: np.ndarray
    status: np.ndarray
    active: np.ndarray
    used: list
    sess_used: list
    ref: int


@dataclass
class _Graph:
    """The priors of the mapping problem: ``graph`` (gtsam.NonlinearFactorGraph, priors only), ``init``
    (gtsam.Values), ``guess`` (nb, 3) world m: initial beacon positions (anchors.csv's; x, y of the active ones
    from their strongest readings unless ``use_map_prior``); which optional variables exist: ``gamma_fixed``
    (None: G(0) estimated, else the fixed exponent), ``has_body`` (W(0)), ``has_walls`` (M(0)), ``multi`` (O(s)
    per used session)."""

    graph: object
    init: object
    guess: np.ndarray
    gamma_fixed: float | None
    has_body: bool
    has_walls: bool
    multi: bool


@dataclass
class _Fit:
    """The shared values at the estimate: ``gamma`` (path-loss exponent; ``cfg.gamma`` when fixed or unsolved),
    ``gamma_std`` (0 when fixed or without covariance), ``body`` W (dB), ``wall_db`` M (dB per wall; 0 when not
    modelled), ``offsets`` {session id: receiver offset, dB} (empty with one session)."""

    gamma: float
    gamma_std: float
    body: float
    wall_db: float
    offsets: dict


def map_beacons(sessions, anchors: pd.DataFrame, cfg: MappingConfig) -> MappingResult:
    """Estimate the BLE anchors' positions and RSSI at 1 m from labelled ``sessions`` (all in one building whose
    anchors.csv rows are ``anchors``). Never invents a beacon: see the module docstring for the checks."""
    import gtsam  # noqa: F401  (without GTSAM this fails here, before any check)

    t0 = time.perf_counter()
    sessions = list(sessions)
    if not sessions:
        raise ValueError("no session to map beacons from")
    ble = anchors[anchors["kind"] == "ble"].reset_index(drop=True)
    ids = ble["anchor_id"].astype(str).to_numpy()
    pairs, notes = collect_readings(sessions, ids, cfg)
    sc = _screen(pairs, len(ids), cfg)
    gp = _priors(ble, sc, cfg)
    est, cov_of, walls_at_est = _solve(sessions, sc, gp, cfg, notes)
    fit = _fit_values(est, cov_of, sessions, sc, gp, cfg)
    resid, cells = _residuals(est, sessions, sc, gp, fit, walls_at_est, cfg)
    rho = _intra_cell_correlation([resid[j] for j in resid], [cells[j] for j in resid])
    if resid:
        notes.append(f"shadowing: intra-cell ({cfg.shadow_corr_m:g} m) correlation of the residuals {rho:.2f}; "
                     f"stds inflated by the design effect 1 + (m - 1) rho (m: readings per cell)")
    table, res_std = _beacon_table(ble, ids, sessions, pairs, sc, est, cov_of, fit, resid, cells, rho, cfg)
    ref_id = _fit_notes(notes, sessions, sc, gp, fit, est, cfg)
    return MappingResult(table, fit.gamma, fit.gamma_std, fit.offsets, ref_id, res_std, notes, time.perf_counter() - t0)


def _screen(pairs: list[_Pair], nb: int, cfg: MappingConfig) -> _Screening:
    """Readings per beacon (of nb) and the checks before the solve: a beacon needs ``min_readings`` readings
    heard from positions whose minor-axis spread is at least ``min_spread_m`` (m); the others get the reason."""
    n_read = np.zeros(nb, int)
    for p in pairs:
        n_read[p.j] += len(p.rssi)
    P_all = {j: np.vstack([p.P for p in pairs if p.j == j]) for j in np.unique([p.j for p in pairs])}
    y_all = {j: np.concatenate([p.rssi for p in pairs if p.j == j]) for j in P_all}
    spread = np.array([_spread(P_all[j]) if j in P_all else 0.0 for j in range(nb)])
    status = np.array(["placed"] * nb, dtype=object)
    for j in range(nb):
        if n_read[j] < cfg.min_readings:
            status[j] = f"heard too little: {n_read[j]} reading(s) < {cfg.min_readings}"
        elif spread[j] < cfg.min_spread_m:
            status[j] = f"bad geometry: heard from positions spread {spread[j]:.2f} m across < {cfg.min_spread_m:g} m"
    active = np.flatnonzero(status == "placed")
    sess_used = sorted({p.s for p in pairs if status[p.j] == "placed"})
    ref = sess_used[0] if sess_used else 0
    used = [p for p in pairs if status[p.j] == "placed"]
    return _Screening(n_read, P_all, y_all, spread, status, active, used, sess_used, ref)


def _priors(ble: pd.DataFrame, sc: _Screening, cfg: MappingConfig) -> _Graph:
    """The variables, their initial values and broad priors (see the module docstring): per active beacon L(j)
    (Point3, world m) and A(j) (1-D, dBm; around the common level A(nb) when ``a_x_spread_db``), then G(0),
    W(0), O(s) (one per used session when there are several) and M(0) (1-D each). ``ble``: the nb BLE rows of
    anchors.csv (x, y, z in world m)."""
    import gtsam
    from gtsam.symbol_shorthand import A, G, L, M, O, W

    nb, active = len(ble), sc.active
    graph = gtsam.NonlinearFactorGraph()
    init = gtsam.Values()
    nm = gtsam.noiseModel
    rssi_prior_noise = nm.Isotropic.Sigma(1, cfg.a_x_prior_sigma_db)  # dB
    gamma_prior_noise = nm.Isotropic.Sigma(1, 1.0)  # path-loss exponent, broad
    offset_noise = nm.Isotropic.Sigma(1, 10.0)  # dB, receiver offsets of the other sessions
    reference_noise = nm.Isotropic.Sigma(1, 1e-3)  # dB, the reference session's offset held at 0
    beacon_prior_noise = nm.Diagonal.Sigmas(np.array([cfg.prior_sigma_m, cfg.prior_sigma_m, cfg.height_sigma_m]))  # m
    guess = ble[["x", "y", "z"]].to_numpy(float).copy()
    guess[~np.isfinite(guess[:, 2]), 2] = cfg.default_z_m  # a beacon of unknown height (an imported survey)
    level_spread_noise = None if cfg.a_x_spread_db is None else nm.Isotropic.Sigma(1, cfg.a_x_spread_db)  # dB
    if len(active) and level_spread_noise is not None:  # the deployment's common 1 m level, A(nb)
        init.insert(A(nb), np.array([cfg.a_x_prior_dbm]))
        graph.add(gtsam.PriorFactorVector(A(nb), np.array([cfg.a_x_prior_dbm]), rssi_prior_noise))
    for j in active:
        if not cfg.use_map_prior or not np.isfinite(guess[j, :2]).all():  # no map prior, or no position to centre on
            guess[j, :2] = _initial_xy(sc.P_all[j], sc.y_all[j])
        init.insertPoint3(L(j), guess[j])
        graph.add(gtsam.PriorFactorPoint3(L(j), guess[j], beacon_prior_noise))
        init.insert(A(j), np.array([cfg.a_x_prior_dbm]))
        if level_spread_noise is None:
            graph.add(gtsam.PriorFactorVector(A(j), np.array([cfg.a_x_prior_dbm]), rssi_prior_noise))
        else:  # A_j = common level + a beacon's own deviation
            graph.add(gtsam.BetweenFactorVector(A(nb), A(j), np.zeros(1), level_spread_noise))
    gamma_fixed = None if cfg.estimate_gamma else float(cfg.gamma)
    if len(active) and cfg.estimate_gamma:
        init.insert(G(0), np.array([cfg.gamma]))
        graph.add(gtsam.PriorFactorVector(G(0), np.array([cfg.gamma]), gamma_prior_noise))
    has_body = bool(cfg.body_loss) and len(active) > 0
    if has_body:
        body_prior_noise = nm.Isotropic.Sigma(1, cfg.body_db_sigma)  # dB
        init.insert(W(0), np.array([cfg.body_db_prior]))
        graph.add(gtsam.PriorFactorVector(W(0), np.array([cfg.body_db_prior]), body_prior_noise))
    multi = len(sc.sess_used) > 1
    for s in sc.sess_used if multi else []:
        init.insert(O(s), np.zeros(1))
        graph.add(gtsam.PriorFactorVector(O(s), np.zeros(1), reference_noise if s == sc.ref else offset_noise))
    has_walls = bool(cfg.walls) and len(active) > 0
    if has_walls:
        wall_prior_noise = nm.Isotropic.Sigma(1, cfg.wall_db_sigma)  # dB per wall
        init.insert(M(0), np.array([cfg.wall_db_prior]))
        graph.add(gtsam.PriorFactorVector(M(0), np.array([cfg.wall_db_prior]), wall_prior_noise))
    return _Graph(graph, init, guess, gamma_fixed, has_body, has_walls, multi)


def _measurement_factors(used: list[_Pair], walls: list | None, gp: _Graph, cfg: MappingConfig, unit: dict):
    """The RSSI factors (a gtsam.NonlinearFactorGraph) of every used (beacon, session) pair: one
    ``CustomFactor`` of the pair's n readings (n residuals, whitened and robustified inside :func:`rssi_error`,
    hence unit noise; ``unit`` caches the n-D models), keys in the order it expects. ``walls``: per pair (n,)
    wall counts, bound (held fixed in one solve), or None."""
    import gtsam
    from gtsam.symbol_shorthand import A, G, L, M, O, W

    g = gtsam.NonlinearFactorGraph()
    for q, p in enumerate(used):
        keys = ([L(p.j), A(p.j)] + ([G(0)] if gp.gamma_fixed is None else []) + ([W(0)] if gp.has_body else [])
                + ([M(0)] if gp.has_walls else []) + ([O(p.s)] if gp.multi else []))
        n = len(p.rssi)
        if n not in unit:
            unit[n] = gtsam.noiseModel.Unit.Create(n)  # the residuals are whitened and robustified in rssi_error
        err = partial(rssi_error, p.P, p.rssi, p.heading, None if walls is None else walls[q],
                      float(cfg.sigma_db), cfg.robust, float(cfg.robust_k), gp.gamma_fixed, gp.has_body, gp.multi)
        g.add(gtsam.CustomFactor(unit[n], keys, err))
    return g


def _wall_counts(sessions: list, used: list[_Pair], xyz: np.ndarray, cap: int | None) -> list:
    """Per used pair, the (n,) walls crossed from its beacon at ``xyz`` (nb, 3) world m (x, y used) to its
    readings' positions, on its session's floor plan, capped at ``cap``."""
    return [_walls_on_cells(sessions[p.s].floor, xyz[p.j, :2], p.P[:, :2], cap) for p in used]


def _solve(sessions: list, sc: _Screening, gp: _Graph, cfg: MappingConfig, notes: list[str]):
    """Levenberg-Marquardt on the priors and the RSSI factors; with walls up to ``wall_passes`` solves, each with
    the wall counts at the previous estimate (stops when fewer than 1 % of them change). Appends one note per
    solve, or the failure (the active beacons are marked failed when there is no estimate at all). Returns
    (estimate gtsam.Values or None, the marginal covariance of a key (a function) or None, the wall counts at the
    estimate: per used pair (n,), or None)."""
    import gtsam
    from gtsam.symbol_shorthand import L

    est, cov_of, walls_at_est = None, None, None
    if not len(sc.active):
        return est, cov_of, walls_at_est
    unit = {}
    params = gtsam.LevenbergMarquardtParams()
    params.setMaxIterations(int(cfg.max_iterations))
    params.setRelativeErrorTol(float(cfg.relative_tol))
    walls = _wall_counts(sessions, sc.used, gp.guess, cfg.max_walls) if gp.has_walls else None
    walls_at_est = walls
    values = gp.init
    try:
        for it in range(max(int(cfg.wall_passes), 1) if gp.has_walls else 1):
            full = gtsam.NonlinearFactorGraph()
            full.push_back(gp.graph)
            full.push_back(_measurement_factors(sc.used, walls, gp, cfg, unit))
            opt = gtsam.LevenbergMarquardtOptimizer(full, values, params)
            est = opt.optimize()
            notes.append(f"LM{f' (wall pass {it + 1})' if gp.has_walls else ''}: {opt.iterations()} iterations, "
                         f"error {full.error(values):.4g} -> {full.error(est):.4g}")
            if not gp.has_walls:
                break
            xyz = gp.guess.copy()
            for jj in sc.active:
                xyz[jj] = est.atPoint3(L(jj))
            again = walls_at_est = _wall_counts(sessions, sc.used, xyz, cfg.max_walls)
            changed = sum(int(np.count_nonzero(a != b)) for a, b in zip(again, walls))
            total = sum(len(a) for a in again)
            if changed <= 0.01 * total:  # the counts this solve used still hold at its estimate
                break
            walls, values = again, est
        marg = gtsam.Marginals(full, est)
        cov_of = marg.marginalCovariance
    except RuntimeError as exc:
        msg = " ".join(str(exc).split())[:200]
        notes.append(f"mapping solve failed: {msg}")
        if est is None:
            sc.status[sc.active] = f"solve failed: {msg}"
    return est, cov_of, walls_at_est


def _fit_values(est, cov_of, sessions: list, sc: _Screening, gp: _Graph, cfg: MappingConfig) -> _Fit:
    """The shared values at the estimate ``est`` (gtsam.Values or None; ``cov_of``: marginal covariance or None)."""
    from gtsam.symbol_shorthand import G, M, O, W

    gamma = float(est.atVector(G(0))[0]) if est is not None and cfg.estimate_gamma else float(cfg.gamma)
    gamma_std = 0.0
    if est is not None and cfg.estimate_gamma and cov_of is not None:
        gamma_std = float(np.sqrt(cov_of(G(0))[0, 0]))
    body = float(est.atVector(W(0))[0]) if est is not None and gp.has_body else 0.0
    wall_db = float(est.atVector(M(0))[0]) if est is not None and gp.has_walls else 0.0
    offsets = {}
    if est is not None and gp.multi:
        offsets = {sessions[s].id: float(est.atVector(O(s))[0]) for s in sc.sess_used}
    return _Fit(gamma, gamma_std, body, wall_db, offsets)


def _residuals(est, sessions: list, sc: _Screening, gp: _Graph, fit: _Fit, walls_at_est: list | None,
               cfg: MappingConfig) -> tuple[dict, dict]:
    """Residuals (prediction - reading, dB) at the estimate of each active beacon's readings {j: (n_j,)}, and the
    ``shadow_corr_m`` cells they were read in {j: (n_j,) int}; both empty without an estimate."""
    from gtsam.symbol_shorthand import A, L

    resid, cells = {}, {}
    for j in sc.active if est is not None else []:
        l, a_j = np.asarray(est.atPoint3(L(j)), float), float(est.atVector(A(j))[0])
        resid[j] = np.concatenate([_residual_db(p, l, a_j, fit.gamma, fit.offsets.get(sessions[p.s].id, 0.0), fit.body)
                                   - (fit.wall_db * walls_at_est[q] if gp.has_walls else 0.0)
                                   for q, p in enumerate(sc.used) if p.j == j])
        cells[j] = _cell_ids(sc.P_all[j], cfg.shadow_corr_m)
    return resid, cells


def _stated_stds(j: int, u: np.ndarray, cells_j: np.ndarray, rho: float, cov_of, cfg: MappingConfig):
    """(std_m, tx_power_std_db) stated for beacon j: its marginal covariance (horizontal std per axis, m; A(j),
    dB) times the a-posteriori variance factor of its residuals ``u`` (n,) dB (robust scale against sigma_db,
    never below 1) and the design effect 1 + (m - 1) rho (m: readings per cell, ``cells_j`` (n,)), then
    ``std_scale``; NaN without a covariance (``cov_of`` None)."""
    from gtsam.symbol_shorthand import A, L

    std = a_std = np.nan
    # a-posteriori variance factor (robust scale of the residuals against sigma_db, never below 1) times
    # the design effect of cluster sampling: readings within one shadowing cell share their shadowing
    scale2 = max(1.0, (1.4826 * float(np.median(np.abs(u - np.median(u)))) / cfg.sigma_db) ** 2)
    m = len(u) / max(len(np.unique(cells_j)), 1)
    deff = 1.0 + (m - 1.0) * rho
    if cov_of is not None:
        c = np.asarray(cov_of(L(j))) * scale2 * deff
        std = float(np.sqrt(max(np.trace(c[:2, :2]), 0.0) / 2.0)) * cfg.std_scale
        a_std = float(np.sqrt(cov_of(A(j))[0, 0] * scale2 * deff)) * cfg.std_scale
    return std, a_std


def _beacon_table(ble: pd.DataFrame, ids: np.ndarray, sessions: list, pairs: list[_Pair], sc: _Screening, est,
                  cov_of, fit: _Fit, resid: dict, cells: dict, rho: float,
                  cfg: MappingConfig) -> tuple[pd.DataFrame, float]:
    """The beacons table of :class:`MappingResult` (one row per BLE anchor, see there) and the robust std (dB,
    1.4826 MAD) of all placed beacons' residuals. A beacon whose stated std is not finite, or above
    ``max_std_m`` (m), is not placed: its reason goes to ``sc.status``, its position stays the input's."""
    from gtsam.symbol_shorthand import A, L

    status = sc.status
    rows, all_u = [], []
    for j in range(len(ids)):
        xyz = ble.loc[j, ["x", "y", "z"]].to_numpy(float)
        std = a_db = a_std = np.nan
        if status[j] == "placed" and est is not None:
            xyz = np.asarray(est.atPoint3(L(j)), float)
            a_db = float(est.atVector(A(j))[0])
            u = resid[j]
            all_u.append(u)
            std, a_std = _stated_stds(j, u, cells[j], rho, cov_of, cfg)
            if not np.isfinite(std):
                status[j] = "no covariance (solve failed)"
            elif std > cfg.max_std_m:
                status[j] = f"bad geometry: std {std:.2f} m > {cfg.max_std_m:g} m"
            if status[j] != "placed":
                xyz = ble.loc[j, ["x", "y", "z"]].to_numpy(float)
        peak = np.nan
        if j in sc.y_all:  # the beacon's strong readings (95th percentile, receiver offsets removed)
            y_corr = np.concatenate([p.rssi - fit.offsets.get(sessions[p.s].id, 0.0) for p in pairs if p.j == j])
            peak = float(np.percentile(y_corr, 95))
        rows.append({"anchor_id": ids[j], "x": xyz[0], "y": xyz[1], "z": xyz[2], "std_m": std, "tx_power_dbm": a_db,
                     "peak_dbm": peak,
                     "tx_power_std_db": a_std, "n_readings": int(sc.n_read[j]), "spread_m": float(sc.spread[j]),
                     "placed": status[j] == "placed", "status": status[j]})
    table = pd.DataFrame(rows)
    for c in ("std_m", "tx_power_dbm", "tx_power_std_db"):
        table.loc[~table["placed"], c] = np.nan
    res_std = (1.4826 * float(np.median(np.abs(np.concatenate(all_u) - np.median(np.concatenate(all_u)))))
               if all_u else float("nan"))
    return table, res_std


def _fit_notes(notes: list[str], sessions: list, sc: _Screening, gp: _Graph, fit: _Fit, est,
               cfg: MappingConfig) -> str:
    """Appends the notes on the shared values (receiver offsets, body shadow, wall loss) to ``notes``; returns
    the reference session's id ('' when no session was used)."""
    ref = sc.ref
    ref_id = sessions[ref].id if sc.sess_used else ""
    if gp.multi:
        notes.append(f"tx_power_dbm is the RSSI at 1 m as session {ref_id}'s receiver ({sessions[ref].device_model}) "
                     f"reads it; receiver offsets of the others: "
                     + ", ".join(f"{k} {v:+.1f} dB" for k, v in fit.offsets.items() if k != ref_id))
    if gp.has_body and est is not None:
        notes.append(f"body shadow W = {fit.body:.1f} dB")
    if gp.has_walls and est is not None:
        notes.append(f"wall loss M = {fit.wall_db:.1f} dB per wall (at most {cfg.max_walls} walls)")
    return ref_id


def _cell_ids(P: np.ndarray, size_m: float) -> np.ndarray:
    """(n,) integer id of the horizontal grid cell (``size_m``) of each position P (n, >= 2)."""
    ij = np.floor(P[:, :2] / max(size_m, 1e-6)).astype(np.int64)
    return ij[:, 0] * 1_000_003 + ij[:, 1]


def _intra_cell_correlation(resid: list[np.ndarray], cells: list[np.ndarray]) -> float:
    """Pooled one-way ANOVA estimate of the intra-cell correlation rho = s_b^2 / (s_b^2 + s_w^2) of residuals
    grouped by (beacon, cell), in [0, 1]; 0 without enough data."""
    ss_w = ss_b = 0.0
    n_tot = n_groups = 0
    sizes = []
    for u, c in zip(resid, cells):
        if len(u) < 2:
            continue
        _, inv, cnt = np.unique(c, return_inverse=True, return_counts=True)
        means = np.bincount(inv, weights=u) / cnt
        ss_w += float(np.sum((u - means[inv]) ** 2))
        ss_b += float(np.sum(cnt * (means - u.mean()) ** 2))
        n_tot += len(u)
        n_groups += len(cnt)
        sizes.append(cnt)
    n_beacons = len(sizes)
    if n_tot - n_groups < 1 or n_groups - n_beacons < 1:
        return 0.0
    msw = ss_w / (n_tot - n_groups)
    msb = ss_b / (n_groups - n_beacons)
    cnt = np.concatenate(sizes)
    m0 = (n_tot - float(np.sum(cnt**2)) / n_tot) / max(n_groups - n_beacons, 1)  # unbalanced ANOVA group size
    s_b2 = max((msb - msw) / max(m0, 1e-9), 0.0)
    return float(s_b2 / (s_b2 + msw)) if s_b2 + msw > 0 else 0.0


def _residual_db(p: _Pair, l: np.ndarray, a: float, gamma: float, offset: float, body_db: float) -> np.ndarray:
    """Prediction - reading (dB) of one pair's readings at the estimate."""
    diff = l - p.P
    d = np.maximum(np.linalg.norm(diff, axis=-1), D_MIN)
    cos_t = np.einsum("ij,ij->i", p.heading, diff[:, :2]) / np.maximum(np.hypot(diff[:, 0], diff[:, 1]), 1e-6)
    return a + offset - 10.0 * gamma * np.log10(d) - body_db * 0.5 * (1.0 - cos_t) - p.rssi


def mean_map(maps: list[pd.DataFrame]) -> pd.DataFrame:
    """Mean over maps of x, y, z per anchor; std_m the root mean square of the maps' std_m; other columns of the
    first map."""
    if len(maps) == 1:
        return maps[0]
    cat = pd.concat(maps, ignore_index=True)
    g = cat.groupby("anchor_id", sort=False)
    out = g[["x", "y", "z"]].mean()
    if "std_m" in cat:
        out["std_m"] = np.sqrt(g["std_m"].apply(lambda s: float(np.nanmean(s.to_numpy(float) ** 2))
                                                 if s.notna().any() else np.nan))
    rest = [c for c in maps[0].columns if c not in ("anchor_id", "x", "y", "z", "std_m")]
    first = maps[0].set_index("anchor_id")
    for c in rest:
        out[c] = first[c]
    return out.reset_index()
