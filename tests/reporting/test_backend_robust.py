"""The back-end robustness table (blenav tables backend, issue 32) from two evaluations' results.json."""

import json

import pytest

from blenav.reporting.backend_robust import backend_rows, markdown


def _results(path, rmse, beacons=None):
    path.mkdir()
    methods = {k: {"rmse_m": {"mean": v}} for k, v in rmse.items()}
    if beacons:
        methods["B-end"]["beacon_error_m"] = beacons
    (path / "results.json").write_text(json.dumps({"runs": 5, "methods": methods}))


def test_table_ratios_changes_and_beacons_by_how_often_heard(tmp_path):
    _results(tmp_path / "t", {"IMU": 4.0, "F-end": 3.5, "B-end": 3.0})
    bh = [{"from": 0, "to": 10, "beacons": 4, "given_m": 3.0, "optimized_m": 3.0},
          {"from": 200, "to": None, "beacons": 6, "given_m": 4.0, "optimized_m": 2.0}]
    _results(tmp_path / "n", {"IMU": 4.4, "F-end": 4.0, "B-end": 3.6},
             {"prior": 3.6, "optimized": 2.4, "by_heard": bh})
    rows = backend_rows(["office=" + f"{tmp_path / 't'},{tmp_path / 'n'}"])
    assert rows[0]["ratio"] == pytest.approx(3.0 / 3.5)
    md = markdown("T", rows)
    assert "| office | 4.00 | 3.50 | 3.00 | 0.86 ok | 4.00 | 3.60 (+20 %) | 3.60 -> 2.40 (33 %) |" in md
    assert "| building, channel | 0-9 | 200+ |" in md
    assert "| office | 3.00 -> 3.00 (4) | 4.00 -> 2.00 (6) |" in md


@pytest.mark.parametrize("made_by", [None, "make backend-robust-lio"])
def test_the_command_line_says_which_command_made_the_page(tmp_path, made_by):
    from blenav.cli.tables import _main

    _results(tmp_path / "t", {"IMU": 4.0, "F-end": 3.5, "B-end": 3.0})
    out = tmp_path / "page.md"
    flag = ["--made-by", made_by] if made_by else []
    assert _main(["backend", *flag, str(out), "Title", f"office={tmp_path / 't'}"]) == 0
    assert f"made by `{made_by or 'make backend-robust'}`" in out.read_text()


def test_pooled_rows_add_their_columns(tmp_path):
    """A perturbed run with B-end+pool (blenav.backend.pooled) adds its B-end against the true map and its beacons;
    a building without it shows dashes there."""
    _results(tmp_path / "t", {"IMU": 4.0, "F-end": 3.5, "B-end": 3.0})
    _results(tmp_path / "n", {"IMU": 4.4, "F-end": 4.0, "B-end": 3.6, "B-end+pool": 3.3},
             {"prior": 3.6, "optimized": 3.5})
    methods = json.loads((tmp_path / "n" / "results.json").read_text())
    methods["methods"]["B-end+pool"]["beacon_error_m"] = {"prior": 3.6, "optimized": 2.7}
    (tmp_path / "n" / "results.json").write_text(json.dumps(methods))
    rows = backend_rows([f"annex={tmp_path / 't'},{tmp_path / 'n'}", f"office={tmp_path / 't'}"])
    md = markdown("T", rows)
    assert ("| annex | 4.00 | 3.50 | 3.00 | 0.86 ok | 4.00 | 3.60 (+20 %) | 3.60 -> 3.50 (3 %) | 3.30 (+10 %) | "
            "3.60 -> 2.70 (25 %) |") in md
    assert "| office | 4.00 | 3.50 | 3.00 | 0.86 ok | - | - (-) | - -> - (-) | - (-) | - -> - (-) |" in md
    assert md.count("|---") == 10
