"""Sparse ground truth (surveyed waypoints) and the train/test split by walk of blenav.eval."""

from __future__ import annotations

import json
from types import SimpleNamespace

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from blenav.errors import EvalError
from blenav.eval.config import SplitConfig
from blenav.eval.sessions import split_sessions
from blenav.eval.metrics import errors_at_waypoints, pool, pool_segment_errors, segment_errors, waypoint_metrics


def test_waypoint_errors_interpolate_the_estimate_not_the_truth():
    t = np.array([0.0, 1.0, 2.0, 3.0])
    pos = np.stack([np.stack([t * 2.0, np.zeros(4)], -1), np.stack([t * 2.0, np.ones(4)], -1)])  # (2, 4, 2)
    gt_t = np.array([-1.0, 0.5, 2.25, 9.0])  # the first and last waypoints lie outside the estimate's span
    gt_xy = np.array([[0.0, 0.0], [1.0, 0.0], [4.5, 3.0], [0.0, 0.0]])
    err, tw = errors_at_waypoints(t, pos, gt_t, gt_xy)
    np.testing.assert_allclose(tw, [0.5, 2.25])
    np.testing.assert_allclose(err, [[0.0, 3.0], [1.0, 2.0]], atol=1e-12)
    m = waypoint_metrics(t, pos, gt_t, gt_xy)
    assert m["waypoints"] == 2 and m["init_error_m"] is None
    np.testing.assert_allclose(m["rmse_m"]["mean"], np.mean([np.sqrt(4.5), np.sqrt(2.5)]))
    far = waypoint_metrics(t, pos + np.array([0.0, 3.0]), gt_t, gt_xy)  # run mean errors 1.5 and 2.5 m
    p = pool({"a": m, "b": far})  # walk (session x run) mean errors 1.5, 1.5, 1.5, 2.5 m
    assert p["walks_within_m"] == {"2": 0.75, "5": 1.0}
    with pytest.raises(ValueError, match="no waypoint"):
        waypoint_metrics(t, pos, np.array([5.0, 6.0]), np.zeros((2, 2)))


def _walks(floor, n):
    b = SimpleNamespace(id="mall")
    return [SimpleNamespace(id=f"{floor}_{i:02d}", building=b, meta={"floor": floor}) for i in range(n)]


def test_split_by_walk_is_seeded_per_floor_and_leaves_a_test_walk():
    walks = _walks("F1", 7) + _walks("F2", 2) + _walks("B1", 1)
    cfg = SplitConfig(train_fraction=0.5, seed=3)
    train, test = split_sessions(walks[::-1], cfg)  # the input order does not matter
    again, _ = split_sessions(walks, cfg)
    assert [s.id for s in train] == [s.id for s in again]
    ids = lambda xs, f: sorted(s.id for s in xs if s.meta["floor"] == f)  # noqa: E731
    assert len(ids(train, "F1")) == 4 and len(ids(test, "F1")) == 3
    assert len(ids(train, "F2")) == 1 and len(ids(test, "F2")) == 1
    assert ids(train, "B1") == ["B1_00"] and ids(test, "B1") == []  # one walk: train only
    assert not set(ids(train, "F1")) & set(ids(test, "F1"))
    other, _ = split_sessions(walks, SplitConfig(train_fraction=0.5, seed=4))
    assert [s.id for s in other] != [s.id for s in train]
    with pytest.raises(EvalError, match="train_fraction"):
        split_sessions(walks, SplitConfig(train_fraction=1.0))


def test_fix_coverage_counts_the_waypoints_inside_the_stated_regions():
    """Fixes at 0, 10 s with std 2 m, at (0, 0) and (10, 0); waypoints at 0, 5, 10 s: the fix interpolated there is
    (0, 0), (5, 0), (10, 0); errors 1, 3, 5 m against std 2 m: 1 inside 1 sigma, 2 inside 2 sigma; pooled per role."""
    from blenav.eval.metrics import fix_coverage_counts, pool_fix_coverage

    t = np.array([0.0, 10.0])
    xy = np.array([[0.0, 0.0], [10.0, 0.0]])
    gt_t = np.array([0.0, 5.0, 10.0])
    gt = np.array([[0.0, 1.0], [5.0, 3.0], [10.0, 5.0]])
    assert fix_coverage_counts(t, xy, np.array([2.0, 2.0]), gt_t, gt) == (1, 2, 3)
    assert fix_coverage_counts(t, xy, np.array([np.nan, np.nan]), gt_t, gt) is None
    pooled = pool_fix_coverage([{"wifi": (1, 2, 3)}, {"wifi": (3, 3, 3), "ble": (0, 1, 2)}])
    assert pooled == {"ble": {"1sigma": 0.0, "2sigma": 0.5, "waypoints": 2},
                      "wifi": {"1sigma": 4 / 6, "2sigma": 5 / 6, "waypoints": 6}}


def test_convergence_is_the_time_from_which_the_track_stays_within_5_m():
    from blenav.eval.metrics import convergence_times, pool_convergence

    tw = np.array([0.0, 5.0, 10.0, 15.0, 20.0])
    err = np.array([[20.0, 4.0, 9.0, 3.0, 2.0],    # settles at the 4th waypoint: 15 s
                    [1.0, 2.0, 3.0, 4.0, 4.9],     # from the start: 0 s
                    [1.0, 1.0, 1.0, 1.0, 6.0]])    # never settles (ends above 5 m)
    got = convergence_times(err, tw)
    np.testing.assert_array_equal(got[:2], [15.0, 0.0])
    assert np.isnan(got[2])
    assert pool_convergence([got]) == {"within_m": 5.0, "settled": 2 / 3, "median_s": 7.5, "p90_s": 13.5}


def test_segment_errors_by_hand():
    """An estimate along x at 1 m/s against waypoints at t = 0, 2, 6 s: the second segment's displacement is 4 m east,
    the truth 3 m east and 3 m north (length 4.24 m, 45 deg off); the first is exact. A segment outside the estimate's
    span is left out."""
    t = np.array([0.0, 10.0])
    pos = np.array([[[0.0, 0.0], [10.0, 0.0]]])
    gt_t = np.array([0.0, 2.0, 6.0, 12.0])
    gt_xy = np.array([[0.0, 0.0], [2.0, 0.0], [5.0, 3.0], [9.0, 3.0]])
    s = segment_errors(t, pos, gt_t, gt_xy)
    np.testing.assert_allclose(s["err"], [[0.0, np.hypot(1.0, 3.0)]])
    np.testing.assert_allclose(s["length"], [[0.0, 4.0 - np.hypot(3.0, 3.0)]])
    np.testing.assert_allclose(s["angle"], [[0.0, -45.0]])
    p = pool_segment_errors([s])
    assert p["segments"] == 2 and p["mean"] == pytest.approx(np.hypot(1.0, 3.0) / 2)
    assert p["heading_abs_median_deg"] == pytest.approx(22.5)  # both segments >= 2 m
    assert pool_segment_errors([segment_errors(t, pos, gt_t[2:], gt_xy[2:])]) is None  # no segment inside


def test_summary_ci99_is_student_t_by_hand_and_clipped_at_zero():
    """Two runs with RMSE 2 and 9 m (the issue's case): mean 5.5, std 4.95, stderr 3.5; t(0.995, 1) = 63.657 (scipy),
    so the interval is 5.5 +- 222.8 m, its lower end clipped at 0 m; the normal approximation gave [-3.52, 14.52]."""
    from scipy import stats

    from blenav.eval.metrics import summary

    s = summary(np.array([2.0, 9.0]))
    assert s["n"] == 2 and s["mean"] == 5.5 and s["stderr"] == pytest.approx(3.5)
    t = stats.t.ppf(0.995, 1)
    assert t == pytest.approx(63.6567, abs=1e-4)
    assert s["ci99"] == [0.0, pytest.approx(5.5 + t * 3.5)]
    assert summary(np.array([2.0, 9.0]), lower=None)["ci99"][0] == pytest.approx(5.5 - t * 3.5)
    # ten runs 1..10 m: mean 5.5, stderr sqrt(55/6)/sqrt(10), t(0.995, 9) = 3.2498; nothing to clip
    s10 = summary(np.arange(1.0, 11.0))
    half = stats.t.ppf(0.995, 9) * np.sqrt(55 / 6) / np.sqrt(10)
    assert stats.t.ppf(0.995, 9) == pytest.approx(3.2498, abs=1e-4)
    np.testing.assert_allclose(s10["ci99"], [5.5 - half, 5.5 + half])
    assert summary(np.array([3.0])) == {"mean": 3.0, "std": 0.0, "stderr": 0.0, "ci99": [3.0, 3.0], "n": 1}
    json.dumps(summary(np.array([3.0])), allow_nan=False)  # one run: still plain JSON


@settings(max_examples=200, deadline=None)
@given(st.lists(st.floats(0.0, 1e4, allow_nan=False), min_size=0, max_size=30))
def test_summary_ci99_never_below_zero_and_contains_the_mean(values):
    from blenav.eval.metrics import summary

    s = summary(np.array(values))
    assert len(s["ci99"]) == 2 and s["n"] == len(values)
    if values:
        lo, hi = s["ci99"]
        assert 0.0 <= lo <= s["mean"] + 1e-9 * (1 + s["mean"]) and hi >= s["mean"] - 1e-9 * (1 + s["mean"])
