"""Issue 30: the crowd-sourced survey (blenav.localizers.crowd): the KNN that leaves a walk's own windows out, the
out-of-fold errors with the crowd in every fold's reference set, and the localizer prepared from another row's
estimates of the scored walks (never their ground truth)."""

from __future__ import annotations

import numpy as np
import pytest

from blenav.configs import compose
from blenav.errors import EvalError, MissingStream
from blenav.eval.batch import prepare_transductive, transductive_of
from blenav.filters.estimate import Estimate
from blenav.localizers import knn as KNN
from blenav.localizers.crowd import CrowdFingerprint
from blenav.localizers.fingerprint import FingerprintLocalizer

SETTING = KNN.KnnSetting("cosine", 3, "uniform", 1.0)


def _windows(rng, n, f=6):
    S = rng.uniform(0.0, 60.0, (n, f, 1))
    S[rng.uniform(size=S.shape) < 0.3] = 0.0
    S[:, 0, 0] += 1.0  # every window heard something
    return S


def test_knn_model_leaves_out_one_walk_exactly():
    """exclude=g is the KNN fitted without group g's windows (every query), and no exclusion the plain fit."""
    rng = np.random.default_rng(3)
    S, xy = _windows(rng, 40), rng.uniform(0, 50, (40, 2))
    groups = np.array([""] * 20 + ["w1"] * 10 + ["w2"] * 10, object)
    Q = _windows(rng, 7)
    full = KNN.fit(S, xy, SETTING, np.zeros(6, bool), -100.0, 1.0, groups=groups)
    keep = groups != "w1"
    ref = KNN.fit(S[keep], xy[keep], SETTING, np.zeros(6, bool), -100.0, 1.0)
    for a, b in zip(full(Q, exclude="w1"), ref(Q)):
        np.testing.assert_allclose(a, b)
    for a, b in zip(full(Q), KNN.fit(S, xy, SETTING, np.zeros(6, bool), -100.0, 1.0)(Q)):
        np.testing.assert_allclose(a, b)


def test_out_of_fold_keeps_the_crowd_in_every_fold():
    """No extra rows: the plain out-of-fold errors. Exact copies of the windows labelled 100 m off: with k = 1 each
    window's nearest reference is its own copy (distance 0, whatever fold it is in), so every error is 100 m; the
    copies are never predicted themselves (as many errors as windows)."""
    rng = np.random.default_rng(5)
    S, xy = _windows(rng, 30), rng.uniform(0, 50, (30, 2))
    walk_of = np.repeat(np.arange(6), 5)
    one = KNN.KnnSetting("cosine", 1, "uniform", 1.0)
    args = (S, xy, walk_of, one, np.zeros(6, bool), -100.0, 1.0)
    plain = KNN.out_of_fold(*args, folds=3, seed=0)
    for a, b in zip(plain, KNN.out_of_fold(*args, folds=3, seed=0, extra=(S[:0], xy[:0]))):
        np.testing.assert_allclose(a, b)
    err, _, d1 = KNN.out_of_fold(*args, folds=3, seed=0, extra=(S.copy(), xy + [100.0, 0.0]))
    assert len(err) == 30
    np.testing.assert_allclose(err, 100.0)
    np.testing.assert_allclose(d1, 0.0, atol=1e-6)


def _estimate(session, y: float) -> Estimate:
    """The labels row's estimate of a coded walk: its own x track (4 m/s from 5 m) at height y."""
    t = np.linspace(0.0, 6.0, 61)
    return Estimate("fused-offline", session.id, t, np.stack([5.0 + 4.0 * t, np.full_like(t, y)], axis=1)[None])


def test_crowd_labels_reach_the_other_walks_never_the_walk_itself(coded):
    """walkA (y = 5 m) surveyed; walkB and walkC scored, walkC labelled by the labels row at y = Y. walkB's fixes
    (k = 2: its own-code window of walkA and of walkC) sit half-way to Y; walkC's own windows are never its
    neighbours: its fixes are walkA's (y = 5 m) for every Y."""
    A, B, C = (coded.session(f"mall_F1_walk{c}") for c in "ABC")
    ys = {}
    for Y in (50.0, -40.0):
        loc = CrowdFingerprint("KNN+crowd", k=2, fix_std="calibrated", wifi_age_ref="scan", wifi_time="heard",
                               crowd={"labels": "fused-offline"})
        loc.fit([A])
        with pytest.raises(MissingStream, match="not prepared"):
            loc.run(B, 1, seed=0)
        info = loc.prepare_batch([B, C], {C.id: _estimate(C, Y)})
        assert info["floors"]["mall/F1"]["walks"] == 1 and info["floors"]["mall/F1"]["windows"] >= 4
        ys[Y] = (loc.run(B, 1, seed=0).position[0, :, 1], loc.run(C, 1, seed=0).position[0, :, 1])
    for Y, (yb, yc) in ys.items():
        np.testing.assert_allclose(yc, 5.0)
        np.testing.assert_allclose(yb, (5.0 + Y) / 2.0)
    np.testing.assert_array_equal(ys[50.0][1], ys[-40.0][1])
    plain = FingerprintLocalizer("KNN", k=2, wifi_age_ref="scan", wifi_time="heard")
    plain.fit([A])
    np.testing.assert_allclose(plain.run(C, 1, seed=0).position[0, :, 1], 5.0)


def test_a_walk_without_the_stream_stays_out_of_the_crowd(coded, monkeypatch):
    """A scored walk that lacks the localizer's stream (a BLE crowd, a walk without rssi.csv) is left out of the crowd,
    not an error."""
    A, B, C = (coded.session(f"mall_F1_walk{c}") for c in "ABC")
    loc = CrowdFingerprint("KNN+crowd", k=2, fix_std="calibrated", crowd={"labels": "fused-offline"})
    loc.fit([A])

    def no_stream(*a, **k):
        raise MissingStream("no rssi.csv")

    monkeypatch.setattr(FingerprintLocalizer, "heard_windows", no_stream)
    info = loc.prepare_batch([B, C], {B.id: _estimate(B, 7.0), C.id: _estimate(C, 5.0)})
    assert info["floors"]["mall/F1"] == {"walks": 0, "windows": 0}
    monkeypatch.undo()
    np.testing.assert_allclose(loc.run(C, 1, seed=0).position[0, :, 1], 5.0)


def test_a_scored_walk_is_read_once(coded, monkeypatch):
    """The windows prepare_batch reads for the crowd are the ones run localizes: each scored walk's readings are
    windowed once (FP.session_windows), and a walk run again is read afresh."""
    import blenav.features.fingerprints as FP

    A, B, C = (coded.session(f"mall_F1_walk{c}") for c in "ABC")
    loc = CrowdFingerprint("KNN+crowd", k=2, fix_std="calibrated", crowd={"labels": "fused-offline"})
    loc.fit([A])
    calls = []
    real = FP.session_windows
    monkeypatch.setattr(FP, "session_windows", lambda s, *a, **k: calls.append(s.id) or real(s, *a, **k))
    loc.prepare_batch([B, C], {B.id: _estimate(B, 7.0), C.id: _estimate(C, 5.0)})
    first = loc.run(B, 1, seed=0).position
    loc.run(C, 1, seed=0)
    assert sorted(calls) == sorted([B.id, C.id])
    np.testing.assert_array_equal(loc.run(B, 1, seed=0).position, first)
    assert calls.count(B.id) == 2


def test_crowd_settings_are_checked():
    with pytest.raises(ValueError, match="crowd.labels"):
        CrowdFingerprint("c", fix_std="calibrated", crowd={})
    with pytest.raises(ValueError, match="keys"):
        CrowdFingerprint("c", fix_std="calibrated", crowd={"labels": "x", "label": "y"})
    with pytest.raises(ValueError, match="cross-validated KNN"):
        CrowdFingerprint("c", crowd={"labels": "x"})  # the plain KNN keeps no arrays to extend
    with pytest.raises(ValueError, match="std_scale"):
        CrowdFingerprint("c", fix_std="calibrated", crowd={"labels": "x", "std_scale": 0})


def test_realwalks_crowd_rows_and_their_order():
    """experiment=realwalks: the crowd KNN labelled by fused-offline, its role read by the two crowd rows, all
    after fused-offline; the evaluation refuses a crowd row whose labels row did not run before it."""
    m = compose("eval", "experiment=realwalks").methods
    keys = list(m)
    assert keys.index("fused_offline") < keys.index("knn_both_crowd") < keys.index("fused_online_crowd")
    assert m.knn_both_crowd.crowd.labels == "fused-offline" and m.knn_both_crowd.crowd.std_scale == 1.4
    for k in ("fused_online_crowd", "fused_offline_crowd"):
        assert list(m[k].fix_roles) == ["both_crowd", "ble_crowd"]
    loc = CrowdFingerprint("KNN-WiFi+BLE+crowd", fix_std="calibrated", crowd={"labels": "fused-offline"})
    assert transductive_of(loc, None) == [loc]
    with pytest.raises(EvalError, match="has not run before it"):
        prepare_transductive("KNN-WiFi+BLE+crowd", loc, None, {}, [], None, {})
