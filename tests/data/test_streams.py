"""Issue 28, section 2: pathological anchored streams. 200,000 identical rssi.csv rows at one instant went
unremarked by the validator and moved PF-PL from 2.09 to 5.02 m (memory 0.31 -> 2.0 GB). Now the validator warns
(many readings of one anchor at one instant; an anchor heard faster than 100 Hz), and the readers keep each exact
duplicate once, counted in the dropped rows (``duplicate-row``), so the evaluation's errors do not move."""

from __future__ import annotations

import shutil

import numpy as np
import pandas as pd
import pytest

from blenav.data import Dataset, validate
from blenav.data.streams import BURST_MAX_ROWS

RSSI = "sessions/walk0/rssi.csv"
ROW = 40  # line 42 of rssi.csv: anchor b1 at t = 2 s in the tiny dataset


def _with_copies(root, copies: int, **change):
    """``root``'s rssi.csv with ``copies`` copies of row ROW inserted after it (cells in ``change`` altered)."""
    p = root / RSSI
    d = pd.read_csv(p)
    extra = pd.DataFrame([d.iloc[ROW]] * copies).assign(**change)
    pd.concat([d.iloc[:ROW + 1], extra, d.iloc[ROW + 1:]]).to_csv(p, index=False)
    return d


def test_validator_warns_on_a_burst_and_the_reader_keeps_each_reading_once(tiny_dataset):
    orig = Dataset.open(tiny_dataset).session("walk0").rssi.copy()
    d = _with_copies(tiny_dataset, 20_000)
    assert (d.iloc[ROW]["anchor_id"], d.iloc[ROW]["t"]) == ("b1", 2.0)
    issues = validate(tiny_dataset)
    assert not [i for i in issues if i.is_error]
    by_rule = {i.rule: i for i in issues}
    burst = by_rule["reading-burst"]
    assert (burst.path, burst.line) == (str(tiny_dataset / RSSI), ROW + 2)
    assert burst.message.startswith("20,001 readings of anchor 'b1' at t = 2 s, more than 100 at one instant")
    assert by_rule["reading-rate"].message.startswith("anchor 'b1' heard 20,100 times within 19.8 s (1,015 Hz")
    assert by_rule["duplicate-row"].message.startswith("20,000 rows repeat an earlier row exactly")
    s = Dataset.open(tiny_dataset).session("walk0")
    pd.testing.assert_frame_equal(s.rssi, orig)  # the very frame of the file without the copies
    assert s.load_all().dropped == {"rssi": {"duplicate-row": 20_000}}


def test_legitimate_repeats_pass_unremarked(tiny_dataset):
    # readings of one anchor at one instant with other values are readings (the Kolakowski data has 11): kept,
    # and no warning up to BURST_MAX_ROWS
    _with_copies(tiny_dataset, BURST_MAX_ROWS - 1, rssi=np.arange(BURST_MAX_ROWS - 1) * -0.5 - 30.0)
    assert validate(tiny_dataset) == []
    s = Dataset.open(tiny_dataset).session("walk0")
    assert len(s.rssi) == 400 + BURST_MAX_ROWS - 1 and s.load_all().dropped == {}


def test_evaluation_is_unmoved_by_duplicates_and_reports_them(tiny_dataset, tmp_path):
    from blenav.configs import compose
    from blenav.eval.harness import evaluate

    dup = tmp_path / "dup"
    shutil.copytree(tiny_dataset, dup)
    _with_copies(dup, 20_000)
    res = {}
    for name, root in (("clean", tiny_dataset), ("dup", dup)):
        res[name] = evaluate(compose("eval", "progress=false", "experiment=mapfusion_002", f"data={root}", "runs=2",
                                     "methods={pf_pl_map: null, pf_ps_map: null, pf_pl_offset: null, "
                                     "pf_ps_map_offset: null}", "filter.n_particles=100", "calibration=none",
                                     "plots=false", "init_s=2", f"out={tmp_path / name}"))
    assert set(res["dup"]["methods"]) == {"PF-PL", "PF-PS"}
    for m in ("PF-PL", "PF-PS"):
        a, b = res["clean"]["methods"][m]["rmse_m"]["mean"], res["dup"]["methods"][m]["rmse_m"]["mean"]
        assert np.isfinite(a) and a == b, (m, a, b)
    assert "dropped" not in res["clean"]
    assert res["dup"]["dropped"] == {"walk0": {"rssi": {"duplicate-row": 20_000}}}
