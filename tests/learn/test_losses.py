"""Losses of the cross-phone localizer against brute-force loops over the equations."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from blenav.learn.crossphone.losses import (brand_statistics, localization_loss, position_smoothness_loss, ssl_loss,
                                            temporal_smoothness_loss, total_loss)


def _windows(rng, n=6, B=4, H=3):
    S = rng.uniform(0, 0.6, (n, B, H)) * (rng.random((n, B, H)) > 0.4)
    return S.astype(np.float32)


def test_brand_statistics_matches_eq_3_1():
    rng = np.random.default_rng(0)
    S = _windows(rng, n=20)
    M = brand_statistics(S)
    vecs = [S[k, :, t] for k in range(S.shape[0]) for t in range(S.shape[2])]
    for i in range(4):
        for j in range(4):
            sel = [v[j] for v in vecs if v[i] > 0]
            np.testing.assert_allclose(M[i, j], np.mean(sel) if sel else 0.0, rtol=1e-6)


def test_ssl_loss_matches_eqs_3_2_to_3_4():
    rng = np.random.default_rng(1)
    S = _windows(rng)
    g = _windows(rng)
    M = brand_statistics(_windows(rng, n=30))
    got = ssl_loss(torch.tensor(g), torch.tensor(S), torch.tensor(M), tau=0.1).item()
    total = 0.0
    for b in range(S.shape[0]):
        for t in range(S.shape[2]):
            for i in range(S.shape[1]):
                w = np.exp((S[b, i, t] - M[i, i]) / 0.1)
                for j in range(S.shape[1]):
                    d = M[i, j] - g[b, j, t]
                    total += w * (abs(d) if d < 0 else d * d)
    np.testing.assert_allclose(got, total / S.shape[0], rtol=1e-5)


def test_smoothness_and_localization_losses():
    rng = np.random.default_rng(2)
    g = torch.tensor(_windows(rng))
    ref = sum(abs(float(g[b, i, t] - g[b, i, t + 1])) for b in range(6) for i in range(4) for t in range(2)) / 6
    np.testing.assert_allclose(temporal_smoothness_loss(g).item(), ref, rtol=1e-5)
    f = torch.tensor([[0.0, 0.0], [3.0, 4.0]])
    x = torch.tensor([[0.0, 1.0], [0.0, 0.0]])
    assert localization_loss(f, x).item() == (1.0 + 25.0) / 2
    assert position_smoothness_loss(f, x).item() == (1.0 + 25.0) / 2
    terms = {"loc": torch.tensor(2.0), "ts": torch.tensor(3.0)}
    assert total_loss(terms, {"loc": 1.0, "ts": 0.5, "ssl": 9.0}).item() == 3.5


def test_ssl_loss_equals_its_dense_form_with_gradients():
    """The sorted-prefix-sum evaluation of eq. 3.2 gives the direct form's value and gradient."""
    from blenav.learn.crossphone.losses import ssl_loss_dense

    gen = torch.Generator().manual_seed(3)
    S = torch.rand(16, 12, 5, generator=gen) * 0.6 * (torch.rand(16, 12, 5, generator=gen) > 0.5)
    M = torch.tensor(brand_statistics(_windows(np.random.default_rng(4), n=40, B=12, H=5)))
    grads = []
    for f in (ssl_loss, ssl_loss_dense):
        g = (torch.rand(16, 12, 5, generator=torch.Generator().manual_seed(5)) * 0.6).double().requires_grad_()
        L = f(g, S.double(), M.double())
        L.backward()
        grads.append((L.item(), g.grad))
    assert grads[0][0] == pytest.approx(grads[1][0], rel=1e-10)
    torch.testing.assert_close(grads[0][1], grads[1][1], rtol=1e-9, atol=1e-12)
