"""RSSI windows for the learned localizer (Roy, section 3.1.3)."""

from __future__ import annotations

import numpy as np
import pytest

from blenav.data import Dataset
from blenav.features.windows import WindowConfig, beacon_order, rssi_to_scale, session_windows, split_by_device


def test_windows_match_a_hand_computation(tiny_dataset):
    ds = Dataset.open(tiny_dataset)
    s = ds.session("walk0")
    beacons = beacon_order(s.building)
    assert beacons == ["b1", "b2", "b3", "b4"]  # BLE anchors only, sorted; the RTT AP is not a row
    w = session_windows(s, beacons, WindowConfig(history=5, step_hz=1.0))
    r = s.rssi
    K = int(np.floor(r["t"].max())) + 1
    assert w.S.shape == (K - 4, 4, 5) and w.S.dtype == np.float32
    # entry (window 3, beacon b2, last step) = mean of b2's packets in [7, 8) s on the +100 scale
    sel = r[(r["anchor_id"] == "b2") & (r["t"] >= 7) & (r["t"] < 8)]["rssi"]
    assert w.S[3, 1, 4] == pytest.approx(float(np.mean(sel + 100)), rel=1e-6)
    np.testing.assert_allclose(w.t[:2], [5.0, 6.0])
    np.testing.assert_allclose(w.xy[0], s.positions_at(np.array([5.0]))[0])


def test_not_heard_is_zero_and_weak_packets_are_not(tiny_dataset):
    ds = Dataset.open(tiny_dataset)
    s = ds.session("walk0")
    r = s.rssi.copy()
    r.loc[r["anchor_id"] == "b4", "rssi"] = -120.0  # heard, but below -100 dBm
    r = r[~((r["anchor_id"] == "b1") & (r["t"] < 3))].reset_index(drop=True)  # b1 silent for 3 s
    s.__dict__["_streams"]["rssi"] = r  # the session's cached stream, as if read from disk
    w = session_windows(s, beacon_order(s.building))
    assert (w.S[0, 0, :3] == 0).all() and (w.S[0, 0, 3:] > 0).all()
    assert (w.S[:, 3, :] == WindowConfig().floor_u).all()
    assert rssi_to_scale(np.array([-70.0]), WindowConfig())[0] == pytest.approx(30.0)  # Table 3.2's 1 m level


def test_unlabelled_session_has_nan_labels(tiny_dataset):
    ds = Dataset.open(tiny_dataset)
    s = ds.session("walk0")
    s.meta["labelled"] = False
    s.__dict__.pop("_streams", None)
    w = session_windows(s, beacon_order(s.building))
    assert len(w.S) > 0 and np.isnan(w.xy).all()


def test_split_by_device_and_clear_errors(tiny_dataset):
    ds = Dataset.open(tiny_dataset)
    sessions = list(ds.sessions())
    assert [s.id for s in split_by_device(sessions, test_devices=["test-phone"])["test"]] == ["walk0"]
    assert split_by_device(sessions)["train"] == sessions
    with pytest.raises(ValueError, match="both train and unlabelled"):
        split_by_device(sessions, train_devices=["test-phone"], unlabelled_devices=["test-phone"])
    with pytest.raises(ValueError, match="no session"):
        split_by_device(sessions, test_devices=["nokia"])


def _fake_sessions(per_device: dict[str, tuple[int, int]]):
    """SimpleNamespace sessions: device -> (labelled count, unlabelled count)."""
    from types import SimpleNamespace
    out = []
    for d, (n_lab, n_unl) in per_device.items():
        out += [SimpleNamespace(id=f"{d}-{i}", device_model=d, labelled=i < n_lab) for i in range(n_lab + n_unl)]
    return out


def test_split_holds_out_whole_sessions_and_shares_unlabelled_devices():
    sessions = _fake_sessions({"a": (4, 0), "b": (4, 0), "c": (4, 0), "d": (2, 1), "e": (3, 0)})
    g = split_by_device(sessions, train_devices=["a", "b"], unlabelled_devices=["c", "d"], holdout=0.25, seed=1)
    ids = {k: {s.id for s in v} for k, v in g.items()}
    assert not (ids["train"] & ids["test"]) and not (ids["unlabelled"] & ids["test"])
    assert len([i for i in ids["test"] if i[0] in "ab"]) == 2  # one of four per trained device
    assert len([i for i in ids["train"] if i[0] in "ab"]) == 6
    assert len([i for i in ids["unlabelled"] if i[0] == "c"]) == 2  # no unlabelled session: half of them
    assert {i for i in ids["unlabelled"] if i[0] == "d"} == {"d-2"}  # its unlabelled session
    assert {i for i in ids["test"] if i[0] in "de"} == {"d-0", "d-1", "e-0", "e-1", "e-2"}
    again = split_by_device(sessions, train_devices=["a", "b"], unlabelled_devices=["c", "d"], holdout=0.25, seed=1)
    assert [s.id for s in again["test"]] == [s.id for s in g["test"]]  # seeded


def test_packets_of_unknown_beacons_are_ignored_counted_and_said(tiny_dataset, caplog):
    ds = Dataset.open(tiny_dataset)
    s = ds.session("walk0")
    beacons = beacon_order(s.building)
    full = session_windows(s, beacons)
    fewer = session_windows(s, beacons[:-1])  # a model that never knew b4: its packets are no row of S
    n_b4 = int((s.rssi["anchor_id"].astype(str) == "b4").sum())
    assert fewer.unknown == {"b4": n_b4} and full.unknown == {}
    np.testing.assert_array_equal(fewer.S, full.S[:, :-1])
    assert "outside the model's beacon list" in caplog.text and "b4" in caplog.text
