"""The real cross-phone test: UJI BLE (three phones at the same points), train on two, test on the third."""

from __future__ import annotations

import numpy as np
import pytest

from blenav.configs import compose
from blenav.eval.harness import evaluate
from blenav.features.windows import WindowConfig, beacon_order, session_windows
from blenav.importers import run_import
from blenav.data import Dataset
from helpers import RAW

pytestmark = pytest.mark.realdata


@pytest.fixture(scope="module")
def uji(tmp_path_factory):
    if not RAW.is_dir():
        pytest.skip(f"public recordings not found at {RAW} (../shared/data/raw is absent)")
    out = tmp_path_factory.mktemp("uji") / "ds"
    run_import("uji_ble", RAW / "uji_ble", out)
    return out


def test_scan_windows_stay_at_one_point(uji):
    s = Dataset.open(uji).session("lib_s6_c1_txm12")
    w = session_windows(s, beacon_order(s.building), WindowConfig(steps="scan"))
    assert len(w.S) > 40 and w.S.shape[1:] == (24, 5)
    gt = s.groundtruth
    for k in (0, len(w.S) // 2, len(w.S) - 1):  # the window's 5 scans share the labelled point
        rows = gt[(gt["t"] <= w.t[k]) & np.isclose(gt["x"], w.xy[k, 0]) & np.isclose(gt["y"], w.xy[k, 1])]
        assert len(rows) >= 5


def test_unseen_phone_against_knn(uji, tmp_path):
    res = evaluate(compose("eval", "experiment=crossphone_uji", f"data={uji}", f"out={tmp_path}", "progress=false",
                           "plots=false", "trainer.max_epochs=30", "trainer.enable_progress_bar=false",
                           "~experiment.learned.dlrnn", "~experiment.learned.transnet_locnet",
                           "~experiment.baselines.bayesian", "~experiment.baselines.krr_kf"))
    assert res["split"]["train"] == ["A5", "Bq"] and res["split"]["test"] == ["S6"]
    knn, loc = res["methods"]["KNN"], res["methods"]["LocNet"]
    assert set(knn["per_device"]) == set(loc["per_device"]) == {"S6"}
    assert knn["n_windows"] == loc["n_windows"] > 100
    # both localize the unseen phone far better than the library's size (about 30 m x 10 m) would by chance
    assert knn["error_m"]["mean"] < 6.0 and loc["error_m"]["mean"] < 8.0
