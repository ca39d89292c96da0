"""The PCRLB recursion (blenav.eval.pcrlb) against references: the Kalman filter's covariance on a
linear-Gaussian model (where the bound is attained), the Fisher information of RSSI and RTT by finite
differences, and the bound along a tiny simulated session against the Kalman covariance of its BLE information
rebuilt packet by packet (smaller with more sensors, larger with more shadowing, skipped on real data)."""

from __future__ import annotations

import numpy as np
import pytest

from blenav.eval.pcrlb import (LN10, cv_model, fit_process_noise, pcrlb_recursion, range_information,
                               rssi_information)


def kalman_covariances(F, Q, H, R, P0, K):
    """Posterior covariances P_1..P_K of the Kalman filter (predict, then update with z = H x + N(0, R))."""
    P, out = P0, []
    for _ in range(K):
        P = F @ P @ F.T + Q
        S = H @ P @ H.T + R
        G = P @ H.T @ np.linalg.inv(S)
        P = (np.eye(len(P)) - G @ H) @ P
        out.append(P)
    return np.array(out)


def test_pcrlb_equals_kalman_covariance_on_linear_gaussian_model():
    F, Q = cv_model(0.5, 0.3)
    H = np.array([[1.0, 0, 0, 0], [0, 1.0, 0, 0]])
    R = np.array([[0.8, 0.1], [0.1, 0.5]])
    P0 = np.diag([4.0, 9.0, 1.0, 1.0])
    K = 40
    Jz = np.broadcast_to(H.T @ np.linalg.inv(R) @ H, (K, 4, 4)).copy()
    Jz[::3] = 0.0  # some steps without a measurement
    P_kf = []
    P = P0
    for k in range(K):
        P = F @ P @ F.T + Q
        if k % 3:
            P = kalman_covariances(np.eye(4), np.zeros((4, 4)), H, R, P, 1)[0]
        P_kf.append(P)
    J = pcrlb_recursion(F, Q, Jz, np.linalg.inv(P0))
    np.testing.assert_allclose(np.linalg.inv(J), np.array(P_kf), rtol=1e-9, atol=1e-12)


def test_pcrlb_time_varying_model_matches_kalman():
    rng = np.random.default_rng(3)
    K = 25
    F = np.stack([np.eye(2) + 0.1 * rng.standard_normal((2, 2)) for _ in range(K)])
    A = rng.standard_normal((K, 2, 2))
    Q = A @ np.transpose(A, (0, 2, 1)) + 0.1 * np.eye(2)
    H = np.array([[1.0, 0.5]])
    R = np.array([[0.2]])
    P0 = np.eye(2) * 3.0
    P, ref = P0, []
    for k in range(K):
        P = F[k] @ P @ F[k].T + Q[k]
        P = kalman_covariances(np.eye(2), np.zeros((2, 2)), H, R, P, 1)[0]
        ref.append(P)
    J = pcrlb_recursion(F, Q, np.broadcast_to(H.T @ H / 0.2, (K, 2, 2)), np.linalg.inv(P0))
    np.testing.assert_allclose(np.linalg.inv(J), np.array(ref), rtol=1e-9)


def test_rssi_information_is_the_gradient_outer_product():
    """One packet: J = g g^T / sigma^2 with g the finite-difference gradient of the log-distance mean."""
    a = np.array([[1.0, 2.0, 2.5]])
    p = np.array([[4.0, -1.0, 1.2]])
    slope, var = 22.5, 9.0

    def mean(xy):
        return -slope * np.log10(np.linalg.norm(np.array([*xy, 1.2]) - a[0]))

    h = 1e-6
    g = np.array([(mean(p[0, :2] + h * e) - mean(p[0, :2] - h * e)) / (2 * h) for e in np.eye(2)])
    J = rssi_information(np.array([0]), np.array([0]), p, a, 1, slope, var_shadow=0.0, var_white=var)
    np.testing.assert_allclose(J[0], np.outer(g, g) / var, rtol=1e-6)
    # n packets of one beacon in one step: the white part averages, the shadowing does not
    Jn = rssi_information(np.zeros(4, int), np.zeros(4, int), np.repeat(p, 4, 0), a, 1, slope, var_shadow=4.0,
                          var_white=var)
    np.testing.assert_allclose(Jn[0], np.outer(g, g) / (4.0 + var / 4), rtol=1e-6)
    # the 2-D formula (10 n / ln 10)^2 / sigma^2 u u^T / d^2 when the heights agree
    p2 = np.array([[4.0, -1.0, 2.5]])
    J2 = rssi_information(np.array([0]), np.array([0]), p2, a, 1, slope, 0.0, var)[0]
    d = p2[0, :2] - a[0, :2]
    u = d / np.linalg.norm(d)
    np.testing.assert_allclose(J2, (slope / LN10) ** 2 / var * np.outer(u, u) / (d @ d), rtol=1e-9)


def test_range_information():
    a = np.array([[0.0, 0.0, 2.0]])
    p = np.array([[3.0, 4.0, 2.0]])
    J = range_information(np.array([1]), np.array([0]), p, a, 2, std_m=0.3, std_per_m=0.02)
    u = np.array([0.6, 0.8])
    np.testing.assert_allclose(J[1], np.outer(u, u) / (0.3 + 0.02 * 5.0) ** 2)
    assert not J[0].any()


def test_fit_process_noise_recovers_white_acceleration():
    """A velocity random walk of intensity q sampled at 100 Hz: the fit at dt = 1 s recovers q."""
    rng = np.random.default_rng(0)
    q, h, T = 0.2, 0.01, 3000.0
    n = int(T / h)
    v = np.cumsum(rng.standard_normal((n, 2)) * np.sqrt(q * h), axis=0)
    xy = np.cumsum(v * h, axis=0)
    q_hat = fit_process_noise(np.arange(n) * h, xy, 1.0)
    assert q_hat == pytest.approx(q, rel=0.1)


@pytest.fixture(scope="module")
def tiny_sim(tmp_path_factory):
    from blenav.sim.config import make_sim_config
    from blenav.sim.world import simulate

    cfg = make_sim_config({"name": "quay_lab", "layout": {"width_m": 12.0, "height_m": 9.0, "n_h": 1, "n_v": 0,
                                                          "layout_seed": 1, "furniture_max": 0},
                           "n_beacons": 5, "n_rtt_aps": 1, "receivers": ["honor-20-pro"], "carriers": ["pedestrian"]})
    return simulate(cfg, seed=4, out=tmp_path_factory.mktemp("pcrlb") / "sim", duration_s=30.0, sessions=1)


def kalman_position_covariances(F, Q, Jz, P0):
    """Position blocks (K, 2, 2) of the Kalman filter's posterior covariances when step k brings the
    information ``Jz[k]`` (n, n): written as the pseudo-measurement ``z = H x + N(0, I)`` with ``H^T H = Jz[k]``
    (rows sqrt(lambda_i) e_i^T of its eigen-decomposition), predict then the textbook gain update."""
    P, out = P0, []
    for Jk in Jz:
        P = F @ P @ F.T + Q
        lam, vec = np.linalg.eigh(Jk)
        H = (np.sqrt(np.clip(lam, 0.0, None))[:, None] * vec.T)[lam > 1e-12 * max(lam.max(), 1.0)]
        if len(H):
            G = P @ H.T @ np.linalg.inv(H @ P @ H.T + np.eye(len(H)))
            P = (np.eye(len(P)) - G @ H) @ P
            P = 0.5 * (P + P.T)
        out.append(P[:2, :2])
    return np.array(out)


def rssi_information_reference(session, simcfg, K, dt):
    """The BLE packets' position information (K, 2, 2) rebuilt packet by packet from the simulator's channel
    model (blenav.sim.radio: reported = gain (P - 10 n log10 d + S + F) + N(0, rx_std^2), d the 3-D distance):
    the packet at time t belongs to step k when t_0 + k dt < t <= t_0 + (k + 1) dt; its gradient is the central
    difference of the mean level at the interpolated true position; per step and beacon the n gradients are
    averaged and weighted by 1 / (var_shadow + var_white / n)."""
    import pandas as pd

    from blenav.sim.radio import fading_moments_db, k_factor
    from blenav.sim.receivers import make_profile

    fading = fading_moments_db(float(k_factor(simcfg.ble, np.array(1.0), np.array(0.0))))
    prof = make_profile(session.meta["device_model"], fading)
    slope = prof.gain * 10.0 * simcfg.ble.path_loss_exponent
    var_shadow = (prof.gain * simcfg.ble.shadow_std_db) ** 2
    var_white = prof.gain**2 * fading[1] + prof.std_db[0] ** 2
    a = pd.read_csv(session.building.root / "anchors.csv").set_index("anchor_id")
    gt = session.groundtruth
    t0 = float(gt["t"].iloc[0])
    grads: dict = {}
    for t, aid in zip(session.rssi["t"].to_numpy(float), session.rssi["anchor_id"].astype(str)):
        k = int(np.floor((t - t0) / dt))
        if np.isclose((t - t0) / dt, round((t - t0) / dt)):
            k = int(round((t - t0) / dt)) - 1  # on a step's end: that step
        if not 0 <= k < K or aid not in a.index:
            continue
        anchor = a.loc[aid, ["x_true", "y_true", "z_true"]].to_numpy(float)
        p = np.array([np.interp(t, gt["t"], gt[c]) for c in ("x", "y", "z")])

        def level(xy):
            return -slope * np.log10(np.linalg.norm(np.array([xy[0], xy[1], p[2]]) - anchor))

        h = 1e-5
        g = np.array([(level(p[:2] + h * e) - level(p[:2] - h * e)) / (2 * h) for e in np.eye(2)])
        grads.setdefault((k, aid), []).append(g)
    J = np.zeros((K, 2, 2))
    for (k, _), gs in grads.items():
        g = np.mean(gs, axis=0)
        J[k] += np.outer(g, g) / (var_shadow + var_white / len(gs))
    return J


def test_session_bound_on_a_tiny_sim(tiny_sim):
    """The bound along a simulated walk is the Kalman filter's covariance (textbook gain update, computed here)
    of the CV model fed with the walk's BLE information rebuilt here packet by packet from the simulator's
    channel model; it brackets physically (never above the prior alone, nor above a step's own measurements),
    grows with the shadowing, scales as the noise std, and shrinks with more sensors."""
    from dataclasses import replace

    from blenav.data import Dataset
    from blenav.eval.pcrlb import (BoundSettings, bound_entry, bound_of, session_bound, session_information,
                                   sim_parameters)
    from blenav.sim.radio import fading_moments_db, rician_db

    ds = Dataset.open(tiny_sim)
    simcfg = sim_parameters(ds.meta)
    assert simcfg is not None and simcfg.name == "quay_lab"
    s = ds.session(ds.session_ids[0])
    ble_only = BoundSettings(rtt=False, visual=False)
    ble = session_bound(s, simcfg, ble_only)
    full = session_bound(s, simcfg, BoundSettings())
    assert np.all(np.isfinite(ble["bound_m"])) and len(ble["t"]) == 29  # 1 s steps over 0..29.9 s
    assert np.all(full["bound_m"] <= ble["bound_m"] + 1e-9)  # more sensors: never a larger bound
    assert np.any(full["bound_m"] < 0.99 * ble["bound_m"])  # and the RTT access point does help
    # the reference: the information rebuilt from rssi.csv + anchors.csv, through the Kalman covariance recursion
    info = session_information(s, simcfg, 1.0, ("rssi",))
    K, t0, x0, x1, y0, y1 = len(ble["t"]), float(s.groundtruth["t"].iloc[0]), *s.floor.extent
    np.testing.assert_allclose(ble["t"], t0 + np.arange(1, K + 1))
    Jz_ref = rssi_information_reference(s, simcfg, K, 1.0)
    assert (np.trace(Jz_ref, axis1=1, axis2=2) > 0).sum() >= K - 1  # five beacons: (nearly) every step hears some
    np.testing.assert_allclose(info["Jz"]["rssi"], Jz_ref, rtol=1e-6, atol=1e-12)
    speed = simcfg.motion.speed
    P0 = np.diag([(x1 - x0) ** 2 / 12, (y1 - y0) ** 2 / 12, speed**2, speed**2])  # uniform floor, nominal speed
    F, Q = cv_model(1.0, fit_process_noise(s.groundtruth["t"], s.groundtruth[["x", "y"]], 1.0))
    np.testing.assert_allclose(info["F"], F)
    np.testing.assert_allclose(info["Q"], Q, rtol=1e-12)
    pad = np.zeros((K, 4, 4))
    pad[:, :2, :2] = Jz_ref
    P_ref = kalman_position_covariances(F, Q, pad, P0)
    np.testing.assert_allclose(ble["P"], P_ref, rtol=1e-6, atol=1e-12)
    np.testing.assert_allclose(ble["bound_m"], np.sqrt(np.trace(P_ref, axis1=1, axis2=2)), rtol=1e-6)
    # the fading variance in the white noise is the simulator's Rician fading (Monte Carlo of its draws, 2 %)
    k_los = 10.0 ** (simcfg.ble.k_factor_1m_db / 10.0)
    mc = rician_db(np.random.default_rng(0), np.full(400_000, k_los))
    assert fading_moments_db(k_los)[1] == pytest.approx(mc.var(), rel=0.02)
    # brackets: below the prior alone (no measurement), below one step's own measurements (no prior, no motion)
    prior = kalman_position_covariances(F, Q, np.zeros((K, 4, 4)), P0)
    assert np.all(ble["bound_m"] < np.sqrt(np.trace(prior, axis1=1, axis2=2)))
    own = np.linalg.det(Jz_ref) > 1e-9 * np.trace(Jz_ref, axis1=1, axis2=2) ** 2
    assert own.sum() >= K // 2
    assert np.all(ble["bound_m"][own] < np.sqrt(np.trace(np.linalg.inv(Jz_ref[own]), axis1=1, axis2=2)))
    # physics: twice the shadowing, a larger bound at every step that hears a beacon
    loud = replace(simcfg, ble=replace(simcfg.ble, shadow_std_db=2 * simcfg.ble.shadow_std_db))
    heard = np.trace(Jz_ref, axis1=1, axis2=2) > 0
    assert np.all(session_bound(s, loud, ble_only)["bound_m"][heard] > ble["bound_m"][heard] * 1.01)
    # every noise std (prior, motion, measurement) times c: the bound times c, exactly
    c = 3.0
    scaled = {**info, "Q": c**2 * info["Q"], "J0": info["J0"] / c**2, "Jz": {"rssi": info["Jz"]["rssi"] / c**2}}
    np.testing.assert_allclose(bound_of(scaled, ble_only)["bound_m"], c * ble["bound_m"], rtol=1e-9)
    e = bound_entry(ds.meta, [s], init_s=5.0)
    track = full["t"] >= full["t"][0] - 1.0 + 5.0
    assert e["kind"] == "bound"
    assert e["rmse_m"]["mean"] == pytest.approx(np.sqrt(np.mean(full["bound_m"][track] ** 2)), rel=1e-12)
    # real data (no simulator parameters): skipped with the reason
    sk = bound_entry({"name": "mall"}, [s], init_s=5.0)
    assert "rmse_m" not in sk and "simulator" in sk["skipped"][s.id]


def test_variants_share_one_information_pass(tiny_sim, monkeypatch):
    """bound_entries computes each session's information once for every variant, and each variant's entry is
    the one bound_entry gives alone (same numbers, same efficient-estimator draws)."""
    import blenav.eval.pcrlb as pcrlb
    from blenav.data import Dataset

    ds = Dataset.open(tiny_sim)
    s = ds.session(ds.session_ids[0])
    variants = {"PCRLB": pcrlb.BoundSettings(), "PCRLB-BLE": pcrlb.BoundSettings(rtt=False, visual=False)}
    alone = {n: pcrlb.bound_entry(ds.meta, [s], 5.0, st, seed=3) for n, st in variants.items()}
    calls = []
    real = pcrlb.session_information
    monkeypatch.setattr(pcrlb, "session_information", lambda *a, **k: calls.append(a[0].id) or real(*a, **k))
    both = pcrlb.bound_entries(ds.meta, [s], 5.0, variants, seed=3)
    assert calls == [s.id]
    for n in variants:
        assert both[n]["rmse_m"] == alone[n]["rmse_m"] and both[n]["error_m"] == alone[n]["error_m"]
        np.testing.assert_array_equal(both[n]["_errors"], alone[n]["_errors"])
    assert both["PCRLB"]["rmse_m"]["mean"] < both["PCRLB-BLE"]["rmse_m"]["mean"]


def test_anchor_without_position_is_not_counted_and_named(tiny_sim, tmp_path):
    import shutil

    import pandas as pd

    from blenav.data import Dataset
    from blenav.eval.pcrlb import BoundSettings, bound_entry, session_bound, sim_parameters

    root = tmp_path / "sim"
    shutil.copytree(tiny_sim, root)
    ds0 = Dataset.open(root)
    s0 = ds0.session(ds0.session_ids[0])
    heard = s0.rssi["anchor_id"].astype(str).value_counts().index[0]  # the beacon heard most
    path = s0.building.root / "anchors.csv"
    a = pd.read_csv(path)
    rows = a["anchor_id"].astype(str) == heard
    for c in ("x", "y", "z", "x_true", "y_true", "z_true"):
        if c in a:
            a[c] = a[c].astype(float)
            a.loc[rows, c] = np.nan
    a.to_csv(path, index=False)
    ds = Dataset.open(root)
    s = ds.session(ds.session_ids[0])
    b = session_bound(s, sim_parameters(ds.meta), BoundSettings(rtt=False, visual=False))
    assert np.all(np.isfinite(b["bound_m"]))
    full = session_bound(s0, sim_parameters(ds0.meta), BoundSettings(rtt=False, visual=False))
    assert np.all(b["bound_m"] >= full["bound_m"] - 1e-12)  # one beacon less: never a smaller bound
    e = bound_entry(ds.meta, [s], init_s=5.0)
    assert e["no_position"] == {s.id: [heard]} and np.isfinite(e["rmse_m"]["mean"])


def test_robot_velocity_prior_is_the_robots_speed(tiny_sim):
    from blenav.data import Dataset
    from blenav.eval.pcrlb import session_information, sim_parameters

    ds = Dataset.open(tiny_sim)
    simcfg = sim_parameters(ds.meta)
    s = ds.session(ds.session_ids[0])
    assert session_information(s, simcfg, 1.0, ())["J0"][2, 2] == pytest.approx(1.0 / simcfg.motion.speed**2)
    s.meta["carrier"] = "robot"
    assert session_information(s, simcfg, 1.0, ())["J0"][2, 2] == pytest.approx(1.0 / simcfg.motion.robot_speed**2)
