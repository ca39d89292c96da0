"""Localization metrics against ground truth (pure numpy; no plotting).

Errors are planar Euclidean distances (m) between estimates and ground truth linearly interpolated at
the estimate times; estimates outside the ground truth's time span are not scored. The first
``init_s`` seconds (global localization) are scored separately, not hidden and not mixed in.

Per run: RMSE over the tracking period; ATE is that RMSE (Roy's absolute trajectory error, the
estimates being in the world frame no alignment is applied); EE is the error at the last scored step.
Sparse ground truth (surveyed waypoints, ``groundtruth_kind: waypoints``): the estimate is interpolated
at each waypoint time instead (:func:`waypoint_metrics`); waypoints outside the estimate's time span are
not scored, and no position between waypoints is invented. With ``hold_ends`` (the experiment's
``scoring.hold_ends``) they are scored against the first / last estimate held (zero-order hold), so that a
method whose first estimate comes after the walk's first waypoint (a fingerprint waiting for its first scan, a
filter's first step) is charged for every waypoint instead of skipping the early ones; the hold is applied
here, at scoring only: the estimates themselves (and fixes made from them) never contain the held values.

Across runs: mean, standard deviation, standard error and a 99 % confidence interval of the mean
(:func:`summary`: Student t with n - 1 degrees of freedom, mean +- t(0.995, n - 1) stderr, the lower bound clipped at
zero since the quantities summarised are errors; with n = 2 runs t is 63.66, not the normal 2.576), and pooled error
percentiles.
"""

from __future__ import annotations

import numpy as np
from scipy import stats

#: the confidence level of ``ci99`` in :func:`summary`
CI_LEVEL = 0.99


def errors_vs_groundtruth(t: np.ndarray, pos: np.ndarray, gt_t: np.ndarray, gt_xy: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Errors (R, K') at the K' estimate times inside the ground truth span, and those times (K',)."""
    inside = (t >= gt_t[0]) & (t <= gt_t[-1])
    tt = t[inside]
    ref = np.stack([np.interp(tt, gt_t, gt_xy[:, 0]), np.interp(tt, gt_t, gt_xy[:, 1])], axis=-1)
    return np.linalg.norm(pos[:, inside] - ref[None], axis=-1), tt


def summary(values: np.ndarray, lower: float | None = 0.0) -> dict:
    """Mean, standard deviation (ddof 1), standard error and the 99 % confidence interval of the mean of ``values``
    (one per run, e.g. the per-run RMSEs), with their number ``n``.

    ``ci99``: ``mean -+ t * stderr`` with ``t = scipy.stats.t.ppf(0.995, n - 1)`` (Student t: a handful of runs gives a
    wide interval, not the normal approximation's), the lower bound clipped at ``lower``: summary() is for
    non-negative quantities (errors, RMSEs; the default ``lower=0.0``), ``lower=None`` for signed ones. With
    ``n < 2`` no interval can be estimated: ``ci99`` is ``[mean, mean]`` and ``std`` and ``stderr`` are 0, kept as
    two floats so that results.json stays plain JSON; ``n`` says so, and results.md prints ``- (n=1)`` instead of an
    interval (:mod:`blenav.eval.report`). With ``n == 0`` the mean and ``ci99`` are NaN."""
    v = np.asarray(values, float).ravel()
    n = v.size
    mean = float(v.mean()) if n else float("nan")
    if n < 2:
        return {"mean": mean, "std": 0.0, "stderr": 0.0, "ci99": [mean, mean], "n": int(n)}
    std = float(v.std(ddof=1))
    se = std / float(np.sqrt(n))
    half = float(stats.t.ppf(0.5 + CI_LEVEL / 2, n - 1)) * se
    lo = mean - half if lower is None else max(mean - half, float(lower))
    return {"mean": mean, "std": std, "stderr": se, "ci99": [lo, mean + half], "n": int(n)}


def error_stats(err: np.ndarray) -> dict:
    e = np.asarray(err, float).ravel()
    if e.size == 0:
        return {k: float("nan") for k in ("mean", "median", "p75", "p90", "max")}
    return {"mean": float(e.mean()), "median": float(np.median(e)), "p75": float(np.percentile(e, 75)),
            "p90": float(np.percentile(e, 90)), "max": float(e.max())}


def session_metrics(t: np.ndarray, pos: np.ndarray, gt_t: np.ndarray, gt_xy: np.ndarray, init_s: float) -> dict:
    """Metrics of R runs on one session; includes the raw per-run arrays under '_runs' for pooling."""
    err, tt = errors_vs_groundtruth(t, pos, gt_t, gt_xy)
    if err.shape[1] == 0:
        raise ValueError("no estimate falls inside the ground truth's time span")
    track = tt >= tt[0] + init_s
    if not track.any():  # a session shorter than the init period: score everything, say so
        track = np.ones_like(tt, bool)
    return _scored(err, tt, track)


def _scored(err: np.ndarray, tt: np.ndarray, track: np.ndarray) -> dict:
    """The metrics of errors ``err`` (R, K') at times ``tt`` (K',), the ``track`` (K',) ones scored as tracking,
    the others as initialisation."""
    rmse = np.sqrt(np.mean(err[:, track] ** 2, axis=1))
    ee = err[:, np.flatnonzero(track)[-1]]
    init = err[:, ~track]
    return {
        "rmse_m": summary(rmse), "error_m": error_stats(err[:, track]), "ate_m": float(rmse.mean()),
        "ee_m": float(ee.mean()), "init_error_m": error_stats(init) if init.size else None,
        "_runs": {"rmse": rmse, "ee": ee, "err": err[:, track], "t": tt, "err_all": err},
    }


def positions_at(t: np.ndarray, pos: np.ndarray, tw: np.ndarray) -> np.ndarray:
    """(R, W, 2): the estimate (R, K, 2) at times ``t`` (K,) linearly interpolated at ``tw`` (W,), held before t[0] and
    after t[-1]."""
    ix = np.clip(np.searchsorted(t, tw, side="right") - 1, 0, max(len(t) - 2, 0))
    if len(t) > 1:
        w = np.clip((tw - t[ix]) / np.maximum(t[ix + 1] - t[ix], 1e-12), 0.0, 1.0)  # clipped: ends held
        return pos[:, ix] * (1.0 - w)[None, :, None] + pos[:, ix + 1] * w[None, :, None]
    return pos[:, ix]


def errors_at_waypoints(t: np.ndarray, pos: np.ndarray, gt_t: np.ndarray, gt_xy: np.ndarray,
                        hold_ends: bool = False) -> tuple[np.ndarray, np.ndarray]:
    """Errors (R, W') of the estimate (R, K, 2), linearly interpolated at the W' waypoint times inside its
    span [t[0], t[-1]], against the waypoints (W, 2); and those times (W',). ``hold_ends``: every waypoint
    (W' = W), those before t[0] / after t[-1] against the first / last estimate."""
    inside = np.ones(len(gt_t), bool) if hold_ends and len(t) else (gt_t >= t[0]) & (gt_t <= t[-1])
    tw = gt_t[inside]
    return np.linalg.norm(positions_at(t, pos, tw) - gt_xy[inside][None], axis=-1), tw


def segment_errors(t: np.ndarray, pos: np.ndarray, gt_t: np.ndarray, gt_xy: np.ndarray) -> dict[str, np.ndarray]:
    """The estimate's displacement over each segment between consecutive waypoints that lies inside its span, against
    the surveyed one (the 2021 indoor challenge's measure of a step / odometry model; issue 31's ``segment_error_m``):
    ``err`` (R, S) m = |(p(b) - p(a)) - (g(b) - g(a))|, ``length`` (R, S) m = |p(b) - p(a)| - |g(b) - g(a)| (how much
    the odometry over- or under-shoots), ``angle`` (R, S) deg between the two displacements (how far its heading is
    off), ``true`` (S,) m = |g(b) - g(a)|. S = 0 when no segment lies inside."""
    a, b = gt_t[:-1], gt_t[1:]
    ok = (a >= t[0]) & (b <= t[-1]) & (b > a) if len(t) else np.zeros(len(a), bool)
    d = (gt_xy[1:] - gt_xy[:-1])[ok]
    e = positions_at(t, pos, b[ok]) - positions_at(t, pos, a[ok]) if ok.any() else np.zeros((pos.shape[0], 0, 2))
    true = np.linalg.norm(d, axis=-1)
    ang = np.arctan2(e[..., 1], e[..., 0]) - np.arctan2(d[:, 1], d[:, 0])[None]
    return {"err": np.linalg.norm(e - d[None], axis=-1), "length": np.linalg.norm(e, axis=-1) - true[None],
            "angle": np.degrees(np.angle(np.exp(1j * ang))), "true": true}


#: segments shorter than this (m) are left out of the heading statistic: their angle is mostly noise
MIN_SEGMENT_FOR_ANGLE_M = 2.0


def pool_segment_errors(segs: list[dict]) -> dict | None:
    """``{mean, median, segments, length_abs_mean, length_mean, heading_abs_median_deg}`` (m, deg) of the segment
    errors (:func:`segment_errors`) of every session and run: the displacement error, the mean absolute and signed
    length error, and the median absolute angle of the segments of at least :data:`MIN_SEGMENT_FOR_ANGLE_M`; None
    without any segment."""
    segs = [x for x in segs if x["err"].size]
    if not segs:
        return None
    e = np.concatenate([x["err"].ravel() for x in segs])
    ln = np.concatenate([x["length"].ravel() for x in segs])
    ang = np.concatenate([x["angle"][:, x["true"] >= MIN_SEGMENT_FOR_ANGLE_M].ravel() for x in segs])
    return {"mean": float(e.mean()), "median": float(np.median(e)), "segments": int(sum(x["err"].shape[-1] for x in segs)),
            "length_abs_mean": float(np.abs(ln).mean()), "length_mean": float(ln.mean()),
            "heading_abs_median_deg": float(np.median(np.abs(ang))) if len(ang) else None}


def waypoint_metrics(t: np.ndarray, pos: np.ndarray, gt_t: np.ndarray, gt_xy: np.ndarray,
                     hold_ends: bool = False) -> dict:
    """:func:`session_metrics` for sparse ground truth: every waypoint inside the estimate's span is scored
    (a walk starts at its first waypoint: there is no separate initialisation period); ``hold_ends``: every
    waypoint, those outside the span against the first / last estimate (module doc)."""
    err, tw = errors_at_waypoints(t, pos, gt_t, gt_xy, hold_ends)
    if err.shape[1] == 0:
        raise ValueError("no waypoint falls inside the estimate's time span")
    return {**_scored(err, tw, np.ones(len(tw), bool)), "waypoints": int(err.shape[1])}


def fix_coverage_counts(t: np.ndarray, xy: np.ndarray, std: np.ndarray, gt_t: np.ndarray, gt_xy: np.ndarray
                        ) -> tuple[int, int, int] | None:
    """(inside 1 sigma, inside 2 sigma, waypoints) of fixes (t (F,) s sorted, xy (F, 2) m, std (F,) m: isotropic 2-D)
    at the ground truth's times (gt_t (W,), gt_xy (W, 2): surveyed waypoints, or every row of a dense ground truth): the
    fix and its std interpolated at each time (ends held, as ``hold_ends`` scores); a waypoint is inside k sigma when its error <= k std (a 2-D Gaussian holds 39.3 % / 86.5 %
    there). None when no fix has a finite std."""
    ok = np.isfinite(std) & np.isfinite(xy).all(axis=1)
    if not ok.any() or not len(gt_t):
        return None
    err, _ = errors_at_waypoints(t[ok], xy[ok][None], gt_t, gt_xy, hold_ends=True)
    sd = np.interp(gt_t, t[ok], std[ok])
    e = err[0]
    return int((e <= sd).sum()), int((e <= 2.0 * sd).sum()), int(len(e))


#: error (m) below which a track counts as converged (:func:`convergence_times`)
CONVERGED_M = 5.0


def convergence_times(err: np.ndarray, tw: np.ndarray, within_m: float = CONVERGED_M) -> np.ndarray:
    """(R,) s per run: the time from the first scored waypoint to the first waypoint from which every later error is
    within ``within_m``; NaN for a run that never settles (its last error above it). err (R, W) m at times tw (W,)."""
    ok = err <= within_m
    # index of the first waypoint of the final run of True values: after the last False
    last_bad = np.where(~ok, np.arange(err.shape[1])[None, :], -1).max(axis=1)
    out = np.full(err.shape[0], np.nan)
    settled = last_bad < err.shape[1] - 1
    out[settled] = tw[last_bad[settled] + 1] - tw[0]
    return out


def pool_convergence(per_session: list[np.ndarray], within_m: float = CONVERGED_M) -> dict | None:
    """Over (session x run) values of :func:`convergence_times`: median / p90 seconds of those that settle and the share
    that settle."""
    v = np.concatenate(per_session) if per_session else np.zeros(0)
    if not v.size:
        return None
    s = v[np.isfinite(v)]
    return {"within_m": within_m, "settled": float(s.size / v.size),
            "median_s": float(np.median(s)) if s.size else None, "p90_s": float(np.percentile(s, 90)) if s.size else None}


def pool_fix_coverage(per_session: list[dict]) -> dict | None:
    """Per role, the shares of waypoints inside the fixes' 1-sigma / 2-sigma regions pooled over sessions
    (``{role: (n1, n2, n)}`` each, from :func:`fix_coverage_counts`): ``{role: {"1sigma", "2sigma", "waypoints"}}``."""
    tot: dict[str, np.ndarray] = {}
    for d in per_session:
        for role, c in d.items():
            tot[role] = tot.get(role, np.zeros(3, np.int64)) + np.asarray(c, np.int64)
    return {r: {"1sigma": float(c[0] / c[2]), "2sigma": float(c[1] / c[2]), "waypoints": int(c[2])}
            for r, c in sorted(tot.items()) if c[2] > 0} or None


#: thresholds (m) of the share of walks whose mean error is within them (``walks_within_m`` in results)
WALK_THRESHOLDS_M = (2.0, 5.0)


def best_against_bound(ran: dict[str, float], bound_rmse: float) -> dict:
    """The best of ``ran`` (method -> RMSE mean, m; not empty) against a bound's RMSE: {method, rmse_m, ratio}."""
    best = min(ran, key=ran.get)
    return {"method": best, "rmse_m": ran[best], "ratio": ran[best] / max(bound_rmse, 1e-12)}


def finite_number(v) -> float | None:
    """``v`` as a float when it is a finite int or float of a JSON file (a stranger's may hold anything), else None."""
    return float(v) if isinstance(v, (int, float)) and not isinstance(v, bool) and np.isfinite(v) else None


def rmse_mean(m) -> float | None:
    """A results.json row's RMSE mean when it is a finite number (a stranger's file may hold anything), else None."""
    r = m.get("rmse_m") if isinstance(m, dict) else None
    return finite_number(r.get("mean") if isinstance(r, dict) else None)


def public(value):
    """A metric as results.json shows it: a dict without its private (``_``) keys (e.g. beacon_error_m's per-beacon
    rows); anything else as it is."""
    return {k: v for k, v in value.items() if not str(k).startswith("_")} if isinstance(value, dict) else value


def pool(per_session: dict[str, dict]) -> dict:
    """Aggregate session metrics: RMSE stats over all (session, run) pairs, pooled error percentiles."""
    rmse = np.concatenate([m["_runs"]["rmse"] for m in per_session.values()])
    ee = np.concatenate([m["_runs"]["ee"] for m in per_session.values()])
    err = np.concatenate([m["_runs"]["err"].ravel() for m in per_session.values()])
    inits = [m["_runs"]["err_all"][:, : m["_runs"]["err_all"].shape[1] - m["_runs"]["err"].shape[1]].ravel()
             for m in per_session.values()]
    init = np.concatenate(inits) if inits else np.zeros(0)
    walk_mean = np.concatenate([m["_runs"]["err"].mean(axis=1) for m in per_session.values()])  # (session x run,)
    within = {f"{d:g}": float(np.mean(walk_mean <= d)) for d in WALK_THRESHOLDS_M}
    return {"rmse_m": summary(rmse), "error_m": error_stats(err), "ate_m": float(rmse.mean()), "ee_m": float(ee.mean()),
            "init_error_m": error_stats(init) if init.size else None, "walks_within_m": within}


def cdf_band(err_runs: list[np.ndarray], grid: np.ndarray, q=(0.05, 0.5, 0.95)) -> np.ndarray:
    """Per-run empirical CDFs on ``grid`` and their quantiles across runs: (len(q), len(grid))."""
    cdfs = np.stack([np.searchsorted(np.sort(e), grid, side="right") / max(e.size, 1) for e in err_runs])
    return np.quantile(cdfs, q, axis=0)
