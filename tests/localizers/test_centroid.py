"""The weighted-centroid baseline (004 sec. VI-E): one class and one YAML file behind the localizer interface."""

from __future__ import annotations

import numpy as np
import pytest

from blenav.configs import compose
from blenav.eval.harness import build_methods, evaluate
from blenav.filters.measurement import AnchorTable
from blenav.localizers.centroid import WeightedCentroidLocalizer
from helpers import simulate_small

A_X, GAMMA = -60.0, 2.0


def _rssi(d):
    """Path-loss RSSI (dBm) at distance d (m): a_X - 10 gamma log10(d), d0 = 1 m."""
    return A_X - 10 * GAMMA * np.log10(d)


def _anchors():
    xyz = np.array([[0.0, 0.0, 1.2], [10.0, 0.0, 1.2], [0.0, 10.0, 1.2], [10.0, 10.0, 1.2], [30.0, 30.0, 1.2]])
    return AnchorTable(np.array(["a", "b", "c", "d", "e"]), xyz, np.full(5, np.nan))


def _loc(**kw):
    return WeightedCentroidLocalizer("centroid", a_x=A_X, gamma=GAMMA, d0=1.0, calibrated=False, device_z=1.2, **kw)


def test_three_nearest_anchors_weighted_by_inverse_distance():
    anchors = _anchors()
    d = np.array([2.0, 4.0, 8.0, 9.0, 20.0])  # a, b, c nearest; d and e must not count
    # window 0: the true median per anchor is the middle reading of three (one outlier each side)
    t = np.repeat([0.1, 0.4, 0.8], 5)
    idx = np.tile(np.arange(5), 3)
    rssi = np.tile(_rssi(d), 3) + np.repeat([-5.0, 0.0, 5.0], 5)
    tw, xy = _loc().estimate(t, idx, rssi, anchors, t_start=0.0)
    w = 1.0 / d[:3]
    expect = (w[:, None] * anchors.xyz[:3, :2]).sum(0) / w.sum()
    np.testing.assert_allclose(tw, [1.0])
    np.testing.assert_allclose(xy[0], expect, atol=1e-9)


def test_empty_windows_repeat_the_last_estimate_and_weak_readings_are_dropped():
    anchors = _anchors()
    loc = _loc()
    # window 0: a and b heard; window 1: nothing usable (below -90 dBm is dropped by run(), not estimate());
    # window 2: only d heard
    t = np.array([0.2, 0.3, 2.5])
    idx = np.array([0, 1, 3])
    rssi = _rssi(np.array([1.0, 3.0, 2.0]))
    tw, xy = loc.estimate(t, idx, rssi, anchors, t_start=0.0)
    np.testing.assert_allclose(tw, [1.0, 2.0, 3.0])
    first = (1.0 * anchors.xyz[0, :2] + (1 / 3) * anchors.xyz[1, :2]) / (1 + 1 / 3)
    np.testing.assert_allclose(xy[0], first)
    np.testing.assert_allclose(xy[1], first)  # nothing heard: held
    np.testing.assert_allclose(xy[2], anchors.xyz[3, :2])  # one anchor: its position
    with pytest.raises(ValueError, match="k must be"):
        _loc(k=0)


@pytest.fixture(scope="module")
def small(tmp_path_factory):
    return simulate_small(tmp_path_factory.mktemp("centroid") / "small", 4, 60, 2)


def test_runs_in_an_experiment_from_its_yaml_alone(small, tmp_path):
    """`+localizer@methods.centroid=centroid` adds the method; the harness scores it like any other."""
    cfg = compose("eval", "experiment=mapfusion_002", f"data={small}", "runs=2", f"out={tmp_path}", "plots=false",
                  "progress=false", "+localizer@methods.centroid=centroid", "methods.pf_pl_map=null",
                  "methods.pf_ps=null", "methods.pf_ps_map=null")
    assert isinstance(build_methods(cfg)["centroid"], WeightedCentroidLocalizer)
    res = evaluate(cfg)
    c, pl = res["methods"]["centroid"], res["methods"]["PF-PL"]
    assert all(v["rmse_m"]["std"] == 0.0 for v in c["per_session"].values())  # deterministic: runs identical
    # a 20 x 15 m building with its beacons: metres, not tens of metres, and not better than a filter by chance
    assert 0.5 < c["error_m"]["mean"] < 6.0, c["error_m"]
    assert np.isfinite(pl["error_m"]["mean"])
