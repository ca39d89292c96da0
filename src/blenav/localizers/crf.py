"""The multi-modal CRF localizer of Duembgen et al. (004): WiFi RTT + BLE RSSI + IMU steps + visual fixes on
a 0.5 m grid, solved step by step with Viterbi (:mod:`blenav.crf`).

Per window of ``window_s`` (1 s) from the session's first sample:

1. pre-processing (004 sec. V-A, :mod:`blenav.crf.preprocess`): medians per anchor, BLE below
   ``ble_min_rssi_dbm`` (-90 dBm) dropped, RTT dropped when the AP's WiFi RSSI (optional ``rssi`` column
   of rtt.csv) is below ``rtt_min_wifi_rssi_dbm`` (-65 dBm);
2. calibration (004 sec. V-B, :mod:`blenav.crf.calibration`): ``none`` / ``offline`` (labelled static
   survey sessions of the same building in the dataset; none there: the session is skipped with the reason)
   / ``online`` (at each visual fix, from the following second; needs visual.csv);
3. features (004 sec. IV-A, :mod:`blenav.crf.features`), switched by ``modalities`` (lambda in {0, 1}):
   RTT (eq. 6, ``rtt_sigma_m``), BLE (eqs. 11-12, ``ble_sigma_db``, path-loss exponent
   ``ble_path_loss_exponent``, T_m from anchors.csv or ``ble_tx_power_dbm``), IMU (eqs. 13-14: steps of
   the project's detector times ``step_length_m`` along the AHRS heading, summed per window;
   ``imu_sigma_l_m``, ``imu_sigma_theta_rad``); without IMU the transition is uniform over the cells
   reachable in one step (``max_step_m``);
4. visual fixes (``use_visual``) reset the map to eq. 15 (``visual_sigma_m`` = 0.05 m) in every row,
   as in 004 (their position is the estimate at that step);
5. Viterbi with pruning at ``prune`` (1e-10), the argmax per step (eq. 16), and the backtracked track
   ("CRF recursive", sec. IV-B) under ``outputs['smoothed']``; ``recursive: true`` reports that track as
   the method's position.

Deterministic: all R runs are the same estimate (as the weighted centroid). Estimates at the window ends
(s), world x, y (m), no covariance. Where the map holds no absolute information yet (the start of an
IMU-only walk before the first visual fix), the maximum is shared by many cells: the estimate is the mean of
the tied cells (a careful choice where 004 says nothing).

Rows that need a stream the session lacks raise :class:`MissingStream` (RTT: rtt.csv and WiFi RTT anchors;
BLE: rssi.csv and BLE anchors; IMU: imu.csv; online: visual.csv; offline: static survey sessions).

Config: ``conf/localizer/crf.yaml`` (CRF) and ``conf/localizer/crf_recursive.yaml`` (CRF recursive).
"""

from __future__ import annotations

import time

import numpy as np

from blenav.crf.calibration import (CALIBRATIONS, Calibration, CalibrationTrack, offline_calibration, online_track,
                                    static_sessions)
from blenav.crf.features import cell_anchor_distances, rssi_log_feature, rtt_log_feature, visual_log_feature
from blenav.crf.grid import build_grid
from blenav.crf.preprocess import (BLE_MIN_RSSI_DBM, WIFI_MIN_RSSI_DBM, anchor_tables, preprocess, session_span,
                                   window_count)
from blenav.crf.viterbi import ViterbiDecoder
from blenav.errors import MissingStream
from blenav.filters.attitude import AttitudeConfig, estimate_attitude, yaw_of_device_forward
from blenav.filters.steps import StepDetectorConfig, step_flags
from blenav.limits import check_range

from .base import Estimate, Localizer, RunInputs

__all__ = ["CrfLocalizer", "MODALITIES", "parse_modalities"]

MODALITIES = ("RTT", "BLE", "IMU")


def parse_modalities(spec) -> frozenset:
    """'RTT+BLE+IMU' or a list -> frozenset of MODALITIES (order and case free)."""
    items = spec.split("+") if isinstance(spec, str) else list(spec)
    mods = frozenset(str(m).strip().upper() for m in items if str(m).strip())
    bad = sorted(mods - set(MODALITIES))
    if bad or not mods:
        raise ValueError(f"modalities {spec!r}: need one or more of {'+'.join(MODALITIES)} (unknown: {bad})")
    return mods


def _schema(cls, *nodes):
    from omegaconf import OmegaConf

    merged = OmegaConf.merge(OmegaConf.structured(cls), *[n for n in nodes if n is not None])
    return OmegaConf.to_object(merged)


class CrfLocalizer(Localizer):
    """Linear-chain CRF on a grid solved with Viterbi (004); see the module docstring for the settings."""

    def __init__(self, name: str, shared=None, modalities="RTT+BLE+IMU", calibration: str = "online",
                 recursive: bool = False, use_visual: bool = True, cell_m: float = 0.5, max_step_m: float = 2.0,
                 min_free_fraction: float = 0.5, window_s: float = 1.0, prune: float = 1e-10,
                 device_z: float = 1.2, rtt_sigma_m: float = 1.0,
                 rtt_min_wifi_rssi_dbm: float | None = WIFI_MIN_RSSI_DBM,
                 ble_sigma_db: float = 6.0, ble_path_loss_exponent: float = 2.0, ble_tx_power_dbm: float = -60.0,
                 ble_min_rssi_dbm: float | None = BLE_MIN_RSSI_DBM, ble_mode_correction: bool = True,
                 step_length_m: float = 0.7, imu_sigma_l_m: float = 0.5, imu_sigma_theta_rad: float = 0.3,
                 visual_sigma_m: float = 0.05, calibration_window_s: float = 1.0,
                 calibrate_heading: bool = True, calibration_pool: bool = False, attitude=None, steps=None):
        super().__init__(name, shared)
        self.modalities = parse_modalities(modalities)
        if calibration not in CALIBRATIONS:
            raise ValueError(f"method {name!r}: calibration must be one of {CALIBRATIONS}, got {calibration!r}")
        for k, v in {"cell_m": cell_m, "window_s": window_s, "rtt_sigma_m": rtt_sigma_m, "ble_sigma_db": ble_sigma_db,
                     "step_length_m": step_length_m, "imu_sigma_l_m": imu_sigma_l_m,
                     "imu_sigma_theta_rad": imu_sigma_theta_rad, "visual_sigma_m": visual_sigma_m,
                     "ble_path_loss_exponent": ble_path_loss_exponent,
                     "calibration_window_s": calibration_window_s}.items():
            if not float(v) > 0:
                raise ValueError(f"method {name!r}: {k} must be > 0, got {v}")
        if not 0 <= float(prune) < 1:
            raise ValueError(f"method {name!r}: prune must be in [0, 1), got {prune}")
        # the grid's and the windows' sizes come from the config: bounded (blenav.limits) before a grid is built
        for k, v, rng in (("cell_m", cell_m, "cell_m"), ("max_step_m", max_step_m, "max_step_m"),
                          ("window_s", window_s, "window_s"), ("calibration_window_s", calibration_window_s, "window_s")):
            check_range(v, rng, f"method {name!r}", field=k)
        self.calibration, self.recursive, self.use_visual = calibration, bool(recursive), bool(use_visual)
        self.cell_m, self.max_step_m, self.min_free_fraction = float(cell_m), float(max_step_m), float(min_free_fraction)
        self.window_s, self.prune, self.device_z = float(window_s), float(prune), float(device_z)
        self.rtt_sigma_m, self.rtt_min_wifi_rssi_dbm = float(rtt_sigma_m), rtt_min_wifi_rssi_dbm
        self.ble_sigma_db, self.ble_n, self.ble_tx_default = float(ble_sigma_db), float(ble_path_loss_exponent), \
            float(ble_tx_power_dbm)
        self.ble_min_rssi_dbm, self.ble_mode_correction = ble_min_rssi_dbm, bool(ble_mode_correction)
        self.step_length_m, self.sigma_l, self.sigma_theta = float(step_length_m), float(imu_sigma_l_m), \
            float(imu_sigma_theta_rad)
        self.visual_sigma_m, self.cal_window_s = float(visual_sigma_m), float(calibration_window_s)
        self.calibrate_heading, self.calibration_pool = bool(calibrate_heading), bool(calibration_pool)
        shared = shared or {}
        try:
            self.attitude = _schema(AttitudeConfig, shared.get("attitude") if hasattr(shared, "get") else None, attitude)
            self.steps = _schema(StepDetectorConfig, steps)
        except Exception as exc:
            raise ValueError(f"method {name!r}, attitude/steps: {exc}") from exc

    # ------------------------------------------------------------------ inputs
    def _check_streams(self, session) -> None:
        wifi, ble = anchor_tables(session.building, session.meta.get("floor"))
        if "RTT" in self.modalities:
            if not len(wifi.ids):
                raise MissingStream(f"building {session.building.id} has no WiFi RTT access point with a known "
                                    f"position (RTT rows of {self.name})")
            if not session.has("rtt"):
                raise MissingStream(f"session {session.id} has no RTT ranges (rtt.csv absent or empty), which "
                                    f"{self.name} needs")
        if "BLE" in self.modalities:
            if not len(ble.ids):
                raise MissingStream(f"building {session.building.id} has no BLE beacon with a known position")
            if not session.has("rssi"):
                raise MissingStream(f"session {session.id} has no BLE readings (rssi.csv absent or empty), which "
                                    f"{self.name} needs")
        if "IMU" in self.modalities and not session.has("imu"):
            raise MissingStream(f"session {session.id} has no IMU data (imu.csv), which {self.name} needs")
        if self.calibration == "online" and not session.has("visual"):
            raise MissingStream(f"session {session.id} has no visual fixes (visual.csv absent or empty): online "
                                f"calibration of {self.name} calibrates at visual fixes (004 sec. V-B)")

    def _grid(self, session, inputs: RunInputs | None):
        key = ("crf-grid", session.building.id, str(session.meta.get("floor")), self.cell_m, self.max_step_m,
               self.min_free_fraction)
        cache = inputs.cache if inputs is not None else {}
        if key not in cache:
            cache[key] = build_grid(session.floor, self.cell_m, self.max_step_m, self.min_free_fraction)
        return cache[key]

    def _imu(self, session, inputs: RunInputs | None):
        """(step times (S,) s, step AHRS yaw (S,) rad, IMU times (T,), AHRS yaw (T,), q (T, 4)) of the session."""
        key = ("crf-imu", session.id, repr(self.attitude), repr(self.steps))
        cache = inputs.cache if inputs is not None else {}
        if key not in cache:
            # imu_features' AHRS and its step detector, the latter compiled (blenav.filters.steps.step_flags: same flags)
            c = np.ascontiguousarray
            imu, mag = session.imu, session.mag
            imu_t = c(imu["t"].to_numpy(float))
            acc = c(imu[["ax", "ay", "az"]].to_numpy(float))
            q = estimate_attitude(imu_t, acc, c(imu[["gx", "gy", "gz"]].to_numpy(float)),
                                  c(mag["t"].to_numpy(float)) if len(mag) else None,
                                  c(mag[["mx", "my", "mz"]].to_numpy(float)) if len(mag) else None, self.attitude)
            dt = np.diff(imu_t)
            dt = dt[dt > 0]
            flags = step_flags(imu_t, acc, self.steps, 1.0 / np.median(dt) if len(dt) else 100.0)
            yaw = yaw_of_device_forward(q)
            cache[key] = (imu_t[flags], yaw[flags], imu_t, yaw, q)
        return cache[key]

    def _offline(self, session, inputs, wifi, ble):
        # per session: the static sessions are those of the building other than the session itself
        key = ("crf-offline", str(session.root.parent.parent), session.id, self.ble_n, self.ble_min_rssi_dbm,
               self.rtt_min_wifi_rssi_dbm)
        cache = inputs.cache if inputs is not None else {}
        if key not in cache:
            stat = static_sessions(session, cache)
            cache[key] = (offline_calibration(stat, wifi, ble, self.ble_n, self.ble_min_rssi_dbm,
                                              self.rtt_min_wifi_rssi_dbm) if stat else None, [s.id for s in stat])
        return cache[key]

    def _unary(self, k, rtt_d, ranges, ble_ld, ble, ble_tx):
        """The unary log features of window k (eqs. 6, 12) as a function of the cells they are needed on, or None."""
        parts = []
        if rtt_d is not None:
            ok = np.isfinite(ranges[k])
            if ok.any():
                parts.append((rtt_d, ok, lambda d, ok=ok: rtt_log_feature(d, ranges[k][ok], self.rtt_sigma_m)))
        if ble_ld is not None:
            ok = np.isfinite(ble[k]) & np.isfinite(ble_tx)
            if ok.any():
                parts.append((ble_ld, ok, lambda ld, ok=ok: rssi_log_feature(ld, ble[k][ok], ble_tx[ok], self.ble_n,
                                                                         self.ble_sigma_db, self.ble_mode_correction)))
        if not parts:
            return None

        def unary(cells):
            return sum(f(m[np.ix_(cells, ok)]) for m, ok, f in parts)

        return unary

    # ------------------------------------------------------------------ run
    def run(self, session, n_runs: int, seed: int, inputs: RunInputs | None = None) -> Estimate:
        t0 = time.perf_counter()
        self._check_streams(session)
        wifi, ble = anchor_tables(session.building, session.meta.get("floor"))
        notes: list[str] = []
        grid = self._grid(session, inputs)
        t_first, t_last = session_span(session)
        K = window_count(t_first, t_last, self.window_s)
        radio = preprocess(session, t_first, K, self.window_s, self.ble_min_rssi_dbm, self.rtt_min_wifi_rssi_dbm,
                           wifi, ble)
        if "RTT" in self.modalities:
            notes += radio.notes
        ble_prior = np.where(np.isfinite(ble.tx_power_dbm), ble.tx_power_dbm, self.ble_tx_default)
        base = Calibration.empty(len(wifi.ids), len(ble.ids))
        if self.calibration == "offline":
            cal, ids = self._offline(session, inputs, wifi, ble)
            if cal is None:
                raise MissingStream(f"offline calibration of {self.name} needs labelled static points (sessions with "
                                    f"carrier: static in building {session.meta.get('building')}); the dataset has none")
            base = cal
            notes.append(f"offline calibration from static session(s) {', '.join(ids)}")
        track = CalibrationTrack.constant(base, ble_prior)
        imu = self._imu(session, inputs) if "IMU" in self.modalities else None
        vis = session.visual if session.has("visual") else None
        if self.calibration == "online":
            fixes = vis[["t", "x", "y", "z", "yaw"]].to_numpy(float)
            rtt_raw = radio.rtt_raw if "RTT" in self.modalities else None
            rssi_raw = radio.ble_raw if "BLE" in self.modalities else None
            yaw = (imu[2], imu[3]) if imu is not None else None
            track = online_track(track, fixes, wifi, ble, self.ble_n, rtt_raw, rssi_raw, yaw, self.cal_window_s,
                                 calibrate_heading=self.calibrate_heading, pool=self.calibration_pool)
        rows = track.rows(radio.t)  # the parameters valid at each window's end
        # ---- per-window inputs
        use_rtt, use_ble, use_imu = ("RTT" in self.modalities), ("BLE" in self.modalities), ("IMU" in self.modalities)
        rtt_d = cell_anchor_distances(grid.xy, self.device_z, wifi.xyz) if use_rtt else None
        ble_ld = np.log(cell_anchor_distances(grid.xy, self.device_z, ble.xyz)) if use_ble else None
        ranges = radio.rtt - track.rtt_offset[rows] if use_rtt else None
        if use_imu:
            st, syaw = imu[0], imu[1]
            syaw = syaw + track.heading_offset[track.rows(st)]
            w = np.floor((st - t_first) / self.window_s).astype(np.int64)
            ok = (w >= 0) & (w < K)
            vx = np.bincount(w[ok], weights=self.step_length_m * np.cos(syaw[ok]), minlength=K)
            vy = np.bincount(w[ok], weights=self.step_length_m * np.sin(syaw[ok]), minlength=K)
            n_steps = np.bincount(w[ok], minlength=K)
            step_len = np.hypot(vx, vy)
            step_dir = np.arctan2(vy, vx)
        reset_at: dict[int, np.ndarray] = {}
        if self.use_visual and vis is not None and len(vis):
            vw = np.floor((vis["t"].to_numpy(float) - t_first) / self.window_s).astype(np.int64)
            for k, x, y in zip(vw, vis["x"].to_numpy(float), vis["y"].to_numpy(float)):
                if 0 <= k < K:
                    reset_at[int(k)] = np.array([x, y])  # the last fix of a window wins
        # ---- Viterbi
        dec = ViterbiDecoder(grid, self.prune, self.sigma_l, self.sigma_theta)
        est = np.empty((K, 2))
        for k in range(K):
            reset = None
            unary = None
            if k in reset_at:
                reset = visual_log_feature(grid.xy, reset_at[k], self.visual_sigma_m)
            else:
                unary = self._unary(k, rtt_d, ranges, ble_ld, radio.ble, track.ble_tx[rows[k]])
            step_imu = (float(step_len[k]), float(step_dir[k]), bool(n_steps[k] > 0)) if use_imu else None
            best = dec.step(unary, step_imu, reset)
            s = dec.score
            tied = s >= s[best] - 1e-9
            est[k] = grid.xy[tied].mean(axis=0) if tied.sum() > 1 else grid.xy[best]
        smoothed = grid.xy[dec.backtrack()]
        pos = smoothed if self.recursive else est
        wall = time.perf_counter() - t0
        outputs = {"smoothed": np.broadcast_to(smoothed, (n_runs, K, 2)).copy()}
        if self.calibration == "online":
            outputs["calibration"] = {"t": track.t_avail, "rtt_offset_m": track.rtt_offset,
                                      "ble_tx_dbm": track.ble_tx, "heading_offset_rad": track.heading_offset}
        outputs["active_cells"] = np.asarray(dec.active)
        return Estimate(self.name, session.id, radio.t, np.broadcast_to(pos, (n_runs, K, 2)).copy(), None, [], outputs,
                        wall * n_runs, notes)
