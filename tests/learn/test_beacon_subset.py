"""Window data restricted to sessions and to a beacon subset (a sparse BLE localizer, Roy Table 3.7): the
subset choice is the evaluation's ``spread_beacons``, the windows hold only its rows, the export says it is
a subset model and the loader accepts a building with more beacons (never one that lacks some)."""

from __future__ import annotations

import dataclasses
import itertools
import json
import logging

import numpy as np
import pandas as pd
import pytest

from blenav.configs import compose
from blenav.data import Dataset
from blenav.features.windows import WindowConfig, beacon_order, select_beacons, session_windows, spread_beacons
from blenav.learn.crossphone.data import WindowDataModule
from blenav.learn.crossphone.train import data_config

WARN = "outside the model's beacon list"


def _dm(path, *overrides) -> WindowDataModule:
    dm = WindowDataModule(data_config(compose("train", f"data.path={path}", "data.val_fraction=0", *overrides)))
    dm.setup()
    return dm


def _mean_nearest(demand, anchors, ids):
    """Mean distance from the demand points (P, 2) to the nearest of the anchors ``ids``."""
    xy = anchors.set_index("anchor_id").loc[list(ids), ["x", "y"]].to_numpy(float)
    return np.linalg.norm(demand[:, None, :] - xy[None], axis=-1).min(axis=1).mean()


def test_spread_beacons_is_a_greedy_k_median():
    """spread_beacons itself (the evaluation's fixes.sparse_beacons and data.beacons=k use it). Without a
    floor the anchors are the demand points, so each greedy round can be checked exactly: it adds the
    candidate that most lowers the mean distance to the nearest chosen anchor (ties: the smaller id). Unlike
    farthest-point sampling a lone far anchor is not the first choice. Only BLE anchors of the asked floor
    are candidates; the table's row order does not matter."""
    xy = [(0, 0), (2, 0), (0, 2), (2, 2), (1, 1), (40, 0), (40, 3), (20, 30)]
    t = pd.DataFrame({"anchor_id": [f"c{i}" for i in range(8)] + ["w", "up"],
                      "kind": ["ble"] * 8 + ["wifi_rtt", "ble"],
                      "x": [p[0] for p in xy] + [1.0, 1.0], "y": [p[1] for p in xy] + [1.0, 1.0],
                      "floor": ["0"] * 9 + ["1"]})
    cand = t[(t["kind"] == "ble") & (t["floor"] == "0")]
    demand = cand[["x", "y"]].to_numpy(float)
    prev: list[str] = []
    for k in range(1, 8):
        got = spread_beacons(t, k, 0)
        assert len(got) == len(set(got)) == k and got[:-1] == prev  # each round extends the previous choice
        costs = {c: _mean_nearest(demand, cand, prev + [c]) for c in sorted(set(cand["anchor_id"]) - set(prev))}
        want = min(costs, key=lambda c: (round(costs[c], 12), c))
        assert got[-1] == want, (k, got, costs)
        prev = got
    assert prev[0] in {"c0", "c1", "c2", "c3", "c4"}  # first a beacon of the cluster, not an outlier
    assert spread_beacons(t.sample(frac=1.0, random_state=0), 7, 0) == prev  # row order irrelevant
    assert spread_beacons(t, 1, 1) == ["up"] and "w" not in spread_beacons(t, 8, 0)
    assert sorted(spread_beacons(t, 20, 0)) == sorted(cand["anchor_id"])  # fewer than k: all of them


def test_spread_beacons_with_a_floor_serve_the_walkable_area(tiny_dataset):
    """With the floor plan the demand is the walkable area: on the tiny two-room house two beacons go one into
    each room (either side of the inner wall at x 5.0-5.2), and every choice is a BLE beacon."""
    s = Dataset.open(tiny_dataset).session("walk0")
    a = s.building.anchors
    ble = set(a.loc[a["kind"] == "ble", "anchor_id"])
    for k in (1, 2, 3):
        got = spread_beacons(a, k, 0, s.floor)
        assert len(got) == len(set(got)) == k and set(got) <= ble
    two = a.set_index("anchor_id").loc[spread_beacons(a, 2, 0, s.floor)]
    assert (two["x"] < 5.0).sum() == 1 and (two["x"] > 5.2).sum() == 1


def test_spread_beacons_pair_is_near_the_best_pair_on_the_walkable_area(tiny_dataset):
    s = Dataset.open(tiny_dataset).session("walk0")
    a = s.building.anchors
    free = s.floor.free_points()
    ble = sorted(a.loc[a["kind"] == "ble", "anchor_id"])
    best = min(_mean_nearest(free, a, c) for c in itertools.combinations(ble, 2))
    # greedy k-median on one demand point per 1 m cell (the cell's top-most free pixel, as documented): not
    # the optimum, but close on the whole walkable area (measured: 5 % above the best pair on the tiny house)
    assert _mean_nearest(free, a, spread_beacons(a, 2, 0, s.floor)) <= 1.08 * best


def test_select_beacons_rules_and_errors(tiny_dataset):
    s = Dataset.open(tiny_dataset).session("walk0")
    b = s.building
    assert select_beacons(b) == (["b1", "b2", "b3", "b4"], None)
    assert select_beacons(b, ["b3", "b1"]) == (["b1", "b3"], "list")  # rows sorted by id
    two, rule = select_beacons(b, 2, 0, s.floor)
    assert rule == "spread:2" and two == sorted(spread_beacons(b.anchors, 2, 0, s.floor)) and len(two) == 2
    assert select_beacons(b, 9, 0, s.floor) == (["b1", "b2", "b3", "b4"], "spread:9")  # fewer than k: all
    with pytest.raises(ValueError, match=r"\['ap1', 'zz'\] are not BLE anchors of building 'house'"):
        select_beacons(b, ["b1", "zz", "ap1"])  # the RTT AP is no BLE beacon either
    for bad, msg in ((0, "at least one"), ([], "empty list"), (["b1", "b1"], "more than once"), ("b1", "string")):
        with pytest.raises(ValueError, match=msg):
            select_beacons(b, bad)


def test_subset_windows_are_the_full_rows_and_not_unknown(tiny_dataset, caplog):
    s = Dataset.open(tiny_dataset).session("walk0")
    full = session_windows(s, beacon_order(s.building))
    with caplog.at_level(logging.WARNING, logger="blenav.learn"):
        sub = session_windows(s, ["b1", "b3"], WindowConfig(beacon_subset="list"))
    np.testing.assert_array_equal(sub.S, full.S[:, [0, 2]])
    np.testing.assert_array_equal(sub.xy, full.xy)
    assert sub.unknown == {} and WARN not in caplog.text  # b2, b4 are left out on purpose
    # an anchor the building does not list is still unknown for a subset model
    r = s.rssi
    foreign = pd.DataFrame({"t": r["t"].iloc[:3].to_numpy(), "anchor_id": "zz", "rssi": -60.0})
    s.__dict__["_streams"]["rssi"] = pd.concat([r, foreign], ignore_index=True).sort_values("t", kind="stable")
    caplog.clear()
    with caplog.at_level(logging.WARNING, logger="blenav.learn"):
        again = session_windows(s, ["b1", "b3"], WindowConfig(beacon_subset="list"))
    assert again.unknown == {"zz": 3} and WARN in caplog.text and "b2" not in caplog.text


def test_data_module_sessions_and_beacons(tiny_dataset, caplog):
    dm = _dm(tiny_dataset)
    assert dm.beacons == ["b1", "b2", "b3", "b4"] and dm.window.beacon_subset is None
    with caplog.at_level(logging.WARNING, logger="blenav.learn"):
        sub = _dm(tiny_dataset, "data.sessions=[walk0]", "data.beacons=[b4,b2]")
    assert sub.beacons == ["b2", "b4"] and sub.window.beacon_subset == "list"
    S_full, S_sub = dm.sets["train"].tensors[0].numpy(), sub.sets["train"].tensors[0].numpy()
    assert S_sub.shape == (S_full.shape[0], 2, 5)
    np.testing.assert_array_equal(S_sub, S_full[:, [1, 3]])
    np.testing.assert_array_equal(sub.sets["train"].tensors[2].numpy(), dm.sets["train"].tensors[2].numpy())
    assert WARN not in caplog.text
    k = _dm(tiny_dataset, "data.beacons=3")
    s = Dataset.open(tiny_dataset).session("walk0")
    assert k.beacons == sorted(spread_beacons(s.building.anchors, 3, 0, s.floor)) and k.window.beacon_subset == "spread:3"
    with pytest.raises(ValueError, match=r"data.sessions names sessions not in the dataset: \['nope', 'walk9'\]"):
        _dm(tiny_dataset, "data.sessions=[walk0,walk9,nope]")
    with pytest.raises(ValueError, match=r"data.beacons: beacons \['b7'\] are not BLE anchors"):
        _dm(tiny_dataset, "data.beacons=[b1,b7]")


@pytest.mark.onnx
def test_subset_model_export_loader_fixes_and_eval_choice(two_phones, tmp_path, caplog):
    """A 3-beacon model of the 8-beacon 'small' building: metadata, loader, blenav-fixes, same beacons as
    the evaluation's fixes.sparse_beacons: 3."""
    import onnx

    from blenav.cli.fixes import main as fixes_main
    from blenav.eval.fixes import FixProvider
    from blenav.learn.export import export
    from blenav.learn.train import train
    from blenav.runtime import OnnxLocalizer
    from blenav.runtime.fixes import session_fixes

    run = tmp_path / "run"
    train(compose("train", "model=locnet", f"data.path={two_phones}", f"out={run}", "data.batch_size=32",
                  "data.beacons=3", "data.holdout=0", "trainer.enable_progress_bar=false", "trainer.max_epochs=1",
                  "model.locnet.hidden=16", "model.locnet.fc_hidden=8"))
    path = export(compose("export", f"ckpt={run / 'last.ckpt'}", f"out={tmp_path / 'sparse3.onnx'}"))
    props = {p.key: json.loads(p.value) for p in onnx.load(str(path)).metadata_props}
    ds = Dataset.open(two_phones)
    s = next(ds.sessions())
    building = s.building
    want = sorted(spread_beacons(building.anchors, 3, s.meta.get("floor"), s.floor))
    assert props["beacons"] == want and props["beacon_subset"] == "spread:3"
    assert props["window"]["beacon_subset"] == "spread:3" and len(beacon_order(building)) == 8
    # the evaluation's sparse fixes (fixes.sparse_beacons: 3) use the same beacons
    provider = FixProvider({"sparse": None}, {}, 3, tmp_path / "eval")
    assert sorted(provider.beacons_for("sparse", s)) == want
    loc = OnnxLocalizer(path, building=building)  # 5 more beacons than the model: fine for a subset model
    assert loc.beacon_subset == "spread:3" and loc.n_beacons == 3
    with caplog.at_level(logging.WARNING, logger="blenav.learn"):
        t, xy, _ = session_fixes(loc, s)
    assert len(t) > 30 and np.isfinite(xy).all() and WARN not in caplog.text
    # still refused when one of its beacons is missing
    a = building.anchors
    gone = dataclasses.replace(building, anchors=a[a["anchor_id"] != want[1]].reset_index(drop=True))
    with pytest.raises(ValueError, match=rf"with 3 beacons \(a subset: spread:3\); this building 'small' lacks 1 "
                                         rf"of them \({want[1]}\)"):
        OnnxLocalizer(path, building=gone)
    # a full model (no subset) is unaffected: its metadata says null
    full_run = tmp_path / "full"
    train(compose("train", "model=locnet", f"data.path={two_phones}", f"out={full_run}", "data.batch_size=32",
                  "trainer.enable_progress_bar=false", "trainer.max_epochs=1", "model.locnet.hidden=8",
                  "model.locnet.fc_hidden=4"))
    full = OnnxLocalizer(export(compose("export", f"ckpt={full_run / 'last.ckpt'}", f"out={tmp_path / 'f.onnx'}")))
    assert full.beacon_subset is None and full.meta["beacon_subset"] is None and full.n_beacons == 8
    # blenav-fixes writes the subset model's fixes under the chosen source
    import shutil

    data = tmp_path / "d"
    shutil.copytree(two_phones, data)
    assert fixes_main([str(data), str(path), "--source", "locnet-sparse3", "--sessions", s.id]) == 0
    fx = Dataset.open(data).session(s.id).fixes
    assert set(fx["source"]) == {"locnet-sparse3"} and len(fx) == len(t)
    np.testing.assert_allclose(fx[["x", "y"]].to_numpy(), xy, atol=1e-3)


def test_data_sessions_comma_list_is_a_list_not_a_sweep():
    from blenav.configs import cli_overrides

    assert cli_overrides(["data.sessions=a,b", "sessions=c,d", "data.sessions=[e]"]) == [
        "data.sessions=[a,b]", "sessions=[c,d]", "data.sessions=[e]"]
