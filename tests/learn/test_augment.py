"""Receiver augmentation: a random phone per training window (blenav.learn.crossphone.augment)."""

from __future__ import annotations

import pytest
import torch

from blenav.learn.crossphone.augment import ReceiverAugment
from blenav.learn.crossphone.module import CrossPhoneModule
from blenav.models import LocNet


def windows(b=64, B=6, H=5, seed=0):
    g = torch.Generator().manual_seed(seed)
    u = 10.0 + 30.0 * torch.rand(b, B, H, generator=g)  # heard: u in [10, 40)
    u[torch.rand(b, B, H, generator=g) < 0.3] = 0.0  # not heard
    return u / 100.0


def test_off_by_default_and_identity_when_zero():
    assert not ReceiverAugment().active
    S = windows()
    (out,) = ReceiverAugment(offset_db_std=0.0)([S], torch.Generator().manual_seed(0))
    torch.testing.assert_close(out, S)


def test_offset_shifts_heard_readings_only_and_equally_for_the_windows_of_a_sample():
    S, P = windows(seed=1), windows(seed=2)
    aug = ReceiverAugment(offset_db_std=3.0)
    g = torch.Generator().manual_seed(5)
    out_S, out_P = aug([S, P], g)
    d_S = (out_S - S)[S > 0].reshape(-1)
    assert torch.equal(out_S[S == 0], S[S == 0])  # not heard stays not heard
    shift_S = torch.stack([((out_S - S)[i][S[i] > 0]).mean() for i in range(len(S))])
    shift_P = torch.stack([((out_P - P)[i][P[i] > 0]).mean() for i in range(len(P))])
    torch.testing.assert_close(shift_S, shift_P, atol=1e-5, rtol=0)  # same phone for S and S_prev
    for i in range(len(S)):  # one offset per sample: every heard reading of the window moves by it
        diff = (out_S - S)[i][S[i] > 0]
        torch.testing.assert_close(diff, torch.full_like(diff, float(shift_S[i])), atol=1e-5, rtol=0)
    assert 1.5 < float(shift_S.std() * 100) < 4.5 and d_S.abs().max() > 0  # std about 3 dB


def test_readings_left_between_0_and_the_floor_count_as_the_floor():
    S = torch.tensor([[[0.3, 0.0, 20.0]]]) / 100.0  # u = 0.3 (a weak reading), not heard, u = 20
    (out,) = ReceiverAugment(offset_db_std=1e-9)([S], torch.Generator().manual_seed(0))  # about the identity
    torch.testing.assert_close(out * 100, torch.tensor([[[0.5, 0.0, 20.0]]]))


def test_a_large_negative_offset_loses_weak_readings():
    S = windows(b=2000)
    aug = ReceiverAugment(offset_db_std=15.0)
    (out,) = aug([S], torch.Generator().manual_seed(3))
    heard_before, heard_after = (S > 0).sum(dim=(1, 2)), (out > 0).sum(dim=(1, 2))
    assert torch.all(heard_after <= heard_before)
    assert (heard_after < heard_before).float().mean() > 0.2  # windows shifted below -100 dBm lose readings
    assert out.min() >= 0 and torch.all(out[(out > 0)] >= 0.005 - 1e-7)


def test_dropout_share_matches_its_distribution():
    S = windows(b=4000)
    (out,) = ReceiverAugment(dropout_max=0.6)([S], torch.Generator().manual_seed(4))
    kept = ((out > 0).sum() / (S > 0).sum()).item()
    assert kept == pytest.approx(1 - 0.3, abs=0.02)  # q ~ U(0, 0.6) per window: 0.3 dropped on average
    torch.testing.assert_close(out[out > 0], S[out > 0])  # kept readings unchanged without offset/slope


def test_seeded_and_resumable():
    S = windows()
    a = ReceiverAugment(offset_db_std=6.0, gain_std=0.1, dropout_max=0.3)
    x1 = a([S], torch.Generator().manual_seed(9))[0]
    x2 = a([S], torch.Generator().manual_seed(9))[0]
    assert torch.equal(x1, x2)
    m = CrossPhoneModule(LocNet(6, hidden=8, fc_hidden=4), augment=a, seed=9)
    a([S], m.aug_generator)  # one batch drawn
    ck: dict = {}
    m.on_save_checkpoint(ck)
    nxt = a([S], m.aug_generator)[0]
    m2 = CrossPhoneModule(LocNet(6, hidden=8, fc_hidden=4), augment=a, seed=9)
    m2.on_load_checkpoint(ck)  # a resumed run continues the stream where the checkpoint left it
    assert torch.equal(a([S], m2.aug_generator)[0], nxt)
