"""Receivers that calibrate themselves (blenav.filters.offset): the closed form against quadrature and a
Kalman filter, and an online offset that converges on a phone reading 10 dB low."""

from __future__ import annotations

import shutil

import numpy as np
import pandas as pd
import pytest

from blenav.configs import compose
from blenav.data import Dataset
from blenav.eval.harness import build_methods
from blenav.filters.calibration import fit_sessions
from blenav.filters.offset import RssiDomainOffset
from helpers import simulate_small


def test_marginal_likelihood_equals_quadrature_over_the_offset():
    rng = np.random.default_rng(0)
    m = RssiDomainOffset(sigma_s=4.0, offset_prior_std_db=6.0)
    lead = (2, 3)
    m._state(lead)
    m.mu[:] = rng.normal(0, 3, lead)
    m.P[:] = rng.uniform(1, 40, lead)
    mu0, P0 = m.mu.copy(), m.P.copy()
    e = rng.normal(2.0, 5.0, (5, 6))  # M = 5 packets, P = 6 particles
    ll = m._marginal(e, 4.0, lead)
    b = np.linspace(-80, 80, 40001)
    db = b[1] - b[0]
    for p in range(6):
        r, n = divmod(p, 3)
        prior = np.exp(-0.5 * (b - mu0[r, n]) ** 2 / P0[r, n]) / np.sqrt(2 * np.pi * P0[r, n])
        lik = np.exp(-0.5 * ((e[:, p, None] - b[None]) ** 2).sum(0) / 16.0)  # constants common to all particles
        ref = np.log((prior * lik).sum() * db)
        post_mean = (b * prior * lik).sum() / (prior * lik).sum()
        assert ll[r, n] == pytest.approx(ref, abs=1e-6)
        assert m.mu[r, n] == pytest.approx(post_mean, abs=1e-6)


def test_sequential_updates_equal_the_batch_posterior_and_follow_resampling():
    rng = np.random.default_rng(1)
    m = RssiDomainOffset(offset_prior_std_db=10.0)
    lead = (1, 4)
    es = [rng.normal(-7.0, 3.0, (k, 4)) for k in (3, 1, 6)]
    for e in es:
        m._marginal(e, 3.0, lead)
    allv = np.concatenate(es)
    prec = 1 / 100.0 + len(allv) / 9.0  # conjugate Gaussian posterior over every reading at once
    np.testing.assert_allclose(m.P, 1 / prec)
    np.testing.assert_allclose(m.mu[0], allv.sum(0) / 9.0 / prec)
    before = m.mu.copy()
    m.on_resample(np.array([0]), np.array([[3, 3, 0, 1]]))
    np.testing.assert_array_equal(m.mu[0], before[0, [3, 3, 0, 1]])


@pytest.fixture(scope="module")
def low_phone(tmp_path_factory):
    """Two small-building walks; the second re-received by a phone that reads every beacon 10 dB low."""
    root = tmp_path_factory.mktemp("offset")
    src = simulate_small(root / "src", 5, 90, 2, "sim.receivers=[iphone-8]")
    dst = root / "low"
    shutil.copytree(src, dst)
    sid = Dataset.open(dst).session_ids[1]
    f = dst / "sessions" / sid / "rssi.csv"
    df = pd.read_csv(f)
    df["rssi"] = df["rssi"] - 10.0
    df.to_csv(f, index=False)
    return src, dst, sid


def test_the_online_offset_converges_on_a_phone_reading_10_db_low(low_phone):
    src, dst, sid = low_phone
    ds0, ds = Dataset.open(src), Dataset.open(dst)
    fit = fit_sessions([ds0.session(ds0.session_ids[0])])  # calibrated on the first (unshifted) walk
    ms = build_methods(compose("eval", "experiment=mapfusion_002", f"data={dst}"))
    s = ds.session(sid)
    gt = s.groundtruth
    rmse = {}
    for name in ("PF-PS+MAP", "PF-PS+MAP+offset", "PF-PL+offset"):
        m = ms[name]
        m.apply_path_loss_fit(fit)
        est = m.run(s, 10, 3)
        ref = np.stack([np.interp(est.t, gt.t, gt.x), np.interp(est.t, gt.t, gt.y)], -1)
        e = np.linalg.norm(est.position - ref, axis=-1)[:, est.t > 10]
        rmse[name] = float(np.sqrt((e ** 2).mean(1)).mean())
        if "offset" in name:
            (model,) = m.method.measurements
            assert np.all(np.abs(model.offset_estimate() + 10.0) < 2.0), (name, model.offset_estimate())
    assert rmse["PF-PS+MAP+offset"] < 0.6 * rmse["PF-PS+MAP"], rmse
    assert rmse["PF-PS+MAP+offset"] < 4.0 and rmse["PF-PL+offset"] < 5.0, rmse
