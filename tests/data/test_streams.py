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


def _random_stream(rng, n: int, sort: bool) -> pd.DataFrame:
    """rssi rows of 1-6 anchors (some ids missing), few time stamps and two rssi values: exact duplicates and
    (t, anchor) repeats with other values both occur."""
    t = rng.integers(0, max(1, n // int(rng.integers(1, 300))), n).astype(float) * float(rng.choice([1.0, 0.001]))
    ids = rng.choice([f"b{k}" for k in range(int(rng.integers(1, 7)))], n).astype(object)
    ids[rng.random(n) < 0.05] = np.nan
    return pd.DataFrame({"t": np.sort(t) if sort else t, "anchor_id": ids, "rssi": rng.choice([-70.0, -71.0], n)})


def test_anchored_checks_agree_with_pandas_groupby_and_duplicated():
    # the checks run on every read of every anchored stream, so they avoid pandas' groupby / duplicated where
    # they can (factorize + bincount; no (t run, anchor) pair twice = no duplicate); the counts stay pandas' own
    from blenav.data.streams import ANCHOR_MAX_RATE_HZ, RATE_MIN_ROWS, _collapse_duplicates, reading_bursts

    rng = np.random.default_rng(3)
    n_rate = n_dup = 0
    for trial in range(200):
        df = _random_stream(rng, int(rng.choice([2, 99, 100, 400, 3000])), sort=trial % 4 != 0)
        skip = rng.random(len(df)) < 0.05
        g = df[~skip].groupby("anchor_id", sort=False)["t"].agg(["size", "min", "max"])
        with np.errstate(divide="ignore", invalid="ignore"):
            hz = np.where(g["size"] >= RATE_MIN_ROWS, (g["size"] - 1) / (g["max"] - g["min"]), 0.0)
        n, span = g["size"].to_numpy(), (g["max"] - g["min"]).to_numpy()
        fast = [f"anchor {g.index[k]!r} heard {n[k]:,} times within {span[k]:g} s ({hz[k]:,.0f} Hz"
                for k in np.argsort(-hz, kind="stable") if hz[k] > ANCHOR_MAX_RATE_HZ][:20]
        got = [i.message for i in reading_bursts("rssi.csv", df, skip) if i.rule == "reading-rate"]
        assert len(got) == len(fast) and all(m.startswith(f) for m, f in zip(got, fast)), trial
        dup = df.duplicated(keep="first").to_numpy()
        out, issues, n = _collapse_duplicates("rssi.csv", df)
        assert n == dup.sum() and len(issues) == (n > 0), trial
        pd.testing.assert_frame_equal(out, df[~dup].reset_index(drop=True))
        n_rate, n_dup = n_rate + bool(fast), n_dup + (n > 0)
    assert 10 < n_rate < 190 and 10 < n_dup < 190, (n_rate, n_dup)  # both outcomes exercised


def test_duplicates_apart_within_one_instant_are_found():
    # line 5 repeats line 3 with another anchor's reading between them (same t): kept once; line 2 and lines 6-7
    # hold the same values at other times, readings
    from blenav.data.streams import _collapse_duplicates

    df = pd.DataFrame({"t": [0.0, 1.0, 1.0, 1.0, 2.0, 2.0], "anchor_id": ["b0", "b0", "b1", "b0", "b1", "b0"],
                       "rssi": [-70.0, -70.0, -71.0, -70.0, -71.0, -70.0]})
    out, issues, n = _collapse_duplicates("rssi.csv", df)
    assert n == 1 and [i.message for i in issues] == ["1 rows repeat an earlier row exactly (same t, anchor and "
                                                      "values; the first at line 5); each reading is kept once"]
    pd.testing.assert_frame_equal(out, df.drop(index=3).reset_index(drop=True))


def _most_and_fastest(root) -> tuple[int, float]:
    """Most rows of one anchor at one t, and the fastest anchor with RATE_MIN_ROWS rows or more (Hz), over the
    rssi.csv / rtt.csv files of a dataset."""
    from blenav.data.streams import RATE_MIN_ROWS

    most, fastest = 0, 0.0
    ds = Dataset.open(root)
    sessions = [ds.session(sid) for sid in ds.session_ids]
    for d in (s.stream(n) for s in sessions for n in ("rssi", "rtt") if s.has(n)):
        most = max(most, int(d.groupby(["t", "anchor_id"]).size().max()))
        g = d.groupby("anchor_id")["t"].agg(["size", "min", "max"])
        g = g[g["size"] >= RATE_MIN_ROWS]
        fastest = max(fastest, float(((g["size"] - 1) / (g["max"] - g["min"])).max()))
    return most, fastest


@pytest.mark.realdata
def test_the_real_datasets_stay_far_below_the_burst_and_rate_thresholds(raw_dir, tmp_path):
    # the figures docs/dataset-format.md quotes for the thresholds' margin: at most 11 readings of one anchor at one
    # instant and 6.5 Hz (Kolakowski et al.'s calibration, with different values); ILC 2.0: the next test
    from blenav.importers import run_import

    got = {}
    for kind in ("uji_ble", "danis_ble_tracks", "kolakowski_ble_calib", "feng_wifi_rtt"):
        run_import(kind, raw_dir / kind, tmp_path / kind)
        got[kind] = _most_and_fastest(tmp_path / kind)
    assert {k: m for k, (m, _) in got.items()} == {"uji_ble": 1, "danis_ble_tracks": 1, "kolakowski_ble_calib": 11,
                                                    "feng_wifi_rtt": 1}
    hz = {k: round(f, 1) for k, (_, f) in got.items()}
    assert max(hz.values()) == hz["kolakowski_ble_calib"] == 6.5, hz


@pytest.mark.realdata
@pytest.mark.slow
def test_the_ilc20_floors_stay_far_below_the_burst_and_rate_thresholds(raw_dir, tmp_path):
    # docs/dataset-format.md: one reading of an anchor per instant, at most 5.5 Hz (B1); 3 imports, about 30 s
    from blenav.importers import run_import

    got = {}
    for floor in ("B1", "F1", "F2"):
        run_import("ilc20", raw_dir / "ilc20" / f"site1_{floor}.tar.gz", tmp_path / floor)
        most, fastest = _most_and_fastest(tmp_path / floor)
        got[floor] = (most, round(fastest, 1))
    assert got == {"B1": (1, 5.5), "F1": (1, 2.0), "F2": (1, 2.1)}, got
