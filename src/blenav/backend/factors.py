"""The pieces of the radio-inertial graph's factors (:mod:`blenav.backend.graph`): GTSAM's IMU preintegration
between keyframes, the assignment of ranges to keyframes and their selection (gate, median, nearest beacons),
the robust noise models, the errors of the range factors with the receiver's RSSI offset and the path-loss exponent
as variables (many ranges to one vectorised factor), and the between-factors of a learned inertial
odometry. GTSAM is imported
when one of them is called (:func:`load_gtsam`), not with this module.
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from .config import Combine, RobustKernel
from .graph_types import ImuSamples, OdometryTrack

__all__ = ["load_gtsam", "preintegration_params", "integration_pieces", "preintegrate", "nearest_keyframe",
           "select_ranges", "robust_noise", "kernel_loss", "channel_range_error", "channel_range_factor",
           "odometry_increments", "odometry_factor"]


def load_gtsam():
    import gtsam

    return gtsam


def preintegration_params(cfg) -> "gtsam.PreintegrationCombinedParams":
    """GTSAM preintegration parameters from :class:`~blenav.backend.config.ImuConfig` (ENU: gravity -z)."""
    gtsam = load_gtsam()
    p = gtsam.PreintegrationCombinedParams.MakeSharedU(float(cfg.gravity_mps2))
    I3 = np.eye(3)
    p.setAccelerometerCovariance(I3 * cfg.accel_noise_density**2)  # (m/s^2)^2 / Hz
    p.setGyroscopeCovariance(I3 * cfg.gyro_noise_density**2)  # (rad/s)^2 / Hz
    p.setIntegrationCovariance(I3 * cfg.integration_sigma**2)
    p.setBiasAccCovariance(I3 * cfg.accel_bias_rw**2)  # (m/s^3)^2 / Hz
    p.setBiasOmegaCovariance(I3 * cfg.gyro_bias_rw**2)  # (rad/s^2)^2 / Hz
    return p


def integration_pieces(imu_t: np.ndarray, kf_t: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Split [kf_t[0], kf_t[-1]] at every IMU time and keyframe time: for each piece, the IMU sample held over
    it (the latest at or before its start; the first sample before the IMU starts), its duration (s) and the
    keyframe interval k (1..K-1) it belongs to (piece in (t_{k-1}, t_k]). Returns (sample (P,), dt (P,),
    interval (P,))."""
    inside = imu_t[(imu_t > kf_t[0]) & (imu_t < kf_t[-1])]
    grid = np.union1d(inside, kf_t)
    start = grid[:-1]
    sample = np.clip(np.searchsorted(imu_t, start, side="right") - 1, 0, len(imu_t) - 1)
    interval = np.searchsorted(kf_t, start, side="right")
    return sample, np.diff(grid), interval


def preintegrate(params, imu: ImuSamples, kf_t: np.ndarray) -> tuple[list, int]:
    """One ``PreintegratedCombinedMeasurements`` per keyframe interval (K - 1 of them; bias estimate 0: the
    factor corrects to first order for the bias variable), zero-order hold of each IMU sample over its
    interval. Returns (pims, number of intervals without an IMU sample of their own)."""
    gtsam = load_gtsam()
    K = len(kf_t)
    pims = [gtsam.PreintegratedCombinedMeasurements(params) for _ in range(max(K - 1, 0))]
    if K < 2:
        return pims, 0
    sample, dt, interval = integration_pieces(imu.t, kf_t)
    acc, gyr = imu.acc, imu.gyr
    for s, d, k in zip(sample.tolist(), dt.tolist(), interval.tolist()):
        if d > 0:
            pims[k - 1].integrateMeasurement(acc[s], gyr[s], d)
    own = np.zeros(K, bool)
    own[np.searchsorted(kf_t, imu.t[(imu.t > kf_t[0]) & (imu.t <= kf_t[-1])], side="left")] = True
    return pims, int(np.count_nonzero(~own[1:]))


def nearest_keyframe(kf_t: np.ndarray, t: np.ndarray) -> np.ndarray:
    """(M,) index of the keyframe nearest to each time t (M,) s: a range is a measurement of the pose at its
    own time, and the nearest keyframe halves the time offset (and removes its bias) compared with the step
    that closes its interval."""
    i = np.clip(np.searchsorted(kf_t, t, side="left"), 1, max(len(kf_t) - 1, 1))
    if len(kf_t) < 2:
        return np.zeros(len(t), int)
    return np.where(np.abs(t - kf_t[i - 1]) <= np.abs(kf_t[i] - t), i - 1, i)


def select_ranges(k: np.ndarray, j: np.ndarray, r: np.ndarray, combine: Combine, max_beacons: int | None):
    """Ranges r (M,) m of beacons j (M,) attached to keyframes k (M,) -> (k, j, r) sorted by keyframe (stable):
    all of them, or (``combine`` median) one per (keyframe, beacon) with the median range; with
    ``max_beacons``, only the ranges of the N beacons per keyframe whose median range is shortest."""
    order = np.argsort(k, kind="stable")
    k, j, r = k[order], j[order], r[order]
    if Combine(combine) == Combine.all and not max_beacons:
        return k, j, r
    df = pd.DataFrame({"k": k, "j": j, "r": r})
    med = df.groupby(["k", "j"], sort=True)["r"].median().reset_index()
    if max_beacons:
        med = med.sort_values(["k", "r"], kind="stable").groupby("k").head(int(max_beacons))
        med = med.sort_values(["k", "j"], kind="stable")
    if Combine(combine) == Combine.median:
        return med["k"].to_numpy(), med["j"].to_numpy(), med["r"].to_numpy()
    keep = df.merge(med[["k", "j"]], on=["k", "j"], how="inner", sort=False)  # df's order within a keyframe
    keep = keep.sort_values("k", kind="stable")
    return keep["k"].to_numpy(), keep["j"].to_numpy(), keep["r"].to_numpy()


def robust_noise(kind: RobustKernel, k: float, sigma: float, dim: int = 1):
    """Isotropic noise of ``sigma`` (the quantity's unit) inside an M-estimator of width ``k`` sigmas."""
    gtsam = load_gtsam()
    base = gtsam.noiseModel.Isotropic.Sigma(dim, float(sigma))
    kind = RobustKernel(kind)
    if kind == RobustKernel.none:
        return base
    est = gtsam.noiseModel.mEstimator
    make = {RobustKernel.huber: lambda: est.Huber.Create(float(k)), RobustKernel.cauchy: lambda: est.Cauchy.Create(float(k)),
            RobustKernel.geman_mcclure: lambda: est.GemanMcClure.Create(float(k)),
            RobustKernel.dcs: lambda: est.DCS.Create(float(k) ** 2)}  # DCS: Phi in squared whitened units
    return gtsam.noiseModel.Robust.Create(make[kind](), base)


def kernel_loss(kind: RobustKernel, k: float, u: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(rho (n,), weight (n,)) of the M-estimator ``kind`` of width ``k`` at whitened errors ``u`` (n,): GTSAM's
    ``noiseModel.mEstimator`` definitions (Huber, Cauchy, Geman-McClure, DCS with Phi = k^2; tests compare them),
    weight = rho'(u) / u."""
    u = np.asarray(u, float)
    a2 = u * u
    kind, k = RobustKernel(kind), float(k)
    if kind == RobustKernel.none:
        return 0.5 * a2, np.ones_like(u)
    if kind == RobustKernel.huber:
        a = np.abs(u)
        inner = a <= k
        return np.where(inner, 0.5 * a2, k * a - 0.5 * k * k), np.where(inner, 1.0, k / np.maximum(a, 1e-300))
    if kind == RobustKernel.cauchy:
        return 0.5 * k * k * np.log1p(a2 / (k * k)), k * k / (k * k + a2)
    if kind == RobustKernel.geman_mcclure:
        return 0.5 * k * k * a2 / (k * k + a2), k ** 4 / (k * k + a2) ** 2
    c = k * k  # DCS: Phi
    inner = a2 <= c
    return (np.where(inner, 0.5 * a2, c * (3.0 * a2 - c) / (2.0 * (c + a2))),
            np.where(inner, 1.0, (2.0 * c / (c + a2)) ** 2))


def channel_range_error(r: np.ndarray, pcol: np.ndarray, col: np.ndarray, gamma: float, d0: float, sigma: float,
                        kind: RobustKernel, k: float, exponent: bool, this, values, H) -> np.ndarray:
    """Ranges through the channel's variables, many in one GTSAM CustomFactor (:func:`channel_range_factor` builds
    it): GTSAM's optimizers hand every Python error call a copy of all the graph's values, so one call per range
    costs more than the solve; one per keyframe, or per group of keyframes, does not (``lm_split`` of
    benchmarks/backend_speed.py).

    Keys: the poses X_1..X_P (Pose3), the beacons L_1..L_B (Point3), O (1-D, the receiver's RSSI offset delta,
    dB), and with ``exponent`` E (1-D, b = the channel's path-loss exponent over the ranges' ``gamma``). Range i
    (r[i] m, from pose ``pcol[i]`` to beacon ``col[i]``) is predicted as r_hat = d0 (d / d0)^b 10^(-delta / (10
    gamma)), d = ||t - l|| (000 sec. IV-B's conversion r = d0 10^((a_X - rssi) / (10 gamma)) of an RSSI read by a
    receiver delta dB hot through a channel of exponent b gamma; b = 1, delta = 0: RangeFactor3D's). The
    M-estimator ``kind`` (width ``k`` sigmas) acts per range, inside, as GTSAM's robust noise model acts on a
    factor of one range: the error (``values`` alone: what the solvers' cost reads) is sigma sign(u) sqrt(2 rho(u))
    with u = (r_hat - r) / sigma, so that the factor's whitened squared norm over 2 (noise ``Isotropic(sigma)``) is
    the sum of rho over its ranges; linearized (``H`` given), each range's error and Jacobian row are those of the
    plain range times sqrt(w(u)), GTSAM's iteratively reweighted system (``Robust.WhitenSystem``), so that the
    steps and the marginals are those of one robust RangeFactor3D per range (tests/backend/test_channel_factor.py).
    Jacobians of r_hat: pose [0, g u^T R] (GTSAM's Pose3 tangent), beacon -g u^T, g = d r_hat / d d = b r_hat / d;
    delta -r_hat ln(10) / (10 gamma); b r_hat ln(d / d0)."""
    keys = this.keys()
    n_p, n_b = int(pcol.max()) + 1, int(col.max()) + 1
    poses = [values.atPose3(keys[i]) for i in range(n_p)]
    T = np.array([p.translation() for p in poses], float).reshape(n_p, 3)
    L = np.array([values.atPoint3(keys[n_p + j]) for j in range(n_b)], float).reshape(n_b, 3)
    delta = float(values.atVector(keys[n_p + n_b])[0])
    b = float(values.atVector(keys[n_p + n_b + 1])[0]) if exponent else 1.0
    diff = T[pcol] - L[col]  # (m, 3)
    d = np.maximum(np.sqrt(np.einsum("ij,ij->i", diff, diff)), 1e-9)
    rhat = d0 * (d / d0) ** b * 10.0 ** (-delta / (10.0 * gamma))
    u = (rhat - r) / sigma
    rho, w = kernel_loss(kind, k, u)
    if H is None:
        return sigma * np.sign(u) * np.sqrt(2.0 * rho)
    m, sw = len(r), np.sqrt(w)
    gu = (sw * b * rhat / d)[:, None] * (diff / d[:, None])  # sqrt(w) d r_hat / dt = -sqrt(w) d r_hat / dl, (m, 3)
    for i, pose in enumerate(poses):
        Hi = np.zeros((m, 6))
        rows = pcol == i
        Hi[rows, 3:] = gu[rows] @ pose.rotation().matrix()
        H[i] = Hi
    for j in range(n_b):
        Hj = np.zeros((m, 3))
        rows = col == j
        Hj[rows] = -gu[rows]
        H[n_p + j] = Hj
    H[n_p + n_b] = (-sw * rhat * np.log(10.0) / (10.0 * gamma))[:, None]
    if exponent:
        H[n_p + n_b + 1] = (sw * rhat * np.log(d / d0))[:, None]
    return sw * (rhat - r)


def channel_range_factor(pose_keys: list, beacon_keys: list, offset_key, exponent_key, r: np.ndarray, gamma: float,
                         d0: float, sigma: float, kind: RobustKernel, k: float):
    """One CustomFactor (:func:`channel_range_error`) for the ranges r (m,) m from the poses ``pose_keys`` (m,) to
    the beacons ``beacon_keys`` (m,) (repeats allowed), with the receiver offset ``offset_key`` and, unless None, the
    exponent ratio ``exponent_key``; range noise ``sigma`` m inside the M-estimator ``kind`` of width ``k``."""
    from functools import partial

    gtsam = load_gtsam()
    upose, pcol = np.unique(np.asarray(pose_keys, np.int64), return_inverse=True)
    ubeacon, col = np.unique(np.asarray(beacon_keys, np.int64), return_inverse=True)
    keys = [int(x) for x in upose] + [int(x) for x in ubeacon] + [offset_key] + \
        ([exponent_key] if exponent_key is not None else [])
    noise = gtsam.noiseModel.Isotropic.Sigma(len(r), float(sigma))
    return gtsam.CustomFactor(noise, keys, partial(channel_range_error, np.asarray(r, float), pcol, col, float(gamma),
                                                   float(d0), float(sigma), RobustKernel(kind), float(k),
                                                   exponent_key is not None))


def odometry_increments(track: OdometryTrack, kf_t: np.ndarray, cfg) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The odometry's displacement into each keyframe: row k (k >= 1) from keyframe k-1 to k, the track
    interpolated at both times. Returns (d (K, 3) world m, z 0; var (K, 3) m^2 per axis: the track's variance
    increment times ``cfg.var_scale``, z ``cfg.z_sigma_m``^2 per second, each floored at ``cfg.min_sigma_m``^2; ok (K,):
    both times inside the track, row 0 False). ``cfg``: :class:`~blenav.backend.config.OdometryConfig`."""
    kf_t = np.asarray(kf_t, float)
    K = len(kf_t)
    x = np.interp(kf_t, track.t, track.xy[:, 0])
    y = np.interp(kf_t, track.t, track.xy[:, 1])
    v = np.interp(kf_t, track.t, track.var)
    inside = (kf_t >= track.t[0]) & (kf_t <= track.t[-1])
    ok = np.zeros(K, bool)
    ok[1:] = inside[1:] & inside[:-1]
    d = np.zeros((K, 3))
    var = np.zeros((K, 3))
    d[1:, 0], d[1:, 1] = np.diff(x), np.diff(y)
    var[1:, :2] = np.maximum(np.diff(v) * float(cfg.var_scale), float(cfg.min_sigma_m) ** 2)[:, None]
    var[1:, 2] = np.maximum(float(cfg.z_sigma_m) ** 2 * np.diff(kf_t), float(cfg.min_sigma_m) ** 2)
    return d, var, ok


def odometry_factor(key_a, key_b, rot_a, rot_b, d: np.ndarray, var: np.ndarray):
    """GTSAM's BetweenFactorPose3 of a world-frame displacement ``d`` (3,) m with per-axis variance ``var`` (3,) m^2
    between poses ``key_a`` and ``key_b`` whose attitudes are ``rot_a`` / ``rot_b`` (gtsam.Rot3, the AHRS the graph's
    attitude priors hold): the relative pose (R_a^T R_b, R_a^T d), the relative rotation left free (100 rad^2: the
    attitude priors and the IMU constrain it). Its error Logmap(measured^-1 T_a^-1 T_b) is then, at those attitudes,
    R_b^T (t_b - t_a - d): the world residual in b's frame, so the covariance is the world one turned into it
    (R_b^T S R_b)."""
    gtsam = load_gtsam()
    Ra, Rb = rot_a.matrix(), rot_b.matrix()
    cov = np.zeros((6, 6))
    cov[:3, :3] = np.eye(3) * 100.0  # rad^2: rotation part unconstrained by this factor
    cov[3:, 3:] = Rb.T @ np.diag(np.asarray(var, float)) @ Rb
    return gtsam.BetweenFactorPose3(key_a, key_b, gtsam.Pose3(rot_a.between(rot_b), Ra.T @ np.asarray(d, float)),
                                    gtsam.noiseModel.Gaussian.Covariance(cov))
