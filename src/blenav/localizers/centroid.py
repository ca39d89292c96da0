"""Weighted centroid of the three nearest anchors (Duembgen et al., 004, sec. VI-E): a distance-based
baseline that needs no motion model, no map and no training.

"We linearly interpolate the 3 closest anchor coordinates, using the inverse of the distance
measurements as weights" (004). Per window of ``window_s`` seconds (pre-processing of 004 sec. V-A:
the median of each anchor's readings over the window; BLE readings below ``min_rssi_dbm`` = -90 dBm
dropped), every heard BLE anchor's RSSI becomes a distance with the path-loss model

    d = d0 10^((a_X - rssi) / (10 gamma))     (Patel et al. eq. 1, inverted; as PF-PL)

and the estimate is sum_j w_j l_j / sum_j w_j over the ``k`` anchors of smallest d, w_j = 1 / d_j
(fewer when fewer were heard). A window in which nothing was heard repeats the previous estimate;
times before the first heard window have no estimate. a_X and gamma are fitted on labelled data
like the filters' path-loss models (``calibrated: true``).

Config: ``conf/localizer/centroid.yaml``.
"""

from __future__ import annotations

import time

import numpy as np

from blenav.crf.preprocess import keyed_medians
from blenav.errors import MissingStream
from blenav.filters.calibration import apply_fit
from blenav.filters.measurement import AnchorTable, PathLossRange

from .base import Estimate, Localizer, PathLossCalibrated, RunInputs


class WeightedCentroidLocalizer(Localizer, PathLossCalibrated):
    """Inverse-distance weighted centroid of the ``k`` nearest BLE anchors per ``window_s`` window.

    Deterministic: every run gets the same trajectory. Estimates at each window's end (s); positions
    in world m (the anchors' frame); no covariance."""

    uses_floor_plan = False  # anchors only

    def __init__(self, name: str, shared=None, k: int = 3, window_s: float = 1.0, min_rssi_dbm: float = -90.0,
                 a_x: float = -60.0, gamma: float = 2.25, d0: float = 1.0, use_anchor_tx_power: bool = True,
                 calibrated: bool = True, device_z: float = 1.2):
        super().__init__(name, shared)
        if int(k) < 1:
            raise ValueError(f"method {name!r}: k must be >= 1, got {k}")
        if not window_s > 0:
            raise ValueError(f"method {name!r}: window_s must be > 0 s, got {window_s}")
        self.k, self.window_s, self.min_rssi_dbm = int(k), float(window_s), float(min_rssi_dbm)
        self.path_loss = PathLossRange(a_x=a_x, gamma=gamma, d0=d0, device_z=device_z, max_range_m=np.inf,
                                       use_anchor_tx_power=use_anchor_tx_power, calibrated=calibrated)

    def wants_path_loss_fit(self) -> bool:
        return self.path_loss.calibrated

    def apply_path_loss_fit(self, fit) -> None:
        apply_fit([self.path_loss], fit)

    def run(self, session, n_runs: int, seed: int, inputs: RunInputs | None = None) -> Estimate:
        t0 = time.perf_counter()
        anchors = AnchorTable.from_frame(session.building.anchors, "ble")
        known = np.isfinite(anchors.xyz[:, :2]).all(axis=1)
        anchors = AnchorTable(anchors.ids[known], anchors.xyz[known], anchors.tx_power_dbm[known])
        if not len(anchors.ids):
            raise MissingStream(f"building {session.building.id} has no BLE anchor with a known position")
        r = session.rssi
        idx = anchors.index_of(r["anchor_id"].astype(str).to_numpy()) if len(r) else np.zeros(0, int)
        rssi = r["rssi"].to_numpy(float) if len(r) else np.zeros(0)
        keep = (idx >= 0) & np.isfinite(rssi) & (rssi >= self.min_rssi_dbm)
        if not keep.any():
            raise MissingStream(f"session {session.id} has no BLE reading of a known anchor at or above "
                                f"{self.min_rssi_dbm:g} dBm")
        t = r["t"].to_numpy(float)[keep]
        t_ends, xy = self.estimate(t, idx[keep], rssi[keep], anchors, float(r["t"].min()))
        pos = np.broadcast_to(xy, (n_runs,) + xy.shape).copy()
        return Estimate(self.name, session.id, t_ends, pos, None, [], {}, n_runs * (time.perf_counter() - t0), [])

    def estimate(self, t: np.ndarray, idx: np.ndarray, rssi: np.ndarray, anchors: AnchorTable,
                 t_start: float) -> tuple[np.ndarray, np.ndarray]:
        """Window ends (W,) s and estimates (W, 2) world m from readings t (M,) s, anchor rows idx (M,),
        rssi (M,) dBm; windows [t_start + w window_s, t_start + (w + 1) window_s), from the first with a
        reading to the last."""
        win = np.floor((t - t_start) / self.window_s).astype(np.int64)
        w0 = int(win.min())
        win -= w0
        W, A = int(win.max()) + 1, len(anchors.ids)
        med = medians_by_window(win, idx, rssi, W, A)  # (W, A) dBm, NaN where not heard
        self.path_loss.bind(anchors)
        wi, ai = np.nonzero(np.isfinite(med))
        _, r = self.path_loss.ranges({"rssi_idx": ai, "rssi": med[wi, ai]})  # max_range_m = inf: keeps all
        d = np.full((W, A), np.inf)  # (W, A) m; inf where not heard
        d[wi, ai] = np.maximum(r, 1e-3)
        k = min(self.k, A)
        near = np.argpartition(d, k - 1, axis=1)[:, :k] if k < A else np.broadcast_to(np.arange(A), (W, A))
        dk = np.take_along_axis(d, near, axis=1)  # (W, k)
        wgt = np.where(np.isfinite(dk), 1.0 / dk, 0.0)
        total = wgt.sum(axis=1)
        xy = np.einsum("wk,wkc->wc", wgt, anchors.xyz[near][..., :2]) / np.where(total > 0, total, 1.0)[:, None]
        heard = total > 0
        last = np.maximum.accumulate(np.where(heard, np.arange(W), 0))  # the last heard window so far
        xy = xy[last]
        t_ends = t_start + (np.arange(W) + w0 + 1) * self.window_s
        return t_ends, xy


def medians_by_window(win: np.ndarray, idx: np.ndarray, values: np.ndarray, W: int, A: int) -> np.ndarray:
    """(W, A) median of ``values`` (N,) per (window ``win`` (N,) in [0, W), anchor ``idx`` (N,) in [0, A)), NaN
    where the anchor was not heard in the window: the RSSI here, the ranges of the range baselines
    (:mod:`blenav.localizers.ranging_windows`)."""
    return keyed_medians(win * A + idx, values, W * A).reshape(W, A)
