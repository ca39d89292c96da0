"""Posterior Cramer-Rao lower bound (PCRLB) of the position error along a simulated session's true trajectory.

Tichavsky, Muravchik and Nehorai (1998) give the Fisher information J_k of the state x_k of a Markov
model ``x_{k+1} ~ p(.|x_k)``, ``z_k ~ p(.|x_k)`` by the recursion::

    J_{k+1} = D22_k - D21_k (J_k + D11_k)^{-1} D12_k                                  # eq. 21, Tichavsky et al. 1998
    D11_k = E[-d2/dx_k dx_k  log p(x_{k+1}|x_k)],  D12_k = E[-d2/dx_k dx_{k+1} log p(x_{k+1}|x_k)] = D21_k^T,
    D22_k = E[-d2/dx_{k+1} dx_{k+1} log p(x_{k+1}|x_k)] + E[-d2/dx_{k+1} dx_{k+1} log p(z_{k+1}|x_{k+1})]

and every unbiased-in-the-Bayesian-sense estimator has ``E[(x^_k - x_k)(x^_k - x_k)^T] >= J_k^{-1}``. For
additive Gaussian process noise ``x_{k+1} = F x_k + w_k``, ``w_k ~ N(0, Q)`` the D terms are (Tichavsky et
al. 1998, the linear-Gaussian dynamics case)::

    D11 = F^T Q^{-1} F,   D12 = -F^T Q^{-1},   D22 = Q^{-1} + J_z(x_{k+1})

so that (matrix inversion lemma) ``J_{k+1} = (Q + F J_k^{-1} F^T)^{-1} + J_z``: with a linear-Gaussian
measurement ``J_z = H^T R^{-1} H`` this is the Kalman filter's information recursion, and the bound equals
the KF's covariance (tests/test_pcrlb.py checks it).

The model here (all arrays in the floor's world frame, metres, seconds):

- State ``x = (p_x, p_y, v_x, v_y)``, a nearly-constant-velocity walker: ``F = [[I, dt I], [0, I]]``,
  ``Q = q [[dt^3/3 I, dt^2/2 I], [dt^2/2 I, dt I]]`` (white acceleration of spectral density q, m^2/s^3).
  The simulator's walker is not such a Markov process (it follows routes, :mod:`blenav.sim.motion`), so q is
  the one that describes the simulator's own motion: fitted on the session's true trajectory (10 Hz) as
  ``q = mean(|v_{k+1} - v_k|^2) / (2 dt)`` (the per-axis variance of a velocity increment is q dt).
- BLE RSSI (:mod:`blenav.sim.radio`): ``rssi = P - 10 n log10(d) + ...`` with d the 3-D distance, so
  ``d rssi / d p = -(10 n / ln 10) g (p - a)_h / d^2`` (g the receiver's gain slope, (p - a)_h the horizontal
  offset) and a beacon heard n_kb times in step k adds ``grad grad^T / (sigma_s^2 + sigma_w^2 / n_kb)``:
  shadowing (sigma_s = g shadow_std_db, a field that does not average out within a step) plus the white
  part (sigma_w^2 = g^2 var(fading at line of sight) + receiver std^2 at no interference, averaged over the
  step's packets). This is the Fisher information of the issue's formula ``(10 n / ln 10)^2 / sigma^2 u u^T
  / d^2`` with the 3-D distance and the per-step noise. The beacons heard and their packet counts are the
  session's own rssi.csv (what the receiver actually reported).
- WiFi RTT (optional rtt.csv): range = d + offset + NLOS bias + N(0, sigma(d)^2), sigma(d) = std_m +
  std_per_m d: each range adds ``u_h u_h^T (r_h / d)^2 / sigma(d)^2`` (u_h the horizontal unit vector).
- Visual fixes (optional visual.csv): ``I / pos_std_m^2`` at the step of each fix.

Every simplification makes the bound lower (more optimistic), as a bound should be: channel parameters
(beacon powers, receiver offset, RTT offsets, path-loss exponent) known, wall and body losses known,
shadowing independent between steps (it is correlated over ``shadow_corr_m``), fading at its line-of-sight
(smallest) variance, quantisation ignored. Not in the bound: the inertial sensors and odometry (a method
that uses them has information the radio bound does not count) and the floor plan (walls constrain a
walker; a map-aware method can go below a bound that does not know them). The start: ``J_0`` of a uniform
position over the floor's bounding box (variance W^2 / 12 per axis) and a velocity of std ``speed``.

Pure numpy; no plotting, no I/O beyond reading the session's CSVs through :mod:`blenav.data`.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

LN10 = np.log(10.0)


# ------------------------------------------------------------------------------------------ recursion
def pcrlb_recursion(F: np.ndarray, Q: np.ndarray, Jz: np.ndarray, J0: np.ndarray) -> np.ndarray:
    """Fisher information matrices J_1..J_K of the state (K, n, n) (eq. 21, Tichavsky et al. 1998).

    ``F`` (n, n) or (K, n, n) transition, ``Q`` (n, n) or (K, n, n) process noise covariance (positive
    definite), ``Jz`` (K, n, n) measurement information at steps 1..K, ``J0`` (n, n) the prior's information.
    """
    K, n = Jz.shape[0], Jz.shape[-1]
    F = np.broadcast_to(F, (K, n, n))
    Qi = np.linalg.inv(np.broadcast_to(Q, (K, n, n)))  # all steps at once
    D11 = np.einsum("kji,kjl,klm->kim", F, Qi, F)  # F^T Q^-1 F
    D12 = -np.einsum("kji,kjl->kil", F, Qi)  # -F^T Q^-1
    D21 = np.transpose(D12, (0, 2, 1))
    D22 = Qi + Jz
    out = np.empty((K, n, n))
    J = np.asarray(J0, float)
    for k in range(K):  # the recursion is sequential; each step is a few n x n products
        J = D22[k] - D21[k] @ np.linalg.solve(J + D11[k], D12[k])  # eq. 21, Tichavsky et al. 1998
        J = 0.5 * (J + J.T)
        out[k] = J
    return out


def cv_model(dt: float, q: float) -> tuple[np.ndarray, np.ndarray]:
    """Nearly-constant-velocity model in 2-D: F (4, 4), Q (4, 4) for step ``dt`` s and acceleration
    spectral density ``q`` (m^2/s^3); state (p_x, p_y, v_x, v_y)."""
    I2 = np.eye(2)
    F = np.block([[I2, dt * I2], [0 * I2, I2]])
    Q = q * np.block([[dt**3 / 3 * I2, dt**2 / 2 * I2], [dt**2 / 2 * I2, dt * I2]])
    return F, Q


def fit_process_noise(t: np.ndarray, xy: np.ndarray, dt: float, floor_q: float = 1e-3) -> float:
    """q (m^2/s^3) of the CV model that describes a densely sampled trajectory (t (T,) s, xy (T, 2) m, e.g.
    the 10 Hz ground truth) at step ``dt`` s: the velocity (central differences at the samples) taken every
    ``dt`` s, and ``q = mean |v_{k+1} - v_k|^2 / (2 dt)`` (each axis of a velocity increment has variance
    q dt under the model); at least ``floor_q``."""
    t = np.asarray(t, float)
    if len(t) < 3:
        return floor_q
    v = np.gradient(np.asarray(xy, float), t, axis=0)
    tk = np.arange(t[0], t[-1], dt)
    vk = np.stack([np.interp(tk, t, v[:, 0]), np.interp(tk, t, v[:, 1])], axis=1)
    if len(vk) < 2:
        return floor_q
    dv = np.diff(vk, axis=0)
    return max(float(np.mean(np.sum(dv**2, axis=1)) / (2.0 * dt)), floor_q)


# ------------------------------------------------------------------------------------------ information
def rssi_information(step: np.ndarray, anchor: np.ndarray, pos: np.ndarray, anchors_xyz: np.ndarray, K: int,
                     slope_db: float, var_shadow: float, var_white: float) -> np.ndarray:
    """Position information (K, 2, 2) of the BLE packets (one row each): ``step`` (N,) step index in
    [0, K), ``anchor`` (N,) anchor index, ``pos`` (N, 3) true receiver position at the packet (m),
    ``anchors_xyz`` (A, 3); ``slope_db`` = g 10 n (dB per decade), variances in dB^2 (see module doc)."""
    out = np.zeros((K, 2, 2))
    if len(step) == 0:
        return out
    delta = pos - anchors_xyz[anchor]
    d2 = np.maximum(np.sum(delta**2, axis=1), 1e-2)
    grad = (slope_db / LN10) * delta[:, :2] / d2[:, None]  # d rssi / d p, up to sign (N, 2)
    A = len(anchors_xyz)
    key = step * A + anchor
    uk, inv, cnt = np.unique(key, return_inverse=True, return_counts=True)
    gsum = np.zeros((len(uk), 2))
    np.add.at(gsum, inv, grad)
    g = gsum / cnt[:, None]  # the step's mean gradient per beacon
    w = 1.0 / (var_shadow + var_white / cnt)
    info = w[:, None, None] * g[:, :, None] * g[:, None, :]
    np.add.at(out, uk // A, info)
    return out


def range_information(step: np.ndarray, anchor: np.ndarray, pos: np.ndarray, anchors_xyz: np.ndarray, K: int,
                      std_m: float, std_per_m: float) -> np.ndarray:
    """Position information (K, 2, 2) of RTT ranges (one row each, arguments as :func:`rssi_information`):
    ``u_h u_h^T (r_h / d)^2 / sigma(d)^2`` per range, sigma(d) = std_m + std_per_m d."""
    out = np.zeros((K, 2, 2))
    if len(step) == 0:
        return out
    delta = pos - anchors_xyz[anchor]
    d = np.maximum(np.linalg.norm(delta, axis=1), 1e-2)
    grad = delta[:, :2] / d[:, None]  # d range / d p
    sig = std_m + std_per_m * d
    np.add.at(out, step, grad[:, :, None] * grad[:, None, :] / (sig**2)[:, None, None])
    return out


# ------------------------------------------------------------------------------------------ sessions
@dataclass
class BoundSettings:
    """``bound`` block of the leaderboard experiment."""

    dt_s: float = 1.0  # step of the recursion (the rate the methods estimate at is about 1-10 Hz)
    rssi: bool = True
    rtt: bool = True
    visual: bool = True


def sim_parameters(meta: dict):
    """The :class:`blenav.sim.config.SimConfig` a dataset was simulated with (``dataset.yaml`` key
    ``simulator``), or None for data that do not carry it (real recordings, older simulations)."""
    sim = (meta or {}).get("simulator")
    if not isinstance(sim, dict) or not isinstance(sim.get("config"), dict):
        return None
    from blenav.sim.config import make_sim_config

    return make_sim_config(sim["config"])


def _interp_xyz(gt, t: np.ndarray) -> np.ndarray:
    gt_t = gt["t"].to_numpy(float)
    z = gt["z"].to_numpy(float) if "z" in gt and not gt["z"].isna().all() else np.zeros(len(gt_t))
    return np.stack([np.interp(t, gt_t, gt["x"].to_numpy(float)), np.interp(t, gt_t, gt["y"].to_numpy(float)),
                     np.interp(t, gt_t, z)], axis=1)


def session_bound(session, simcfg, settings: BoundSettings = BoundSettings()) -> dict:
    """The PCRLB along ``session``'s ground truth: ``{"t" (K,), "bound_m" (K,) = sqrt(trace of the position
    block of J_k^{-1}), "P" (K, 2, 2) that block (m^2), "q", "dt_s"}``. Raises ValueError for a session it cannot bound (no ground truth
    span, a static survey)."""
    from blenav.sim.calibration import profile_for
    from blenav.sim.radio import fading_moments_db, k_factor

    if session.carrier == "static":
        raise ValueError("a static survey has no motion model (the device jumps between survey points)")
    gt = session.groundtruth
    gt_t = gt["t"].to_numpy(float)
    dt = float(settings.dt_s)
    tk = np.arange(gt_t[0] + dt, gt_t[-1] + 1e-9, dt)  # the end of each step
    K = len(tk)
    if K < 2:
        raise ValueError(f"ground truth spans {gt_t[-1] - gt_t[0]:g} s, less than two {dt:g} s steps")
    q = fit_process_noise(gt_t, gt[["x", "y"]].to_numpy(float), dt)
    F, Q = cv_model(dt, q)
    anchors = session.building.anchors
    cols = ["x_true", "y_true", "z_true"] if "x_true" in anchors else ["x", "y", "z"]
    index = {a: i for i, a in enumerate(anchors["anchor_id"].astype(str))}
    xyz = anchors[cols].to_numpy(float)
    Jz = np.zeros((K, 4, 4))

    def steps_of(t):
        s = np.ceil((t - gt_t[0]) / dt - 1e-9).astype(int) - 1
        return s, (s >= 0) & (s < K)

    if settings.rssi and session.has("rssi"):
        r = session.stream("rssi")
        t = r["t"].to_numpy(float)
        aid = r["anchor_id"].astype(str).map(index)
        s, ok = steps_of(t)
        ok &= aid.notna().to_numpy()
        prof = profile_for(str(session.meta.get("device_model")), simcfg.ble) \
            if str(session.meta.get("device_model")) in _profiles() else None
        gain = prof.gain if prof else 1.0
        rx_std = float(prof.std_db[0]) if prof else 0.0
        fade_var = fading_moments_db(float(k_factor(simcfg.ble, np.array(1.0), np.array(0.0))))[1]
        Jz[:, :2, :2] += rssi_information(s[ok], aid[ok].to_numpy(int), _interp_xyz(gt, t[ok]), xyz, K,
                                          gain * 10.0 * simcfg.ble.path_loss_exponent,
                                          (gain * simcfg.ble.shadow_std_db) ** 2, gain**2 * fade_var + rx_std**2)
    if settings.rtt and session.has("rtt"):
        r = session.stream("rtt")
        t = r["t"].to_numpy(float)
        aid = r["anchor_id"].astype(str).map(index)
        s, ok = steps_of(t)
        ok &= aid.notna().to_numpy()
        Jz[:, :2, :2] += range_information(s[ok], aid[ok].to_numpy(int), _interp_xyz(gt, t[ok]), xyz, K,
                                           simcfg.rtt.std_m, simcfg.rtt.std_per_m)
    if settings.visual and session.has("visual"):
        s, ok = steps_of(session.stream("visual")["t"].to_numpy(float))
        np.add.at(Jz, (s[ok], slice(0, 2), slice(0, 2)), np.eye(2) / simcfg.visual.pos_std_m**2)
    fl = session.floor
    w, h = _floor_extent(fl)
    J0 = np.diag([12.0 / w**2, 12.0 / h**2, 1.0 / simcfg.motion.speed**2, 1.0 / simcfg.motion.speed**2])
    J = pcrlb_recursion(F, Q, Jz, J0)
    P = np.linalg.inv(J)[:, :2, :2]
    return {"t": tk, "bound_m": np.sqrt(np.trace(P, axis1=1, axis2=2)), "P": P, "q": q, "dt_s": dt}


def _profiles():
    from blenav.sim.receivers import TABLE_3_2

    return TABLE_3_2


def _floor_extent(floor) -> tuple[float, float]:
    """Width and height (m) of a floor's plan."""
    occ = np.asarray(floor.occupancy)
    return occ.shape[1] * float(floor.resolution), occ.shape[0] * float(floor.resolution)


def bound_entry(dataset_meta: dict, sessions: list, init_s: float, settings: BoundSettings = BoundSettings(),
                n_draws: int = 200, seed: int = 0) -> dict:
    """The results.json entry ``methods.PCRLB`` (``kind: bound``): ``rmse_m`` (per session the RMS of the
    per-step bound over the tracking period t >= t_0 + init_s, as the methods' RMSE; mean etc. over
    sessions), ``error_m`` of an efficient estimator (errors drawn from N(0, J_k^{-1}) per step: what the
    error percentiles would be for an estimator that attains the bound), ``per_session``, ``settings``; or
    ``{"skipped": {session: reason}}`` on data without the simulator's parameters."""
    simcfg = sim_parameters(dataset_meta)
    if simcfg is None:
        reason = ("not a simulated dataset (dataset.yaml has no `simulator` parameters): the bound needs the "
                  "simulator's motion and channel models")
        return {"kind": "bound", "skipped": {s.id: reason for s in sessions}}
    from .metrics import error_stats, summary

    rng = np.random.default_rng(seed)
    per, skipped, rms, draws, curves = {}, {}, [], [], {}
    for s in sessions:
        try:
            b = session_bound(s, simcfg, settings)
        except ValueError as exc:
            skipped[s.id] = str(exc)
            continue
        track = b["t"] >= b["t"][0] - b["dt_s"] + init_s
        if not track.any():
            track[:] = True
        v = float(np.sqrt(np.mean(b["bound_m"][track] ** 2)))
        rms.append(v)
        # an efficient estimator's planar error at each step: |e|, e ~ N(0, P_k) with P_k the bound's covariance
        L = np.linalg.cholesky(b["P"][track])
        e = np.linalg.norm(np.einsum("kij,nkj->nki", L, rng.standard_normal((n_draws, int(track.sum()), 2))), axis=-1)
        draws.append(e.ravel())
        per[s.id] = {"rmse_m": summary(np.array([v])), "q_m2s3": b["q"], "steps": int(track.sum())}
        curves[s.id] = {"t": b["t"], "bound_m": b["bound_m"]}
    out: dict = {"kind": "bound", "settings": {"dt_s": settings.dt_s, "rssi": settings.rssi, "rtt": settings.rtt,
                                               "visual": settings.visual}}
    if rms:
        out.update({"rmse_m": summary(np.array(rms)), "error_m": error_stats(np.concatenate(draws)),
                    "ate_m": float(np.mean(rms)), "per_session": per})
    if skipped:
        out["skipped"] = skipped
    out["_curves"] = curves  # not for results.json: the leaderboard's plots (popped by blenav.eval.leaderboard)
    out["_errors"] = np.concatenate(draws) if draws else np.zeros(0)
    return out
