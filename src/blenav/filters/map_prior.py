"""The learned map prior of Roy (section 3.2, eq. 3.8) as a particle-filter measurement model.

Roy's Map Prior Network scores how likely it is that the last n seconds of odometry ``O`` end at a
map location x: S(x | M, O) = f(M)_x . g(O) (eq. 3.8), with f(M) the "Deep Map Tensor" (c channels per
map pixel, computed once per floor) and g(O) the "Deep Trajectory Vector" (the last hidden state of an
LSTM over the odometry window, c values). The score weighs the particles together with the BLE fixes
(eq. 3.9); weights stay in log space, so this model adds ``weight * log S`` to each particle's log-weight.

**Prior protocol.** :class:`MapPriorLikelihood` wraps any object with

* ``bind(floor) -> None``: compute (or load from a cache) the Deep Map Tensor of a
  :class:`~blenav.data.Floor`;
* ``window_steps -> int``: n, the odometry samples per window (at 1 Hz; Roy: n = 5 s of walking); a prior
  without it may give ``n_points`` instead, and ``step_hz`` (the window's sample rate) when it is not 1 Hz;
* ``dtv(odo) -> (K, c)``: Deep Trajectory Vectors of K odometry windows ``odo`` (K, n, 2) in metres,
  world-aligned axes, relative to the window's first sample (so ``odo[:, 0] == 0``);
* ``log_score_at(xy, dtv) -> (...)``: log of the eq. 3.8 score at world points ``xy`` (..., 2) m for one
  trajectory vector ``dtv`` (c,): a gather of the map tensor at those points and a dot product, never
  a full-map product.

The learned implementation is ``blenav.runtime.map_prior.MapPrior(path)`` (attached by :func:`attach_prior` with
the loader its caller hands in, :func:`blenav.localizers.particle.load_prior`: the filters import nothing of the
runtime above them; it caches the Deep Map Tensor per floor in memory and on disk, so ``bind`` is called
for every session without re-running the U-Net); :class:`FeasibilityPrior` is a non-learned reference
implementation (the training target of the network, computed on the occupancy grid) used by tests and as
a stand-in.

**Odometry frame.** ``odometry.csv`` is in an arbitrary frame fixed at the session's start, so the
window must be rotated into the world before the prior can compare it with the map. Each particle of
:class:`~blenav.filters.motion.OdometryIncrement` carries its own frame angle theta (state column
``frame_angle_col`` = 4). Running the LSTM once per particle would cost N LSTM passes per step; instead
the circle is cut into K ``heading_bins`` (default 36, 10 degrees) with centres theta_k = 2 pi k / K, the
window is rotated by every theta_k (K windows), ``prior.dtv`` runs once on the K windows per step, and a
particle is scored with the vector of the bin nearest its theta (``round(theta K / 2 pi) mod K``). The
quantisation error is at most pi / K (5 degrees: 0.44 m lateral at the end of a 5 m window). Motion models
without a frame angle (the odometry is then taken as world-aligned) use ``theta`` (default 0) for all.

**Window.** The model keeps its own ring buffer of odometry positions, sampled at the filter's steps
from the ``odo_xy`` observation (the odometry position at the step's time, see
:mod:`blenav.filters.steps`). The window holds the positions at t - (n-1) dt, ..., t - dt, t with
dt = ``window_dt_s`` (default: 1 / the prior's ``step_hz``, else 1 s): the last buffered sample at or
before each of these times. Until the buffer
reaches back (n - 1) dt seconds (the first n - 1 steps at 1 Hz) the model contributes nothing:
``n_obs`` is 0 and the weights come from the other models alone. The buffer is cleared by ``bind``
(every new session/filter).

Scores are clipped below at ``min_log_score`` (log 1e-6, the floor of the network's training target
T = 1e-6 e^(14 T_bar)), and NaN (e.g. the log of a non-positive dot product) counts as that floor: below
the target's floor the network's output is regression noise (1e-9 vs 1e-4 would otherwise be an 11-nat
weight ratio), so every location the network calls infeasible -- including obstacles and off-map points,
which the runtime scores log 1e-12 -- counts the same. The model is not part of the engine's divergence
test (``divergence_check = False``): a prior score is not a measurement residual.
"""

from __future__ import annotations

import logging
from collections import deque
from dataclasses import dataclass, field
from typing import Any, Callable, Optional

import numpy as np

from .measurement import MeasurementModel

log = logging.getLogger("blenav.filters.map_prior")

LOG_1E6 = float(np.log(1e-6))


def heading_bins(theta: np.ndarray, k: int) -> np.ndarray:
    """Bin index (same shape, int) of frame angles ``theta`` (rad, any range): the nearest of the K centres
    2 pi j / K."""
    return np.rint(np.asarray(theta, dtype=float) * (k / (2.0 * np.pi))).astype(np.int64) % k


def rotated_windows(window: np.ndarray, k: int) -> np.ndarray:
    """(K, n, 2): the odometry window (n, 2) rotated by each bin centre 2 pi j / K (j = 0..K-1), CCW."""
    ang = 2.0 * np.pi * np.arange(k) / k
    c, s = np.cos(ang)[:, None], np.sin(ang)[:, None]
    x, y = window[None, :, 0], window[None, :, 1]
    return np.stack([c * x - s * y, s * x + c * y], axis=-1)


@dataclass
class MapPriorLikelihood(MeasurementModel):
    """Roy's map prior score as a measurement: log-weight += weight * log S(x | M, O) (eq. 3.8, Roy).

    ``prior``: an object of the protocol above (None: the method cannot run; :func:`attach_prior` sets it
    from ``model_path=``). ``heading_bins``: K. ``window_dt_s``: spacing of the window's samples (s; None: 1 /
    the prior's ``step_hz``, or 1 s).
    ``weight``: exponent on the score (1: the score is the likelihood, as in Roy). ``min_log_score``: the
    floor of log S. ``theta``: frame angle (rad) for motion models without one.
    """

    prior: Any = None
    heading_bins: int = 36
    window_dt_s: Optional[float] = None
    weight: float = 1.0
    min_log_score: float = LOG_1E6
    theta: float = 0.0

    needs = ("odo",)
    wants_state = True
    divergence_check = False

    frame_angle_col: Optional[int] = field(default=None, init=False, repr=False)
    unavailable: Optional[str] = field(default=None, init=False, repr=False)
    _buf: deque = field(default_factory=deque, init=False, repr=False)
    _window: Optional[np.ndarray] = field(default=None, init=False, repr=False)

    def __post_init__(self):
        if int(self.heading_bins) < 1:
            raise ValueError(f"heading_bins must be >= 1, got {self.heading_bins}")
        if self.window_dt_s is not None and not self.window_dt_s > 0:
            raise ValueError(f"window_dt_s must be > 0 s or null, got {self.window_dt_s}")
        self.heading_bins = int(self.heading_bins)

    # ------------------------------------------------------------------ binding
    def missing_reason(self) -> str | None:
        """Why the model cannot run (no prior), or None; the runner turns it into a skipped method."""
        if self.prior is not None:
            return None
        return self.unavailable or ("no learned map prior was given: pass model_path=DIR (a trained map prior network, "
                                    "loaded by blenav.runtime.map_prior.MapPrior)")

    def bind(self, anchors) -> None:
        """New filter (session): clear the odometry window. The anchors are not used."""
        self._buf.clear()
        self._window = None

    def bind_floor(self, floor) -> None:
        """Let the prior make ``floor`` current (its Deep Map Tensor; the prior caches it per floor). Called for
        every filter: one prior object may be shared by several methods, so its current floor is not ours
        to assume."""
        if self.prior is not None:
            self.prior.bind(floor)

    def bind_motion(self, motion) -> None:
        """Read the particles' odometry frame angle from the motion model's state column, if it has one."""
        self.frame_angle_col = motion.frame_angle_col

    @property
    def n(self) -> int:
        """Samples per window: the prior's ``window_steps`` (or ``n_points``)."""
        n = getattr(self.prior, "window_steps", None)
        return int(n if n is not None else self.prior.n_points)

    @property
    def dt(self) -> float:
        """Seconds between the window's samples."""
        if self.window_dt_s is not None:
            return float(self.window_dt_s)
        hz = getattr(self.prior, "step_hz", None)
        return 1.0 / float(hz) if hz else 1.0

    # ------------------------------------------------------------------ the odometry window
    def observe(self, obs: dict) -> None:
        """Append the step's odometry position (``obs['odo_xy']``, at ``obs['t']``) and rebuild the window."""
        self._window = None
        if self.prior is None or "odo_xy" not in obs:
            return
        t = float(obs.get("t", np.nan))
        dt = self.dt
        if not np.isfinite(t):  # no step time: count steps as dt apart
            t = self._buf[-1][0] + dt if self._buf else 0.0
        self._buf.append((t, np.asarray(obs["odo_xy"], dtype=float).reshape(2)))
        span = (self.n - 1) * dt
        while len(self._buf) > 1 and self._buf[1][0] <= t - span + 1e-6:
            self._buf.popleft()  # keep one sample at or before t - span
        tb = np.fromiter((b[0] for b in self._buf), float, len(self._buf))
        want = t - dt * np.arange(self.n - 1, -1, -1)
        i = np.searchsorted(tb, want + 1e-6, side="right") - 1
        if i[0] < 0:
            return  # less than (n - 1) dt seconds of odometry so far: no window yet
        pos = np.stack([self._buf[j][1] for j in i])
        self._window = pos - pos[0]

    def n_obs(self, obs: dict) -> int:
        return 1 if self._window is not None else 0

    def window(self) -> np.ndarray | None:
        """The current odometry window (n, 2) m, odometry frame, relative to its first sample (None before n s)."""
        return self._window

    # ------------------------------------------------------------------ scores
    def log_likelihood(self, x: np.ndarray, obs: dict) -> np.ndarray:
        """(R, N) weight * log S for particles with state ``x`` (R, N, D) (or positions (R, N, 2))."""
        lead = x.shape[:-1]
        if self._window is None:
            return np.zeros(lead)
        K = self.heading_bins
        dtv = np.asarray(self.prior.dtv(rotated_windows(self._window, K)))  # (K, c): one LSTM pass per step
        col = self.frame_angle_col
        if col is not None and x.shape[-1] > col:
            bins = heading_bins(x[..., col], K).ravel()
        else:
            bins = np.full(int(np.prod(lead)), heading_bins(self.theta, K), dtype=np.int64)
        xy = x[..., :2].reshape(-1, 2)
        out = np.empty(len(xy))
        order = np.argsort(bins, kind="stable")
        present, start = np.unique(bins[order], return_index=True)
        stop = np.append(start[1:], len(order))
        for k, a, b in zip(present, start, stop):  # a loop over heading bins (<= K), not over particles
            sel = order[a:b]
            out[sel] = np.asarray(self.prior.log_score_at(xy[sel], dtv[k]), dtype=float).reshape(-1)
        out = np.where(np.isnan(out), self.min_log_score, np.maximum(out, self.min_log_score))
        return (self.weight * out).reshape(lead)


# ------------------------------------------------------------------------------------------ loading
def attach_prior(models, path: str | None, loader: Callable[[str], object]) -> str | None:
    """Give every :class:`MapPriorLikelihood` in ``models`` without a prior the prior of ``path``.

    Loads once, ``loader(path)``: the caller's (the particle localizer hands in
    :func:`blenav.localizers.particle.load_prior`, the runtime's ``MapPrior``; a checkpoint needs the PyTorch loader
    from ``blenav.learn``). Without ``path``, or when the loader raises ImportError (the runtime module absent), the
    models keep ``prior = None`` with the reason in ``unavailable`` (their methods are then skipped with it).
    Errors of the loader itself (a wrong path, bad weights) propagate. Returns the reason the prior is
    unavailable, or None.
    """
    todo = [m for m in models if isinstance(m, MapPriorLikelihood) and m.prior is None]
    if not todo:
        return None
    reason = None
    prior = None
    if not path:
        reason = ("no learned map prior was given: pass model_path=DIR (a trained map prior network, loaded by "
                  "blenav.runtime.map_prior.MapPrior)")
    else:
        try:
            prior = loader(path)
        except ImportError as exc:
            reason = f"model_path={path} was given but blenav.runtime.map_prior cannot be imported ({exc})"
    for m in todo:
        m.prior, m.unavailable = prior, reason
    if reason:
        log.warning("map prior unavailable: %s", reason)
    return reason


# --------------------------------------------------------------------------------- reference prior
class FeasibilityPrior:
    """A non-learned map prior with the protocol above: the network's training target, on the grid.

    Roy trains the MPN to output T = 1e-6 exp(14 T_bar) (Fig. 3.8), T_bar measuring how much of the
    trajectory window, placed to end at x, lies in free space. This class computes that directly: the
    "trajectory vector" is the window itself (c = 2 n values), and ``log_score_at`` places the window's
    points relative to its last one at each x and looks them up in the occupancy grid:

        log S(x) = log(floor) + gain * (fraction of the n window points in FREE pixels)

    with floor = 1e-6 and gain = 14 (Roy's target). It knows nothing of odometry noise (the network learns
    some tolerance to drift), and costs n lookups per particle. Useful as a stand-in where no trained
    network exists (tests, smoke runs), never reported as the learned prior.
    """

    def __init__(self, window_steps: int = 5, gain: float = 14.0, floor: float = 1e-6):
        self.window_steps = int(window_steps)
        self.gain = float(gain)
        self.log_floor = float(np.log(floor))
        self.floor = None
        self.binds = 0

    def bind(self, floor) -> None:
        self.floor = floor
        self.binds += 1

    def dtv(self, odo: np.ndarray) -> np.ndarray:
        odo = np.asarray(odo, dtype=float)
        return odo.reshape(len(odo), -1)

    def log_score_at(self, xy: np.ndarray, dtv: np.ndarray) -> np.ndarray:
        w = np.asarray(dtv, dtype=float).reshape(-1, 2)
        pts = np.asarray(xy, dtype=float)[..., None, :] + (w - w[-1])  # (..., n, 2)
        return self.log_floor + self.gain * self.floor.is_free(pts).mean(axis=-1)
