"""Receivers that calibrate themselves: the RSSI offset of an unknown phone, estimated during the walk.

The path-loss model (Patel et al. eq. 1) is fitted on one phone; another reads every beacon a few dB
higher or lower (the project's own measurement: PF-PS 7.6 m on a Galaxy S10 calibrated on an iPhone 7).
000 names the remedy -- Problem 3's "system calibration parameters" theta_t, and, as future work, "joint
state and parameters estimation of radio signal measurements". Here the receiver's offset b (dB, common
to all beacons) is a Rao-Blackwellised state of every particle: conditioned on a particle's trajectory,
the offset is linear-Gaussian, so its posterior N(mu, P) is carried per particle in closed form and
marginalised out of the weights.

Model, per step with M packets: e_i = rssi_i - rssi_hat_i(x) = b + n_i, n_i ~ N(0, sigma^2) i.i.d.,
b ~ N(mu, P) (prior N(0, ``offset_prior_std_db``^2) at the start; between steps P grows by
``offset_drift_db2_per_s`` dt). With d_i = e_i - mu, S1 = sum d_i, S2 = sum d_i^2:

    log p(e | x) = -0.5 [ S2 / sigma^2 - P S1^2 / (sigma^2 (sigma^2 + M P)) ] - 0.5 log(1 + M P / sigma^2) + c

(the Gaussian N(mu 1, sigma^2 I + P 1 1^T) by Sherman-Morrison), and the update is the scalar Kalman step
mu += P S1 / (sigma^2 + M P), P = P sigma^2 / (sigma^2 + M P). The posterior follows its particle through
resampling (:meth:`on_resample`).

* :class:`RssiDomainOffset` (PF-PS+offset): the RSSI-domain likelihood of Patel et al. with the offset
  marginalised as above (sigma = ``sigma_s``).
* :class:`PathLossRangeOffset` (PF-PL+offset): the range likelihood of PF-PL on ranges converted from the
  offset-corrected RSSI, rssi_i - mu (each particle its own mu; ranges over ``max_range_m`` discarded per
  particle), while the offset's posterior is updated from the RSSI-domain residuals (sigma =
  ``sigma_rssi_db``): the range model itself is not linear in b.

``offset_estimate()`` gives the weighted posterior mean per run (dB; the receiver reads that much above
the calibration). Positions in world m, offsets in dB.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from .measurement import PathLossRange, RssiDomain


@dataclass
class _OffsetPosterior:
    """Per-particle Gaussian posterior of the receiver offset: mu, P (R, N) in dB, dB^2."""

    offset_prior_std_db: float = 10.0
    offset_drift_db2_per_s: float = 0.0
    mu: np.ndarray | None = field(default=None, init=False, repr=False)
    P: np.ndarray | None = field(default=None, init=False, repr=False)
    _t: float | None = field(default=None, init=False, repr=False)

    def _reset(self) -> None:
        self.mu = self.P = None
        self._t = None

    def _state(self, lead: tuple) -> tuple[np.ndarray, np.ndarray]:
        if self.mu is None or self.mu.shape != lead:
            self.mu = np.zeros(lead)
            self.P = np.full(lead, float(self.offset_prior_std_db) ** 2)
        return self.mu, self.P

    def _drift(self, obs: dict) -> None:
        t = obs.get("t")
        if t is None:
            return
        if self._t is not None and self.P is not None and self.offset_drift_db2_per_s > 0:
            self.P += self.offset_drift_db2_per_s * max(float(t) - self._t, 0.0)
        self._t = float(t)

    def _marginal(self, e: np.ndarray, sigma: float, lead: tuple) -> np.ndarray:
        """log p(e | x) (R, N) with the offset marginalised, and the posterior updated; e (M, R*N) dB."""
        mu, P = self._state(lead)
        M = e.shape[0]
        d = e.astype(np.float64) - mu.reshape(1, -1)
        s1 = d.sum(axis=0).reshape(lead)
        s2 = np.einsum("mp,mp->p", d, d).reshape(lead)
        s2_ = sigma * sigma
        denom = s2_ + M * P
        ll = -0.5 * (s2 / s2_ - P * s1 * s1 / (s2_ * denom)) - 0.5 * np.log1p(M * P / s2_)
        self.mu = mu + P * s1 / denom
        self.P = P * s2_ / denom
        return ll

    def on_resample(self, runs: np.ndarray, idx: np.ndarray) -> None:
        if self.mu is None:
            return
        self.mu[runs] = np.take_along_axis(self.mu[runs], idx, axis=1)
        self.P[runs] = np.take_along_axis(self.P[runs], idx, axis=1)

    def offset_estimate(self, w: np.ndarray | None = None) -> np.ndarray | None:
        """(R,) dB: the posterior mean of the offset per run (weighted by ``w`` (R, N), else uniform)."""
        if self.mu is None:
            return None
        return np.average(self.mu, axis=1, weights=w)


def _expected_rssi(model, xy: np.ndarray, idx: np.ndarray) -> np.ndarray:
    """(M, R*N) float32 expected RSSI (dBm) at the particles for the step's packets (Patel et al. eq. 1)."""
    d = model._distances(xy, idx)
    np.maximum(d, np.float32(model.d_min), out=d)
    ax = model._ax()[idx].astype(np.float32)[:, None]
    return ax - np.float32(10.0 * model.gamma) * np.log10(d / np.float32(model.d0))


@dataclass
class RssiDomainOffset(_OffsetPosterior, RssiDomain):
    """PF-PS+offset: :class:`~blenav.filters.measurement.RssiDomain` with the receiver's RSSI offset
    marginalised per particle (module docstring)."""

    def bind(self, anchors) -> None:
        super().bind(anchors)
        self._reset()

    def observe(self, obs: dict) -> None:
        self._drift(obs)

    def log_likelihood(self, xy: np.ndarray, obs: dict) -> np.ndarray:
        idx, rssi = obs["rssi_idx"], obs["rssi"]
        if len(idx) == 0:
            return np.zeros(xy.shape[:-1])
        e = rssi.astype(np.float32)[:, None] - _expected_rssi(self, xy, idx)
        return self._marginal(e, float(self.sigma_s), xy.shape[:-1])


@dataclass
class PathLossRangeOffset(_OffsetPosterior, PathLossRange):
    """PF-PL+offset: :class:`~blenav.filters.measurement.PathLossRange` on offset-corrected RSSI, the offset's
    posterior updated from RSSI-domain residuals (module docstring)."""

    sigma_rssi_db: float = 6.85
    d_min: float = 0.5

    def bind(self, anchors) -> None:
        super().bind(anchors)
        self._reset()

    def observe(self, obs: dict) -> None:
        self._drift(obs)

    def n_obs(self, obs: dict) -> int:
        """Packets whose range at the population's mean offset is within ``max_range_m``."""
        idx, rssi = obs["rssi_idx"], obs["rssi"]
        mu = float(self.mu.mean()) if self.mu is not None else 0.0
        r = self.d0 * 10.0 ** ((self._ax()[idx] - (rssi - mu)) / (10.0 * self.gamma))
        return int(np.count_nonzero(r <= self.max_range_m))

    def log_likelihood(self, xy: np.ndarray, obs: dict) -> np.ndarray:
        idx, rssi = obs["rssi_idx"], obs["rssi"]
        lead = xy.shape[:-1]
        if len(idx) == 0:
            return np.zeros(lead)
        mu, _ = self._state(lead)
        # r_i(p) = d0 10^((a_X - (rssi_i - mu_p)) / (10 gamma)) = r0_i g_p: the offset scales every range alike
        r0 = (self.d0 * 10.0 ** ((self._ax()[idx] - rssi) / (10.0 * self.gamma))).astype(np.float32)  # (M,)
        g = (10.0 ** (mu.reshape(-1) / (10.0 * self.gamma))).astype(np.float32)  # (P,)
        r = r0[:, None] * g[None, :]  # (M, P) m
        keep = r <= np.float32(self.max_range_m)
        res = self._distances(xy, idx)
        res -= r
        res *= np.float32(1.0 / self.sigma_n)
        res[~keep] = 0.0
        ll = self._sum_squares(res, lead)
        e = rssi.astype(np.float32)[:, None] - _expected_rssi(self, xy, idx)
        self._marginal(e, float(self.sigma_rssi_db), lead)  # update the offset's posterior only
        return ll
