"""The cross-phone LightningModule: one step for all stages, losses that train."""

from __future__ import annotations

import pytest
import torch

from blenav.learn.crossphone.losses import brand_statistics, ssl_loss, temporal_smoothness_loss
from blenav.learn.crossphone.module import CrossPhoneModule
from blenav.models import LocNet, TransNet


def _data(n=256, B=6, H=5, seed=0):
    """Windows whose readings are a smooth function of a 2-D position (a toy radio map)."""
    g = torch.Generator().manual_seed(seed)
    xy = torch.rand(n, 2, generator=g) * 20
    beacons = torch.rand(B, 2, generator=g) * 20
    d = torch.cdist(xy, beacons)  # (n, B)
    u = (0.6 - 0.2 * torch.log10(1 + d)).clamp_min(0)
    S = u[:, :, None].repeat(1, 1, H) + 0.01 * torch.randn(n, B, H, generator=g)
    return S.clamp_min(0), xy


def _module(transnet: bool, weights=None, M=None):
    with torch.random.fork_rng():
        torch.manual_seed(0)
        loc = LocNet(6, hidden=32, fc_hidden=16)
        tn = TransNet(6, channels=(16, 8, 4)) if transnet else None
    return CrossPhoneModule(loc, tn, optimizer=lambda p: torch.optim.Adam(p, lr=3e-3), weights=weights, M=M)


@pytest.mark.parametrize("transnet", [False, True])
def test_training_reduces_the_localization_error(transnet):
    S, xy = _data()
    M = torch.tensor(brand_statistics(S.numpy())) if transnet else None
    m = _module(transnet, weights={"loc": 1.0, "ssl": 1e-4 if transnet else 0.0, "ts": 1e-3 if transnet else 0.0}, M=M)
    m.locnet.set_normalisation(xy)
    opt = m.configure_optimizers()
    batch = {"S": S, "xy": xy}
    before = m.model_step(batch)["err_m"].item()
    for _ in range(150):
        opt.zero_grad()
        out = m.model_step(batch)
        out["loss"].backward()
        opt.step()
    after = m.model_step(batch)["err_m"].item()
    assert after < 0.5 * before, (before, after)
    assert set(out) >= ({"loc", "ssl", "ts", "loss"} if transnet else {"loc", "loss"})


def _grads(loss, params):
    """d loss / d p for every p (zeros where p is not in the graph)."""
    gs = torch.autograd.grad(loss, params, retain_graph=True, allow_unused=True)
    return [torch.zeros_like(p) if g is None else g for g, p in zip(gs, params)]


def test_unlabelled_rows_only_feed_the_unsupervised_terms():
    """Adding unlabelled rows (NaN labels) to a batch leaves the supervised term, its gradient and err_m exactly
    as on the labelled rows alone, whatever the unlabelled windows contain; the SSL and temporal terms are
    computed over every row and change with the unlabelled windows."""
    S, xy = _data(n=8)
    lab = slice(4, 8)
    xy_mixed = xy.clone()
    xy_mixed[:4] = float("nan")
    M = torch.tensor(brand_statistics(S.numpy()))
    w = {"loc": 1.0, "ssl": 0.5, "ts": 2.0}
    m = _module(True, weights=w, M=M)
    m.locnet.set_normalisation(xy[lab])
    params = list(m.parameters())
    mixed = m.model_step({"S": S, "xy": xy_mixed})
    only = m.model_step({"S": S[lab], "xy": xy[lab]})
    assert set(mixed) == {"loc", "ssl", "ts", "loss", "err_m"}
    assert mixed["loc"].item() > 0 and torch.isfinite(mixed["loss"])
    torch.testing.assert_close(mixed["loc"], only["loc"], rtol=1e-6, atol=1e-7)
    torch.testing.assert_close(mixed["err_m"], only["err_m"], rtol=1e-6, atol=1e-7)
    g_mixed, g_only = _grads(mixed["loc"], params), _grads(only["loc"], params)
    assert all(torch.isfinite(g).all() for g in g_mixed)  # the NaN labels do not leak into the gradient
    assert sum(g.abs().sum() for g in g_mixed) > 0
    for a, b in zip(g_mixed, g_only):
        torch.testing.assert_close(a, b, rtol=1e-5, atol=1e-8)
    # other readings in the unlabelled rows: the supervised term does not move, the unsupervised ones do
    S_other = S.clone()
    S_other[:4] = torch.rand(4, 6, 5, generator=torch.Generator().manual_seed(1)) * 0.7
    other = m.model_step({"S": S_other, "xy": xy_mixed})
    torch.testing.assert_close(other["loc"], mixed["loc"], rtol=1e-6, atol=1e-7)
    for g_a, g_b in zip(_grads(other["loc"], params), g_mixed):
        torch.testing.assert_close(g_a, g_b, rtol=1e-5, atol=1e-8)
    for k in ("ssl", "ts"):
        assert abs(other[k].item() - mixed[k].item()) > 1e-4 * abs(mixed[k].item()), k
    # ... because they are the losses of eqs. 3.2-3.5 over all 8 rows, and the total is eq. 3.6
    with torch.no_grad():
        g_all = m.transnet(S)
        torch.testing.assert_close(mixed["ts"], temporal_smoothness_loss(g_all), rtol=1e-6, atol=1e-7)
        torch.testing.assert_close(mixed["ssl"], ssl_loss(g_all, S, M, m.tau), rtol=1e-5, atol=1e-7)
        torch.testing.assert_close(mixed["loss"], w["loc"] * mixed["loc"] + w["ssl"] * mixed["ssl"]
                                   + w["ts"] * mixed["ts"], rtol=1e-6, atol=1e-7)
    # a batch of unlabelled rows only: no supervised term and no error; the loss trains TransNet, not LocNet
    none = m.model_step({"S": S, "xy": torch.full_like(xy, float("nan"))})
    assert set(none) == {"ssl", "ts", "loss"}
    g_t = _grads(none["loss"], list(m.transnet.parameters()))
    g_l = _grads(none["loss"], list(m.locnet.parameters()))
    assert all(torch.isfinite(g).all() for g in g_t) and all(g.abs().sum() > 0 for g in g_t)
    assert all((g == 0).all() for g in g_l)
    with pytest.raises(ValueError, match="no loss term"):
        _module(False).model_step({"S": S, "xy": torch.full_like(xy, float("nan"))})
