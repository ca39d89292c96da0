"""The SIR particle filter: the algorithm, separate from the models it runs.

One :class:`ParticleFilter` holds R independent runs of N particles each (state (R, N, D)) and advances
them together through one session: all runs see the same observations and draw their own random
numbers from one explicit ``numpy.random.Generator``. A step:

1. ``propagate``: the motion model moves every particle (proposal); then every ``constraint`` component
   sees the move (:class:`Constraint`: e.g. :class:`~blenav.filters.constraints.ObstacleRules`, the
   wall-crossing penalty and Roy's re-initialisation on obstacles) and may re-initialise runs and return
   a log-weight term for each particle;
2. ``reweight``: log-weights += sum of the measurement models' log-likelihoods + the constraints' terms;
   non-finite log-weights become -inf;
3. ``recover``: a run whose weights all vanished, or whose best particle explains the observations
   worse than ``divergence_sigma`` standard deviations per observation for ``patience_s``, is
   re-initialised around its last estimate (``local_sigma_m``), and globally (the initialiser) if it
   diverges again within ``global_after_s``; each recovery is recorded as an event. Only models with
   ``divergence_check`` count: a map-prior score is not a residual;
4. ``estimate``: weighted mean and covariance (and, if asked, the median particle: the particle closest
   to the coordinate-wise weighted median, Roy's estimate, always a particle so never inside an
   obstacle the cloud avoids);
5. ``resample`` the runs whose effective sample size n_eff = 1 / sum w^2 fell below
   ``ess_threshold * N``, then let the map component condition the new particles (Patel et al. eq. 4-5).

The components' interfaces are declared: :class:`~blenav.filters.motion.MotionModel`,
:class:`~blenav.filters.measurement.MeasurementModel`, :class:`Initializer`, :class:`Constraint`; the
engine calls them without probing for optional methods.

Weights stay in log space; normalisation subtracts the row maximum first.
"""

from __future__ import annotations

from dataclasses import dataclass
from enum import StrEnum
from typing import Optional

import numpy as np

from blenav.limits import check_memory, check_range

from .kernels import add_loglik, duplicates, gather_rows, mean_cov, recover_checks
from .noise import motion_stream
from .resampling import ess, get_scheme, log_normalise


class Resampling(StrEnum):
    """``filter.resampling``: the schemes of :mod:`blenav.filters.resampling`, by the same names."""

    systematic = "systematic"
    stratified = "stratified"
    multinomial = "multinomial"
    residual = "residual"
    low_variance = "low_variance"


class EstimateMode(StrEnum):
    """``filter.estimate``: the weighted mean, or the particle nearest the weighted median (Roy)."""

    mean = "mean"
    median = "median"


@dataclass
class FilterConfig:
    """Algorithm settings (Hydra ``filter/``; the structured schema of the filter)."""

    n_particles: int = 300
    rate_hz: float = 10.0
    resampling: Resampling = Resampling.systematic
    ess_threshold: float = 0.2  # fraction of N: 000 uses n_thr = 60 of 300
    estimate: EstimateMode = EstimateMode.mean
    divergence_sigma: float = 4.0
    patience_s: float = 3.0
    local_sigma_m: float = 3.0
    global_after_s: float = 10.0
    # Settings of the obstacle rules (blenav.filters.constraints.ObstacleRules, built by the runner when the
    # method asks for them; the engine itself does not read these three):
    wall_log_penalty: float = -np.inf  # log-weight added to a particle whose step crossed a wall (map.walls)
    # Roy section 3.2: re-initialise a run when more than reinit_fraction (s_reinit) of its particles crossed an
    # obstacle on one step, uniformly over free space within reinit_radius_m (r_reinit) of the last estimate.
    # None disables the rule.
    reinit_fraction: Optional[float] = None
    reinit_radius_m: float = 5.0


#: (R, N) float64 arrays a step holds besides the state: log-weights, log-likelihoods (and the divergence test's
#: copy), the constraints' term, normalised weights, resampling indices, duplicate flags, a measurement's term
STEP_ARRAYS = 8


def memory_bytes(n_runs: int, n_particles: int, state_dim: int) -> float:
    """Estimated peak bytes of a filter of ``n_runs`` x ``n_particles`` particles of ``state_dim`` float64 values:
    the state twice (propagation returns a new one while the old is alive) plus :data:`STEP_ARRAYS` (R, N)
    arrays. Checked (:func:`blenav.limits.check_memory`) before anything is allocated."""
    return float(n_runs) * float(n_particles) * 8.0 * (2 * int(state_dim) + STEP_ARRAYS)


def check_size(n_runs, n_particles, state_dim: int, where: str, field: str = "n_particles") -> tuple[int, int]:
    """``(R, N)`` as ints after checking ``n_runs`` and ``n_particles`` against their ranges
    (:data:`blenav.limits.RANGES`) and the filter's memory estimate (:func:`memory_bytes`) against the limit;
    ``where`` and ``field`` name the setting in the one-line :class:`~blenav.limits.LimitError`."""
    N = check_range(n_particles, "n_particles", where, field=field)
    R = check_range(n_runs, "runs", where)
    check_memory(memory_bytes(R, N, state_dim), f"{field} {N:,} x {R:,} run(s) x {int(state_dim)} state values", where)
    return R, N


@dataclass
class Event:
    t: float
    run: int
    kind: str  # 'recover-local' | 'recover-global' | 'reinit-obstacles'
    detail: str = ""


@dataclass
class StepResult:
    """Estimates of all runs at one step: position (R, 2) m, covariance (R, 2, 2), n_eff (R,)."""

    t: float
    position: np.ndarray
    cov: np.ndarray
    n_eff: np.ndarray
    resampled: np.ndarray


class Initializer:
    """Where particles start, and where runs restart: the engine's initializer interface.

    ``sample(rng, R, N) -> (R, N, 2)`` world m must be implemented (uniform over free space, or map-aware);
    the others have defaults: ``adjust_state(x, rng) -> x`` after ``motion.init_state`` at initialisation
    (e.g. a known odometry frame angle; default: unchanged), ``sample_within(rng, centres (M, 2), N, radius)
    -> (M, N, 2)`` (free space within a radius, for the obstacle re-initialisation; default: the disc,
    free space unknown), ``snap_free(xy) -> xy`` (move points into free space; default: unchanged).
    """

    def sample(self, rng: np.random.Generator, R: int, N: int) -> np.ndarray:
        raise NotImplementedError

    def adjust_state(self, x: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        return x

    def sample_within(self, rng: np.random.Generator, centres: np.ndarray, N: int, radius: float) -> np.ndarray:
        """Uniform in the disc of ``radius`` m around each centre (sqrt of a uniform radius)."""
        M = len(centres)
        rad = radius * np.sqrt(rng.random((M, N)))
        ang = rng.uniform(-np.pi, np.pi, (M, N))
        return centres[:, None, :] + np.stack([rad * np.cos(ang), rad * np.sin(ang)], axis=-1)

    def snap_free(self, xy: np.ndarray) -> np.ndarray:
        return xy


class Constraint:
    """A problem-specific rule the engine applies after every propagation (e.g. walls).

    ``after_propagate(pf, t, xy_prev) -> (R, N) log-weight term or None``: ``xy_prev`` (R, N, 2) are the
    positions before the move, ``pf.x`` the state after it; the component may re-initialise runs of ``pf``
    (state, log-weights, ``pf.events``). The term is added to the step's log-likelihood after the
    measurement models."""

    def after_propagate(self, pf: "ParticleFilter", t: float, xy_prev: np.ndarray) -> np.ndarray | None:
        raise NotImplementedError


class ParticleFilter:
    """SIR filter over R runs, from declared components:

    * ``motion``: a :class:`~blenav.filters.motion.MotionModel`;
    * ``measurements``: :class:`~blenav.filters.measurement.MeasurementModel` objects;
    * ``initializer``: an :class:`Initializer`;
    * ``conditioner`` (optional): ``condition(xy, rng, mask) -> xy`` applied to the new copies made by resampling;
    * ``constraints``: :class:`Constraint` components (walls, obstacle re-initialisation).

    Public state for components: ``x`` (R, N, D), ``logw`` (R, N), ``rng``, ``events``, ``last_est`` (R, 2)
    (the previous step's estimates, NaN before the first), ``R``, ``N``. ``motion_rng``: the motion model's
    own stream (a child of ``rng``, drawn a step ahead in a worker thread: :mod:`blenav.filters.noise`).
    """

    def __init__(self, cfg: FilterConfig, motion, measurements: list, initializer: Initializer,
                 rng: np.random.Generator, n_runs: int = 1, conditioner=None, constraints=()):
        self.cfg = cfg
        self.motion = motion
        self.measurements = list(measurements)
        self.initializer = initializer
        self.conditioner = conditioner
        self.constraints = list(constraints)
        self.rng = rng
        self.motion_rng = motion_stream(rng)
        # bounded before anything is allocated (n_particles 1e9 asked numpy for 37 GiB)
        self.R, self.N = check_size(n_runs, cfg.n_particles, motion.state_dim, "filter settings")
        check_range(cfg.rate_hz, "rate_hz", "filter settings")
        self.resample_fn = get_scheme(cfg.resampling)
        if cfg.estimate not in ("mean", "median"):
            raise ValueError(f"filter.estimate must be 'mean' or 'median', got {cfg.estimate!r}")
        self.events: list[Event] = []
        self.x = np.zeros((self.R, self.N, motion.state_dim))
        self.logw = np.zeros((self.R, self.N))
        self.t = 0.0
        self._bad_since = np.full(self.R, np.nan)
        self._last_local = np.full(self.R, -np.inf)
        self.last_est = np.full((self.R, 2), np.nan)

    # ------------------------------------------------------------------ phases
    def initialize(self, t0: float = 0.0) -> None:
        self.t = t0
        xy = self.initializer.sample(self.rng, self.R, self.N)
        self.x = self.initializer.adjust_state(self.motion.init_state(xy, self.rng), self.rng)
        self.logw = np.full((self.R, self.N), -np.log(self.N))

    def step(self, t: float, ctrl: dict, obs: dict) -> StepResult:
        dt = max(t - self.t, 1e-6)
        xy_prev = self.x[..., :2].copy() if self.constraints else None  # only the constraints read it
        self.x = self.motion.propagate(self.x, ctrl, dt, self.motion_rng)
        penalty = None  # the constraints' log-weight terms (R, N)
        for c in self.constraints:
            term = c.after_propagate(self, t, xy_prev)
            if term is not None:
                penalty = term if penalty is None else penalty + term
        loglik = np.zeros((self.R, self.N))
        loglik_div = None  # the part the divergence test sees (None: all of loglik)
        n_obs = 0
        for m in self.measurements:
            m.observe(obs)
            k = m.n_obs(obs)
            if k:
                ll = m.log_likelihood(self.x if m.wants_state else self.x[..., :2], obs)
                if m.divergence_check:
                    n_obs += k
                    if loglik_div is not None:
                        loglik_div = loglik_div + ll
                elif loglik_div is None:
                    loglik_div = loglik.copy()
                loglik += ll
        if penalty is not None:
            loglik = loglik + penalty
            if loglik_div is not None:
                loglik_div = loglik_div + penalty
        self.logw = add_loglik(self.logw, loglik)  # compiled: logw + loglik, non-finite -> -inf
        self.t = t
        self._recover(t, loglik if loglik_div is None else loglik_div, n_obs)
        w, _ = log_normalise(self.logw)
        pos, cov = self._estimate(w)
        n_eff = ess(w)
        resample = n_eff < self.cfg.ess_threshold * self.N
        if resample.any():
            self._resample(np.flatnonzero(resample), w)
        self.last_est = pos
        return StepResult(t, pos, cov, n_eff, resample)

    # ------------------------------------------------------------------ helpers
    def _estimate(self, w: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        xy = self.x[..., :2]
        # compiled: the numbers of einsum("rn,rnk->rk", w, xy) and einsum("rn,rni,rnj->rij", w, d, d), d = xy - mean
        mean, cov = mean_cov(w, self.x)
        if self.cfg.estimate == "median":
            med = _weighted_median(xy, w)
            nearest = np.argmin(np.sum((xy - med[:, None, :]) ** 2, axis=-1), axis=1)
            return xy[np.arange(self.R), nearest], cov
        return mean, cov

    def _resample(self, runs: np.ndarray, w: np.ndarray) -> None:
        idx = self.resample_fn(w[runs], self.rng)
        if self.x.flags.c_contiguous and self.x.dtype == np.float64:  # compiled, in place: take_along_axis's copies
            gather_rows(self.x, runs.astype(np.int64), np.ascontiguousarray(idx, dtype=np.int64))
        else:
            self.x[runs] = np.take_along_axis(self.x[runs], idx[..., None], axis=1)
        for m in self.measurements:
            m.on_resample(runs, idx)
        self.logw[runs] = -np.log(self.N)
        if self.conditioner is not None:
            # Patel et al. eq. 4: the *new* particles (the extra copies that replace the dropped ones) are
            # generated around the strong particle and conditioned on the map; one copy of each survivor stays
            # (idx (len(runs), N), runs never empty: the compiled kernel's flags, no argsort)
            copies = duplicates(np.ascontiguousarray(idx, dtype=np.int64))
            self.x[runs, :, :2] = self.conditioner.condition(self.x[runs, :, :2], self.rng, mask=copies)

    def _recover(self, t: float, loglik: np.ndarray, n_obs: int) -> None:
        """Re-initialise runs whose weights vanished or whose cloud no longer explains the data."""
        # compiled: ~isfinite(logw).any(axis=1) and np.max(np.where(np.isfinite(loglik), loglik, -inf), axis=1)
        dead, best = recover_checks(self.logw, np.ascontiguousarray(loglik, dtype=float))
        if n_obs:
            best = best / n_obs
            bad = best < -0.5 * self.cfg.divergence_sigma**2
            self._bad_since = np.where(bad, np.where(np.isnan(self._bad_since), t, self._bad_since), np.nan)
        diverged = np.isfinite(self._bad_since) & (t - self._bad_since >= self.cfg.patience_s)
        redo = np.flatnonzero(dead | diverged)
        if len(redo) == 0:
            return
        go_global = (t - self._last_local[redo] < self.cfg.global_after_s) | ~np.isfinite(self.last_est[redo, 0])
        xy = self.initializer.sample(self.rng, len(redo), self.N)
        local = redo[~go_global]
        if len(local):
            centre = self.last_est[local][:, None, :]
            xy_local = centre + self.cfg.local_sigma_m * self.rng.standard_normal((len(local), self.N, 2))
            xy[~go_global] = self.initializer.snap_free(xy_local)
        self.x[redo] = self.motion.init_state(xy, self.rng)
        self.logw[redo] = -np.log(self.N)
        for r, g, was_dead in zip(redo, go_global, dead[redo]):
            self.events.append(Event(t, int(r), "recover-global" if g else "recover-local",
                                     "all weights vanished" if was_dead else "measurements unexplained"))
        self._last_local[redo[~go_global]] = t
        self._bad_since[redo] = np.nan


def _weighted_median(xy: np.ndarray, w: np.ndarray) -> np.ndarray:
    """Coordinate-wise weighted median (R, 2) of particles xy (R, N, 2) with weights (R, N)."""
    out = np.empty(xy.shape[::2])
    for k in range(2):  # two coordinates, not a loop over particles
        order = np.argsort(xy[..., k], axis=1)
        cw = np.cumsum(np.take_along_axis(w, order, axis=1), axis=1)
        i = np.argmax(cw >= 0.5, axis=1)
        out[:, k] = np.take_along_axis(xy[..., k], order, axis=1)[np.arange(len(i)), i]
    return out
