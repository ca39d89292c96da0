"""Wrong floor plans (blenav.eval.plan_errors): spurious barriers close doorways and corridors, never halls;
offsets shift the plan; the same seed and building give the same plan."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from PIL import Image

from blenav.data import Dataset
from blenav.eval.plan_errors import PlanErrorConfig, building_rng, draw_barriers, perturb_building, run_lengths
from blenav.filters.map import WallCrossing

from helpers import make_tiny_dataset


@pytest.fixture(scope="module")
def session(tmp_path_factory):
    """A session of helpers.py's tiny dataset."""
    ds = Dataset.open(make_tiny_dataset(tmp_path_factory.mktemp("plan") / "tiny"))
    return ds.session(ds.session_ids[0])


@pytest.fixture(scope="module")
def house(session):
    """helpers.py's 10 m x 8 m house: inner wall at x in [5.0, 5.2), door y in [3.5, 4.5)."""
    return session.building


def corridor_and_hall() -> np.ndarray:
    """(100, 200) free mask at 0.1 m: a 2 m corridor (rows 10-29) and a 5 m hall (rows 50-99)."""
    free = np.zeros((100, 200), bool)
    free[10:30, 5:195] = True
    free[50:100, 5:195] = True
    return free


def test_barriers_span_free_runs_of_at_most_max_span():
    free = corridor_and_hall()
    mask, boxes = draw_barriers(free, 0.1, 12, max_span_m=2.5, thickness_m=0.2, rng=np.random.default_rng(3))
    assert len(boxes) == 12
    assert not (mask & ~free).any()  # barriers only cover free space
    for r0, c0, r1, c1 in boxes:
        # only across the corridor (20 px), as vertical walls 2 px thick; the hall (50 px) is never closed
        assert (r0, r1) == (10, 30) and c1 - c0 == 2, (r0, c0, r1, c1)
    # each barrier cuts the corridor: no free row survives at the barrier's columns
    cols = sorted({c for _, c0, _, c1 in boxes for c in range(c0, c1)})
    assert not (free & ~mask)[10:30, cols].any()
    np.testing.assert_array_equal((free & ~mask)[50:100], free[50:100])


def test_run_lengths_match_a_brute_force_count():
    free = np.random.default_rng(2).random((17, 23)) < 0.7
    want = np.zeros(free.shape, int)
    for r in range(free.shape[0]):
        for c in range(free.shape[1]):
            if free[r, c]:
                a = c
                while a > 0 and free[r, a - 1]:
                    a -= 1
                b = c
                while b + 1 < free.shape[1] and free[r, b + 1]:
                    b += 1
                want[r, c] = b - a + 1
    np.testing.assert_array_equal(run_lengths(free, 1), want)
    np.testing.assert_array_equal(run_lengths(free.T, 0), want.T)


def test_no_barrier_when_no_span_is_narrow_enough():
    free = corridor_and_hall()
    mask, boxes = draw_barriers(free, 0.1, 5, max_span_m=1.0, thickness_m=0.2, rng=np.random.default_rng(0),
                                max_tries=20)
    assert boxes == [] and not mask.any()


def test_barriers_close_the_house_door_and_the_filter_sees_it(house, tmp_path):
    cfg = PlanErrorConfig(barriers_per_100m2=4.0, max_span_m=1.5)  # only the 1 m door is that narrow
    wrong, info = perturb_building(house, cfg, tmp_path)
    fi = info["0"]
    assert fi["requested"] == round(4.0 * fi["free_m2"] / 100.0) > 1
    assert fi["barriers"] == 1  # one barrier per place: the house has one door
    assert 0.1 <= fi["closed_m2"] <= 0.4  # the door's 1 m x 0.2 m, one pixel column either side at most
    true_fl, wrong_fl = house.floor(0), wrong.floor(0)
    assert not wrong_fl.is_free(np.array([5.1, 4.0])) and true_fl.is_free(np.array([5.1, 4.0]))
    through_door = np.array([[2.5, 4.0]]), np.array([[7.5, 4.0]])
    assert not WallCrossing.from_floor(true_fl).crossed(*through_door).any()
    assert WallCrossing.from_floor(wrong_fl).crossed(*through_door).all()
    assert Image.open(fi["image"]).size == (true_fl.shape[1], true_fl.shape[0])
    # only the plan changed: anchors, rooms and routes are the building's
    assert wrong.anchors is house.anchors and wrong.rooms is house.rooms and wrong.navgraph is house.navgraph


def test_offset_shifts_the_plan_and_zero_errors_keep_it(house, tmp_path):
    same, info = perturb_building(house, PlanErrorConfig(), tmp_path / "same")
    assert not PlanErrorConfig().active and info["0"]["barriers"] == 0
    np.testing.assert_array_equal(same.floor(0).occupancy, house.floor(0).occupancy)
    shifted, _ = perturb_building(house, PlanErrorConfig(offset_m=[0.7, -0.4]), tmp_path / "shift")
    xy = np.random.default_rng(1).uniform([0, 0], [10, 8], (500, 2))
    np.testing.assert_array_equal(shifted.floor(0).lookup(xy + [0.7, -0.4]), house.floor(0).lookup(xy))


def test_same_seed_same_plan_other_seed_other_draws():
    free = corridor_and_hall()
    a = draw_barriers(free, 0.1, 6, 2.5, 0.2, building_rng(0, "b1"))[1]
    assert a == draw_barriers(free, 0.1, 6, 2.5, 0.2, building_rng(0, "b1"))[1]
    assert a != draw_barriers(free, 0.1, 6, 2.5, 0.2, building_rng(1, "b1"))[1]
    assert a != draw_barriers(free, 0.1, 6, 2.5, 0.2, building_rng(0, "b2"))[1]


@pytest.mark.parametrize("bad", [dict(barriers_per_100m2=-1), dict(max_span_m=0), dict(offset_m=[1.0]),
                                 dict(offset_m=[np.nan, 0.0])])
def test_bad_settings_fail_with_the_key(bad):
    with pytest.raises(ValueError, match="plan_error"):
        PlanErrorConfig(**bad)


def test_a_session_in_its_wrong_plan_shares_streams_and_keeps_its_building_id(session, tmp_path):
    s = session
    wrong, _ = perturb_building(s.building, PlanErrorConfig(barriers_per_100m2=5), tmp_path / "plans")
    w = s.with_building(wrong)
    assert w.building is wrong and s.building is not wrong and w.id == s.id
    assert w.stream("groundtruth") is s.stream("groundtruth")  # read once, for both
    with pytest.raises(ValueError, match="is not"):
        s.with_building(replace(wrong, id="elsewhere"))
