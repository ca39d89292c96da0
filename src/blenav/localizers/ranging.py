"""Distance-based baselines of Duembgen et al. (004, sec. VI-E): range least squares by grid search
(grid-L2), its absolute-residual variant (grid-L1), and squared-range least squares (SRLS, closed form).

"We compare to the two algorithms proposed by [5]: the grid-search implementation of Range Least Squares
(RLS, denoted by grid-L2) and the Squared Range Least Squares (SRLS) solution. We also introduce a variation
of RLS using the median rather than mean distance error (denoted by grid-L1) [...] For fairness, we always use
the Pixlive measurements as position estimate if it is available." (004 sec. VI-E; [5] = Beck, Stoica and Li,
"Exact and approximate solutions of source localization problems", IEEE Trans. Signal Process. 56(5), 2008.)

Per window of ``window_s`` seconds (004 sec. III: every measurement is the median over a one-second window):

* **Ranges.** WiFi RTT: the median ``range_m`` per access point, readings whose WiFi RSSI (the optional
  ``rssi`` column of rtt.csv) is below ``min_wifi_rssi_dbm`` = -65 dBm dropped (004 sec. V-A; rows without an
  RSSI are kept). BLE: the median RSSI per beacon, readings below ``min_ble_rssi_dbm`` = -90 dBm dropped
  (sec. V-A), turned into a distance by the path-loss model ``d = d0 10^((a_X - rssi) / (10 gamma))`` as the
  weighted centroid does (a_X and gamma fitted on labelled data by the evaluation: :class:`PathLossCalibrated`).
  ``sources`` selects the modalities (default both, as the paper's "distance-based" comparison). A dataset
  without RTT uses its BLE ranges; one with neither usable raises :class:`MissingStream` with the reason.
* **Calibration** (``calibration``; 004 sec. V-B and VI-C): ``none``; ``offline`` -- a range offset per AP
  (median of measured minus true range) and a 1 m level a_X per beacon (median of ``rssi + 10 gamma
  log10(d / d0)``), from the labelled static sessions of the same building (``calibration_sessions``);
  ``online`` -- the same medians over the ``calib_window_s`` = 1 s after each visual fix, with the fix as the
  true position, used from then on (before the first fix: uncalibrated); ``calibration_modalities`` names the
  modalities corrected (default both, as 004; on simulated walks the 1 s BLE medians make online a_X noisy
  enough to hurt, which 004 Fig. 9 reports for some beacons too). Functions: :func:`rtt_offsets`,
  :func:`ble_levels`, :func:`online_corrections` (:mod:`~blenav.localizers.ranging_windows`).
* **Solver** (the class): grid-L2 ``argmin_y sum_m (d_m - ||y - a_m||)^2`` and grid-L1 ``argmin_y sum_m
  |d_m - ||y - a_m|||`` over the centres of the floor's free cells at ``grid_m`` = 0.5 m (the CRF's grid,
  004 sec. VI-D; 3-D distances with the device at ``device_z``); SRLS ``argmin_x sum_m (||x - a_m||^2 -
  d_m^2)^2`` exactly, by the generalized trust region subproblem of Beck et al. (:func:`srls`), in the
  horizontal plane with ``d_m^2 - (z_m - device_z)^2`` as the squared horizontal range (the same cost as the
  3-D one with the device's height fixed). A window needs ``min_ranges`` = 3 ranges (an estimate from fewer
  is a circle or two points, not a position).
* **Visual fixes**: a window with a fix in ``visual.csv`` takes the (last) fix as its estimate (``visual``;
  online calibration uses the fixes either way).

Estimates: one per window from the first with ranges or a fix to the last, stamped at the window's end
(``stamp: end``, as the centroid and the CRF) or at the time of its last reading (``stamp: last``: the estimate
is ready then, and a static survey scan is scored at its own time, not interpolated towards the next point);
a window without an estimate repeats the previous one, stamped at the window's end (``hold: false``: it has
no estimate; the evaluation then scores only the windows a method could localize -- used for static surveys,
where the previous window may be another point). Deterministic: every run
gets the same trajectory. Positions in world metres (the anchors' frame); no covariance.

"grid-L1": the paper describes it as "the median rather than mean distance error"; we read the name: the sum
of absolute residuals (an L1 cost, whose one-dimensional analogue is the median), which, unlike the median
of three to five residuals, uses every anchor.

Configs: ``conf/localizer/grid_l2.yaml``, ``grid_l1.yaml``, ``srls.yaml``. This module holds the localizers;
the readings, calibration and window ranges are in :mod:`blenav.localizers.ranging_windows`, the solvers in
:mod:`blenav.localizers.ranging_solvers`.
"""

from __future__ import annotations

import time

import numpy as np

from blenav.crf.calibration import CALIBRATIONS, offline_calibration
from blenav.crf.preprocess import BLE_MIN_RSSI_DBM, WIFI_MIN_RSSI_DBM
from blenav.errors import MissingStream
from blenav.filters.calibration import apply_fit
from blenav.filters.measurement import AnchorTable, PathLossRange

from .base import Estimate, Localizer, PathLossCalibrated, RunInputs
from .ranging_solvers import collinear_anchors, free_cells, grid_costs, srls
from .ranging_windows import (NO_ANCHORS, WindowRanges, ble_readings, correction_at, dist3, online_corrections,
                              rtt_readings, window_ranges)

__all__ = ["GridL2Localizer", "GridL1Localizer", "SrlsLocalizer", "RangeBaseline", "SOURCES"]

SOURCES = ("rtt", "ble")


class RangeBaseline(Localizer, PathLossCalibrated):
    """Shared part of the range baselines (module docstring): readings -> calibrated window ranges -> one
    solver per window (:meth:`solve`) -> visual override -> hold. Subclasses set ``solver``."""

    solver = "grid_l2"

    def __init__(self, name: str, shared=None, sources=("rtt", "ble"), window_s: float = 1.0, grid_m: float = 0.5,
                 min_ranges: int = 3, min_wifi_rssi_dbm: float | None = WIFI_MIN_RSSI_DBM,
                 min_ble_rssi_dbm: float | None = BLE_MIN_RSSI_DBM, calibration: str = "online",
                 calibration_sessions="auto", calib_window_s: float = 1.0, visual: bool = True,
                 a_x: float = -60.0, gamma: float = 2.25, d0: float = 1.0, use_anchor_tx_power: bool = True,
                 calibrated: bool = True, device_z: float = 1.2, stamp: str = "end", hold: bool = True,
                 calibration_modalities=("rtt", "ble")):
        super().__init__(name, shared)
        src = [sources] if isinstance(sources, str) else list(sources)
        bad = [s for s in src if s not in SOURCES]
        if bad or not src:
            raise ValueError(f"method {name!r}: sources must be a non-empty subset of {list(SOURCES)}, got {src}")
        if calibration not in CALIBRATIONS:
            raise ValueError(f"method {name!r}: calibration must be one of {CALIBRATIONS}, got {calibration!r}")
        if not window_s > 0 or not grid_m > 0 or not calib_window_s > 0:
            raise ValueError(f"method {name!r}: window_s, grid_m and calib_window_s must be > 0 "
                             f"(got {window_s}, {grid_m}, {calib_window_s})")
        if stamp not in ("end", "last"):
            raise ValueError(f"method {name!r}: stamp must be 'end' or 'last', got {stamp!r}")
        self.stamp, self.hold = stamp, bool(hold)
        cal_mod = ([calibration_modalities] if isinstance(calibration_modalities, str)
                   else list(calibration_modalities or []))
        if [c for c in cal_mod if c not in SOURCES]:
            raise ValueError(f"method {name!r}: calibration_modalities must be a subset of {list(SOURCES)}, got {cal_mod}")
        self.calibration_modalities = cal_mod
        if int(min_ranges) < 1:
            raise ValueError(f"method {name!r}: min_ranges must be >= 1, got {min_ranges}")
        self.sources, self.window_s, self.grid_m, self.min_ranges = src, float(window_s), float(grid_m), int(min_ranges)
        self.min_wifi_rssi_dbm = None if min_wifi_rssi_dbm is None else float(min_wifi_rssi_dbm)
        self.min_ble_rssi_dbm = None if min_ble_rssi_dbm is None else float(min_ble_rssi_dbm)
        self.calibration, self.calibration_sessions = calibration, calibration_sessions
        self.calib_window_s, self.visual, self.device_z = float(calib_window_s), bool(visual), float(device_z)
        self.path_loss = PathLossRange(a_x=a_x, gamma=gamma, d0=d0, device_z=device_z, max_range_m=np.inf,
                                       use_anchor_tx_power=use_anchor_tx_power, calibrated=calibrated)
        self.uses_floor_plan = self.solver != "srls"

    # PathLossCalibrated: BLE ranges use the fitted a_X, gamma (as the weighted centroid)
    def wants_path_loss_fit(self) -> bool:
        return "ble" in self.sources and self.path_loss.calibrated

    def apply_path_loss_fit(self, fit) -> None:
        apply_fit([self.path_loss], fit)

    # -------------------------------------------------------------------------------------- calibration data
    def _offline_sessions(self, session, inputs: RunInputs | None) -> list:
        """Labelled static sessions of ``session``'s building (``calibration_sessions``: 'auto' or ids), never
        ``session`` itself."""
        from blenav.data import Dataset

        root = session.root.parent.parent
        cache = inputs.cache if inputs is not None else {}
        key = ("ranging-dataset", str(root))
        if key not in cache:
            cache[key] = Dataset.open(root)
        ds = cache[key]
        spec = self.calibration_sessions
        if spec in (None, "auto"):
            cand = [s for s in ds.sessions(labelled=True) if s.carrier == "static"
                    and s.building.id == session.building.id and s.id != session.id]
        else:
            ids = [spec] if isinstance(spec, str) else [str(i) for i in spec]
            cand = [s for s in ds.sessions(ids) if s.id != session.id] if ids else []
        return cand

    def _corrections(self, session, inputs, wr: WindowRanges, rtt, ble, notes: list):
        """(W, A_rtt) RTT offsets (m) and (W, A_ble) BLE 1 m levels (dBm) in force at each window."""
        (tr, ir, rr, ar), (tb, ib, sb, ab) = rtt, ble
        W = len(wr.t_stamp)
        off_base = np.zeros(len(ar.ids))
        ax_base = self.path_loss._ax() if len(ab.ids) else np.zeros(0)
        gamma, d0 = self.path_loss.gamma, self.path_loss.d0
        do_rtt, do_ble = "rtt" in self.calibration_modalities, "ble" in self.calibration_modalities
        if self.calibration == "offline" and (do_rtt or do_ble):
            cal = self._offline_sessions(session, inputs)
            if not cal:
                raise MissingStream(f"offline calibration needs labelled static sessions of building "
                                    f"{session.building.id} besides {session.id} (calibration_sessions="
                                    f"{self.calibration_sessions!r}); none found")
            c = offline_calibration(cal, ar if do_rtt else NO_ANCHORS, ab if do_ble else NO_ANCHORS, gamma,
                                    self.min_ble_rssi_dbm, self.min_wifi_rssi_dbm, device_z=self.device_z, d0=d0)
            if len(ar.ids) and do_rtt:
                off_base = np.where(np.isfinite(c.rtt_offset), c.rtt_offset, 0.0)
            if len(ab.ids) and do_ble:
                ax_base = np.where(np.isfinite(c.ble_tx), c.ble_tx, ax_base)
            notes.append(f"offline calibration on {', '.join(s.id for s in cal)}")
        off = np.broadcast_to(off_base, (W, len(off_base))).copy()
        axw = np.broadcast_to(ax_base, (W, len(ax_base))).copy()
        if self.calibration == "online":
            vis = session.visual
            ft, fxy = vis["t"].to_numpy(float), vis[["x", "y"]].to_numpy(float)
            z = self.device_z
            if len(ar.ids) and do_rtt:
                ta, c = online_corrections(ft, fxy, tr, ir, rr,
                                           lambda v, i, xy: v - dist3(xy, z, ar.xyz[i]), len(ar.ids), self.calib_window_s)
                off = correction_at(wr.t_stamp, off_base, ta, c)
            if len(ab.ids) and do_ble:
                ta, c = online_corrections(
                    ft, fxy, tb, ib, sb,
                    lambda v, i, xy: v + 10.0 * gamma * np.log10(np.maximum(dist3(xy, z, ab.xyz[i]), 0.1) / d0),
                    len(ab.ids), self.calib_window_s)
                axw = correction_at(wr.t_stamp, ax_base, ta, c)  # before a beacon's first: the configured / fitted a_X
            notes.append(f"online calibration at {len(ft)} visual fix(es)" if len(ft) else
                         f"{session.id}: no visual fix, so no online calibration (ranges uncalibrated)")
        return off, axw

    # -------------------------------------------------------------------------------------- run
    def run(self, session, n_runs: int, seed: int, inputs: RunInputs | None = None) -> Estimate:
        t_start = time.perf_counter()
        notes: list[str] = []
        empty_rtt = (np.zeros(0), np.zeros(0, int), np.zeros(0),
                     AnchorTable(np.zeros(0, str), np.zeros((0, 3)), np.zeros(0)))
        empty_ble = empty_rtt
        n_weak = 0
        rtt = empty_rtt
        if "rtt" in self.sources:
            tr, ir, rr, ar, n_weak = rtt_readings(session, self.min_wifi_rssi_dbm)
            rtt = (tr, ir, rr, ar)
        ble = empty_ble
        if "ble" in self.sources:
            ble = ble_readings(session, self.min_ble_rssi_dbm)
            self.path_loss.bind(ble[3])
        why = []
        if "rtt" in self.sources and not len(rtt[0]):
            why.append("no RTT range of an AP with a known position" + (
                f" at or above {self.min_wifi_rssi_dbm:g} dBm" if n_weak else ""))
        if "ble" in self.sources and not len(ble[0]):
            why.append("no BLE reading of a beacon with a known position"
                       + (f" at or above {self.min_ble_rssi_dbm:g} dBm" if self.min_ble_rssi_dbm is not None else ""))
        if not len(rtt[0]) and not len(ble[0]):
            raise MissingStream(f"session {session.id}: " + "; ".join(why))
        if why:
            notes.append(f"{session.id}: " + "; ".join(why) + " (ranges from the other modality only)")
        if n_weak:
            notes.append(f"{session.id}: {n_weak} RTT ranges below {self.min_wifi_rssi_dbm:g} dBm dropped (004 V-A)")
        vis = session.visual if self.visual else None
        vt = vis["t"].to_numpy(float) if vis is not None else np.zeros(0)
        vxy = vis[["x", "y"]].to_numpy(float) if vis is not None else np.zeros((0, 2))
        (tr, ir, rr, ar), (tb, ib, sb, ab) = rtt, ble
        # windows over the raw readings (RSSI medians for BLE: the distance is monotone in the RSSI)
        wr = window_ranges([tr, tb], [ir, ib], [rr, sb], [ar.xyz, ab.xyz], ["rtt", "ble"], vt, vxy, self.window_s)
        off, axw = self._corrections(session, inputs, wr, rtt, ble, notes)
        nr = len(ar.ids)
        d = wr.d.copy()
        d[:, :nr] -= off
        if len(ab.ids):
            d[:, nr:] = self.path_loss.d0 * 10.0 ** ((axw - d[:, nr:]) / (10.0 * self.path_loss.gamma))
        xy = self.solve(session, inputs, wr.anchors, d)
        enough = np.isfinite(d).sum(axis=1) >= self.min_ranges
        xy[~enough] = np.nan
        if self.visual:
            hv = np.isfinite(wr.visual[:, 0])
            xy[hv] = wr.visual[hv]
        good = np.isfinite(xy).all(axis=1)
        if not good.any():
            raise MissingStream(f"session {session.id}: no window with {self.min_ranges} or more ranges or a visual fix")
        first = int(np.argmax(good))
        last = np.maximum.accumulate(np.where(good, np.arange(len(good)), -1))[first:]
        xy = xy[first:][last - first]
        stamp = wr.t_stamp[first:]
        held = ~good[first:]
        ends = wr.t0 + (wr.window[first:] + 1) * self.window_s
        stamp = np.where(held | (self.stamp == "end"), ends, stamp)
        stamp = np.maximum.accumulate(stamp)  # a held window's end can pass the next window's first reading only by 0
        if not self.hold:
            xy, stamp = xy[~held], stamp[~held]
        notes.append(f"{session.id}: {int((~held).sum())} of {len(held)} windows localized "
                     f"({'the others hold the previous estimate' if self.hold else 'the others have no estimate'})")
        pos = np.broadcast_to(xy, (n_runs,) + xy.shape).copy()
        return Estimate(self.name, session.id, stamp, pos, None, [], {}, n_runs * (time.perf_counter() - t_start), notes)

    def solve(self, session, inputs, anchors: np.ndarray, d: np.ndarray) -> np.ndarray:
        """(W, 2) estimates from ranges ``d`` (W, A) m (NaN = none) to ``anchors`` (A, 3) m."""
        raise NotImplementedError


class _GridBaseline(RangeBaseline):
    loss = "l2"

    def solve(self, session, inputs, anchors, d):
        cells = free_cells(session.floor, self.grid_m, inputs.cache if inputs is not None else None)
        if not len(cells):
            raise MissingStream(f"floor {session.floor.id} of {session.building.id} has no free cell at {self.grid_m:g} m")
        best = grid_costs(cells, anchors, d, self.device_z, self.loss)
        xy = np.full((len(d), 2), np.nan)
        ok = best >= 0
        xy[ok] = cells[best[ok]]
        return xy


class GridL2Localizer(_GridBaseline):
    """grid-L2 (004 sec. VI-E; Beck et al.'s range least squares, RLS, by grid search): the free cell that
    minimises the sum of squared range residuals. Config ``conf/localizer/grid_l2.yaml``."""

    solver, loss = "grid_l2", "l2"


class GridL1Localizer(_GridBaseline):
    """grid-L1 (004 sec. VI-E): the free cell that minimises the sum of absolute range residuals (the paper's
    "median rather than mean distance error"; see the module docstring). Config ``conf/localizer/grid_l1.yaml``."""

    solver, loss = "grid_l1", "l1"


class SrlsLocalizer(RangeBaseline):
    """SRLS (004 sec. VI-E; Beck, Stoica and Li 2008): the exact squared-range least-squares position
    (:func:`srls`), in the horizontal plane at height ``device_z``; not confined to the floor plan. Config
    ``conf/localizer/srls.yaml``."""

    solver = "srls"

    def solve(self, session, inputs, anchors, d):
        r2 = d * d - (anchors[None, :, 2] - self.device_z) ** 2
        # a negative range (Android reports some) squared would pretend a distance: such ranges count as 0
        r2 = np.where(np.isfinite(d) & (d < 0), 0.0, r2)
        x = srls(anchors[:, :2], r2)
        # collinear anchors: the mirror image across their line is as good; take the one on free space
        a = np.broadcast_to(anchors[:, :2], (len(d),) + anchors[:, :2].shape)
        col, c, u = collinear_anchors(a, np.isfinite(r2))
        col &= np.isfinite(x).all(axis=1)
        if col.any():
            rel = x[col] - c[col]
            mirror = c[col] + 2.0 * (rel * u[col]).sum(1, keepdims=True) * u[col] - rel
            floor = session.floor
            swap = ~floor.is_free(x[col]) & floor.is_free(mirror)
            idx = np.flatnonzero(col)[swap]
            x[idx] = mirror[swap]
        return x
