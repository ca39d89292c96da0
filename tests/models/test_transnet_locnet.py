"""TransNet and LocNet: shapes, the residual form of TransNet, normalisation, ONNX parity."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from blenav.models import LocNet, TransNet
from helpers import seeded


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
    """Every parameter tensor of both networks gets a finite, non-zero gradient through LocNet(TransNet(S))."""
    t, l = seeded(0, lambda: (TransNet(7), LocNet(7, hidden=16)))
    loss = l(t(_S())).pow(2).mean()
    loss.backward()
    for name, p in list(t.named_parameters(prefix="transnet")) + list(l.named_parameters(prefix="locnet")):
        assert p.grad is not None and p.grad.shape == p.shape, name
        assert torch.isfinite(p.grad).all(), name
        assert p.grad.abs().sum() > 0, name


def _tiny_double(seed=0):
    t, l = seeded(seed, lambda: (TransNet(3, channels=(4, 3, 2)), LocNet(3, hidden=4, fc_hidden=3)))
    return t.double(), l.double()


def test_gradients_match_finite_differences():
    """Autograd of LocNet(TransNet(S)) against central differences, w.r.t. the input and to parameters of
    both networks, in float64 on a tiny input (readings away from 0 so no ReLU sits on its kink)."""
    t, l = _tiny_double()
    g = torch.Generator().manual_seed(3)
    S = (torch.rand(2, 3, 4, generator=g, dtype=torch.float64) * 30 + 5).requires_grad_(True)

    def f(S):  # LocNet.initial_state is float32: pass a float64 state explicitly
        h0, c0 = (z.double() for z in l.initial_state(S.shape[0]))
        return l.forward_state(t(S), h0, c0)[0]

    loss_of = lambda: f(S).square().sum()  # noqa: E731
    params = dict(list(t.named_parameters(prefix="t")) + list(l.named_parameters(prefix="l")))
    names = ["t.r.0.weight", "t.r.10.weight", "t.r.10.bias", "l.lstm.weight_ih_l0", "l.lstm.weight_hh_l1",
             "l.head.0.weight", "l.head.2.bias"]
    grads = dict(zip(["S", *names], torch.autograd.grad(loss_of(), [S, *(params[n] for n in names)])))
    h = 1e-6
    checked = 0
    for name, x in [("S", S), *((n, params[n]) for n in names)]:
        flat = x.data.view(-1)
        for i in (range(flat.numel()) if name == "S" else (0, flat.numel() // 2, flat.numel() - 1)):
            old = flat[i].item()
            with torch.no_grad():
                flat[i] = old + h
                up = loss_of().item()
                flat[i] = old - h
                down = loss_of().item()
                flat[i] = old
            fd = (up - down) / (2 * h)
            ad = grads[name].view(-1)[i].item()
            assert abs(fd - ad) <= 1e-6 + 1e-5 * abs(fd), (name, i, fd, ad)
            checked += fd != 0
    assert checked >= 40  # the check compared non-trivial derivatives


def test_rows_of_a_batch_are_independent():
    """Both networks act on each window alone: a permuted batch gives the permuted outputs, one window alone
    the same output as inside a batch."""
    t, l = seeded(0, lambda: (TransNet(7), LocNet(7, hidden=16, fc_hidden=8)))
    l.set_normalisation(torch.tensor([[0.0, 0.0], [10.0, 20.0], [4.0, 6.0]]))
    S = _S(batch=6, seed=1)
    perm = torch.tensor([3, 0, 5, 1, 4, 2])
    with torch.no_grad():
        g, out = t(S), l(t(S))
        torch.testing.assert_close(t(S[perm]), g[perm], rtol=1e-5, atol=1e-5)
        torch.testing.assert_close(l(t(S[perm])), out[perm], rtol=1e-5, atol=1e-5)
        for i in (0, 4):
            torch.testing.assert_close(l(t(S[i:i + 1])), out[i:i + 1], rtol=1e-5, atol=1e-5)
        assert out.shape == (6, 2) and torch.isfinite(out).all() and out.std(dim=0).min() > 0  # not a constant


def test_locnet_output_follows_the_label_normalisation():
    """Labels scaled by k and shifted by c (same network weights): outputs scaled by k and shifted by c."""
    net = seeded(0, lambda: LocNet(7, hidden=16, fc_hidden=8))
    xy = torch.tensor([[1.0, 2.0], [9.0, 4.0], [5.0, 12.0], [3.0, 7.0]])
    S = _S(batch=5, seed=2)
    net.set_normalisation(xy)
    with torch.no_grad():
        base = net(S)
        k, c = 3.0, torch.tensor([-40.0, 25.0])
        net.set_normalisation(k * xy + c)
        torch.testing.assert_close(net(S), k * base + c, rtol=1e-5, atol=1e-4)
    torch.testing.assert_close(net.xy_mean, k * xy.mean(0) + c)
    torch.testing.assert_close(net.xy_scale, k * xy.std(0))


def test_transnet_sees_a_local_time_window_and_locnet_the_whole_window():
    """TransNet: 6 convolutions of kernel 3 -> the output at step t depends on the input steps within 6 of t
    only (zero Jacobian beyond, non-zero inside). LocNet: the position depends on every step of the window."""
    t, l = seeded(0, lambda: (TransNet(7), LocNet(7, hidden=16, fc_hidden=8)))
    g = torch.Generator().manual_seed(4)
    S = (torch.rand(1, 7, 16, generator=g) * 0.5 + 0.2).requires_grad_(True)
    (jt,) = torch.autograd.grad(t(S)[0, :, 0].sum(), S)
    per_step = jt[0].abs().sum(dim=0)  # (H,)
    assert torch.isfinite(jt).all()
    assert (per_step[7:] == 0).all() and per_step[:7].sum() > 0 and per_step[0] > 0
    (jl,) = torch.autograd.grad(l(S).sum(), S)
    assert torch.isfinite(jl).all() and (jl[0].abs().sum(dim=0) > 0).all()


@pytest.mark.onnx
def test_onnx_export_matches_pytorch(tmp_path):
    from blenav.learn.crossphone.export import StreamingLocalizer, export_onnx, onnx_max_diff, random_inputs

    m = seeded(0, lambda: StreamingLocalizer(LocNet(7, hidden=16), TransNet(7))).eval()
    path = export_onnx(m, random_inputs(7, 5, 2, 16, batch=2, u_max=0.4, zero_state=True), tmp_path / "m.onnx")
    for batch in (1, 3):
        assert onnx_max_diff(path, m, random_inputs(7, 5, 2, 16, batch=batch, seed=batch, u_max=0.4)) < 1e-4
