"""What a beacon-mapping solve reports (:mod:`blenav.backend.mapping`): the residuals at the estimate, each
placed beacon's stated std (its marginal covariance scaled by the a-posteriori variance factor, the design effect
of the shadowing shared within a cell, and ``std_scale``), the beacons table with the reason for every beacon not
placed, and the notes on the shared values.
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from .config import MappingConfig
from .mapping_factor import residual_db
from .mapping_readings import Readings
from .mapping_solve import Fit, GraphPriors, Screening

__all__ = ["residuals", "beacon_table", "fit_notes", "intra_cell_correlation"]


def residuals(est, sessions: list, sc: Screening, gp: GraphPriors, fit: Fit, walls_at_est: list | None,
               cfg: MappingConfig) -> tuple[dict, dict]:
    """Residuals (prediction - reading, dB) at the estimate of each active beacon's readings {j: (n_j,)}, and the
    ``shadow_corr_m`` cells they were read in {j: (n_j,) int}; both empty without an estimate."""
    from gtsam.symbol_shorthand import A, L

    resid, cells = {}, {}
    for j in sc.active if est is not None else []:
        l, a_j = np.asarray(est.atPoint3(L(j)), float), float(est.atVector(A(j))[0])
        resid[j] = np.concatenate([residual_db(p, l, a_j, fit.gamma, fit.offsets.get(sessions[p.s].id, 0.0), fit.body)
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


def beacon_table(ble: pd.DataFrame, ids: np.ndarray, sessions: list, pairs: list[Readings], sc: Screening, est,
                  cov_of, fit: Fit, resid: dict, cells: dict, rho: float,
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


def fit_notes(notes: list[str], sessions: list, sc: Screening, gp: GraphPriors, fit: Fit, est,
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


def intra_cell_correlation(resid: list[np.ndarray], cells: list[np.ndarray]) -> float:
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
