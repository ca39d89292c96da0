"""The realwalks tables (blenav.reporting.realwalks): the fused rows' fix coverage and convergence."""

from __future__ import annotations

from blenav.reporting.realwalks import floor_markdown, fused_table


def _results():
    fused = {"error_m": {"mean": 6.0, "median": 5.0, "p90": 12.0}, "walks_within_m": {"2": 0.1, "5": 0.5},
             "per_session": {"a": {}, "b": {}},
             "fix_coverage": {"both": {"1sigma": 0.4, "2sigma": 0.85, "waypoints": 100}},
             "convergence": {"within_m": 5.0, "settled": 0.75, "median_s": 12.0, "p90_s": 30.0}}
    knn = {"error_m": {"mean": 8.0, "median": 6.0, "p90": 16.0}, "walks_within_m": {"2": 0.0, "5": 0.3},
           "per_session": {"a": {}, "b": {}}}
    return {"sessions": ["a", "b"], "runs": 1, "split": {"train": ["c"], "train_fraction": 0.5, "seed": 0},
            "methods": {"KNN-WiFi+BLE": knn, "fused-offline": fused}}


ROWS = {"all": ("KNN-WiFi+BLE", "fused-offline"), "fingerprint": ("KNN-WiFi+BLE",), "fused": ("fused-offline",)}


def test_fused_rows_report_their_fixes_coverage_and_convergence():
    t = fused_table({"F9": _results()}, ROWS)
    assert "| F9 | fused-offline | both | 40 % | 85 % | 75 % | 12 s |" in t
    page = floor_markdown(_results(), "F9", "make realwalks-tables", ROWS)
    assert "time to converge" in page and "| fused-offline | 6.00 | 5.00 | 12.00 | 10 % | 50 % | 2 |" in page
    assert "best fused fused-offline 6.00 m vs best fingerprint KNN-WiFi+BLE 8.00 m: fusion better" in page
    r = _results()
    del r["methods"]["fused-offline"]["fix_coverage"]
    assert fused_table({"F9": r}, ROWS) is None
