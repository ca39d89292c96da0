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

import numpy as np
import pandas as pd

from .config import MappingConfig, mapping_kernel
from .mapping_readings import collect_readings
from .mapping_report import beacon_table, fit_notes, intra_cell_correlation, residuals
from .mapping_solve import fit_values, priors, screen, solve

__all__ = ["MappingResult", "map_beacons", "mean_map"]


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


def map_beacons(sessions, anchors: pd.DataFrame, cfg: MappingConfig) -> MappingResult:
    """Estimate the BLE anchors' positions and RSSI at 1 m from labelled ``sessions`` (all in one building whose
    anchors.csv rows are ``anchors``). Never invents a beacon: see the module docstring for the checks."""
    import gtsam  # noqa: F401  (without GTSAM this fails here, before any check)

    mapping_kernel(cfg.robust)
    t0 = time.perf_counter()
    sessions = list(sessions)
    if not sessions:
        raise ValueError("no session to map beacons from")
    ble = anchors[anchors["kind"] == "ble"].reset_index(drop=True)
    ids = ble["anchor_id"].astype(str).to_numpy()
    pairs, notes = collect_readings(sessions, ids, cfg)
    sc = screen(pairs, len(ids), cfg)
    gp = priors(ble, sc, cfg)
    est, cov_of, walls_at_est = solve(sessions, sc, gp, cfg, notes)
    fit = fit_values(est, cov_of, sessions, sc, gp, cfg)
    resid, cells = residuals(est, sessions, sc, gp, fit, walls_at_est, cfg)
    rho = intra_cell_correlation([resid[j] for j in resid], [cells[j] for j in resid])
    if resid:
        notes.append(f"shadowing: intra-cell ({cfg.shadow_corr_m:g} m) correlation of the residuals {rho:.2f}; "
                     f"stds inflated by the design effect 1 + (m - 1) rho (m: readings per cell)")
    table, res_std = beacon_table(ble, ids, sessions, pairs, sc, est, cov_of, fit, resid, cells, rho, cfg)
    ref_id = fit_notes(notes, sessions, sc, gp, fit, est, cfg)
    return MappingResult(table, fit.gamma, fit.gamma_std, fit.offsets, ref_id, res_std, notes, time.perf_counter() - t0)


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
