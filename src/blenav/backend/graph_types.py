"""The inputs and the result of the radio-inertial factor graph (:mod:`blenav.backend.graph`): keyframes, IMU
samples, ranges and beacon priors in; the smoothed trajectory, beacon map and failures out, with GTSAM's key
names in its failure messages read back into words (:func:`describe_key`). Plain numpy / pandas; no GTSAM.
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field

import numpy as np
import pandas as pd

__all__ = ["Keyframes", "ImuSamples", "OdometryTrack", "RangeObs", "BeaconPriors", "BackendFailure", "BackendResult",
           "describe_key", "symbol_in", "first_line"]


# ------------------------------------------------------------------------------------------------ inputs
@dataclass
class Keyframes:
    """Keyframe times and initial values. t (K,) s increasing; position (K, 3) world m; velocity (K, 3) world
    m/s; q (K, 4) w-first device -> world (ENU) quaternions (the AHRS at t); bias (K, 6) accelerometer m/s^2,
    gyroscope rad/s (default 0; the prior on B(0) is centred on bias[0]: 0 unless a caller carries an earlier
    estimate over, as the closed loop's windows do); cov (K, 2, 2) world m^2: the front-end's own x, y covariance
    (``priors.front_end_cloud``), or None."""

    t: np.ndarray
    position: np.ndarray
    velocity: np.ndarray
    q: np.ndarray
    bias: np.ndarray | None = None
    cov: np.ndarray | None = None  #: (K, 2, 2) world m^2: the front-end's x, y covariance at each keyframe, or None

    def __post_init__(self):
        self.t = np.asarray(self.t, float)
        K = len(self.t)
        if self.cov is not None:
            self.cov = np.asarray(self.cov, float).reshape(K, 2, 2)
        self.position = np.asarray(self.position, float).reshape(K, 3)
        self.velocity = np.asarray(self.velocity, float).reshape(K, 3)
        self.q = np.asarray(self.q, float).reshape(K, 4)
        self.bias = np.zeros((K, 6)) if self.bias is None else np.asarray(self.bias, float).reshape(K, 6)
        if K and np.any(np.diff(self.t) <= 0):
            raise ValueError("keyframe times must increase strictly")


@dataclass
class ImuSamples:
    """t (T,) s non-decreasing; acc (T, 3) m/s^2 specific force incl. gravity; gyr (T, 3) rad/s; device frame."""

    t: np.ndarray
    acc: np.ndarray
    gyr: np.ndarray


@dataclass
class OdometryTrack:
    """A learned inertial odometry's track (:func:`blenav.filters.inertial_odometry.lio_odometry`): t (T,) s
    increasing; xy (T, 2) world m from its start (its frame: the attitude's, as the keyframes' q); var (T,) m^2 per
    axis, accumulated from the start (the increment between two times is the variance of that displacement). Its
    attitude is the one the model was trained in (the phone's rotation vector or blenav's AHRS with default settings);
    the keyframes' is the front-end's AHRS: both magnetic-north ENU, so a front-end with tuned AHRS settings turns one
    against the other by their heading difference."""

    t: np.ndarray
    xy: np.ndarray
    var: np.ndarray

    def __post_init__(self):
        self.t = np.asarray(self.t, float)
        self.xy = np.asarray(self.xy, float).reshape(len(self.t), 2)
        self.var = np.asarray(self.var, float).reshape(len(self.t))
        if len(self.t) < 2 or np.any(np.diff(self.t) <= 0):
            raise ValueError("an odometry track needs at least 2 points at increasing times")
        if not (np.isfinite(self.xy).all() and np.isfinite(self.var).all()):
            raise ValueError("non-finite odometry track")


@dataclass
class RangeObs:
    """Ranges already converted from RSSI and clamped: t (M,) s, anchor (M,) row in :class:`BeaconPriors`,
    range_m (M,) m; ``gamma``: the path-loss exponent of the conversion (needed only to estimate the receiver
    offset, ``range.estimate_offset``)."""

    t: np.ndarray
    anchor: np.ndarray
    range_m: np.ndarray
    gamma: float | None = None


@dataclass
class BeaconPriors:
    """ids (A,) str; xyz (A, 3) world m (prior mean); sigma (A, 3) m per axis (prior std)."""

    ids: np.ndarray
    xyz: np.ndarray
    sigma: np.ndarray


@dataclass
class BackendFailure:
    """What went wrong: ``stage`` ('isam2-update', 'lm', 'marginals', 'input'), the key GTSAM named (as
    :func:`describe_key` reads it, or None), the keyframe time when known, and GTSAM's message (first line)."""

    stage: str
    key: str | None
    t: float | None
    message: str

    def __str__(self) -> str:
        where = f" near {self.key}" if self.key else ""
        when = f" (t={self.t:.2f} s)" if self.t is not None else ""
        return f"{self.stage}{where}{when}: {self.message}"


@dataclass
class BackendResult:
    """The smoothed trajectory, beacon map and biases of one session.

    t (K,) s; position (K, 3) world m; velocity (K, 3) m/s; q (K, 4) w-first device -> world; bias (K, 6)
    (accelerometer m/s^2, gyroscope rad/s); online_position (K, 3): iSAM2's estimate of keyframe k right after
    its update (the filtered, causal estimate; equals ``position`` for LM; with ``solver.update_every`` N > 1 the
    keyframes between updates keep their front-end values here); beacon_map: DataFrame anchor_id,
    x, y, z, std_m (horizontal, sqrt of trace / 2 of the marginal covariance; the prior's for beacons left at it),
    n_ranges (range factors), n_heard (ranges within the clamp, before the gate), status ('optimized', 'prior:
    why', 'not heard'); update_s (K,) s per iSAM2 update, at the keyframe that triggered it (NaN elsewhere and for LM);
    failures and notes for the report; wall_s: build + solve time."""

    t: np.ndarray
    position: np.ndarray
    velocity: np.ndarray
    q: np.ndarray
    bias: np.ndarray
    online_position: np.ndarray
    beacon_map: pd.DataFrame
    update_s: np.ndarray
    failures: list[BackendFailure] = field(default_factory=list)
    notes: list[str] = field(default_factory=list)
    wall_s: float = 0.0
    solve_s: float = 0.0
    n_factors: int = 0
    offset_db: float = float("nan")  # the receiver's RSSI offset (range.estimate_offset), dB
    offset_std_db: float = float("nan")
    channel_exponent: float = float("nan")  # range.refit_channel: the channel's path-loss exponent refitted; with
    #   range.estimate_exponent the variable's (b times the ranges' gamma)
    channel_exponent_std: float = float("nan")  # range.estimate_exponent: its marginal std
    channel_offset_db: float = float("nan")  # ... and its level against the range model's a_x, dB

    @property
    def ok(self) -> bool:
        return not self.failures


# ------------------------------------------------------------------------------------------------ failures
def describe_key(symbol: str | None, kf_t: np.ndarray | None = None, beacon_ids=None) -> str | None:
    """'l3' -> 'beacon ble-003 (l3)', 'x17' -> 'keyframe 17 at t=1.80 s (x17)' (names when known)."""
    if not symbol:
        return None
    ch, idx = symbol[0], int(symbol[1:])
    if ch == "l" and beacon_ids is not None and idx < len(beacon_ids):
        return f"beacon {beacon_ids[idx]} ({symbol})"
    what = {"x": "pose", "v": "velocity", "b": "bias"}.get(ch)
    if what and kf_t is not None and idx < len(kf_t):
        return f"{what} of keyframe {idx} at t={kf_t[idx]:.2f} s ({symbol})"
    return symbol


_KEY_RE = re.compile(r"Symbol:\s*([A-Za-z])(\d+)")


def symbol_in(message: str) -> str | None:
    """The key GTSAM's exception ``message`` names ('Symbol: l3' -> 'l3', read by :func:`describe_key`), or None."""
    m = _KEY_RE.search(message)
    return f"{m.group(1)}{m.group(2)}" if m else None


def first_line(exc: BaseException) -> str:
    """The first two non-empty lines of a GTSAM exception's message, joined (its type's name when empty)."""
    lines = [s.strip() for s in str(exc).splitlines() if s.strip()]
    return " ".join(lines[:2]) if lines else type(exc).__name__
