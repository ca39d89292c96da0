"""TransNet and LocNet: shapes, the residual form of TransNet, normalisation, ONNX parity."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from blenav.models import LocNet, TransNet


def seeded(seed: int, build):
    """Build modules with a fixed weight initialisation without touching the global torch RNG."""
    with torch.random.fork_rng():
        torch.manual_seed(seed)
        return build()


def _S(batch=4, B=7, H=5, seed=0):
    g = torch.Generator().manual_seed(seed)
    S = torch.rand(batch, B, H, generator=g) * 40
    return S * (torch.rand(batch, B, H, generator=g) > 0.3)  # zeros: not heard


def test_transnet_is_a_nonnegative_residual_map():
    net = seeded(0, lambda: TransNet(7))
    S = _S()
    out = net(S)
    assert out.shape == S.shape and (out >= 0).all()
    for p in net.r.parameters():  # r = 0  ->  g(S) = ReLU(S) = S
        torch.nn.init.zeros_(p)
    assert torch.equal(net(S), S)
    with pytest.raises(ValueError, match="expects"):
        net(torch.zeros(2, 6, 5))
    with pytest.raises(ValueError, match="odd"):
        TransNet(7, kernel=4)


def test_locnet_outputs_metres_and_explicit_state_matches():
    net = seeded(0, lambda: LocNet(7, hidden=16, fc_hidden=8))
    xy = torch.tensor([[10.0, 20.0], [30.0, 40.0], [20.0, 30.0]])
    net.set_normalisation(xy)
    S = _S()
    out = net(S)
    assert out.shape == (4, 2)
    h0, c0 = net.initial_state(4)
    out2, h, c = net.forward_state(S, h0, c0)
    assert torch.equal(out, out2) and h.shape == (2, 4, 16)
    # a trivially zero head outputs the label mean
    for p in net.head.parameters():
        torch.nn.init.zeros_(p)
    np.testing.assert_allclose(net(S).detach().numpy(), np.tile([20.0, 30.0], (4, 1)), atol=1e-6)


def test_gradients_reach_both_networks():
    t, l = seeded(0, lambda: (TransNet(7), LocNet(7, hidden=16)))
    loss = l(t(_S())).pow(2).mean()
    loss.backward()
    assert all(p.grad is not None for p in list(t.parameters()) + list(l.parameters()))


@pytest.mark.onnx
def test_onnx_export_matches_pytorch(tmp_path):
    from blenav.learn.export import StreamingLocalizer, export_onnx, onnx_max_diff, random_inputs

    m = seeded(0, lambda: StreamingLocalizer(LocNet(7, hidden=16), TransNet(7))).eval()
    path = export_onnx(m, random_inputs(7, 5, 2, 16, batch=2, u_max=0.4, zero_state=True), tmp_path / "m.onnx")
    for batch in (1, 3):
        assert onnx_max_diff(path, m, random_inputs(7, 5, 2, 16, batch=batch, seed=batch, u_max=0.4)) < 1e-4
