"""A stranger's results.json given to the table merges: a one-line error naming the file and the field, never a
traceback from deep inside (blenav.eval.merge)."""

from __future__ import annotations

import json

import pytest

from blenav.eval.merge import load_columns, merge_leaderboard


def _results(folder, methods) -> None:
    folder.mkdir(parents=True, exist_ok=True)
    (folder / "results.json").write_text(json.dumps({"dataset": str(folder), "methods": methods}))


GOOD = {"A": {"family": "pf", "rmse_m": {"mean": 1.5}, "per_session": {"s1": {"rmse_m": {"mean": 1.5}}}},
        "B": {"skipped": {"s1": "no beacons"}},
        "PCRLB": {"kind": "bound", "rmse_m": {"mean": 0.5}, "best": {"method": "A", "rmse_m": 1.5, "ratio": 3.0}}}


def test_well_formed_results_merge(tmp_path):
    _results(tmp_path / "a", GOOD)
    cols, sessions = load_columns([(tmp_path / "a", "x/")])
    assert cols == {"x/A": {"s1": 1.5}} and sessions == ["s1"]
    lb = merge_leaderboard([tmp_path / "a"])
    assert lb["methods"]["A"]["pooled_rmse_m"] == 1.5 and lb["methods"]["B"]["skipped"] == {"a": "no beacons"}
    assert lb["best"]["a"] == {"method": "A", "rmse_m": 1.5, "bound_m": 0.5, "ratio": 3.0}


@pytest.mark.parametrize("methods, field, in_columns", [
    ({"A": {"rmse_m": {"mean": "1.5"}}}, "methods.A.rmse_m.mean", False),
    ({"A": {"rmse_m": {"mean": 1.0}, "per_session": {"s1": {"rmse_m": None}}}}, "methods.A.per_session.s1.rmse_m.mean",
     True),
    ({"A": {"rmse_m": {"mean": 1.0}, "per_session": [1, 2]}}, "methods.A.per_session", True),
    ({"A": "fast"}, "methods.A", True),
    ({"PCRLB": {"rmse_m": {"mean": 0.5}, "best": {"method": "A", "rmse_m": 1.0, "ratio": "x"}}}, "methods.PCRLB.best.ratio",
     False),
])
def test_a_malformed_field_is_named_with_its_file(tmp_path, methods, field, in_columns):
    """merge_leaderboard reads every field below; load_columns the per-session rows (in_columns: the field is one)."""
    _results(tmp_path / "bad", methods)
    match = rf"bad/results\.json: {field.replace('.', '[.]')}"
    with pytest.raises(ValueError, match=match):
        merge_leaderboard([tmp_path / "bad"])
    if in_columns:
        with pytest.raises(ValueError, match=match):
            load_columns([(tmp_path / "bad", "")])


def test_a_file_without_methods_is_named(tmp_path):
    (tmp_path / "c").mkdir()
    (tmp_path / "c" / "results.json").write_text("[1, 2]")
    with pytest.raises(ValueError, match=r"c/results\.json: no 'methods' table"):
        load_columns([(tmp_path / "c", "")])
    _results(tmp_path / "d", {"A": {"per_session": {"s1": {"rmse_m": {"mean": float("nan")}}}}})
    with pytest.raises(ValueError, match=r"per_session\.s1\.rmse_m\.mean is missing or not a finite number"):
        load_columns([(tmp_path / "d", "")])
