"""The channel the ranges came through, refitted between the back-end's LM passes (issue 32: "the per-receiver offset
and the path-loss exponent").

A range is r = d0 10^((a_x - rssi) / (10 gamma)) (000 sec. IV-B, the model's a_x and gamma). If the channel's own
level and exponent are A and gamma_c (rssi = A - 10 gamma_c log10(d / d0) + shadowing; A - a_x the receiver's offset
against the model), then

    log10(r / d0) = a + b log10(d / d0) + e,   b = gamma_c / gamma,   a = (a_x - A) / (10 gamma),

e the shadowing in decades: the offset and the exponent are a straight line between the logs of the range and of
the distance. :func:`fit_log_ranges` fits it to the ranges a solution used against that solution's distances
||p_k - l_j|| (the noisy log range as the response, so that the shadowing does not flatten the slope; the 10 m
clamp as a truncation of the likelihood), and :func:`apply_log_fit` turns every range into the distance the refitted
channel reads from it; :func:`channel_of` gives gamma_c and the offset. ``slope=False`` fits the level alone (b = 1:
the receiver offset). numpy and scipy.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .config import ChannelRefit
from .graph_types import RangeObs

__all__ = ["LogRangeFit", "fit_log_ranges", "apply_log_fit", "measured_ranges", "channel_of", "refit_ranges"]


@dataclass(frozen=True)
class LogRangeFit:
    """log10(r / d0) = a + b log10(d / d0) fitted on ``n`` (range, distance) pairs, ``d0`` m."""

    a: float
    b: float
    d0: float
    n: int


def _truncated_nll(p: np.ndarray, X: np.ndarray, y: np.ndarray, c: np.ndarray | None) -> float:
    """Negative log-likelihood of y = X p[:-1] + N(0, exp(p[-1])^2), each y observed only below c (None: all)."""
    from scipy.special import log_ndtr

    s = np.exp(p[-1])
    mu = X @ p[:-1]
    z = (y - mu) / s
    nll = 0.5 * z @ z + len(y) * p[-1]
    if c is not None:  # truncated from above: each density divided by P(y <= c)
        nll += np.sum(log_ndtr((c - mu) / s))
    return float(nll)


def fit_log_ranges(r: np.ndarray, d: np.ndarray, d0: float, slope: bool = False, max_r: float | None = None,
                   min_d: float = 0.3, b_bounds: tuple[float, float] = (0.5, 2.0)) -> LogRangeFit | None:
    """The line log10(r / d0) = a + b log10(d / d0) + e, e ~ N(0, s^2), by maximum likelihood: r (M,) measured ranges
    m, d (M,) a solution's distances m (floored at ``min_d``). ``slope``: a and b (b within ``b_bounds``); else the
    level a alone (b = 1). ``max_r``: the clamp the ranges went through (longer ones discarded, so a far beacon is
    heard only when it came out short): the likelihood is the truncated normal's (truncated regression, Hausman &
    Wise 1977), without which the slope comes out flat. None with fewer than 10 usable pairs (or no spread of d
    for the slope)."""
    from scipy.optimize import minimize

    r, d = np.asarray(r, float), np.asarray(d, float)
    ok = np.isfinite(r) & np.isfinite(d) & (r > 0)
    if np.count_nonzero(ok) < 10:
        return None
    x = np.log10(np.maximum(d[ok], min_d) / d0)
    y = np.log10(r[ok] / d0)
    if slope and np.ptp(x) <= 1e-6:
        return None
    X = np.column_stack([np.ones_like(x), x]) if slope else np.ones((len(x), 1))
    yy = y if slope else y - x  # b = 1: the level of y - x
    c = None if max_r is None else np.log10(float(max_r) / d0) - (0.0 if slope else x)
    coef, *_ = np.linalg.lstsq(X, yy, rcond=None)
    s0 = max(float(np.std(yy - X @ coef)), 1e-3)
    bounds = [(None, None), b_bounds, (np.log(1e-3), np.log(10.0))] if slope else [(None, None), (np.log(1e-3), np.log(10.0))]
    p0 = np.r_[coef, np.log(s0)]
    if slope:
        p0[1] = np.clip(p0[1], *b_bounds)
    res = minimize(_truncated_nll, p0, args=(X, yy, c), method="L-BFGS-B", bounds=bounds)
    p = res.x if np.isfinite(res.x).all() else p0
    return LogRangeFit(float(p[0]), float(p[1]) if slope else 1.0, float(d0), int(np.count_nonzero(ok)))


def apply_log_fit(r: np.ndarray, fit: LogRangeFit) -> np.ndarray:
    """The distance (m) the refitted channel reads from each measured range r (m): d0 10^((log10(r / d0) - a) / b)."""
    r = np.asarray(r, float)
    return fit.d0 * 10.0 ** ((np.log10(np.maximum(r, 1e-6) / fit.d0) - fit.a) / fit.b)


def measured_ranges(r: np.ndarray, fit: LogRangeFit) -> np.ndarray:
    """The inverse of :func:`apply_log_fit`: the measured ranges (m) that ``fit`` turned into r (m)."""
    r = np.asarray(r, float)
    return fit.d0 * 10.0 ** (fit.a + fit.b * np.log10(np.maximum(r, 1e-6) / fit.d0))


def channel_of(fit: LogRangeFit, gamma: float) -> tuple[float, float]:
    """(gamma_c, offset dB = A - a_x) of the channel ``fit`` implies for ranges made with exponent ``gamma``."""
    return float(gamma) * fit.b, -10.0 * float(gamma) * fit.a


def refit_ranges(cfg, used: tuple[np.ndarray, np.ndarray, np.ndarray], position: np.ndarray, beacon_xyz: np.ndarray,
                 ranges0: RangeObs, done: LogRangeFit | None) -> tuple[RangeObs, LogRangeFit | None, str]:
    """A back-end pass's channel refit (``cfg``: :class:`~blenav.backend.config.BackendConfig`, its
    ``range.refit_channel``): the line fitted to the ranges a pass used, ``used`` = (keyframe (M,), beacon (M,), range
    (M,) m, as the pass saw them: turned by ``done``, the previous pass's fit, or as measured), taken back to their
    measured values (the transform is monotone, so a keyframe's median maps to the median), against the distances
    from ``position`` (K, 3) to ``beacon_xyz`` (A, 3) (m); the session's measured ranges ``ranges0`` through it. Every
    pass fits the measured ranges afresh, so the slope's bounds hold for the result. Returns (ranges, the fit, a note);
    the ranges of ``done`` (and a note) when no fit is possible."""
    k, j, r = used
    r = np.asarray(r, float) if done is None else measured_ranges(r, done)
    d = np.linalg.norm(position[k] - beacon_xyz[j], axis=-1)
    rc = cfg.range
    fit = fit_log_ranges(r, d, rc.d0, slope=ChannelRefit(rc.refit_channel) == ChannelRefit.line, max_r=rc.max_range_m)
    if fit is None:
        keep = ranges0 if done is None else RangeObs(ranges0.t, ranges0.anchor, apply_log_fit(ranges0.range_m, done),
                                                     ranges0.gamma)
        return keep, done, f"channel not refitted: {len(r)} range(s) in the graph"
    gamma = ranges0.gamma if ranges0.gamma is not None else rc.gamma
    gc, off = channel_of(fit, gamma)
    out = RangeObs(ranges0.t, ranges0.anchor, apply_log_fit(ranges0.range_m, fit), ranges0.gamma)
    return out, fit, (f"channel refitted on {fit.n} ranges: exponent {gc:.2f} (ranges made with {gamma:.2f}), "
                      f"level {off:+.1f} dB against the model's")
