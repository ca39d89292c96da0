"""The radio-inertial factor graph of Ghaffari Jadidi et al. (000, sec. III Problem 3, sec. IV-D, Fig. 2) on GTSAM.

Variables (keys from ``gtsam.symbol_shorthand``), one set per keyframe k at the front-end's update rate:

* ``X(k)``: device pose, ``gtsam.Pose3`` (device frame -> world ENU, metres);
* ``V(k)``: velocity in the world frame, (3,) m/s;
* ``B(k)``: IMU bias, ``gtsam.imuBias.ConstantBias`` (accelerometer m/s^2, gyroscope rad/s);
* ``L(j)``: position of BLE beacon j (row j of the anchor table), ``Point3`` world m.
* ``O(0)``, ``E(0)`` (``range.estimate_offset`` / ``estimate_exponent``): the receiver's RSSI offset (dB) and the
  channel's path-loss exponent over the ranges' (:mod:`blenav.backend.channel_vars`), one each for the session.

Factors, the terms of the MAP problem eq. (3) of 000, X* = argmin ||r_0||^2_{Sigma_0} + ||r_{0:T}||^2_{Sigma_r}:

* ``CombinedImuFactor(X(k-1), V(k-1), X(k), V(k), B(k-1), B(k))``: GTSAM's on-manifold preintegration
  (Forster et al., ref. [2] of 000) of every IMU sample between the keyframes, with the bias random walk
  (noise densities and gravity from :class:`~blenav.backend.config.ImuConfig`);
* ``RangeFactor3D(X(k), L(j), r)``: range r = d0 10^((a_X - rssi) / (10 gamma)) from an RSSI reading, the
  conversion and 10 m clamp of PF-PL (:class:`blenav.filters.measurement.PathLossRange`, 000 sec. IV-B),
  noise sigma_n = 5 m (000 Table I) inside a robust kernel (Huber or Cauchy) against NLOS ranges. Each
  range belongs to the keyframe nearest its time. Two departures from 000's "does not discard any
  measurements", both configurable (``range.gate_m``, ``range.combine``) and measured on the simulated
  384 s office (accurate map, LM at 2 Hz keyframes; front-end 3.44 m): every range as its own factor,
  smoothed 3.81 m, beacons pulled 2.67 m off their (true) priors; gate (7 m) + median, 1.36 m and 0.29 m
  (the defaults, 5 m gate at 10 Hz keyframes: 1.53 m and 0.44 m).
  (i) a validation gate: a range is used only when the beacon's position (prior, or the previous pass's
  estimate) lies within ``gate_m`` of the keyframe's (front-end, or previous pass's) position. The 10 m
  clamp keeps a far beacon's reading only when it came out short (-5 m on average beyond 6 m), so ungated
  ranges pull every beacon towards the walked path; the gate selects on the *predicted* distance, not on
  the noisy measured one (selecting the shortest ranges per keyframe selects on the noise: -2.7 m);
  (ii) one factor per beacon and keyframe with the median of its ranges (their shadowing is correlated over
  a keyframe, so the sum of per-reading factors would overstate what they know);
* ``PriorFactorPoint3(L(j))``: the map's stated uncertainty of each beacon (anchors.csv ``std_m``, else a
  configured sigma), so every landmark is determined even when it is heard once;
* ``PoseRotationPrior3D(X(k))``: the AHRS orientation (accelerometer + magnetometer heading) as a soft
  prior, isotropic sigma;
* ``PoseTranslationPrior3D(X(k))`` on the world z (x, y sigmas 1 km): the receiver's height above the
  floor, which a walk keeps within decimetres (the IMU alone lets z drift); optionally
  (``priors.front_end_sigma_m``, off by default as in 000) also x, y around the front-end's estimate;
* priors on X(0), V(0), B(0) around the front-end's first estimate (Fig. 2 initialisation).

Initial values come from the front-end (Fig. 2): positions (K, 2) and velocities, and the AHRS attitude.

Solvers: iSAM2 (online, one ``update`` per ``solver.update_every`` keyframes, the paper's choice) or
Levenberg-Marquardt (offline batch, ``solver.passes`` passes, each after the first re-gating the ranges with
the previous solution), :class:`~blenav.backend.config.Solver`. Cholesky by default, QR on request or when
Cholesky fails (LM); beacon covariances from one iSAM2 elimination at the solution.

Failures never reach the caller: :func:`smooth` returns a :class:`BackendResult` whose ``failures`` name
the key (``describe_key``: 'beacon ble-003 (l3)', 'pose of keyframe 17 at t=1.80 s (x17)') GTSAM's
``IndeterminantLinearSystemException`` (a ``RuntimeError`` in Python) points at. A failed iSAM2 update
hands the whole session to batch LM with QR (noted); where no estimate exists at all, the trajectory keeps
the front-end's values. Guards before solving: every beacon variable has a prior; a beacon with fewer than
``range.min_ranges`` ranges keeps no range factor (its ranges are buffered, online, until it has enough;
reported); non-finite inputs are dropped (reported); initial velocities are clipped to ``init.max_speed_mps``
(reported); a keyframe interval without IMU samples is bridged by holding the last sample (reported).

Layout: the graph (:class:`RadioInertialGraph`) and :func:`smooth` here; inputs and result types in
:mod:`blenav.backend.graph_types`, the factors' pieces in :mod:`blenav.backend.factors`.
"""

from __future__ import annotations

import time

import numpy as np
import pandas as pd

from blenav.filters.quaternions import quat_to_matrix

from .config import BackendConfig, ChannelRefit, Solver
from .factors import (load_gtsam, nearest_keyframe, odometry_factor, odometry_increments, preintegrate,
                      preintegration_params, robust_noise, select_ranges)
from .channel import channel_of, refit_ranges
from .channel_vars import ChannelVariables
from .graph_types import (BackendFailure, BackendResult, BeaconPriors, ImuSamples, Keyframes, OdometryTrack, RangeObs,
                          describe_key, first_line, symbol_in)

__all__ = ["RadioInertialGraph", "smooth"]


# ------------------------------------------------------------------------------------------------ the graph
class RadioInertialGraph:
    """Builds the factors of each keyframe (:meth:`keyframe_factors`) for either solver.

    Noise models are built once, each named for what it models (units in comments)."""

    def __init__(self, cfg: BackendConfig, kf: Keyframes, imu: ImuSamples, ranges: RangeObs, beacons: BeaconPriors,
                 beacon_init: np.ndarray | None = None, pims: list | None = None, offset_prior_db: float = 0.0,
                 offset_init_db: float | None = None, cloud: Keyframes | None = None,
                 odometry: OdometryTrack | None = None, exponent_prior: float | None = None,
                 exponent_init: float | None = None):
        """``beacon_init`` (A, 3) world m: initial beacon positions, also used by the range gate (default: the
        prior means; a second pass gives the first pass's estimate); ``pims``: the preintegrated IMU of these
        keyframe times, when already computed (a second pass); ``offset_prior_db`` / ``offset_init_db``: prior
        mean and initial value of the receiver offset (``range.estimate_offset``); ``cloud``: the keyframes whose
        positions and ``cov`` are the front-end's (``priors.front_end_cloud``; default ``kf``; a second pass gives
        the first pass's input, so the prior stays the filter's, not the previous solution's); ``odometry``: a learned
        inertial odometry's track, its displacements between keyframes as between-factors (``odometry.enabled``);
        ``exponent_prior`` / ``exponent_init``: prior mean and initial value of the channel's path-loss exponent
        (``range.estimate_exponent``; None: the ranges' own)."""
        gtsam = load_gtsam()
        self.gtsam = gtsam
        self.cfg, self.kf, self.beacons = cfg, kf, beacons
        self.cloud = kf if cloud is None else cloud
        self.beacon_init = np.asarray(beacons.xyz if beacon_init is None else beacon_init, float)
        if cfg.range.estimate_offset and ranges.gamma is None:
            raise ValueError("range.estimate_offset needs the path-loss exponent of the ranges (RangeObs.gamma)")
        self.channel = ChannelVariables(cfg.range, ranges.gamma, offset_prior_db, offset_init_db, exponent_prior,
                                        exponent_init) if cfg.range.estimate_offset else None
        self.odo = None if odometry is None or not cfg.odometry.enabled else \
            odometry_increments(odometry, kf.t, cfg.odometry)  # (d, var, ok) per keyframe
        self.notes: list[str] = []
        self.failures: list[BackendFailure] = []
        K = len(kf.t)
        pr, rc = cfg.priors, cfg.range
        nm = gtsam.noiseModel
        # --- noise models
        self.range_noise = robust_noise(rc.robust, rc.robust_k, rc.sigma_n)  # m
        dt_kf = float(np.median(np.diff(kf.t))) if K > 1 else 1.0
        inflate = np.sqrt(max(pr.attitude_corr_s / dt_kf, 1.0))  # correlated AHRS errors: one prior per corr_s
        self.attitude_noise = nm.Isotropic.Sigma(3, np.deg2rad(pr.attitude_sigma_deg) * inflate)  # rad
        # world-frame position prior per keyframe: z around the receiver height, x, y free (1 km) or around the
        # front-end's estimate (priors.front_end_sigma_m, inflated for its correlated errors like the attitude)
        xy_sigma = 1e3 if pr.front_end_sigma_m is None else pr.front_end_sigma_m * np.sqrt(
            max(pr.front_end_corr_s / dt_kf, 1.0))
        z_sigma = 1e3 if pr.height_sigma_m is None else pr.height_sigma_m
        self.height_noise = (None if pr.height_sigma_m is None and pr.front_end_sigma_m is None
                             else nm.Diagonal.Sigmas(np.array([xy_sigma, xy_sigma, z_sigma])))  # m
        # the filter's own uncertainty as the x, y prior (priors.front_end_cloud): its covariance per keyframe,
        # floored, scaled and inflated for the correlation of its errors over front_end_corr_s (as the attitude's)
        self.cloud_cov = None
        if pr.front_end_cloud and self.cloud.cov is not None:
            c = self.cloud.cov * (pr.front_end_cloud_scale * max(pr.front_end_corr_s / dt_kf, 1.0))
            c = 0.5 * (c + np.swapaxes(c, 1, 2)) + np.eye(2) * (pr.front_end_min_sigma_m ** 2)
            self.cloud_cov = np.zeros((K, 3, 3))
            self.cloud_cov[:, :2, :2] = c
            self.cloud_cov[:, 2, 2] = z_sigma ** 2
        self.start_pose_noise = nm.Diagonal.Sigmas(np.r_[np.full(3, np.deg2rad(pr.attitude_sigma_deg)),
                                                         np.full(3, pr.start_position_sigma_m)])  # rad, m
        self.start_velocity_noise = nm.Isotropic.Sigma(3, pr.start_velocity_sigma_mps)  # m/s
        self.start_bias_noise = nm.Diagonal.Sigmas(np.r_[np.full(3, cfg.imu.accel_bias_prior),
                                                         np.full(3, cfg.imu.gyro_bias_prior)])  # m/s^2, rad/s
        # --- inputs, checked
        self._check_inputs(imu, ranges)
        n_held = 0
        self.pims = pims
        if pims is None:
            self.pims, n_held = preintegrate(preintegration_params(cfg.imu), self.imu, kf.t)
        if n_held:
            self.notes.append(f"{n_held} keyframe interval(s) without an IMU sample of their own: the last sample "
                              f"was held over them")
        kidx = nearest_keyframe(kf.t, self.ranges.t)
        rj, rr = self.ranges.anchor, self.ranges.range_m
        self.n_heard = np.bincount(rj, minlength=len(beacons.ids))  # usable ranges before the gate
        if rc.gate_m is not None and len(kidx):  # validation gate on the predicted distance (initial values)
            pred = np.linalg.norm(kf.position[kidx] - self.beacon_init[rj], axis=-1)
            gate = rc.gate_m + rc.gate_sigmas * np.sqrt(np.mean(np.asarray(beacons.sigma, float)[rj, :2] ** 2, axis=-1))
            inside = pred < gate
            if not inside.all():
                self.notes.append(f"{np.count_nonzero(~inside)} of {len(inside)} ranges outside the {rc.gate_m:g} m "
                                  f"+ {rc.gate_sigmas:g} sigma gate "
                                  f"(beacon prior to front-end position) left out")
            kidx, rj, rr = kidx[inside], rj[inside], rr[inside]
        self._range_k, self._range_j, self._range_r = select_ranges(kidx, rj, rr,
                                                                    rc.combine, rc.max_beacons_per_keyframe)
        self._bounds = np.searchsorted(self._range_k, np.arange(K + 1), side="left")
        self.n_ranges = np.bincount(self._range_j, minlength=len(beacons.ids))
        self._pending: dict[int, list[tuple[int, float]]] = {}
        self.in_graph = np.zeros(len(beacons.ids), bool)
        self.rots = [gtsam.Rot3(R) for R in quat_to_matrix(kf.q)]

    # ---------------------------------------------------------------- inputs
    def _check_inputs(self, imu: ImuSamples, ranges: RangeObs) -> None:
        kf = self.kf
        t, acc, gyr = (np.asarray(a, float) for a in (imu.t, imu.acc, imu.gyr))
        ok = np.isfinite(t) & np.isfinite(acc).all(1) & np.isfinite(gyr).all(1)
        if not ok.all():
            self.notes.append(f"{np.count_nonzero(~ok)} non-finite IMU sample(s) dropped")
        if not ok.any():
            raise ValueError("no finite IMU sample: the back-end needs the IMU")
        self.imu = ImuSamples(t[ok], acc[ok], gyr[ok])
        rt, rj, rr = np.asarray(ranges.t, float), np.asarray(ranges.anchor, int), np.asarray(ranges.range_m, float)
        good = np.isfinite(rt) & np.isfinite(rr) & (rr >= 0) & (rj >= 0) & (rj < len(self.beacons.ids))
        if not good.all():
            self.notes.append(f"{np.count_nonzero(~good)} non-finite or unknown-beacon range(s) dropped")
        self.ranges = RangeObs(rt[good], rj[good], rr[good])
        bad_b = ~(np.isfinite(self.beacons.xyz).all(1) & np.isfinite(self.beacons.sigma).all(1)
                  & (self.beacons.sigma > 0).all(1))
        if bad_b.any():
            ids = ", ".join(map(str, self.beacons.ids[bad_b][:5]))
            self.notes.append(f"{np.count_nonzero(bad_b)} beacon(s) without a finite prior are left out: {ids}")
            keep = ~bad_b[self.ranges.anchor]
            self.ranges = RangeObs(self.ranges.t[keep], self.ranges.anchor[keep], self.ranges.range_m[keep])
        for name, arr in (("position", kf.position), ("velocity", kf.velocity), ("q", kf.q)):
            if not np.isfinite(arr).all():
                raise ValueError(f"non-finite initial {name} in the keyframes (front-end estimate)")

    # ---------------------------------------------------------------- factors per keyframe
    def keyframe_factors(self, k: int):
        """(NonlinearFactorGraph, Values): the factors that keyframe k adds (priors, IMU from k-1, its
        ranges, beacons that became determined) and initial values of its new variables."""
        gtsam = self.gtsam
        from gtsam.symbol_shorthand import B, V, X

        cfg, kf = self.cfg, self.kf
        g = gtsam.NonlinearFactorGraph()
        v = gtsam.Values()
        pose = gtsam.Pose3(self.rots[k], kf.position[k])
        v.insert(X(k), pose)
        v.insert(V(k), kf.velocity[k])
        v.insert(B(k), gtsam.imuBias.ConstantBias(kf.bias[k, :3], kf.bias[k, 3:]))
        if k == 0:
            g.add(gtsam.PriorFactorPose3(X(0), pose, self.start_pose_noise))
            g.add(gtsam.PriorFactorVector(V(0), kf.velocity[0], self.start_velocity_noise))
            g.add(gtsam.PriorFactorConstantBias(B(0), gtsam.imuBias.ConstantBias(kf.bias[0, :3], kf.bias[0, 3:]),
                                                self.start_bias_noise))
            if self.channel is not None:  # the receiver's RSSI offset (and the exponent), one for the session
                self.channel.add_variables(g, v)
        else:
            g.add(gtsam.CombinedImuFactor(X(k - 1), V(k - 1), X(k), V(k), B(k - 1), B(k), self.pims[k - 1]))
            g.add(gtsam.PoseRotationPrior3D(X(k), self.rots[k], self.attitude_noise))
            if self.odo is not None and self.odo[2][k]:  # the learned odometry's displacement from k-1
                g.add(odometry_factor(X(k - 1), X(k), self.rots[k - 1], self.rots[k], self.odo[0][k], self.odo[1][k]))
        if self.cloud_cov is not None and np.isfinite(self.cloud_cov[k]).all():  # the filter's cloud (and height)
            mean = np.array([self.cloud.position[k, 0], self.cloud.position[k, 1], cfg.range.device_z])
            g.add(gtsam.PoseTranslationPrior3D(X(k), gtsam.Point3(mean),
                                               gtsam.noiseModel.Gaussian.Covariance(self.cloud_cov[k])))
        elif self.height_noise is not None:
            target = np.array([kf.position[k, 0], kf.position[k, 1], cfg.range.device_z])
            g.add(gtsam.PoseTranslationPrior3D(X(k), gtsam.Point3(target), self.height_noise))
        lo, hi = self._bounds[k], self._bounds[k + 1]
        held: list[tuple[int, int, float]] = []  # (keyframe, beacon, range) for the channel factors
        for j, r in zip(self._range_j[lo:hi].tolist(), self._range_r[lo:hi].tolist()):
            if self.in_graph[j]:
                self._range_factor(g, held, k, j, r)
                continue
            pend = self._pending.setdefault(j, [])
            pend.append((k, r))
            if len(pend) >= cfg.range.min_ranges:  # determined enough: the beacon enters with its prior
                self._add_beacon(j, g, v)
                for kk, rr in pend:
                    self._range_factor(g, held, kk, j, rr)
                del self._pending[j]
        if self.channel is not None:
            self.channel.add_factors(g, held)
        return g, v

    def _range_factor(self, g, held: list, k: int, j: int, r: float) -> None:
        """GTSAM's RangeFactor3D ||p_k - l_j|| - r into ``g``; with ``range.estimate_offset`` the range is held for the
        channel's factors (:class:`ChannelVariables`, one per keyframe or per ``range.channel_group`` keyframes)."""
        if self.channel is not None:
            held.append((k, j, r))
        else:
            g.add(self.gtsam.RangeFactor3D(self.gtsam.symbol("x", k), self.gtsam.symbol("l", j), r, self.range_noise))

    def _add_beacon(self, j: int, g, v) -> None:
        gtsam = self.gtsam
        from gtsam.symbol_shorthand import L

        prior = np.asarray(self.beacons.xyz[j], float)
        v.insertPoint3(L(j), self.beacon_init[j])
        beacon_prior_noise = gtsam.noiseModel.Diagonal.Sigmas(np.asarray(self.beacons.sigma[j], float))  # m
        g.add(gtsam.PriorFactorPoint3(L(j), prior, beacon_prior_noise))
        self.in_graph[j] = True

    # ---------------------------------------------------------------- solvers
    def solve(self) -> BackendResult:
        t0 = time.perf_counter()
        method = Solver(self.cfg.solver.method)
        res = self._solve_isam2() if method == Solver.isam2 else self._solve_lm()
        res.notes = self.notes + res.notes
        res.failures = self.failures + res.failures
        res.solve_s = time.perf_counter() - t0
        return res

    def _solve_isam2(self) -> BackendResult:
        gtsam = self.gtsam
        from gtsam.symbol_shorthand import X

        sc = self.cfg.solver
        params = gtsam.ISAM2Params()
        params.setFactorization(str(sc.factorization).upper())
        thresholds = gtsam.ISAM2ThresholdMap()  # per variable type and component (tangent-space order)
        thresholds.insert(("x", np.r_[np.full(3, sc.relinearize_rotation_rad), np.full(3, sc.relinearize_position_m)]))
        thresholds.insert(("v", np.full(3, float(sc.relinearize_velocity_mps))))
        thresholds.insert(("b", np.r_[np.full(3, sc.relinearize_accel_bias), np.full(3, sc.relinearize_gyro_bias)]))
        thresholds.insert(("l", np.full(3, float(sc.relinearize_beacon_m))))
        thresholds.insert(("o", np.full(1, float(sc.relinearize_offset_db))))  # the channel's variables: each
        thresholds.insert(("e", np.full(1, float(sc.relinearize_exponent))))  # relinearizes every range factor
        params.setRelinearizeThreshold(thresholds)
        params.relinearizeSkip = int(sc.relinearize_skip)
        isam = gtsam.ISAM2(params)
        K = len(self.kf.t)
        online = self.kf.position.copy()
        update_s = np.full(K, np.nan)
        graph, initial = gtsam.NonlinearFactorGraph(), gtsam.Values()  # everything so far (for a recovery)
        failed_at = None
        every = max(int(sc.update_every), 1)
        new_g, new_v = gtsam.NonlinearFactorGraph(), gtsam.Values()
        for k in range(K):
            g, v = self.keyframe_factors(k)
            graph.push_back(g)
            initial.insert(v)
            if failed_at is not None:
                continue
            new_g.push_back(g)
            new_v.insert(v)
            if (k + 1) % every and k < K - 1:
                continue
            t1 = time.perf_counter()
            try:
                isam.update(new_g, new_v)
                online[k] = isam.calculateEstimatePose3(X(k)).translation()
            except RuntimeError as exc:
                self._fail("isam2-update", exc, k)
                failed_at = k
                continue
            update_s[k] = time.perf_counter() - t1
            new_g, new_v = gtsam.NonlinearFactorGraph(), gtsam.Values()
        if failed_at is not None:  # the online smoother is gone: the whole session in batch (LM, QR) instead
            self.notes.append(f"iSAM2 failed at keyframe {failed_at}; the session was smoothed in batch (LM, QR) "
                              f"instead, online estimates after it are the front-end's")
            res = self._batch(graph, initial, qr=True)
        else:
            estimate = None
            try:
                estimate = isam.calculateEstimate()
            except RuntimeError as exc:
                self._fail("isam2-estimate", exc, K - 1)
            cov = (lambda key: isam.marginalCovariance(key)) if estimate is not None else None
            res = self._collect(estimate, K - 1 if estimate is not None else -1, cov)
        res.online_position = online
        res.update_s = update_s
        res.n_factors = int(graph.size())
        return res

    def batch_graph(self):
        """(NonlinearFactorGraph, Values): every keyframe's factors and initial values, what LM solves."""
        graph, initial = self.gtsam.NonlinearFactorGraph(), self.gtsam.Values()
        if self.channel is not None:  # its ranges into factors spanning keyframes, once every keyframe is in
            self.channel.defer()
        for k in range(len(self.kf.t)):
            g, v = self.keyframe_factors(k)
            graph.push_back(g)
            initial.insert(v)
        if self.channel is not None:
            self.channel.flush(graph)
        return graph, initial

    def _solve_lm(self) -> BackendResult:
        return self._batch(*self.batch_graph(), qr=str(self.cfg.solver.factorization) == "qr")

    def _lm(self, graph, initial, qr: bool):
        """Levenberg-Marquardt on the whole graph; the estimate, or None after a failure (recorded)."""
        gtsam = self.gtsam
        sc = self.cfg.solver
        params = gtsam.LevenbergMarquardtParams()
        params.setLinearSolverType("MULTIFRONTAL_QR" if qr else "MULTIFRONTAL_CHOLESKY")
        params.setMaxIterations(int(sc.lm_max_iterations))
        params.setRelativeErrorTol(float(sc.lm_relative_tol))
        try:
            opt = gtsam.LevenbergMarquardtOptimizer(graph, initial, params)
            estimate = opt.optimize()
        except RuntimeError as exc:
            if qr:
                self._fail("lm", exc, None)
                return None
            self.notes.append(f"LM with Cholesky failed ({first_line(exc)}); retried with QR")
            return self._lm(graph, initial, qr=True)
        self.notes.append(f"LM{' (QR)' if qr else ''}: {opt.iterations()} iterations, error "
                          f"{graph.error(initial):.4g} -> {graph.error(estimate):.4g}")
        return estimate

    def _batch(self, graph, initial, qr: bool) -> BackendResult:
        estimate = self._lm(graph, initial, qr)
        cov = None
        if estimate is not None and self.cfg.solver.beacon_covariance and self.in_graph.any():
            cov = self._marginals(graph, estimate)
        res = self._collect(estimate, len(self.kf.t) - 1 if estimate is not None else -1, cov)
        res.n_factors = int(graph.size())
        return res

    def _marginals(self, graph, estimate):
        """``key -> marginal covariance`` at ``estimate``: one iSAM2 elimination of the whole graph with the
        configured factorization (gtsam.Marginals has only Cholesky in Python), or None on failure."""
        gtsam = self.gtsam
        params = gtsam.ISAM2Params()
        params.setFactorization(str(self.cfg.solver.factorization).upper())
        params.enableRelinearization = False
        isam = gtsam.ISAM2(params)
        try:
            isam.update(graph, estimate)
        except RuntimeError as exc:
            self._fail("marginals", exc, None)
            return None
        return isam.marginalCovariance

    def _fail(self, stage: str, exc: RuntimeError, k: int | None) -> None:
        sym = symbol_in(str(exc))
        key = describe_key(sym, self.kf.t, self.beacons.ids)
        t = float(self.kf.t[k]) if k is not None else None
        self.failures.append(BackendFailure(stage, key, t, first_line(exc)))

    def _collect(self, estimate, last_good: int, cov) -> BackendResult:
        """Arrays from the estimate for keyframes 0..last_good, the front-end's values after (a failure)."""
        from gtsam.symbol_shorthand import B, L, V, X

        kf = self.kf
        K = len(kf.t)
        pos, vel, q = kf.position.copy(), kf.velocity.copy(), kf.q.copy()
        bias = np.zeros((K, 6))
        for k in range(last_good + 1):
            pose = estimate.atPose3(X(k))
            pos[k] = pose.translation()
            quat = pose.rotation().toQuaternion()
            q[k] = [quat.w(), quat.x(), quat.y(), quat.z()]
            vel[k] = estimate.atVector(V(k))
            bias[k] = estimate.atConstantBias(B(k)).vector()
        if last_good < K - 1:
            self.notes.append(f"keyframes {last_good + 1}..{K - 1} keep the front-end's values (back-end failure)")
        rows = []
        for j, aid in enumerate(self.beacons.ids):
            xyz, std = self.beacons.xyz[j], float(np.sqrt(np.mean(self.beacons.sigma[j, :2] ** 2)))
            n = int(self.n_ranges[j])
            if self.in_graph[j] and estimate is not None and estimate.exists(L(j)):
                xyz = estimate.atPoint3(L(j))
                status = "optimized"
                std = np.nan
                if cov is not None and self.cfg.solver.beacon_covariance:
                    try:
                        c = np.asarray(cov(L(j)))
                        std = float(np.sqrt(max(np.trace(c[:2, :2]), 0.0) / 2.0))
                    except RuntimeError as exc:
                        self._fail("marginals", exc, None)
            elif self.n_heard[j] == 0:
                status = "not heard"
            elif n == 0:
                status = f"prior: none of its {self.n_heard[j]} range(s) inside the gate"
            else:
                status = f"prior: {n} range(s) < min_ranges {self.cfg.range.min_ranges}"
            rows.append({"anchor_id": str(aid), "x": float(xyz[0]), "y": float(xyz[1]), "z": float(xyz[2]),
                         "std_m": std, "n_ranges": n, "n_heard": int(self.n_heard[j]), "status": status})
        few = [r["anchor_id"] for r in rows if r["status"].startswith("prior") and r["n_ranges"]]
        if few:
            self.notes.append(f"{len(few)} beacon(s) heard too little for range factors, kept at their prior: "
                              f"{', '.join(few[:8])}{' ...' if len(few) > 8 else ''}")
        bmap = pd.DataFrame(rows, columns=["anchor_id", "x", "y", "z", "std_m", "n_ranges", "n_heard", "status"])
        res = BackendResult(kf.t.copy(), pos, vel, q, bias, pos.copy(), bmap, np.full(K, np.nan))
        if self.channel is not None:
            self.channel.read(estimate, cov, res, self._fail)
        return res


def smooth(cfg: BackendConfig, kf: Keyframes, imu: ImuSamples, ranges: RangeObs, beacons: BeaconPriors,
           offset_prior_db: float = 0.0, odometry: OdometryTrack | None = None,
           exponent_prior: float | None = None) -> BackendResult:
    """Build the graph of one session and solve it with ``cfg.solver.method``; never raises on a GTSAM failure
    (see :class:`BackendResult`.failures). ``ValueError`` for inputs it cannot use at all (no IMU, < 2
    keyframes, non-finite front-end values). ``offset_prior_db``: prior mean of the receiver offset when
    ``range.estimate_offset``; ``odometry``: a learned inertial odometry's track (between-factors); ``exponent_prior``:
    prior mean of the channel's exponent when ``range.estimate_exponent`` (None: the ranges' own)."""
    t0 = time.perf_counter()
    if len(kf.t) < 2:
        raise ValueError(f"the back-end needs at least 2 keyframes, got {len(kf.t)}")
    graph = RadioInertialGraph(cfg, kf, imu, ranges, beacons, offset_prior_db=offset_prior_db, odometry=odometry,
                               exponent_prior=exponent_prior)
    res = graph.solve()
    passes = int(cfg.solver.passes) if Solver(cfg.solver.method) == Solver.lm else 1  # iSAM2 is online: one pass
    ranges0, channel = ranges, None  # range.refit_channel: the ranges as measured, the channel fitted so far
    for p in range(passes - 1):
        if not res.ok:
            break
        # again, from this solution: its keyframes and beacons re-gate the ranges and initialise the graph
        again = Keyframes(kf.t, res.position, res.velocity, res.q, res.bias)
        init = res.beacon_map[["x", "y", "z"]].to_numpy(float)
        if ChannelRefit(cfg.range.refit_channel) != ChannelRefit.none:  # the channel from this solution
            ranges, channel, note = refit_ranges(cfg, (graph._range_k, graph._range_j, graph._range_r), res.position,
                                                 init, ranges0, channel)
            res.notes.append(note)
        off0 = res.offset_db if np.isfinite(res.offset_db) else None
        e0 = res.channel_exponent if cfg.range.estimate_exponent and np.isfinite(res.channel_exponent) else None
        graph = RadioInertialGraph(cfg, again, imu, ranges, beacons, beacon_init=init, pims=graph.pims,
                                   offset_prior_db=offset_prior_db, offset_init_db=off0, cloud=kf, odometry=odometry,
                                   exponent_prior=exponent_prior, exponent_init=e0)
        res, notes = graph.solve(), res.notes
        res.notes = notes + [f"pass {p + 2}: " + n for n in res.notes]
        if channel is not None:  # the fit of the measured ranges: the channel's exponent and level
            res.channel_exponent, res.channel_offset_db = channel_of(channel, ranges0.gamma or cfg.range.gamma)
    res.wall_s = time.perf_counter() - t0
    return res
