"""Every method's estimates stay on the floor (blenav.localizers.confine), and what the readers drop is reported."""

from __future__ import annotations

import json

import numpy as np
import pandas as pd
import pytest

from blenav.configs import compose
from blenav.data import Dataset
from blenav.eval.harness import evaluate
from blenav.localizers import Estimate
from blenav.localizers.confine import confine
from helpers import make_tiny_dataset


@pytest.fixture(scope="module")
def tiny(tmp_path_factory):
    return make_tiny_dataset(tmp_path_factory.mktemp("confine") / "tiny")


def _floor(root):
    ds = Dataset.open(root)
    return ds.session(ds.session_ids[0]).floor


def test_bbox_clamp_and_free_space_snap_respect_the_uncertainty(tiny):
    floor = _floor(tiny)  # 10 x 8 m at 0.1 m, outer walls 0.2 m thick, an inner wall at x in [5.0, 5.2)
    x0, x1, y0, y1 = floor.extent
    t = np.arange(4.0)
    pos = np.array([[[-30.0, 4.0],    # far outside, confident: clamped onto the box (in the outer wall), then moved
                     [-30.0, 6.0],    # far outside, std 1 m: clamped, and left in the 0.2 m wall (< 2 sigma)
                     [5.1, 1.0],      # inside the inner wall by one pixel: within the one-pixel slack
                     [2.5, 4.0]]])    # free: untouched
    cov = np.zeros((1, 4, 2, 2))
    cov[0, :, 0, 0] = cov[0, :, 1, 1] = 1.0
    cov[0, 0] = cov[0, 2] = np.eye(2) * 1e-6
    est = Estimate("m", "s", t, pos, cov)
    out, info = confine(est, floor)
    p = out.position[0]
    assert floor.is_free(p[0]) and abs(p[0, 1] - 4.0) < 0.2 and p[0, 0] < 0.5  # the nearest free pixel
    assert p[1, 0] == pytest.approx(x0 + 0.05) and p[1, 1] == 6.0 and not floor.is_free(p[1])
    np.testing.assert_array_equal(p[2:], pos[0, 2:])
    assert info == {"bbox": 2, "off_free": 1, "free": 1, "estimates": 4}
    # a map-free method is clamped to the box but not given the free space; its violations are still counted
    out2, info2 = confine(est, floor, snap_free=False)
    assert info2 == {"bbox": 2, "off_free": 1, "free": 0, "estimates": 4}
    assert not floor.is_free(out2.position[0, 0]) and out2.position[0, 0, 0] == pytest.approx(x0 + 0.05)
    # nothing to do: the very same object back
    ok = Estimate("m", "s", t[:1], np.array([[[2.5, 4.0]]]))
    assert confine(ok, floor)[0] is ok


def test_a_miscalibrated_filter_stays_in_the_building_and_drops_are_reported(tiny, tmp_path):
    """Issue 19: PF-PS+MAP with a path loss meant for another phone left a 20 x 15 m building by 28 m; and an
    rssi.csv row naming an anchor that anchors.csv lacks was dropped without a word."""
    sdir = tiny.parent / "tiny_drop"
    import shutil

    shutil.copytree(tiny, sdir)
    rssi = sdir / "sessions" / "walk0" / "rssi.csv"
    df = pd.read_csv(rssi)
    extra = df.head(7).assign(anchor_id="ghost-beacon")
    pd.concat([df, extra]).sort_values("t", kind="stable").to_csv(rssi, index=False)
    out = tmp_path / "out"
    cfg = compose("eval", "experiment=mapfusion_002", f"data={sdir}", "runs=3", f"out={out}", "plots=false",
                  "progress=false", "calibration=none", "methods.pf_pl=null", "methods.pf_pl_map=null",
                  "methods.pf_ps=null", "methods.pf_ps_map.measurements.ps.a_x=-30.0",
                  "methods.pf_ps_map.measurements.ps.use_anchor_tx_power=false")
    res = evaluate(cfg)
    m = res["methods"]["PF-PS+MAP"]
    x0, x1, y0, y1 = Dataset.open(sdir).session("walk0").floor.extent
    assert m["error_m"]["max"] <= np.hypot(x1 - x0, y1 - y0)  # never farther than the building's diagonal
    assert set(m["confined"]) == {"bbox", "off_free", "free", "estimates"}
    assert res["dropped"] == {"walk0": {"rssi": {"unknown-anchor": 7}}}
    on_disk = json.loads((out / "results.json").read_text())
    assert on_disk["dropped"] == res["dropped"]
    md = (out / "results.md").read_text()
    assert "walk0, rssi.csv: 7 rows (unknown-anchor)" in md
    from blenav.cli.eval import summary_lines

    assert any("dropped rows in walk0" in ln and "7 unknown-anchor" in ln for ln in summary_lines(res))
