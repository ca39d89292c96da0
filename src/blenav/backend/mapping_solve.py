"""The graph of the beacon mapping (:mod:`blenav.backend.mapping`): the checks before the solve (readings and
geometry per beacon), the variables with their priors, the RSSI factors, and Levenberg-Marquardt with the wall
counts re-taken at each estimate; then the values shared by all beacons at the solution. GTSAM is imported in the
functions that build or solve.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import partial

import numpy as np
import pandas as pd

from .config import MappingConfig
from .mapping_factor import rssi_error
from .mapping_readings import Readings, walls_on_cells

__all__ = ["Screening", "GraphPriors", "Fit", "screen", "priors", "solve", "fit_values"]


@dataclass
class Screening:
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
class GraphPriors:
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
class Fit:
    """The shared values at the estimate: ``gamma`` (path-loss exponent; ``cfg.gamma`` when fixed or unsolved),
    ``gamma_std`` (0 when fixed or without covariance), ``body`` W (dB), ``wall_db`` M (dB per wall; 0 when not
    modelled), ``offsets`` {session id: receiver offset, dB} (empty with one session)."""

    gamma: float
    gamma_std: float
    body: float
    wall_db: float
    offsets: dict


def screen(pairs: list[Readings], nb: int, cfg: MappingConfig) -> Screening:
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
    return Screening(n_read, P_all, y_all, spread, status, active, used, sess_used, ref)


def priors(ble: pd.DataFrame, sc: Screening, cfg: MappingConfig) -> GraphPriors:
    """The variables, their initial values and broad priors (see :mod:`blenav.backend.mapping`): per active beacon L(j)
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
    return GraphPriors(graph, init, guess, gamma_fixed, has_body, has_walls, multi)


def _measurement_factors(used: list[Readings], walls: list | None, gp: GraphPriors, cfg: MappingConfig, unit: dict):
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


def _wall_counts(sessions: list, used: list[Readings], xyz: np.ndarray, cap: int | None) -> list:
    """Per used pair, the (n,) walls crossed from its beacon at ``xyz`` (nb, 3) world m (x, y used) to its
    readings' positions, on its session's floor plan, capped at ``cap``."""
    return [walls_on_cells(sessions[p.s].floor, xyz[p.j, :2], p.P[:, :2], cap) for p in used]


def solve(sessions: list, sc: Screening, gp: GraphPriors, cfg: MappingConfig, notes: list[str]):
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


def fit_values(est, cov_of, sessions: list, sc: Screening, gp: GraphPriors, cfg: MappingConfig) -> Fit:
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
    return Fit(gamma, gamma_std, body, wall_db, offsets)


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
