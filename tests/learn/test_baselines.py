"""Baselines of Roy, Table 3.5 (KNN, Bayesian grid, KRR+KF, DL-RNN) on a synthetic radio map.

The map: 6 beacons on the corners and long-side midpoints of a 20 x 10 m area, log-distance RSSI on the
thesis scale u = 30 - 20 log10(d) + N(0, 3^2) (u = rssi + 100, -70 dBm at 1 m), a reading is lost with
probability 0.1 or when u < 2; windows of H = 5 steps at 1 Hz, training windows static at uniform points.
"""

from __future__ import annotations

import numpy as np
import pytest
import torch
from threadpoolctl import threadpool_limits

from blenav.configs import compose
from blenav.features.scale import U_SCALE
from blenav.learn.crossphone.baselines import (BASELINES, BayesianGrid, KRRKF, KNNBaseline, cv_kalman_gain,
                                               cv_kalman_smooth, fingerprint, make_baseline)
from blenav.learn.crossphone.checkpoint import build_networks
from blenav.models import DLRNN

BEACONS = np.array([[0, 0], [10, 0], [20, 0], [0, 10], [10, 10], [20, 10]], float)
AREA = np.array([20.0, 10.0])
H = 5


def readings(P: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """Positions (..., 2) m -> one step's readings (..., B) on the thesis scale, 0 = not heard."""
    d = np.linalg.norm(P[..., None, :] - BEACONS, axis=-1).clip(0.5)
    u = 30.0 - 20.0 * np.log10(d) + rng.normal(0.0, 3.0, d.shape)
    heard = (u > 2.0) & (rng.random(d.shape) > 0.1)
    return np.where(heard, u.clip(0.5), 0.0)


def static_windows(n: int, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """n windows (n, B, H) taken at uniform random points, labels (n, 2) m."""
    xy = rng.uniform([0.0, 0.0], AREA, (n, 2))
    return readings(np.repeat(xy[:, None], H, axis=1), rng).transpose(0, 2, 1), xy


@pytest.fixture(scope="module", autouse=True)
def single_thread():
    """These problems are tiny: one BLAS / torch thread is faster, and much faster on a loaded 2-core box."""
    n = torch.get_num_threads()
    torch.set_num_threads(1)
    with threadpool_limits(1):
        yield
    torch.set_num_threads(n)


@pytest.fixture(scope="module")
def radio_map():
    rng = np.random.default_rng(0)
    S, xy = static_windows(1500, rng)
    St, xyt = static_windows(300, rng)
    return S, xy, St, xyt


def mean_err(p: np.ndarray, xy: np.ndarray) -> float:
    return float(np.linalg.norm(p - xy, axis=1).mean())


def test_fingerprint_is_the_mean_of_heard_steps():
    S = np.array([[[0, 10, 20, 0, 0], [0, 0, 0, 0, 0], [5, 5, 5, 5, 5]]], float)  # (1, 3, 5)
    assert np.allclose(fingerprint(S), [[15.0, 0.0, 5.0]])
    with pytest.raises(ValueError, match=r"\(N, B, H\)"):
        fingerprint(np.zeros((3, 5)))


@pytest.mark.parametrize("name,kw,limit_m", [("KNN", {}, 1.5), ("KNN", {"weights": "distance"}, 1.5),
                                             ("Bayesian", {}, 1.5), ("KRR+KF", {"n_components": 500}, 1.5)])
def test_baselines_localize_held_out_points(radio_map, name, kw, limit_m):
    S, xy, St, xyt = radio_map
    model = make_baseline(name, **kw).fit(S, xy)
    p = model.predict(St)
    assert p.shape == (len(St), 2)
    naive = mean_err(np.broadcast_to(xy.mean(axis=0), xyt.shape), xyt)  # about 6 m
    err = mean_err(p, xyt)
    assert err < 0.5 * naive and err < limit_m, (name, err, naive)
    assert np.allclose(model.predict_sequence(St[:20]).shape, (20, 2))


def test_fit_drops_unlabelled_rows_and_checks_beacons(radio_map):
    S, xy, St, xyt = radio_map
    xy_nan = xy.copy()
    xy_nan[::2] = np.nan
    a = KNNBaseline().fit(S, xy_nan)
    b = KNNBaseline().fit(S[1::2], xy[1::2])
    assert np.allclose(a.predict(St), b.predict(St))
    with pytest.raises(ValueError, match="6 beacons"):
        a.predict(St[:, :5])
    with pytest.raises(RuntimeError, match="not fitted"):
        BayesianGrid().predict(St)


def test_bayesian_posterior_is_normalised_and_its_mean_inside_the_grid(radio_map):
    S, xy, St, _ = radio_map
    keep = (xy[:, 0] < 8) | (xy[:, 0] > 12)  # no training data in a 4 m band across the area
    g = BayesianGrid(cell_m=1.0).fit(S[keep], xy[keep])
    lp = g.log_posterior(St[:50])
    assert lp.shape == (50, len(g.centres_)) and np.allclose(np.exp(lp).sum(axis=1), 1.0)
    lo, hi = g.grid_origin_, g.grid_origin_ + np.array(g.grid_shape_) * g.cell_m
    p = g.predict(St)
    assert ((p >= lo) & (p <= hi)).all()
    # candidates: cells with data or within one cell of it -> no centre in the middle of the empty band
    assert not ((g.centres_[:, 0] > 9.5) & (g.centres_[:, 0] < 10.5)).any()
    assert g.sigma_ >= 2.0 and ((g.p_ >= 0.02) & (g.p_ <= 0.98)).all()
    # chunking does not change the estimate
    assert np.allclose(p, BayesianGrid(cell_m=1.0, chunk_elems=1000).fit(S[keep], xy[keep]).predict(St))


def test_steady_state_kalman_filter_matches_the_textbook_recursion():
    rng = np.random.default_rng(1)
    z = np.cumsum(rng.normal(0, 1, (40, 2)), axis=0)
    dt, q, r = 0.5, 0.3, 1.2
    F, K, P = cv_kalman_gain(dt, q, r)
    Q = q * np.array([[dt ** 3 / 3, dt ** 2 / 2], [dt ** 2 / 2, dt]])
    Hm = np.array([[1.0, 0.0]])
    out = np.empty_like(z)
    for a in range(2):  # explicit KF per axis, prior (z_0, 0) with the steady-state covariance
        s, Pk = np.array([z[0, a], 0.0]), P.copy()
        for k in range(len(z)):
            if k:
                s, Pk = F @ s, F @ Pk @ F.T + Q
            G = Pk @ Hm.T / (Hm @ Pk @ Hm.T + r * r)
            s = s + (G * (z[k, a] - s[0])).ravel()
            Pk = (np.eye(2) - G @ Hm) @ Pk
            out[k, a] = s[0]
    assert np.allclose(cv_kalman_smooth(z, dt, q, r), out)
    assert np.allclose(G.ravel(), K)


def test_krr_kalman_filter_reduces_error_on_a_straight_walk(radio_map):
    S, xy, _, _ = radio_map
    model = KRRKF(n_components=500, seed=0).fit(S, xy)
    assert 0.3 < model.r_m_ < 2.0
    rng = np.random.default_rng(7)
    T = 60
    pos = np.stack([2.0 + 0.25 * np.arange(T + H - 1), np.full(T + H - 1, 4.0)], axis=1)  # 0.25 m/s along x
    # window k covers steps k..k+H-1 of the walk, label at its end. Each window draws its own readings:
    # overlapping sliding windows share H-1 steps, their KRR errors are correlated and the filter gains less.
    W = readings(pos[np.arange(T)[:, None] + np.arange(H)], rng).transpose(0, 2, 1)  # (T, B, H)
    lab = pos[H - 1:]
    alone, filtered = mean_err(model.predict(W), lab), mean_err(model.predict_sequence(W), lab)
    assert filtered < 0.9 * alone, (filtered, alone)


def test_make_baseline_rejects_unknown_names():
    assert sorted(BASELINES) == ["Bayesian", "KNN", "KRR+KF"]
    assert isinstance(make_baseline("KNN", k=3), KNNBaseline)
    with pytest.raises(ValueError, match=r"unknown baseline 'SVM'.*\['Bayesian', 'KNN', 'KRR\+KF'\]"):
        make_baseline("SVM")


def seeded(seed: int, build):
    with torch.random.fork_rng():
        torch.manual_seed(seed)
        return build()


def test_dlrnn_shapes_normalisation_and_config():
    net = seeded(0, lambda: DLRNN(6, hidden=16))
    S = torch.rand(4, 6, H, generator=torch.Generator().manual_seed(0))
    final, coarse = net.forward_all(S)
    assert net(S).shape == (4, 2) and final.shape == (4, 2) and coarse.shape == (4, H, 2)
    xy = torch.tensor([[0.0, 0.0], [20.0, 10.0], [10.0, 5.0]])
    net.set_normalisation(xy)
    assert torch.allclose(net.xy_mean, torch.tensor([10.0, 5.0]))
    assert torch.allclose(net(S), final * net.xy_scale + net.xy_mean)
    with pytest.raises(ValueError, match="expects"):
        net(torch.zeros(2, 5, H))
    cfg = compose("train", "model=dlrnn")
    locnet, transnet = build_networks(cfg.model, n_beacons=6)
    assert isinstance(locnet, DLRNN) and transnet is None and locnet.hidden == 64


def test_dlrnn_trains_on_the_radio_map(radio_map):
    S, xy, St, xyt = radio_map
    g = torch.Generator().manual_seed(0)
    X, Y = torch.tensor(S / U_SCALE, dtype=torch.float32), torch.tensor(xy, dtype=torch.float32)
    Xt, Yt = torch.tensor(St / U_SCALE, dtype=torch.float32), torch.tensor(xyt, dtype=torch.float32)
    net = seeded(0, lambda: DLRNN(6, hidden=32))
    net.set_normalisation(Y)
    with torch.no_grad():
        before = (net(Xt) - Yt).norm(dim=1).mean().item()
    opt = torch.optim.Adam(net.parameters(), lr=1e-2)
    for _ in range(300):
        i = torch.randint(0, len(X), (128,), generator=g)
        loss = ((net(X[i]) - Y[i]) ** 2).sum(dim=1).mean()
        opt.zero_grad()
        loss.backward()
        opt.step()
    with torch.no_grad():
        after = (net(Xt) - Yt).norm(dim=1).mean().item()
    assert after < 0.5 * before, (before, after)
