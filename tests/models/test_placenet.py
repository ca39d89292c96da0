"""PlaceNet (issue 29): k-means places of the labels, positions and stds from the place scores by hand, the
cross-entropy to Gaussian soft targets, the pipeline's step (cross-entropy stepped on, the positions' loss monitored),
its calibration, and ONNX parity through the cross-phone export."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from torch.utils.data import TensorDataset

from blenav.learn.crossphone.losses import localization_loss
from blenav.learn.crossphone.module import CrossPhoneModule
from blenav.models import PlaceNet
from blenav.models.placenet import kmeans_anchors
from helpers import exported_streaming, seeded


def _net(B=6, places=4, **kw):
    return seeded(0, lambda: PlaceNet(B, width=16, places=places, **kw))


def test_kmeans_anchors_find_the_clusters_and_repeat_with_the_seed():
    g = torch.Generator().manual_seed(1)
    centres = torch.tensor([[0.0, 0.0], [30.0, 0.0], [0.0, 40.0]])
    xy = (centres[:, None] + 0.5 * torch.randn(3, 40, 2, generator=g)).reshape(-1, 2)
    a = kmeans_anchors(xy, 3, seed=5)
    got = a[torch.cdist(centres, a).argmin(dim=1)]
    truth = xy.reshape(3, 40, 2).mean(dim=1)  # each cluster's own mean: Lloyd's fixed point
    torch.testing.assert_close(got, truth, atol=1e-5, rtol=0)
    torch.testing.assert_close(kmeans_anchors(xy, 3, seed=5), a)
    assert len(kmeans_anchors(xy[:2], 10, seed=0)) == 2  # no more places than distinct labels
    net = _net(places=5)
    net.set_normalisation(xy[:2])  # the spare anchors repeat a centre
    assert net.anchors.shape == (5, 2) and len(torch.unique(net.anchors, dim=0)) == 2


def test_positions_stds_and_loss_by_hand():
    net = _net(places=3, kernel_m=2.0, std_floor_m=0.5).eval()
    net.anchors.copy_(torch.tensor([[0.0, 0.0], [10.0, 0.0], [0.0, 10.0]]))
    net.std_scale.fill_(2.0)
    z = torch.tensor([[0.0, float(np.log(3.0)), 0.0], [5.0, -5.0, -5.0]])
    xy, sigma = net.position_std(z)
    p = torch.softmax(z, dim=1)
    torch.testing.assert_close(xy[0], torch.tensor([6.0, 2.0]))  # p = (1, 3, 1) / 5
    for i in range(2):
        spread = sum(float(p[i, m]) * float(((net.anchors[m] - xy[i]) ** 2).sum()) for m in range(3))
        assert float(sigma[i]) == pytest.approx(2.0 * np.sqrt(spread / 2 + 0.25), rel=1e-5)
    y = torch.tensor([[1.0, 1.0], [9.0, 2.0]])
    d2 = ((y[:, None] - net.anchors[None]) ** 2).sum(dim=2)
    q = np.exp(-d2.numpy() / 8.0)
    q /= q.sum(axis=1, keepdims=True)
    ce = -(q * torch.log_softmax(z, dim=1).numpy()).sum(axis=1).mean()
    assert float(net.place_loss(z, y)) == pytest.approx(ce, rel=1e-5)
    S = torch.rand(2, 6, 3, generator=torch.Generator().manual_seed(0))
    h, c = net.initial_state(2)
    out = net.forward_state_std(S, h, c)
    assert out[2] is h and out[3] is c and h.shape == (1, 2, 1)
    torch.testing.assert_close(out[0], net(S))
    with pytest.raises(ValueError, match=r"expects \(batch, 6, H\)"):
        net(torch.zeros(2, 5, 3))


def test_the_input_is_the_powed_unit_norm_scan():
    """Scaling a scan's readings above the unit norm changes nothing; a reading over u = 100 counts as 100."""
    net = _net().eval()
    S = torch.rand(3, 6, 2, generator=torch.Generator().manual_seed(2)) * 0.8
    x = S.pow(2).mean(dim=2)
    torch.testing.assert_close(net.logits(S), net.mlp(x / x.norm(dim=1, keepdim=True)))
    torch.testing.assert_close(net.logits(S.clamp(max=1.0)), net.logits(S.clamp(max=1.0) + 2.0 * (S >= 1.0)))


def _data(n=64, B=6):
    g = torch.Generator().manual_seed(3)
    xy = torch.rand(n, 2, generator=g) * 20
    beacons = torch.rand(B, 2, generator=g) * 20
    u = (0.6 - 0.2 * torch.log10(1 + torch.cdist(xy, beacons))).clamp_min(0)
    return u[:, :, None].repeat(1, 1, 2), xy


def test_the_module_steps_on_the_cross_entropy_and_monitors_the_positions():
    S, xy = _data()
    net = _net(places=8, kernel_m=2.0, input_dropout=0.0, dropout=0.0)
    net.set_normalisation(xy)
    m = CrossPhoneModule(net, optimizer=lambda p: torch.optim.Adam(p, lr=1e-2))
    m.log = lambda *a, **k: None
    batch = {"S": S, "xy": xy}
    net.eval()  # no dropout: the step's terms are repeatable
    with torch.no_grad():
        out = m.model_step(batch)
    with torch.no_grad():
        assert float(out["loss"]) == pytest.approx(float(localization_loss(net(S), xy)), rel=1e-6)
    assert float(out["place"]) == pytest.approx(float(net.place_loss(net.logits(S), xy)), rel=1e-6)
    assert "nll" not in out
    step = m.training_step(batch, 0)
    assert float(step["loss"]) == pytest.approx(float(out["place"]), rel=1e-6)
    assert float(step["monitored"]) == pytest.approx(float(out["loss"]), rel=1e-6)
    net.train()
    opt = torch.optim.Adam(net.parameters(), lr=1e-2)
    before = float(out["place"])
    for _ in range(300):  # the cross-entropy is what training lowers, and the positions follow
        loss = m.training_step(batch, 0)["loss"]
        opt.zero_grad()
        loss.backward()
        opt.step()
    net.eval()
    after = m.model_step(batch)
    assert float(after["place"]) < before and float(after["err_m"]) < 0.5 * float(out["err_m"])

    class DM:
        sets = {"val": TensorDataset(S, S, xy)}

    rep = m.calibrate(DM())["fix_std"]  # the spread's scale fitted as LocNet's std head's
    assert rep["windows"] == len(S) and float(net.std_scale) == pytest.approx(rep["scale"])


@pytest.mark.onnx
def test_onnx_export_matches_pytorch(tmp_path):
    """The streaming graph (h0, c0 of (1, batch, 1) passed through) equals PyTorch, std_m included."""
    S, xy = _data()
    net = _net(B=6, places=8)
    net.set_normalisation(xy)
    net.std_scale.fill_(1.7)
    exported_streaming(net, 6, 2, 1, 1, tmp_path / "p.onnx", batches=(1, 4), u_max=120.0)  # u over 100: clamped
