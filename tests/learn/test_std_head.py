"""LocNet's std head (issue 29): a per-fix sigma trained with the Gaussian negative log-likelihood beside positions it
leaves untouched, calibrated on the validation windows, exported to ONNX with parity."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from scipy.stats import multivariate_normal, spearmanr
from torch.utils.data import TensorDataset

from blenav.learn.crossphone.losses import gaussian_nll
from blenav.runtime.calibration import std_scale_fit
from blenav.learn.crossphone.module import CrossPhoneModule
from blenav.models import LocNet
from helpers import exported_streaming, seeded


def _data(n=96, B=6, H=3, seed=0):
    """Windows whose readings are a smooth function of a 2-D position (a toy radio map), u / 100 scale."""
    g = torch.Generator().manual_seed(seed)
    xy = torch.rand(n, 2, generator=g) * 20
    beacons = torch.rand(B, 2, generator=g) * 20
    u = (0.6 - 0.2 * torch.log10(1 + torch.cdist(xy, beacons))).clamp_min(0)
    S = u[:, :, None].repeat(1, 1, H) + 0.02 * torch.randn(n, B, H, generator=g)
    return S.clamp_min(0), xy


def test_gaussian_nll_is_the_isotropic_2d_density():
    g = torch.Generator().manual_seed(1)
    f, x = torch.randn(5, 2, generator=g, dtype=torch.float64), torch.randn(5, 2, generator=g, dtype=torch.float64)
    sigma = torch.rand(5, generator=g, dtype=torch.float64) + 0.3
    ref = np.mean([-multivariate_normal(f[i].numpy(), sigma[i].item() ** 2 * np.eye(2)).logpdf(x[i].numpy())
                   for i in range(5)]) - np.log(2 * np.pi)  # the loss leaves out the constant log(2 pi)
    assert gaussian_nll(f, x, sigma).item() == pytest.approx(ref, rel=1e-12)


def test_the_std_head_leaves_the_positions_and_their_initialisation_alone():
    plain = seeded(0, lambda: LocNet(6, hidden=16, fc_hidden=8))
    headed = seeded(0, lambda: LocNet(6, hidden=16, fc_hidden=8, std_head=True))
    S, _ = _data(8)
    for name, p in plain.state_dict().items():  # the same initial weights: the head is built last
        assert torch.equal(p, headed.state_dict()[name]), name
    after = [seeded(0, lambda: (LocNet(6, hidden=16, fc_hidden=8, std_head=h), torch.rand(3))[1]) for h in (0, 1)]
    assert torch.equal(*after)  # a network built next (TransNet) draws the same weights too
    xy, sigma = headed.forward_std(S)
    assert torch.equal(xy, plain(S)) and torch.equal(headed(S), plain(S))
    assert sigma.shape == (8,) and (sigma > 0).all()
    with pytest.raises(ValueError, match="no std head"):
        plain.forward_std(S)


def test_the_nll_reaches_only_the_std_head():
    """The head reads detached features and positions: the NLL's gradient is zero on every other weight, and the
    positions' loss never reaches the head."""
    net = seeded(0, lambda: LocNet(6, hidden=16, fc_hidden=8, std_head=True))
    S, xy = _data(16)
    f, sigma = net.forward_std(S)
    head = {id(p) for p in net.head_std.parameters()}
    grads = torch.autograd.grad(gaussian_nll(f.detach(), xy, sigma), list(net.parameters()), allow_unused=True)
    for p, gr in zip(net.parameters(), grads):
        if id(p) in head:
            assert gr is not None and gr.abs().sum() > 0
        else:
            assert gr is None or gr.abs().sum() == 0
    f, sigma = net.forward_std(S)
    grads = torch.autograd.grad(((f - xy) ** 2).sum(), list(net.head_std.parameters()), allow_unused=True)
    assert all(gr is None or gr.abs().sum() == 0 for gr in grads)


def _module(std_head=True):
    loc = seeded(0, lambda: LocNet(6, hidden=16, fc_hidden=8, std_head=std_head))
    return CrossPhoneModule(loc, optimizer=lambda p: torch.optim.Adam(p, lr=3e-3))


def test_the_monitored_loss_is_the_positions_and_training_adds_the_nll():
    S, xy = _data(32)
    batch = {"S": S, "xy": xy}
    m, plain = _module(), _module(std_head=False)
    out = m.model_step(batch)
    assert out["loss"].item() == pytest.approx(plain.model_step(batch)["loss"].item(), rel=1e-6)
    f, sigma = m.locnet.forward_std(S)
    assert out["nll"].item() == pytest.approx(gaussian_nll(f, xy, sigma).item(), rel=1e-6)
    m.log = lambda *a, **k: None  # no trainer attached
    step = m.training_step(batch, 0)  # the optimizer's loss, and the positions' loss for the learning curve
    assert step["loss"].item() == pytest.approx((out["loss"] + out["nll"]).item(), rel=1e-6)
    assert step["monitored"].item() == pytest.approx(out["loss"].item(), rel=1e-6)
    assert m.validation_step(batch, 0).item() == pytest.approx(out["loss"].item(), rel=1e-6)


class _DM:
    def __init__(self, S, xy):
        self.sets = {"val": TensorDataset(S, S, xy)}


def test_calibration_is_the_maximum_likelihood_scale_on_the_validation_windows():
    S, xy = _data(64)
    xy[0] = float("nan")  # an unlabelled window is left out
    m = _module()
    rep = m.calibrate(_DM(S, xy))["fix_std"]
    with torch.no_grad():
        m.locnet.std_scale.fill_(1.0)
        f, s = m.locnet.forward_std(S[1:])
    e2 = ((f - xy[1:]) ** 2).sum(dim=1).double()
    s = s.double()
    c = float(torch.sqrt((e2 / s ** 2).mean() / 2))
    # c maximises the 2-D Gaussian likelihood of the errors under sigma * c: the derivative of the NLL is 0 there
    nll = [float(gaussian_nll(f, xy[1:], s.float() * k)) for k in (c * 0.99, c, c * 1.01)]
    assert rep["scale"] == pytest.approx(c, rel=1e-5) and nll[1] < min(nll[0], nll[2])
    r = torch.sqrt(e2) / (s * c)
    assert rep["windows"] == 63 and rep["coverage_1sigma"] == pytest.approx(float((r <= 1).double().mean()))
    assert rep["coverage_2sigma"] == pytest.approx(float((r <= 2).double().mean()))
    assert rep["rank_correlation"] == pytest.approx(spearmanr(s.numpy(), e2.numpy())[0], abs=1e-9)
    m.locnet.std_scale.fill_(c)
    assert float(m.locnet.std_scale) == pytest.approx(rep["scale"])  # calibrate left the scale set
    assert "uncalibrated" in _module().calibrate(_DM(S[:0], xy[:0]))["fix_std"]
    assert _module(std_head=False).calibrate(_DM(S, xy)) == {}


def test_the_scale_fit_never_returns_a_non_finite_number():
    """Rows without a finite error and a positive std are left out; a constant column has no rank correlation
    (None, not NaN); without a finite positive scale the scale is 1 and the report says uncalibrated."""
    c, rep = std_scale_fit(np.array([1.0, 2.0, np.nan, 3.0, 4.0]), np.array([1.0, 0.0, 1.0, np.inf, 2.0]))
    assert rep["windows"] == 2 and c == pytest.approx(np.sqrt((1 + 4) / 2 / 2))
    assert std_scale_fit(np.ones(1), np.ones(1))[1]["rank_correlation"] is None
    assert std_scale_fit(np.ones(3), np.array([1.0, 2.0, 3.0]))[1]["rank_correlation"] is None
    for err, sd in ((np.zeros(3), np.ones(3)), (np.ones(2), np.zeros(2)), (np.zeros(0), np.zeros(0))):
        c, rep = std_scale_fit(err, sd)
        assert c == 1.0 and set(rep) == {"uncalibrated"}


@pytest.mark.onnx
def test_onnx_export_of_the_std_head_matches_pytorch(tmp_path):
    from blenav.learn.crossphone.export import random_inputs
    from blenav.onnx_io import session

    loc = seeded(0, lambda: LocNet(7, hidden=16, std_head=True))
    loc.std_scale.fill_(3.5)
    _, path = exported_streaming(loc, 7, 5, 2, 16, tmp_path / "m.onnx")
    S, h0, c0 = random_inputs(7, 5, 2, 16, batch=4, seed=9, u_max=70, zero_state=True)
    std = session(path).run(["std_m"], {"S": S.numpy(), "h0": h0.numpy(), "c0": c0.numpy()})[0]
    with torch.no_grad():
        np.testing.assert_allclose(std, loc.forward_std(S / 100.0)[1].numpy(), rtol=1e-5)
