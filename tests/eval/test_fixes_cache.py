"""The cache of computed BLE fixes (OUT/fixes, :mod:`blenav.eval.fixes`) is keyed by what the filter reads: a rerun
into the same OUT (``overwrite=true`` reuses ``fixes/``) reuses them only while the building's anchors and plan are
those they were computed with."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from blenav.configs import compose
from blenav.data import Dataset
from blenav.eval import fixes as F
from blenav.eval.harness import build_methods
from helpers import simulate_small


@pytest.fixture(scope="module")
def session(tmp_path_factory):
    root = simulate_small(tmp_path_factory.mktemp("fixcache") / "small", 5, 20, 1)
    ds = Dataset.open(root)
    return ds.session(ds.session_ids[0])


def test_cached_fixes_are_reused_only_for_the_same_anchors_and_plan(session, tmp_path, monkeypatch):
    loc = build_methods(compose("eval", "data=unused", "experiment=mapfusion_002", "filter.n_particles=50"))["PF-PL"]
    runs = []
    real = F.ble_fixes
    monkeypatch.setattr(F, "ble_fixes", lambda *a, **k: runs.append(1) or real(*a, **k))

    def dense(s):
        t, xy, src = F.FixProvider({"dense": None}, {"dense": loc}, 4, tmp_path).fixes_for("dense", s)
        assert src == "ps-dense" and len(t) > 5
        return xy

    first = dense(session)
    assert np.array_equal(dense(session), first) and len(runs) == 1  # the same building: read from OUT/fixes
    b = session.building
    moved = b.anchors.copy()
    moved.loc[moved["kind"] == "ble", "x"] += 3.0  # anchors.csv edited (or another beacon_map) between the runs
    dense(session.with_building(replace(b, anchors=moved)))
    assert len(runs) == 2
    fl = session.floor
    grid = fl.occupancy.copy()
    grid[:3, :3] = 1 - grid[:3, :3].clip(0, 1)  # a plan that differs in a corner (plan_error's wrong plans)
    wrong = replace(fl)
    wrong.__dict__["occupancy"] = grid  # the cached property, as a perturbed floor carries it
    key = next(k for k, v in b.floors.items() if v is fl)
    dense(session.with_building(replace(b, floors={**b.floors, key: wrong})))
    assert len(runs) == 3
