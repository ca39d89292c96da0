"""The beacon map an evaluation hands its methods (blenav.eval.beacon_map): true map, per-run perturbation,
beacon errors, stacking one-run estimates, corrected anchors, TUM trajectories."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from blenav.eval import beacon_map as BM
from blenav.localizers.base import Estimate
from blenav.filters.engine import Event
from blenav.trust import register


def _building(tmp_path):
    from helpers import make_tiny_dataset

    from blenav.data import Dataset

    root = make_tiny_dataset(tmp_path / "tiny")
    return Dataset.open(root).session("walk0")


def test_perturbation_is_per_run_paired_and_of_the_stated_size(tmp_path):
    s = _building(tmp_path)
    cfg = BM.BeaconMapConfig(noise_m=3.0, vertical=False, seed=4)
    a0 = s.building.anchors_of("ble")[["x", "y", "z"]].to_numpy(float)
    b = [BM.perturb(s.building, cfg, 0, r).anchors_of("ble")[["x", "y", "z"]].to_numpy(float) for r in range(400)]
    # the same (session, run) gives the same map for every method; runs differ
    np.testing.assert_array_equal(b[0], BM.perturb(s.building, cfg, 0, 0).anchors_of("ble")[["x", "y", "z"]])
    assert not np.allclose(b[0], b[1])
    d = np.stack(b) - a0
    np.testing.assert_array_equal(d[..., 2], 0.0)  # vertical: false
    assert abs(d[..., :2].std() - 3.0) < 0.15  # 400 runs x 4 beacons x 2 axes
    # the rtt AP is not moved
    rtt = [BM.perturb(s.building, cfg, 0, r).anchors_of("wifi_rtt")[["x", "y"]].to_numpy(float) for r in range(2)]
    np.testing.assert_array_equal(rtt[0], rtt[1])


def test_one_draw_per_run_for_every_walk_without_per_walk(tmp_path):
    """per_walk: false: sessions 0 and 5 of run r get the same map (runs still differ); per_walk: true (the default)
    gives them different ones, session 0's map unchanged by the option."""
    s = _building(tmp_path)
    shared = BM.BeaconMapConfig(noise_m=3.0, vertical=False, seed=4, per_walk=False)
    own = BM.BeaconMapConfig(noise_m=3.0, vertical=False, seed=4)

    def xy(cfg, si, r):
        return BM.perturb(s.building, cfg, si, r).anchors_of("ble")[["x", "y"]].to_numpy(float)

    np.testing.assert_array_equal(xy(shared, 0, 1), xy(shared, 5, 1))
    assert not np.allclose(xy(shared, 0, 1), xy(shared, 0, 2))
    assert not np.allclose(xy(own, 0, 1), xy(own, 5, 1))
    np.testing.assert_array_equal(xy(own, 0, 1), xy(shared, 0, 1))


def test_map_error_and_source():
    truth = pd.DataFrame({"x": [0.0, 10.0], "y": [0.0, 0.0]}, index=pd.Index(["a", "b"]))
    m = pd.DataFrame({"anchor_id": ["a", "b", "c"], "x": [3.0, 10.0, 99.0], "y": [4.0, 0.0, 0.0]})
    assert BM.map_error(m, truth) == pytest.approx(2.5)  # (5 + 0) / 2, the unknown 'c' ignored
    assert BM.map_error(None, truth) is None
    with pytest.raises(ValueError, match="source"):
        BM.BeaconMapConfig(source="truth")
    assert BM.BeaconMapConfig(source=True).source == "true"  # `beacon_map.source=true` on a command line


def test_stack_runs_concatenates_run_axes_and_renumbers_events():
    t = np.arange(3.0)
    ests = [Estimate("M", "s", t, np.full((1, 3, 2), float(r)), None, [Event(1.0, 0, "recover-local")],
                     {"smoothed": np.full((1, 3, 2), r), "beacon_map": pd.DataFrame(
                         {"anchor_id": ["a"], "x": [float(r)], "y": [0.0], "z": [1.0], "std_m": [1.0 + r]}),
                      "feedbacks": 3}, 2.0, ["n"]) for r in range(3)]
    out = BM.stack_runs(ests)
    assert out.position.shape == (3, 3, 2) and out.outputs["smoothed"].shape == (3, 3, 2)
    np.testing.assert_array_equal(out.position[:, 0, 0], [0, 1, 2])
    assert [e.run for e in out.events] == [0, 1, 2]
    assert out.wall_s == 6.0 and out.notes == ["n"] and out.outputs["feedbacks"] == 3
    bm = out.outputs["beacon_map"]
    assert bm["x"].iloc[0] == pytest.approx(1.0)
    assert bm["std_m"].iloc[0] == pytest.approx(np.sqrt((1 + 4 + 9) / 3))


def test_optimized_anchors_keep_the_columns_and_move_the_positions(tmp_path):
    s = _building(tmp_path)
    a = s.building.anchors_of("ble")
    bmap = pd.DataFrame({"anchor_id": a["anchor_id"].iloc[:1], "x": [1.5], "y": [2.5], "z": [2.0], "std_m": [0.4],
                         "status": ["optimized"]})
    out = BM.optimized_anchors(s.building, bmap)
    assert list(out.columns[: len(a.columns)]) == list(a.columns)
    assert out[["x", "y", "z"]].iloc[0].tolist() == [1.5, 2.5, 2.0] and out["std_m"].iloc[0] == 0.4
    np.testing.assert_array_equal(out[["x", "y"]].iloc[1:].to_numpy(float), a[["x", "y"]].iloc[1:].to_numpy(float))
    assert out["status"].iloc[1] == ""


def test_write_tum_reads_back(tmp_path):
    from blenav.data.writer import write_tum

    t = np.array([0.0, 0.5, 1.0])
    xy = np.array([[1.0, 2.0], [np.nan, 0.0], [3.0, 4.0]])
    p = write_tum(tmp_path / "a" / "x.tum", t, xy)
    rows = np.loadtxt(p)
    assert rows.shape == (2, 8)  # the non-finite row is left out
    np.testing.assert_allclose(rows[1], [1.0, 3.0, 4.0, 0.0, 0.0, 0.0, 0.0, 1.0])


def _mapper_class():
    from blenav.localizers import Localizer

    class _Mapper(Localizer):
        """The ground truth as estimate, and a 'corrected' beacon map that puts every beacon 1 m east of its
        true position, whatever map it was given."""

        def run(self, session, n_runs, seed, ctx=None):
            gt = session.groundtruth
            t = gt["t"].to_numpy(float)
            xy = gt[["x", "y"]].to_numpy(float)
            a = session.building.anchors_of("ble")
            tx = a["x_true"] if "x_true" in a else a["x"]
            ty = a["y_true"] if "y_true" in a else a["y"]
            bmap = pd.DataFrame({"anchor_id": a["anchor_id"], "x": tx.to_numpy(float) + 1.0, "y": ty.to_numpy(float),
                                 "z": a["z"].to_numpy(float), "std_m": 0.5, "status": "optimized"})
            given = a[["x", "y"]].to_numpy(float)
            return Estimate(self.name, session.id, t, np.broadcast_to(xy, (n_runs,) + xy.shape).copy(), None,
                            outputs={"beacon_map": bmap, "given": np.broadcast_to(given, (n_runs,) + given.shape).copy()})

    return _Mapper


MapperAtOffset = _mapper_class()
register(f"{__name__}.MapperAtOffset")  # code, not a file: the config below may name it (blenav.trust)


def test_harness_perturbs_per_run_scores_beacons_and_writes_the_files(tmp_path):
    import json

    from helpers import make_tiny_dataset

    from blenav.configs import compose
    from blenav.eval.harness import evaluate

    data = make_tiny_dataset(tmp_path / "tiny")
    path = next((data / "buildings").glob("*/anchors.csv"))
    a = pd.read_csv(path)
    a["x_true"], a["y_true"], a["z_true"] = a["x"], a["y"], a["z"]  # a simulation's true positions
    a.to_csv(path, index=False)
    out = tmp_path / "out"
    cfg = compose("eval", "experiment=mapfusion_002", f"data={data}", "runs=3", f"out={out}", "plots=false",
                  "progress=false", "calibration=none", "methods.pf_pl_map=null", "methods.pf_ps=null",
                  "methods.pf_ps_map=null", "methods.pf_pl_offset=null", "methods.pf_ps_map_offset=null",
                  f"+methods.mapper={{_target_: {__name__}.MapperAtOffset}}", "beacon_map.noise_m=2.0",
                  "beacon_map.vertical=false")
    res = evaluate(cfg)
    m = res["methods"]["mapper"]
    assert m["beacon_error_m"]["optimized"] == pytest.approx(1.0)
    assert 1.0 < m["beacon_error_m"]["prior"] < 4.5  # E|N(0, 2^2 I)| = 2.5 m, 3 runs x 4 beacons
    assert res["beacon_map"]["noise_m"] == 2.0
    assert "beacon_error_m" not in res["methods"]["PF-PL"]
    # each run got its own map (the maps a method was given differ between runs)
    assert res["methods"]["PF-PL"]["rmse_m"]["mean"] > 0
    d = out / "walk0"
    anchors = pd.read_csv(d / "anchors_optimized.csv")
    assert {"std_m", "status"} <= set(anchors.columns) and (anchors["status"] == "optimized").all()
    assert (d / "trajectories" / "mapper.tum").exists() and (d / "trajectories" / "PF-PL.tum").exists()
    assert np.loadtxt(d / "trajectories" / "groundtruth.tum").shape[1] == 8
    assert json.loads((out / "results.json").read_text())["methods"]["mapper"]["beacon_error_m"]
    # by how often each beacon was heard: every beacon of every run in one of the bins, the mapper's 1 m in each
    bh = m["beacon_error_m"]["by_heard"]
    n_beacons = len(pd.read_csv(path).query("kind == 'ble'"))
    assert sum(b["beacons"] for b in bh) == 3 * n_beacons
    assert all(b["optimized_m"] == pytest.approx(1.0) for b in bh)
    assert all("_rows" not in v.get("beacon_error_m", {}) for v in m["per_session"].values())


def test_beacon_errors_by_how_often_heard():
    truth = pd.DataFrame({"x": [0.0, 0.0, 0.0, 0.0], "y": [0.0, 0.0, 0.0, 0.0]}, index=["a", "b", "c", "d"])
    given = pd.DataFrame({"anchor_id": ["a", "b", "c", "d"], "x": [3.0, 4.0, 0.0, 1.0], "y": [0.0, 0.0, 2.0, 0.0]})
    opt = pd.DataFrame({"anchor_id": ["a", "b", "c"], "x": [1.0, 2.0, 0.0], "y": [0.0, 0.0, 1.0]})  # d left out
    heard = pd.Series({"a": 5, "b": 60, "c": 250})  # d never heard
    rows = BM.beacon_rows(given, opt, truth, heard)
    assert rows["heard"].tolist() == [5, 60, 250, 0]
    np.testing.assert_allclose(rows["given_m"], [3, 4, 2, 1])
    assert rows["optimized_m"].iloc[:3].tolist() == [1, 2, 1] and np.isnan(rows["optimized_m"].iloc[3])
    bins = BM.by_heard([rows.iloc[:2], rows.iloc[2:]])  # pooled from two sessions
    assert [(b["from"], b["to"], b["beacons"]) for b in bins] == [(0, 10, 2), (50, 200, 1), (200, None, 1)]
    assert bins[0]["given_m"] == pytest.approx(2.0) and bins[0]["optimized_m"] == pytest.approx(1.0)  # d: no estimate
