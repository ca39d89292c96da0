"""The closed loop of Ghaffari Jadidi et al. (000, Fig. 2, sec. IV-D, Remark 2): front-end and back-end together.

The particle filter (the front-end, a :class:`~blenav.filters.runner.BatchRun`) runs ``loop.period_s`` at a
time. After each period the back-end smooths the keyframes of the last ``loop.window_s`` (initialised from the
front-end's estimates, Fig. 2) with the beacon map and IMU bias carried over from the previous window as priors,
and feeds back

* the beacon map: every beacon the window optimized replaces its position in the filter's map
  (:meth:`BatchRun.rebind_anchors`), and becomes the next window's prior (its marginal std, floored);
* the IMU bias: the accelerometer and gyroscope biases are subtracted from the IMU samples after the feedback
  (:meth:`BatchRun.correct_imu`): the AHRS and the IMU proposal see a_t - theta_a (Remark 2, eq. 6 of 000).
  Each window estimates the bias left in the already corrected samples (prior centred on 0), so the
  corrections add up.

When the session ends, the back-end smooths the whole session once more (``solver`` settings, usually LM) from
the closed-loop front-end, with the original map as prior (every range used once): that is the B.-end of Fig. 3,
and its beacon map is the optimized map. ``loop.enabled = false`` gives the open loop (the filter never hears
from the back-end) with the same final smoothing.

Runs: the R runs of one call share one back-end, initialised from their mean (``init.from_runs``); runs that
must be independent (e.g. a perturbed map per run) are separate calls.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np
import pandas as pd

from blenav.filters.estimate import Estimate
from blenav.filters.method import Method
from blenav.filters.runner import BatchRun

from .config import BackendConfig
from .graph import smooth
from .graph_types import BackendResult, BeaconPriors, ImuSamples, OdometryTrack, RangeObs
from .inputs import keyframes_from_front_end


@dataclass
class Feedback:
    """One feedback: its time t (s), the beacons moved (ids), the bias increment (6,) accelerometer m/s^2 then
    gyroscope rad/s, the window's solve time (s), and the receiver offset (dB, NaN unless
    ``range.estimate_offset``) now in the filter."""

    t: float
    moved: list[str]
    bias_increment: np.ndarray
    solve_s: float
    offset_db: float = float("nan")
    exponent: float = float("nan")  # the channel's path-loss exponent (NaN unless range.estimate_exponent)


@dataclass
class LoopOutcome:
    """``front``: the closed-loop filter's estimates (R runs); ``smoothed``: the final back-end (None when it
    could not run, see ``notes``); ``bias_applied`` (K, 6): the bias correction in force at each filter step;
    ``feedbacks``: the history; ``backend_s``: seconds spent in the back-end (windows + final)."""

    front: Estimate
    smoothed: BackendResult | None
    bias_applied: np.ndarray
    feedbacks: list[Feedback] = field(default_factory=list)
    notes: list[str] = field(default_factory=list)
    failures: list[str] = field(default_factory=list)
    backend_s: float = 0.0


def window_inputs(imu: ImuSamples, ranges: RangeObs, t0: float, t1: float) -> tuple[ImuSamples, RangeObs]:
    """The IMU samples and ranges with t0 <= t <= t1."""
    i = (imu.t >= t0) & (imu.t <= t1)
    r = (ranges.t >= t0) & (ranges.t <= t1)
    return ImuSamples(imu.t[i], imu.acc[i], imu.gyr[i]), RangeObs(ranges.t[r], ranges.anchor[r], ranges.range_m[r],
                                                                  ranges.gamma)


def carry_map(prior: BeaconPriors, bmap: pd.DataFrame, floor_m: float, min_gain_m: float) -> tuple[BeaconPriors, list[str]]:
    """The next window's beacon priors: optimized beacons at their estimate with std max(marginal std, floor)
    horizontally (when it beats the prior's by ``min_gain_m``), the others unchanged. Returns (priors, moved ids)."""
    xyz, sigma = prior.xyz.copy(), prior.sigma.copy()
    row = {a: i for i, a in enumerate(prior.ids)}
    moved = []
    for r in bmap.itertuples(index=False):
        j = row.get(str(r.anchor_id))
        if j is None or r.status != "optimized" or not np.isfinite([r.x, r.y, r.z]).all():
            continue
        std = float(r.std_m) if np.isfinite(r.std_m) else float(sigma[j, 0])
        if std > sigma[j, 0] - min_gain_m and min_gain_m > 0:
            continue
        xyz[j] = [r.x, r.y, r.z]
        sigma[j, :2] = max(std, floor_m)
        moved.append(str(r.anchor_id))
    return BeaconPriors(prior.ids, xyz, sigma), moved


def map_frame(anchors: pd.DataFrame, prior: BeaconPriors) -> pd.DataFrame:
    """``anchors`` (the filter's BLE anchors, anchors.csv rows) with x, y, z from ``prior`` (matched by id)."""
    out = anchors.copy()
    pos = pd.DataFrame(prior.xyz, columns=["x", "y", "z"], index=pd.Index(prior.ids, name="anchor_id"))
    ids = out["anchor_id"].astype(str)
    have = ids.isin(pos.index).to_numpy()
    out.loc[have, ["x", "y", "z"]] = pos.loc[ids[have]].to_numpy()
    return out


def run_closed_loop(method: Method, session, n_runs: int, seed: int, cfg: BackendConfig, imu: ImuSamples,
                    ranges: RangeObs, beacons: BeaconPriors, attitude: tuple[np.ndarray, np.ndarray],
                    cache: dict | None = None, odometry: OdometryTrack | None = None) -> LoopOutcome:
    """Front-end ``method`` on ``session`` (R runs, ``seed``) with the back-end of ``cfg`` in the loop.

    ``imu``: the session's raw IMU; ``ranges``: its RSSI as ranges (the front-end's path loss); ``beacons``: the
    map's BLE anchors as priors; ``attitude`` (t (T,), q (T, 4)): the AHRS for keyframe attitudes when the
    front-end has none of its own (a random-walk filter); ``odometry``: a learned inertial odometry's track, whose
    displacements every smoothing (windows and final) takes as between-factors (``backend.odometry``)."""
    lc = cfg.loop
    run = BatchRun(method, session, n_runs, seed, cache=cache)
    anchors = session.building.anchors_of("ble")
    anchors = anchors.set_index(anchors["anchor_id"].astype(str)).loc[list(run.anchors.ids)].reset_index(drop=True)
    prior = beacons
    applied = np.zeros(6)
    bias_applied = np.zeros((len(run.steps), 6))
    feedbacks: list[Feedback] = []
    notes: list[str] = []
    failures: list[str] = []
    backend_s = 0.0
    t_start = float(run.arrays.t_start)
    period = float(lc.period_s)
    if not period > 0:
        raise ValueError(f"backend.loop.period_s must be > 0, got {lc.period_s}")
    feed_bias = lc.feed_bias and run.method.needs_imu  # a filter that reads no IMU has nothing to correct
    t_next = t_start + period
    while not run.done:
        k0 = run.k
        run.advance(t_next)
        bias_applied[k0:run.k] = applied
        if not run.done and lc.enabled:
            fb, prior = _feedback(run, cfg, imu, ranges, prior, anchors, attitude, t_next, feed_bias, notes, failures,
                                  feedbacks[-1].offset_db if feedbacks else 0.0, odometry,
                                  feedbacks[-1].exponent if feedbacks else np.nan)
            if fb is not None:
                feedbacks.append(fb)
                backend_s += fb.solve_s
                applied = applied + fb.bias_increment
        t_next += period
    front = run.result()
    # B.-end: the whole session from the closed-loop front-end, the original map as prior
    q_t, q = _attitude(run, attitude)
    smoothed = None
    t1 = time.perf_counter()
    try:
        kf, kf_notes = keyframes_from_front_end(front.t, front.position, q_t, q, cfg, cov=front.cov)
        smoothed = smooth(cfg, kf, _corrected(run, imu), ranges, beacons, odometry=odometry)
        notes += kf_notes + smoothed.notes
        failures += [str(f) for f in smoothed.failures]
    except ValueError as exc:
        notes.append(f"no final smoothing: {exc}")
    backend_s += time.perf_counter() - t1
    if lc.enabled and feedbacks:
        n_moved = len({b for f in feedbacks for b in f.moved})
        notes.append(f"closed loop: {len(feedbacks)} feedback(s) every {period:g} s, {n_moved} beacon(s) moved, "
                     f"bias applied at the end acc {np.round(applied[:3], 3).tolist()} m/s^2, gyro "
                     f"{np.round(applied[3:], 4).tolist()} rad/s")
    return LoopOutcome(front, smoothed, bias_applied, feedbacks, notes, failures, backend_s)


def _feedback(run: BatchRun, cfg: BackendConfig, imu: ImuSamples, ranges: RangeObs, prior: BeaconPriors,
              anchors: pd.DataFrame, attitude, t_now: float, feed_bias: bool, notes: list, failures: list,
              offset_db: float = 0.0, odometry: OdometryTrack | None = None,
              exponent: float = np.nan) -> tuple[Feedback | None, BeaconPriors]:
    """One window of the loop at ``t_now``: smooth the last ``loop.window_s`` of keyframes with ``prior`` as the
    beacon map (and ``offset_db`` / ``exponent``, the receiver offset and the channel's exponent so far, as their
    priors' means; NaN: the ranges' own exponent), feed the optimized beacons, the bias increment and the receiver
    offset back to ``run`` (the exponent stays the graph's: the filter's range model keeps its own). Returns (the
    feedback or None when the window gave none, the next window's beacon priors)."""
    lc = cfg.loop
    res = run.result()
    w0 = t_now - float(lc.window_s) if lc.window_s is not None else -np.inf
    sel = res.t > w0
    if np.count_nonzero(sel) < 2:
        return None, prior
    kf, _ = keyframes_from_front_end(res.t[sel], res.position[:, sel], *_attitude(run, attitude), cfg,
                                     cov=None if res.cov is None else res.cov[:, sel])
    if len(kf.t) < 2:
        return None, prior
    w_imu, w_ranges = window_inputs(_corrected(run, imu), ranges, float(kf.t[0]), float(kf.t[-1]))
    when = f"window ending {t_now - float(run.arrays.t_start):.0f} s"
    t1 = time.perf_counter()
    try:
        out = smooth(cfg, kf, w_imu, w_ranges, prior, offset_prior_db=offset_db if np.isfinite(offset_db) else 0.0,
                     odometry=odometry, exponent_prior=exponent if np.isfinite(exponent) else None)
    except ValueError as exc:  # inputs the window cannot use (e.g. no IMU in it): no feedback this time
        notes.append(f"{when}: no feedback ({exc})")
        return None, prior
    dt = time.perf_counter() - t1
    if not out.ok:
        failures += [f"{when}: {f}" for f in out.failures]
        return None, prior
    moved: list[str] = []
    if lc.feed_map:
        prior, moved = carry_map(prior, out.beacon_map, lc.beacon_sigma_floor_m, lc.min_beacon_std_gain)
        if moved:
            run.rebind_anchors(map_frame(anchors, prior))
    inc = np.asarray(out.bias[-1], float) if feed_bias else np.zeros(6)
    if not np.isfinite(inc).all():
        inc = np.zeros(6)
    if inc.any():
        run.correct_imu(float(res.t[-1]), inc[:3], inc[3:])
    if np.isfinite(out.offset_db):
        run.set_receiver_offset(out.offset_db)
    exponent = out.channel_exponent if cfg.range.estimate_exponent else np.nan  # the variable's, not a refit's
    return Feedback(float(res.t[-1]), moved, inc, dt, out.offset_db, exponent), prior


def _attitude(run: BatchRun, attitude) -> tuple[np.ndarray, np.ndarray]:
    """The front-end's own AHRS (after any gyroscope correction) when it has one, else ``attitude``."""
    if run.q is not None:
        return run.arrays.imu_t, run.q
    return attitude


def _corrected(run: BatchRun, imu: ImuSamples) -> ImuSamples:
    """The IMU as the front-end now sees it (bias corrections applied), or ``imu`` when it reads none."""
    if run.method.needs_imu and len(run.arrays.imu_t):
        a = run.arrays
        return ImuSamples(a.imu_t, a.acc, a.gyr)
    return imu


__all__ = ["Feedback", "LoopOutcome", "run_closed_loop", "carry_map", "map_frame", "window_inputs"]
