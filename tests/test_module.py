"""The cross-phone LightningModule: one step for all stages, losses that train."""

from __future__ import annotations

import pytest
import torch

from blenav.learn.losses import brand_statistics
from blenav.learn.module import CrossPhoneModule
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


def test_unlabelled_rows_only_feed_the_unsupervised_terms():
    S, xy = _data(n=8)
    xy[:4] = float("nan")
    m = _module(True, weights={"loc": 1.0, "ts": 1.0})
    out = m.model_step({"S": S, "xy": xy})
    assert torch.isfinite(out["loss"]) and "loc" in out
    with pytest.raises(ValueError, match="no loss term"):
        _module(False).model_step({"S": S, "xy": torch.full_like(xy, float("nan"))})
