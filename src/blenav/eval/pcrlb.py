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
the KF's covariance (tests/eval/test_pcrlb.py checks it).

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
- Anchor positions: :func:`blenav.radio_stats.anchor_positions` (the true ones the simulator wrote). Packets of
  an anchor whose position anchors.csv leaves empty are not counted; the entry names those anchors
  (``no_position``) and results.md says so.

Every simplification makes the bound lower (more optimistic), as a bound should be: channel parameters
(beacon powers, receiver offset, RTT offsets, path-loss exponent) known, wall and body losses known,
shadowing independent between steps (it is correlated over ``shadow_corr_m``), fading at its line-of-sight
(smallest) variance, quantisation ignored. Not in the bound: the inertial sensors and odometry (a method
that uses them has information the radio bound does not count) and the floor plan (walls constrain a
walker; a map-aware method can go below a bound that does not know them). The start: ``J_0`` of a uniform
position over the floor's bounding box (variance W^2 / 12 per axis) and a velocity of std the carrier's nominal
speed (``motion.speed`` for a pedestrian, ``motion.robot_speed`` for the robot).

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


SENSORS = ("rssi", "rtt", "visual")


def session_information(session, simcfg, dt_s: float, sensors=SENSORS) -> dict:
    """What the bound of ``session`` needs, whichever measurements a variant counts: ``{"t" (K,) the end of
    each ``dt_s`` step (s), "dt_s", "q" (m^2/s^3), "F", "Q" (4, 4), "J0" (4, 4) the prior's information,
    "Jz": {sensor: (K, 2, 2) position information of that stream}`` for each of ``sensors`` the session has,
    and "no_position": the anchors heard whose position anchors.csv does not give (their packets are not
    counted). Computed once per session; :func:`bound_of` runs the recursion for one choice of sensors.
    Raises ValueError for a session it cannot bound (a static survey, ground truth shorter than two steps)."""
    from blenav.radio_stats import anchor_positions
    from blenav.sim.radio import fading_moments_db, k_factor
    from blenav.sim.receivers import TABLE_3_2, make_profile

    if session.carrier == "static":
        raise ValueError("a static survey has no motion model (the device jumps between survey points)")
    gt = session.groundtruth
    gt_t = gt["t"].to_numpy(float)
    dt = float(dt_s)
    tk = np.arange(gt_t[0] + dt, gt_t[-1] + 1e-9, dt)  # the end of each step
    K = len(tk)
    if K < 2:
        raise ValueError(f"ground truth spans {gt_t[-1] - gt_t[0]:g} s, less than two {dt:g} s steps")
    q = fit_process_noise(gt_t, gt[["x", "y"]].to_numpy(float), dt)
    F, Q = cv_model(dt, q)
    anchors = anchor_positions(session.building)  # the true positions where the simulator wrote them
    xyz = anchors[["x", "y", "z"]].to_numpy(float)
    located = np.isfinite(xyz).all(axis=1)
    index = {a: i for i, a in enumerate(anchors.index)}
    no_position: set[str] = set()

    def steps_of(t):
        s = np.ceil((t - gt_t[0]) / dt - 1e-9).astype(int) - 1
        return s, (s >= 0) & (s < K)

    def packets(name):
        """Step, anchor index and true receiver position (N, 3) of the stream's rows in [t_0, t_K] whose
        anchor has a position."""
        r = session.stream(name)
        t = r["t"].to_numpy(float)
        aid = r["anchor_id"].astype(str).map(index)
        s, ok = steps_of(t)
        ok &= aid.notna().to_numpy()
        a = aid.fillna(-1).to_numpy(int)
        lost = ok & ~located[a]
        no_position.update(r["anchor_id"].astype(str)[lost])
        ok &= ~lost
        return s[ok], a[ok], session.positions_at(t[ok], with_z=True)

    Jz = {}
    if "rssi" in sensors and session.has("rssi"):
        device = str(session.meta.get("device_model"))
        fading = fading_moments_db(float(k_factor(simcfg.ble, np.array(1.0), np.array(0.0))))  # at 1 m, line of sight
        prof = make_profile(device, fading) if device in TABLE_3_2 else None  # as blenav.sim.calibration.profile_for
        gain = prof.gain if prof else 1.0
        rx_std = float(prof.std_db[0]) if prof else 0.0
        Jz["rssi"] = rssi_information(*packets("rssi"), xyz, K, gain * 10.0 * simcfg.ble.path_loss_exponent,
                                      (gain * simcfg.ble.shadow_std_db) ** 2, gain**2 * fading[1] + rx_std**2)
    if "rtt" in sensors and session.has("rtt"):
        Jz["rtt"] = range_information(*packets("rtt"), xyz, K, simcfg.rtt.std_m, simcfg.rtt.std_per_m)
    if "visual" in sensors and session.has("visual"):
        s, ok = steps_of(session.stream("visual")["t"].to_numpy(float))
        Jz["visual"] = np.zeros((K, 2, 2))
        np.add.at(Jz["visual"], s[ok], np.eye(2) / simcfg.visual.pos_std_m**2)
    x0, x1, y0, y1 = session.floor.extent
    speed = simcfg.motion.robot_speed if session.carrier == "robot" else simcfg.motion.speed  # the carrier's own
    J0 = np.diag([12.0 / (x1 - x0) ** 2, 12.0 / (y1 - y0) ** 2, 1.0 / speed**2, 1.0 / speed**2])
    return {"t": tk, "dt_s": dt, "q": q, "F": F, "Q": Q, "J0": J0, "Jz": Jz, "no_position": sorted(no_position)}


def bound_of(info: dict, settings: BoundSettings) -> dict:
    """The PCRLB of one variant from :func:`session_information`: ``{"t" (K,), "bound_m" (K,) = sqrt(trace of
    the position block of J_k^{-1}), "P" (K, 2, 2) that block (m^2), "q", "dt_s"}``, counting the sensors
    ``settings`` switches on."""
    K = len(info["t"])
    Jz = np.zeros((K, 4, 4))
    for sensor in SENSORS:
        if getattr(settings, sensor) and sensor in info["Jz"]:
            Jz[:, :2, :2] += info["Jz"][sensor]
    J = pcrlb_recursion(info["F"], info["Q"], Jz, info["J0"])
    P = np.linalg.inv(J)[:, :2, :2]
    return {"t": info["t"], "bound_m": np.sqrt(np.trace(P, axis1=1, axis2=2)), "P": P, "q": info["q"],
            "dt_s": info["dt_s"]}


def session_bound(session, simcfg, settings: BoundSettings = BoundSettings()) -> dict:
    """The PCRLB along ``session``'s ground truth (:func:`bound_of` of :func:`session_information`). Raises
    ValueError for a session it cannot bound (no ground truth span, a static survey)."""
    used = tuple(k for k in SENSORS if getattr(settings, k))
    return bound_of(session_information(session, simcfg, settings.dt_s, used), settings)


def bound_entries(dataset_meta: dict, sessions: list, init_s: float, variants: dict[str, BoundSettings],
                  n_draws: int = 200, seed: int = 0) -> dict[str, dict]:
    """The results.json entries ``methods[name]`` (``kind: bound``) of every variant ``{name: settings}`` (one
    ``dt_s`` for all): each session's information is computed once (:func:`session_information`) and the
    recursion run per variant (:func:`bound_of`). Each entry: ``rmse_m`` (per session the RMS of the per-step
    bound over the tracking period t >= t_0 + init_s, as the methods' RMSE; mean etc. over sessions),
    ``error_m`` of an efficient estimator (errors drawn from N(0, J_k^{-1}) per step, ``seed`` for every
    variant: what the error percentiles would be for an estimator that attains the bound), ``per_session``,
    ``settings``, ``no_position`` ({session: anchors heard without a position, not counted}) when any; or
    ``{"skipped": {session: reason}}`` on data without the simulator's parameters."""
    dts = {float(st.dt_s) for st in variants.values()}
    if len(dts) != 1:
        raise ValueError(f"bound variants must share one dt_s, got {sorted(dts)}")
    simcfg = sim_parameters(dataset_meta)
    if simcfg is None:
        reason = ("not a simulated dataset (dataset.yaml has no `simulator` parameters): the bound needs the "
                  "simulator's motion and channel models")
        return {name: {"kind": "bound", "skipped": {s.id: reason for s in sessions}} for name in variants}
    from .metrics import error_stats, summary

    used = tuple(k for k in SENSORS if any(getattr(st, k) for st in variants.values()))
    acc = {name: {"rng": np.random.default_rng(seed), "per": {}, "rms": [], "draws": [], "curves": {}}
           for name in variants}
    skipped, no_position, dt = {}, {}, dts.pop()
    for s in sessions:
        try:
            info = session_information(s, simcfg, dt, used)
        except ValueError as exc:
            skipped[s.id] = str(exc)
            continue
        if info["no_position"]:
            no_position[s.id] = info["no_position"]
        for name, settings in variants.items():
            a, b = acc[name], bound_of(info, settings)
            track = b["t"] >= b["t"][0] - b["dt_s"] + init_s
            if not track.any():
                track[:] = True
            v = float(np.sqrt(np.mean(b["bound_m"][track] ** 2)))
            a["rms"].append(v)
            # an efficient estimator's planar error at each step: |e|, e ~ N(0, P_k) with P_k the bound's covariance
            L = np.linalg.cholesky(b["P"][track])
            z = a["rng"].standard_normal((n_draws, int(track.sum()), 2))
            a["draws"].append(np.linalg.norm(np.einsum("kij,nkj->nki", L, z), axis=-1).ravel())
            a["per"][s.id] = {"rmse_m": summary(np.array([v])), "q_m2s3": b["q"], "steps": int(track.sum())}
            a["curves"][s.id] = {"t": b["t"], "bound_m": b["bound_m"]}
    out = {}
    for name, settings in variants.items():
        a = acc[name]
        e: dict = {"kind": "bound", "settings": {"dt_s": settings.dt_s, "rssi": settings.rssi, "rtt": settings.rtt,
                                                 "visual": settings.visual}}
        if a["rms"]:
            e.update({"rmse_m": summary(np.array(a["rms"])), "error_m": error_stats(np.concatenate(a["draws"])),
                      "ate_m": float(np.mean(a["rms"])), "per_session": a["per"]})
        if skipped:
            e["skipped"] = dict(skipped)
        if no_position:
            e["no_position"] = dict(no_position)
        e["_curves"] = a["curves"]  # not for results.json: the leaderboard's plots (popped by blenav.eval.leaderboard)
        e["_errors"] = np.concatenate(a["draws"]) if a["draws"] else np.zeros(0)
        out[name] = e
    return out


def bound_entry(dataset_meta: dict, sessions: list, init_s: float, settings: BoundSettings = BoundSettings(),
                n_draws: int = 200, seed: int = 0) -> dict:
    """The entry ``methods.PCRLB`` of one variant (:func:`bound_entries`)."""
    return bound_entries(dataset_meta, sessions, init_s, {"PCRLB": settings}, n_draws, seed)["PCRLB"]
