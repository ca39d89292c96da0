"""Issue 32: the beacon map pooled from every scored walk before the back-end (blenav.backend.pooled): the walk seen
along another row's track, the pooled map per building and run, the localizer's settings and its place in
experiment=mapnoise_pooled."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

pytest.importorskip("gtsam")

from blenav.backend.pooled import PooledMapBackend, along_track  # noqa: E402
from blenav.configs import compose  # noqa: E402
from blenav.data import Dataset  # noqa: E402
from blenav.eval.beacon_map import BeaconMapConfig, perturb, run_per_run_maps  # noqa: E402
from blenav.filters.estimate import Estimate  # noqa: E402
from blenav.localizers import Localizer, RunInputs  # noqa: E402

FRONT = {"motion": {"_target_": "blenav.filters.motion.RandomWalk"}}


@pytest.fixture
def walks(map_walks):
    return Dataset.open(map_walks)


def _truth_estimate(session, shift=(0.0, 0.0)) -> Estimate:
    """The labels row's estimate of ``session``: run 0 its ground truth every 0.5 s, run 1 the same moved by
    ``shift`` m."""
    gt = session.groundtruth
    t = np.arange(gt["t"].iloc[0], gt["t"].iloc[-1], 0.5)
    xy = session.positions_at(t)
    return Estimate("F-end", session.id, t, np.stack([xy, xy + np.asarray(shift)]))


def _ble_error(anchors: pd.DataFrame) -> np.ndarray:
    b = anchors[anchors["kind"] == "ble"]
    return np.hypot(b["x"] - b["x_true"], b["y"] - b["y_true"]).to_numpy()


def test_a_walk_along_another_track_reads_that_track_as_its_poses(walks):
    s = walks.session(walks.session_ids[0])
    t = np.array([0.0, 10.0, 20.0])
    xy = np.array([[1.0, 2.0], [3.0, 4.0], [5.0, 6.0]])
    v = along_track(s, t, xy, 1.2)
    np.testing.assert_allclose(v.positions_at(np.array([5.0]), with_z=True), [[2.0, 3.0, 1.2]])
    assert v.rssi is s.rssi and v.labelled and v.id == s.id
    assert not np.allclose(s.positions_at(np.array([5.0])), [[2.0, 3.0]])  # the session's own is untouched


def test_pooled_map_moves_the_given_map_toward_the_truth_per_run(walks):
    """A 3 m wrong map (one draw for both walks), each walk placed by its true track in run 0 and by the same track
    100 m east in run 1: run 0's map is closer to the truth than the given one where it places a beacon (and keeps
    the rest where they were), with the estimator's std_m only when asked (pool.stated_std); run 1's differs; without
    a run index the runs' mean track is used; each map is made once per building, map and run."""
    sessions = [walks.session(i) for i in walks.session_ids]
    b = perturb(sessions[0].building, BeaconMapConfig(noise_m=3.0, vertical=False, per_walk=False), 0, 0)
    loc = PooledMapBackend("B-end+pool", front_end=FRONT, pool={"labels": "F-end", "prior_sigma_m": 3.0})
    info = loc.prepare_batch(sessions, {s.id: _truth_estimate(s, (100.0, 0.0)) for s in sessions})
    assert info["buildings"] == {b.id: {"walks": 2}}
    cache: dict = {}
    m0, note = loc.pooled_map(b, 0, cache)
    assert "placed from 2 walks along F-end" in note
    given, err0 = _ble_error(b.anchors), _ble_error(m0)
    moved = err0 != given
    assert moved.sum() >= 3
    assert err0[moved].mean() < 0.8 * given[moved].mean()
    assert ("std_m" in m0) == ("std_m" in b.anchors)  # the back-end's beacon prior as for the given map
    stated = PooledMapBackend("x", front_end=FRONT, pool={"labels": "F-end", "stated_std": True})
    stated.prepare_batch(sessions, {s.id: _truth_estimate(s) for s in sessions})
    ms, _ = stated.pooled_map(b, 0, {})
    np.testing.assert_allclose(ms[["x", "y"]].to_numpy(float), m0[["x", "y"]].to_numpy(float))
    assert np.isfinite(ms.loc[ms["kind"] == "ble", "std_m"].to_numpy(float)[moved]).all()
    m1, _ = loc.pooled_map(b, 1, cache)
    assert not np.allclose(m1[["x", "y"]].to_numpy(float), m0[["x", "y"]].to_numpy(float))
    assert loc.pooled_map(b, 0, cache)[0] is m0
    mean, _ = loc.pooled_map(b, None, {})
    assert not np.allclose(mean[["x", "y"]].to_numpy(float), m0[["x", "y"]].to_numpy(float))


def test_settings_are_checked_and_the_localizer_needs_its_batch():
    with pytest.raises(ValueError, match="pool has keys"):
        PooledMapBackend("x", front_end=FRONT, pool={"labels": "F-end", "prior": 1.0})
    with pytest.raises(ValueError, match="pool.labels"):
        PooledMapBackend("x", front_end=FRONT, pool={})
    with pytest.raises(ValueError, match="prior_sigma_m"):
        PooledMapBackend("x", front_end=FRONT, pool={"labels": "F-end", "prior_sigma_m": 0})
    loc = PooledMapBackend("x", front_end=FRONT, pool={"labels": "F-end"})
    with pytest.raises(ValueError, match="prepare_batch"):
        loc.run(None, 1, 0)


def test_mapnoise_pooled_pools_after_f_end_on_one_deployed_map(tmp_path):
    from blenav.eval import harness as H

    assert compose("eval", "experiment=mapnoise_000", f"data={tmp_path}").beacon_map.per_walk is True
    cfg = compose("eval", "experiment=mapnoise_pooled", f"data={tmp_path}", f"out={tmp_path / 'o'}")
    assert cfg.beacon_map.per_walk is False
    methods = H.build_methods(cfg)
    names = list(methods)
    for row in ("F-end+pool", "B-end+pool"):
        assert isinstance(methods[row], PooledMapBackend) and methods[row].batch_labels == "F-end"
        assert names.index(row) > names.index("F-end")
    assert methods["F-end+pool"].estimate == "front_end" and methods["B-end+pool"].estimate == "smoothed"


class _RunRecorder(Localizer):
    """Its estimate's x is the run index the evaluation gave it (-1: none)."""

    def run(self, session, n_runs, seed, inputs=None):
        t = np.array([0.0, 1.0])
        r = -1.0 if inputs is None or inputs.run is None else float(inputs.run)
        return Estimate(self.name, session.id, t, np.full((n_runs, 2, 2), r))


def test_each_run_alone_is_told_which_run_it_is(tiny_dataset):
    s = Dataset.open(tiny_dataset).session(Dataset.open(tiny_dataset).session_ids[0])
    base = RunInputs(cache={})
    est = run_per_run_maps(_RunRecorder("r"), s, 0, 3, 7, lambda _s: base.with_fixes(None),
                           BeaconMapConfig(noise_m=1.0))
    np.testing.assert_array_equal(est.position[:, 0, 0], [0.0, 1.0, 2.0])
    assert base.for_run(2).with_fixes(None).run == 2 and base.run is None


def test_a_walk_the_back_end_cannot_run_on_is_skipped_before_any_pooling(tiny_dataset):
    """A building whose BLE anchors have no position (an imported survey before blenav map): MissingStream with the
    back-end's reason, as BackendLocalizer says it, not an estimator error."""
    from dataclasses import replace

    from blenav.errors import MissingStream

    s = Dataset.open(tiny_dataset).session(Dataset.open(tiny_dataset).session_ids[0])
    a = s.building.anchors.copy()
    a.loc[a["kind"] == "ble", ["x", "y"]] = np.nan
    unplaced = s.with_building(replace(s.building, anchors=a))
    loc = PooledMapBackend("x", front_end=FRONT, pool={"labels": "F-end"})
    loc.prepare_batch([unplaced], {unplaced.id: _truth_estimate(s)})
    with pytest.raises(MissingStream, match="without a position"):
        loc.run(unplaced, 1, 0)


def test_a_labels_row_skipped_on_every_walk_leaves_the_given_map(tiny_dataset):
    """F-end ran but was skipped everywhere: the pool is prepared with no walk and keeps the given map (its note says
    so); a labels row that did not run at all is an EvalError naming the order."""
    from blenav.errors import EvalError
    from blenav.eval.batch import prepare_transductive

    b = Dataset.open(tiny_dataset).session(Dataset.open(tiny_dataset).session_ids[0]).building
    loc = PooledMapBackend("B-end+pool", front_end=FRONT, pool={"labels": "F-end"})
    prepared: dict = {}
    prepare_transductive("B-end+pool", loc, None, {}, [], None, prepared, {"F-end"})
    assert prepared[id(loc)]["buildings"] == {}
    anchors, note = loc.pooled_map(b, None, {})
    assert anchors is b.anchors and "no walk" in note
    with pytest.raises(EvalError, match="has not run before"):
        prepare_transductive("B-end+pool", PooledMapBackend("p", front_end=FRONT, pool={"labels": "F-end"}), None, {},
                             [], None, {})
