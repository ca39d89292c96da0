"""Measurement models: log-likelihoods of one step's observations for all runs and particles.

``log_likelihood(xy, obs) -> (R, N)`` with xy (R, N, 2) world metres and ``obs`` the step's packed
observations; ``n_obs(obs)`` counts the observations used (for divergence checks). Constants common to
all particles are dropped. The BLE packets of one step are conditionally independent given the position,
so their log-likelihoods add.

Path loss (Patel et al. eq. 1; Ghaffari Jadidi et al. use the same form with a reference distance d0):

    rssi = a_X - 10 gamma log10(d / d0) + eps

* PF-PL (:class:`PathLossRange`): each RSSI becomes a range r = d0 10^((a_X - rssi) / (10 gamma));
  ranges over ``max_range_m`` (10 m) are discarded; likelihood N(||x - l|| - r; 0, sigma_n^2) with
  sigma_n = 5 m (000, Table I) or 6 m (002, Table I).
* PF-PS (:class:`RssiDomain`, Patel et al. section IV, eq. 2): the particle's distance to the beacon gives
  an expected RSSI; the residual rssi - rssi_hat ~ N(0, sigma_s^2), sigma_s = 6.85 dB (002, Table I
  prints "m"; the quantity is a dB residual).

Distances are 3-D: the anchor's z against the device height ``device_z`` (m). a_X is per anchor: the
anchor's ``tx_power_dbm`` (calibrated RSSI at 1 m) when ``use_anchor_tx_power`` and it is known, else
the configured value.

Position fixes (:class:`FixLikelihood`, Roy section 3.2, eq. 3.9): a fix z (world x, y in m) from another
localizer, e.g. a learned BLE localizer, weighs a particle at x by N(||x - z||; 0, sigma), sigma = 3 m.

Every model derives from :class:`MeasurementModel`, which declares the interface the engine calls. Each
names the per-step observations it reads in ``needs`` (``"rssi"``: ``rssi_idx``/``rssi``; ``"fixes"``:
``fix_xy``/``fix_std``/``fix_source``, see :mod:`blenav.filters.steps`).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from . import measurement_kernels as K


def _rows(xy: np.ndarray) -> np.ndarray:
    """(R, N, >= 2) positions as (R * N, >= 2) rows (a view for the engine's ``x[..., :2]``)."""
    return xy.reshape(-1, xy.shape[-1])


class MeasurementModel:
    """Base of every measurement model: the interface the engine and the runner call, with its defaults.

    Subclasses implement ``n_obs(obs) -> int`` and ``log_likelihood(xy, obs) -> (R, N)``. The rest is
    declared here, so the engine never probes for optional methods:

    * ``needs``: the per-step observations the model reads (``"rssi"``, ``"fixes"``, ``"odo"``);
    * ``wants_state``: ``log_likelihood`` receives the full state (R, N, D) instead of positions (R, N, 2);
    * ``divergence_check``: the model's log-likelihood counts in the engine's divergence test (a prior
      score is not a residual: False);
    * ``calibrated``: the evaluation replaces the model's path-loss parameters by a fit on labelled data;
    * ``bind(anchors)``, ``bind_floor(floor)``, ``bind_motion(motion)``: called when a filter is built for a
      session (the building's anchors, the session's floor, the method's motion model);
    * ``observe(obs)``: called every step before ``n_obs`` (models that keep a history);
    * ``missing_reason()``: why the model cannot run (e.g. a learned prior that was not given), or None;
    * ``on_resample(runs, idx)``: called after resampling (models with per-particle state).
    """

    needs: tuple[str, ...] = ()
    wants_state = False
    divergence_check = True
    calibrated = False

    def bind(self, anchors: "AnchorTable") -> None:
        """Attach the building's anchors (a no-op for models that do not use them)."""

    def bind_floor(self, floor) -> None:
        """Attach the session's floor (a no-op for models that do not use the floor plan)."""

    def bind_motion(self, motion) -> None:
        """Attach the method's motion model (a no-op for models that do not read its state columns)."""

    def observe(self, obs: dict) -> None:
        """See every step's observations before ``n_obs`` (a no-op for memoryless models)."""

    def missing_reason(self) -> str | None:
        """Why the model cannot run, or None."""
        return None

    def set_receiver_offset(self, delta_db: float) -> None:
        """The receiver reads ``delta_db`` dB above its calibration (the back-end's estimate): models that
        convert RSSI shift their a_X by it (a no-op for the others)."""

    def on_resample(self, runs: np.ndarray, idx: np.ndarray) -> None:
        """The engine resampled runs ``runs`` (Q,) with ancestor indices ``idx`` (Q, N): a model that keeps
        per-particle state (e.g. a receiver offset's posterior) reorders it the same way (default: none)."""

    def n_obs(self, obs: dict) -> int:
        raise NotImplementedError

    def log_likelihood(self, xy: np.ndarray, obs: dict) -> np.ndarray:
        raise NotImplementedError


@dataclass
class AnchorTable:
    """Anchors one measurement model uses: ids, positions (A, 3) m, 1 m levels (A,) dBm (NaN unknown)."""

    ids: np.ndarray
    xyz: np.ndarray
    tx_power_dbm: np.ndarray

    @classmethod
    def from_frame(cls, anchors, kind: str = "ble") -> "AnchorTable":
        a = anchors[anchors["kind"] == kind]
        return cls(a["anchor_id"].astype(str).to_numpy(), a[["x", "y", "z"]].to_numpy(float),
                   a["tx_power_dbm"].to_numpy(float))

    @classmethod
    def empty(cls) -> "AnchorTable":
        """No anchors (a stream read without its radio measurements)."""
        return cls(np.zeros(0, str), np.zeros((0, 3)), np.zeros(0))

    def index_of(self, ids: np.ndarray) -> np.ndarray:
        """Row of each id in this table, -1 for unknown ids."""
        order = np.argsort(self.ids)
        pos = np.searchsorted(self.ids[order], ids)
        pos = np.clip(pos, 0, len(order) - 1)
        hit = self.ids[order][pos] == ids
        return np.where(hit, order[pos], -1)


@dataclass
class _PathLoss(MeasurementModel):
    a_x: float = -60.0
    gamma: float = 2.25
    d0: float = 1.0
    device_z: float = 1.2
    use_anchor_tx_power: bool = True
    calibrated: bool = False  # True: the harness replaces a_x, gamma, d0 by a fit on labelled data
    rx_offset_db: float = 0.0  # dB added to every anchor's a_X: the receiver's offset (set by the back-end's loop)
    anchors: AnchorTable | None = field(default=None, repr=False)

    needs = ("rssi",)

    def bind(self, anchors: AnchorTable) -> None:
        """Attach the building's anchors (prior map); a later back-end may re-bind a corrected map."""
        self.anchors = anchors

    def set_receiver_offset(self, delta_db: float) -> None:
        self.rx_offset_db = float(delta_db)

    def _ax(self) -> np.ndarray:
        tx = self.anchors.tx_power_dbm
        if self.use_anchor_tx_power:
            ax = np.where(np.isfinite(tx), tx, self.a_x)
        else:
            ax = np.full(len(tx), self.a_x)
        return ax + self.rx_offset_db if self.rx_offset_db else ax

    def _distances(self, xy: np.ndarray, idx: np.ndarray) -> np.ndarray:
        """(M, P) 3-D distances (m) from the particles (P = R * N, flattened) to the anchors of the step's M
        packets, anchor-major.

        float32: these arrays are the filter's largest; centimetre resolution is plenty for residuals of
        metres (PF-PL) or dB (PF-PS), and it halves their time. Compiled (measurement_kernels.distances_mp, the
        inner loop over the particles): the numbers of the numpy expression kept in tests/filters/test_kernels.py
        (dx^2 + dy^2 + dz^2 in float32, then sqrt)."""
        return K.distances_mp(_rows(xy), self.anchors.xyz[idx], float(self.device_z), 0.0)

    @staticmethod
    def _sum_squares(res: np.ndarray, lead: tuple) -> np.ndarray:
        """-0.5 sum over packets of res^2: (M, P) float32 residuals -> ``lead`` (R, N) float64. Summed over a
        particle-major copy by the same einsum as before (its float32 summation order is einsum's own)."""
        r = np.ascontiguousarray(res.T).reshape(*lead, res.shape[0])
        return -0.5 * np.einsum("rnm,rnm->rn", r, r).astype(np.float64)

    def n_obs(self, obs: dict) -> int:
        return int(len(obs["rssi_idx"]))


@dataclass
class PathLossRange(_PathLoss):
    """PF-PL: RSSI -> range by path loss, ranges over max_range_m discarded, Gaussian range likelihood."""

    a_x: float = -64.53
    gamma: float = 1.72
    d0: float = 1.78
    sigma_n: float = 5.0
    max_range_m: float = 10.0

    def ranges(self, obs: dict) -> tuple[np.ndarray, np.ndarray]:
        idx, rssi = obs["rssi_idx"], obs["rssi"]
        r = self.d0 * 10.0 ** ((self._ax()[idx] - rssi) / (10.0 * self.gamma))
        keep = r <= self.max_range_m
        return idx[keep], r[keep]

    def n_obs(self, obs: dict) -> int:
        return int(len(self.ranges(obs)[0]))

    def log_likelihood(self, xy: np.ndarray, obs: dict) -> np.ndarray:
        idx, r = self.ranges(obs)
        if len(idx) == 0:
            return np.zeros(xy.shape[:-1])
        # compiled, one pass: float32 residuals (d - r) / sigma_n of _distances, summed as _sum_squares
        return K.range_loglik(_rows(xy), self.anchors.xyz[idx], float(self.device_z), r.astype(np.float32),
                              1.0 / self.sigma_n).reshape(xy.shape[:-1])


@dataclass
class RssiDomain(_PathLoss):
    """PF-PS: expected RSSI from the particle's distance, residual ~ N(0, sigma_s^2) (Patel et al. eq. 2)."""

    sigma_s: float = 6.85
    d_min: float = 0.5

    def log_likelihood(self, xy: np.ndarray, obs: dict) -> np.ndarray:
        idx, rssi = obs["rssi_idx"], obs["rssi"]
        if len(idx) == 0:
            return np.zeros(xy.shape[:-1])
        # compiled distances (M, P) floored at d_min, numpy's float32 log10 in place (its SIMD routine: the
        # same numbers as before), then one compiled pass for the residuals
        # rssi - (a_X - 10 gamma log10(d / d0)) = 10 gamma log10(d) + base, / sigma_s, summed as _sum_squares
        d = K.distances_mp(_rows(xy), self.anchors.xyz[idx], float(self.device_z), float(self.d_min))
        base = (rssi - self._ax()[idx] - 10.0 * self.gamma * np.log10(self.d0)).astype(np.float32)
        np.log10(d, out=d)
        return K.rssi_sum_squares(d, 10.0 * self.gamma, base, 1.0 / self.sigma_s).reshape(xy.shape[:-1])



@dataclass
class FixLikelihood(MeasurementModel):
    """Position fixes as a measurement: log N(||x - z||; 0, sigma) summed over the step's fixes (eq. 3.9, Roy).

    Roy (section 3.2) weighs every particle x by the output z of the BLE localization model,
    w = N(||x - z||, 0, 3), i.e. sigma = 3 m. Per step, with F selected fixes z_f (world m):

        log p(z_1..z_F | x) = -0.5 sum_f (||x - z_f|| / sigma_f)^2 + const

    The fixes of a step are taken as conditionally independent given x. ``sigma_f`` is ``sigma_m`` or,
    with ``use_std`` and a finite positive ``std`` on the row, that row's std (m). Terms common to all
    particles (the normalisers, -log sigma_f) are dropped, as in the other models. The 2-D isotropic
    Gaussian N(z; x, sigma^2 I) has the same particle-dependent term, so either reading of eq. 3.9 gives
    the same weights.

    ``source``: the ``fixes.csv`` source to use (exact match after stripping spaces); ``None`` uses
    every row whatever its source. ``role`` (optional, e.g. ``"sparse"``): which of an experiment's fix
    sets feeds the model; the evaluation sets ``source`` per session from it (the named ``fixes.<role>``
    source, or fixes it computed from ``rssi.csv``, see :mod:`blenav.eval.fixes`).
    """

    sigma_m: float = 3.0
    source: str | None = None
    use_std: bool = False
    role: str | None = None

    needs = ("fixes",)

    def __post_init__(self):
        if not (np.isfinite(self.sigma_m) and self.sigma_m > 0):
            raise ValueError(f"FixLikelihood.sigma_m must be a positive number of metres, got {self.sigma_m!r}")
        if self.source is not None:
            self.source = str(self.source).strip()

    def bind(self, anchors: AnchorTable) -> None:
        """Fixes are world positions: the anchors are not used."""

    def select(self, source: np.ndarray) -> np.ndarray:
        """(F,) bool: the fixes this model uses, from their ``source`` strings (F,) ('' when empty)."""
        if self.source is None:
            return np.ones(len(source), dtype=bool)
        return np.asarray(source, dtype=str) == self.source

    def _fixes(self, obs: dict) -> tuple[np.ndarray, np.ndarray]:
        """Selected fixes (F, 2) m and their inverse variances (F,) 1/m^2."""
        keep = self.select(obs["fix_source"])
        z = obs["fix_xy"][keep]
        sigma = np.full(len(z), float(self.sigma_m))
        if self.use_std:
            std = obs["fix_std"][keep]
            ok = np.isfinite(std) & (std > 0)
            sigma[ok] = std[ok]
        return z, 1.0 / (sigma * sigma)

    def n_obs(self, obs: dict) -> int:
        if not len(obs.get("fix_xy", ())):
            return 0
        return int(np.count_nonzero(self.select(obs["fix_source"])))

    def log_likelihood(self, xy: np.ndarray, obs: dict) -> np.ndarray:
        """(R, N) log-likelihood (float64) of the step's fixes for particles xy (R, N, 2) world m."""
        if not len(obs.get("fix_xy", ())):
            return np.zeros(xy.shape[:-1])
        z, inv_var = self._fixes(obs)
        if len(z) == 0:
            return np.zeros(xy.shape[:-1])
        dx = xy[..., 0:1] - z[:, 0]  # (R, N, F)
        dy = xy[..., 1:2] - z[:, 1]
        return -0.5 * ((dx * dx + dy * dy) @ inv_var)
