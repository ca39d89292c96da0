"""A session and a front-end estimate -> the inputs of the factor graph (:mod:`blenav.backend.graph`).

* :func:`keyframes_from_front_end`: keyframes at the front-end's step times (every ``keyframe_every``-th),
  positions (R, K, 2) -> their mean over runs or run 0, world z = the receiver height; velocities by
  central differences over ``init.velocity_window_s`` clipped to ``init.max_speed_mps`` (000 Fig. 2:
  the front-end's position and velocity initialise the back-end); attitude = the AHRS sample at or before
  each keyframe.
* :func:`beacon_priors`: the building's BLE anchors with their stated uncertainty (anchors.csv ``std_m``,
  an optional column, else ``priors.beacon_sigma_m``).
* :func:`session_ranges`: RSSI -> range with PF-PL's model (:class:`blenav.filters.measurement.PathLossRange`,
  its 10 m clamp included) -- the same object the front-end uses when given.
* :func:`session_attitude`: the AHRS of :mod:`blenav.filters.attitude` (hard-iron offset fitted as the
  particle filter does) at the IMU times, when the front-end did not hand its own over.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pandas as pd

from blenav.filters.measurement import AnchorTable, PathLossRange

from .config import BackendConfig, InitFrom
from .graph_types import BeaconPriors, ImuSamples, Keyframes, RangeObs

__all__ = ["keyframes_from_front_end", "front_end_covariance", "beacon_priors", "session_ranges", "session_imu", "session_attitude",
           "path_loss_model", "front_end_velocity", "moving_average"]


def front_end_velocity(t: np.ndarray, xy: np.ndarray, window_s: float, max_speed: float) -> tuple[np.ndarray, int]:
    """(K, 2) m/s central differences of positions xy (K, 2) m at times t (K,) s over ``window_s`` (one-sided
    at the ends), scaled down to ``max_speed`` m/s; returns (velocity, number clipped)."""
    if len(t) < 2:
        return np.zeros_like(xy), 0
    h = 0.5 * window_s
    lo, hi = np.clip(t - h, t[0], t[-1]), np.clip(t + h, t[0], t[-1])
    p_lo = np.stack([np.interp(lo, t, xy[:, i]) for i in range(2)], -1)
    p_hi = np.stack([np.interp(hi, t, xy[:, i]) for i in range(2)], -1)
    v = (p_hi - p_lo) / np.maximum(hi - lo, 1e-9)[:, None]
    v[~np.isfinite(v)] = 0.0
    speed = np.linalg.norm(v, axis=-1)
    fast = speed > max_speed
    v[fast] *= (max_speed / speed[fast])[:, None]
    return v, int(np.count_nonzero(fast))


def moving_average(t: np.ndarray, xy: np.ndarray, window_s: float) -> np.ndarray:
    """(K, D) centred moving average over ``window_s`` seconds (shorter at the ends) of xy (K, D) at times t (K,).
    Cumulative sums: O(K)."""
    if window_s <= 0 or len(t) < 2:
        return xy
    lo = np.searchsorted(t, t - 0.5 * window_s, side="left")
    hi = np.searchsorted(t, t + 0.5 * window_s, side="right")
    c = np.vstack([np.zeros((1, xy.shape[1])), np.cumsum(xy, axis=0)])
    return (c[hi] - c[lo]) / (hi - lo)[:, None]


def front_end_covariance(position: np.ndarray, cov: np.ndarray | None, from_mean: bool) -> np.ndarray | None:
    """(K, 2, 2) m^2: the front-end's x, y covariance at each step from its runs' positions (R, K, 2) and cloud
    covariances (R, K, 2, 2): for the mean over runs the law of total variance (mean cloud covariance plus the
    covariance of the runs' means), for run 0 its own cloud. None without a cloud; non-finite entries -> NaN."""
    if cov is None:
        return None
    pos, cov = np.asarray(position, float), np.asarray(cov, float)
    if pos.ndim == 2:
        return cov if cov.ndim == 3 else cov[0]
    if not from_mean:
        return cov[0]
    d = pos - pos.mean(axis=0, keepdims=True)
    return cov.mean(axis=0) + np.einsum("rki,rkj->kij", d, d) / pos.shape[0]


def keyframes_from_front_end(t: np.ndarray, position: np.ndarray, q_t: np.ndarray, q: np.ndarray,
                             cfg: BackendConfig, cov: np.ndarray | None = None) -> tuple[Keyframes, list[str]]:
    """Keyframes from front-end estimates: t (K,) s, position (R, K, 2) or (K, 2) world m; the AHRS q (T, 4)
    at times q_t (T,); ``cov`` (R, K, 2, 2) the front-end's cloud covariances (kept only with
    ``priors.front_end_cloud``). Returns (keyframes, notes)."""
    t = np.asarray(t, float)
    pos = np.asarray(position, float)
    kcov = front_end_covariance(pos, cov, InitFrom(cfg.init.from_runs) == InitFrom.mean) \
        if cfg.priors.front_end_cloud else None
    if pos.ndim == 3:
        pos = pos.mean(axis=0) if InitFrom(cfg.init.from_runs) == InitFrom.mean else pos[0]
    every = max(int(cfg.solver.keyframe_every), 1)
    sel = np.arange(0, len(t), every)
    t, pos = t[sel], pos[sel]
    kcov = None if kcov is None else kcov[sel]
    notes = []
    bad = ~np.isfinite(pos).all(1)
    if bad.all():
        raise ValueError("the front-end gave no finite position to initialise the back-end")
    if bad.any():  # hold the nearest finite estimate
        good = np.flatnonzero(~bad)
        for i in range(2):
            pos[bad, i] = np.interp(t[bad], t[good], pos[good, i])
        notes.append(f"{np.count_nonzero(bad)} non-finite front-end position(s) interpolated")
    pos = moving_average(t, pos, cfg.init.position_window_s)
    vel2, n_fast = front_end_velocity(t, pos, cfg.init.velocity_window_s, cfg.init.max_speed_mps)
    if n_fast:
        notes.append(f"{n_fast} initial velocit(ies) above {cfg.init.max_speed_mps} m/s scaled down")
    K = len(t)
    p3 = np.column_stack([pos, np.full(K, cfg.range.device_z)])
    v3 = np.column_stack([vel2, np.zeros(K)])
    i = np.clip(np.searchsorted(q_t, t, side="right") - 1, 0, len(q_t) - 1)
    if kcov is not None and not np.isfinite(kcov).all():
        bad = ~np.isfinite(kcov).all(axis=(1, 2))
        kcov[bad] = np.nan  # the graph leaves those keyframes without the cloud prior
        notes.append(f"{np.count_nonzero(bad)} keyframe(s) without a finite front-end covariance: no cloud prior")
    return Keyframes(t, p3, v3, np.asarray(q, float)[i], cov=kcov), notes


def beacon_priors(anchors: pd.DataFrame, sigma_m: float, sigma_z_m: float) -> BeaconPriors:
    """BLE anchors (rows of anchors.csv with kind 'ble') with prior std: ``std_m`` where the file states it
    (finite, > 0), else ``sigma_m``, horizontally; ``sigma_z_m`` vertically."""
    a = anchors[anchors["kind"] == "ble"] if "kind" in anchors else anchors
    xyz = a[["x", "y", "z"]].to_numpy(float)
    s = np.full(len(a), float(sigma_m))
    if "std_m" in a:
        stated = pd.to_numeric(a["std_m"], errors="coerce").to_numpy(float)
        ok = np.isfinite(stated) & (stated > 0)
        s[ok] = stated[ok]
    sigma = np.column_stack([s, s, np.full(len(a), float(sigma_z_m))])
    return BeaconPriors(a["anchor_id"].astype(str).to_numpy(), xyz, sigma)


def path_loss_model(cfg: BackendConfig) -> PathLossRange:
    """PF-PL's range model with the back-end's path-loss settings (``range`` node)."""
    rc = cfg.range
    return PathLossRange(a_x=rc.a_x, gamma=rc.gamma, d0=rc.d0, device_z=rc.device_z,
                         use_anchor_tx_power=rc.use_anchor_tx_power, sigma_n=rc.sigma_n, max_range_m=rc.max_range_m)


def session_ranges(session, beacons: BeaconPriors, model: PathLossRange, anchors: pd.DataFrame) -> RangeObs:
    """The session's RSSI readings of the beacons as ranges (m), converted and clamped by ``model``
    (:meth:`PathLossRange.ranges`); rows refer to ``beacons``."""
    table = AnchorTable.from_frame(anchors.set_index("anchor_id").loc[beacons.ids].reset_index()
                                   if len(beacons.ids) else anchors.iloc[:0])
    r = session.rssi
    if not len(r) or not len(beacons.ids):
        return RangeObs(np.zeros(0), np.zeros(0, int), np.zeros(0), float(model.gamma))
    idx = table.index_of(r["anchor_id"].astype(str).to_numpy())
    keep = idx >= 0
    t = r["t"].to_numpy(float)[keep]
    obs = {"rssi_idx": idx[keep], "rssi": r["rssi"].to_numpy(float)[keep]}
    # every reading's range (the model's conversion, unclamped), then the model's clamp: times stay aligned
    # (on a copy: the caller's model, perhaps the front-end's, keeps its own anchors)
    unclamped = replace(model, max_range_m=np.inf)
    unclamped.bind(table)
    j, rng = unclamped.ranges(obs)
    kept = rng <= model.max_range_m
    return RangeObs(t[kept], j[kept], rng[kept], float(model.gamma))


def session_imu(session) -> ImuSamples:
    imu = session.imu
    return ImuSamples(imu["t"].to_numpy(float), imu[["ax", "ay", "az"]].to_numpy(float),
                      imu[["gx", "gy", "gz"]].to_numpy(float))


def session_attitude(session, att_cfg=None) -> tuple[np.ndarray, np.ndarray]:
    """(t (T,) s, q (T, 4)) the AHRS of :func:`blenav.filters.attitude.estimate_attitude` at the IMU times, with
    the magnetometer's hard-iron offset fitted on the session unless ``hard_iron`` is false (as
    :func:`blenav.filters.runner.magnetometer_offset`)."""
    from blenav.filters.attitude import AttitudeConfig, estimate_attitude, estimate_hard_iron

    cfg = att_cfg or AttitudeConfig()
    imu, mag = session.imu, session.mag
    t = imu["t"].to_numpy(float)
    mt = mv = off = None
    if cfg.use_mag and len(mag) >= 50:
        mt, mv = mag["t"].to_numpy(float), mag[["mx", "my", "mz"]].to_numpy(float)
        off = estimate_hard_iron(mv) if cfg.hard_iron else None
    q = estimate_attitude(t, imu[["ax", "ay", "az"]].to_numpy(float), imu[["gx", "gy", "gz"]].to_numpy(float),
                          mt, mv, cfg, mag_offset=off)
    return t, q
