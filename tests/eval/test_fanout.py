"""A fan-out over methods on an existing engine (issue 33, section 5): ``blenav eval -m only=A,B`` with Hydra's
joblib launcher, two workers, then ``blenav merge``: the serial run's results, number for number (timings aside)."""

from __future__ import annotations

import json
import subprocess
import sys

import pytest

from blenav.errors import EvalError
from blenav.eval.config import select_methods
from blenav.eval.merge import merge_runs
from helpers import simulate_small

TIMING = {"wall_s", "realtime_factor"}


def numbers(m):
    """A results.json node without its timings (they differ between any two runs)."""
    if isinstance(m, dict):
        return {k: numbers(v) for k, v in m.items() if k not in TIMING}
    if isinstance(m, list):
        return [numbers(v) for v in m]
    return m


def eval_cmd(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "blenav", "eval", *args], capture_output=True, text=True, timeout=600)


@pytest.mark.slow  # scale-out end to end (17-28 s here): make test-slow
def test_two_worker_fan_out_over_methods_equals_the_serial_run(tmp_path):
    data = simulate_small(tmp_path / "d", 8, 60, 2)
    common = ["experiment=mapfusion_002", f"data={data}", "runs=2", "progress=false", "plots=false"]
    r = eval_cmd(*common, f"out={tmp_path / 'serial'}")
    assert r.returncode == 0, r.stderr[-2000:]
    fan = tmp_path / "fan"
    r = eval_cmd("-m", *common, "only=PF-PL,PF-PS+MAP,pf_pl_offset", f"out={fan}/${{hydra:job.num}}",
                 "hydra/launcher=joblib", "hydra.launcher.n_jobs=2", f"hydra.sweep.dir={fan}/.multirun")
    assert r.returncode == 0, r.stderr[-2000:]
    merged = merge_runs([fan], tmp_path / "merged")
    serial = json.loads((tmp_path / "serial" / "results.json").read_text())
    assert list(merged["methods"]) == ["PF-PL", "PF-PS+MAP", "PF-PL+offset"]
    for name, m in merged["methods"].items():
        assert numbers(m) == numbers(serial["methods"][name]), name
    on_disk = json.loads((tmp_path / "merged" / "results.json").read_text())
    assert on_disk["methods"].keys() == merged["methods"].keys()
    sid = serial["sessions"][0]
    for name in merged["methods"]:
        a = (tmp_path / "merged" / sid / "trajectories" / f"{name}.tum").read_text()
        assert a == (tmp_path / "serial" / sid / "trajectories" / f"{name}.tum").read_text()
    with pytest.raises(ValueError, match="method PF-PL is in"):
        merge_runs([fan / "0", fan / "0"], tmp_path / "twice")
    (tmp_path / "other").mkdir()
    r = eval_cmd(*common[:2], "runs=1", "progress=false", "plots=false", "only=PF-PS", f"out={tmp_path / 'other' / 'x'}")
    assert r.returncode == 0, r.stderr[-2000:]
    with pytest.raises(ValueError, match=r"runs differs: 2 in .* 1 in "):
        merge_runs([fan / "0", tmp_path / "other" / "x"], tmp_path / "mixed")


def test_only_selects_by_label_or_key_and_names_the_rest():
    methods = {"a": {"label": "PF-A"}, "b": {"label": "PF-B"}, "c": None, "d": {}}
    assert list(select_methods(methods, "PF-B,d")) == ["b", "d"]
    assert list(select_methods(methods, ["a"])) == ["a"]
    assert select_methods(methods, None) is methods
    with pytest.raises(EvalError, match=r"only=PF-Z: no such method.*PF-A, PF-B, d \(labels\)"):
        select_methods(methods, "PF-Z")


def test_merge_keeps_one_bound_recomputes_its_best_and_takes_the_fitted_calibration(tmp_path):
    from pathlib import Path

    from blenav.eval.merge import merge_results

    head = {"experiment": "leaderboard", "dataset": "d", "runs": 1, "sessions": ["s"], "init_s": 10.0, "seed": 0,
            "split": None}
    bound = {"kind": "bound", "rmse_m": {"mean": 0.5}, "best": {"method": "A", "rmse_m": 3.0, "ratio": 6.0}}
    a = {**head, "calibration": None, "fixes": {"used": {"wifi": "x"}},
         "methods": {"A": {"rmse_m": {"mean": 3.0}}, "PCRLB": bound}}
    b = {**head, "calibration": {"a_x": -60.0}, "fixes": {"used": {"ble": "y"}},
         "methods": {"B": {"rmse_m": {"mean": 2.0}}, "PCRLB": dict(bound)}}
    m = merge_results([Path("ja"), Path("jb")], [a, b])
    assert list(m["methods"]) == ["A", "PCRLB", "B"] and m["calibration"] == {"a_x": -60.0}
    assert m["methods"]["PCRLB"]["best"] == {"method": "B", "rmse_m": 2.0, "ratio": 4.0}
    assert m["fixes"] == {"used": {"wifi": "x", "ble": "y"}}
    c = {**b, "calibration": {"a_x": -70.0}}
    with pytest.raises(ValueError, match="calibration differs"):
        merge_results([Path("jb"), Path("jc")], [b, c])
