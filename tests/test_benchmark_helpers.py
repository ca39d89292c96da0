"""Helpers the benchmark scripts share (benchmarks/timing.py, benchmarks/crossphone_sweep.py), on fakes: the timed
push loop of benchmarks/runtime_latency.py and benchmarks/soak.py, and the sweep's pooled per-device error."""

from __future__ import annotations

import importlib.util
import math
from types import SimpleNamespace

import pytest

from helpers import REPO

BENCH = REPO / "benchmarks"


def _load(name: str, monkeypatch):
    monkeypatch.syspath_prepend(str(BENCH))  # the scripts import their siblings (timing) as when run
    spec = importlib.util.spec_from_file_location(f"blenav_bench_{name}", BENCH / f"{name}.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


class _Clock:
    """A fake ``time`` module: perf_counter and process_time advance only when the fake localizer works."""

    def __init__(self):
        self.wall, self.cpu = 0.0, 0.0

    def perf_counter(self):
        return self.wall

    def process_time(self):
        return self.cpu


class _Loc:
    """push_event(ev) costs ev[2] s of wall time (half of it CPU) and returns ev[3] estimates stamped at ev[1]."""

    def __init__(self, clock):
        self.clock, self.closed = clock, None

    def push_event(self, ev):
        self.clock.wall += ev[2]
        self.clock.cpu += ev[2] / 2
        return [SimpleNamespace(t=ev[1], k=i) for i in range(ev[3])]

    def close(self, t):
        self.closed = t
        return [SimpleNamespace(t=t, k=0)]


def test_timed_updates_sums_the_push_calls_between_estimates(monkeypatch):
    timing = _load("timing", monkeypatch)
    clock = _Clock()
    monkeypatch.setattr(timing, "time", clock)
    loc = _Loc(clock)
    # (kind, t, seconds of work, estimates): two pushes then an estimate; then one push giving two estimates
    events = [("rssi", 0.5, 0.001, 0), ("odo", 0.7, 0.002, 0), ("rssi", 1.0, 0.003, 1), ("odo", 2.0, 0.004, 2),
              ("rssi", 2.5, 0.010, 0)]
    got = list(timing.timed_updates(loc, iter(events)))
    assert [len(o) for o, _, _ in got] == [1, 2, 1]
    assert got[0][1] == pytest.approx(6.0) and got[0][2] == pytest.approx(3.0)  # (1 + 2 + 3) ms, half CPU
    assert got[1][1] == pytest.approx(2.0) and got[1][2] == pytest.approx(1.0)  # 4 ms over two estimates
    assert math.isnan(got[2][1]) and math.isnan(got[2][2]) and loc.closed == 2.5  # close() at the last event
    assert list(timing.timed_updates(_Loc(clock), [])) == []


def test_crossphone_sweep_pools_per_device_means(monkeypatch):
    sweep = _load("crossphone_sweep", monkeypatch)
    m = {"per_device": {"a": {"mean": 1.0, "n": 3}, "b": {"mean": 3.0, "n": 1}, "c": {"mean": 9.0, "n": 5}}}
    assert sweep.pooled(m, ["a", "b", "zz"]) == pytest.approx(1.5)  # (3 * 1 + 1 * 3) / 4, unknown devices skipped
    assert math.isnan(sweep.pooled(m, ["zz"]))


def test_pooled_map_sees_a_walk_along_another_track_and_scores_against_the_truth(monkeypatch, tmp_path):
    """benchmarks/pooled_map.py: a walk seen along another track has that track as its ground truth (z its own,
    interpolated) and every other stream its own; the map error is the mean horizontal distance of the BLE rows from
    x_true / y_true."""
    import numpy as np
    import pandas as pd

    from blenav.data import Dataset
    from helpers import make_tiny_dataset

    mod = _load("pooled_map", monkeypatch)
    s = next(iter(Dataset.open(make_tiny_dataset(tmp_path / "d")).sessions(None, labelled=True)))
    gt = s.groundtruth
    t = gt["t"].to_numpy(float)
    np.savetxt(tmp_path / "t.tum", np.column_stack([t, gt["x"] + 1.0, gt["y"] - 2.0, np.zeros((len(t), 4)),
                                                    np.ones(len(t))]))
    v = mod.tracked(s, tmp_path / "t.tum")
    np.testing.assert_allclose(v.groundtruth[["x", "y"]].to_numpy(), gt[["x", "y"]].to_numpy() + [1.0, -2.0])
    np.testing.assert_allclose(v.groundtruth["z"].to_numpy(), gt["z"].to_numpy())
    pd.testing.assert_frame_equal(v.rssi, s.rssi)
    assert v.id == s.id and v.labelled and v.positions_at(t[:1])[0, 0] == pytest.approx(gt["x"].iloc[0] + 1.0)
    a = pd.DataFrame({"anchor_id": ["b1", "b2", "ap"], "kind": ["ble", "ble", "wifi_rtt"], "x": [0.0, 3.0, 9.0],
                      "y": [0.0, 4.0, 9.0], "x_true": [0.0, 0.0, 0.0], "y_true": [0.0, 0.0, 0.0]})
    assert mod.map_error(a, a) == pytest.approx(2.5)  # (0 + 5) / 2, the AP not counted


def test_fused_tuning_pools_splits_by_walks_and_measures_how_fix_errors_hang_together(monkeypatch, tmp_path):
    """benchmarks/fused_tuning.py: a row's mean over a floor's splits weighs each split by its walks (and "pooled" over
    every floor); a walk whose fixes share one error vector correlates 1 at every lag and is all offset, a walk whose
    error flips sign every fix correlates -1 one fix apart and has no offset; fix errors are read from the TUM files
    against the ground truth interpolated at the fixes' times, those outside its span dropped."""
    import numpy as np

    mod = _load("fused_tuning", monkeypatch)
    row = lambda mean, n: {"error_m": {"mean": mean}, "per_session": {f"s{i}": {} for i in range(n)}}  # noqa: E731
    t = mod.pooled([("F1", {"r": row(2.0, 1)}), ("F1", {"r": row(5.0, 2)}), ("F2", {"r": row(8.0, 1)})])
    assert t["r"]["F1"] == (pytest.approx(4.0), 3, 2) and t["r"]["F2"] == (pytest.approx(8.0), 1, 1)
    assert t["r"]["pooled"][0] == pytest.approx(5.0)  # (2 + 10 + 8) / 4
    same = (np.arange(6.0), np.tile([3.0, -4.0], (6, 1)))
    corr, share = mod.error_coherence([same], lags=(1, 3))
    assert corr == {1: pytest.approx(1.0), 3: pytest.approx(1.0)} and share == pytest.approx(1.0)
    flip = (np.arange(6.0), np.outer((-1.0) ** np.arange(6), [1.0, 2.0]))
    corr, share = mod.error_coherence([flip], lags=(1, 2))
    assert corr[1] == pytest.approx(-1.0) and corr[2] == pytest.approx(1.0) and share == pytest.approx(0.0)
    d = tmp_path / "walk" / "trajectories"
    d.mkdir(parents=True)
    pad = np.column_stack([np.zeros((3, 4)), np.ones(3)])
    np.savetxt(d / "groundtruth.tum", np.column_stack([[0.0, 10.0, 20.0], [0.0, 10.0, 10.0], [0.0, 0.0, 10.0], pad]))
    np.savetxt(d / "KNN-WiFi+BLE.tum", np.column_stack([[5.0, 15.0, 25.0], [6.0, 11.0, 0.0], [1.0, 5.0, 0.0], pad]))
    (tt, err), = mod.fix_errors(tmp_path)
    np.testing.assert_allclose(tt, [5.0, 15.0])
    np.testing.assert_allclose(err, [[1.0, 1.0], [1.0, 0.0]])  # truth (5, 0) and (10, 5)
