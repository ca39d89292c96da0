"""docs/results-inertial.md from the floors' results (blenav.reporting.realwalks_inertial): every number is read from
the results given, the ratio is computed, a floor without the simulator-only run shows dashes."""

from __future__ import annotations

import json

import pytest

from blenav.reporting.realwalks_inertial import write_inertial


def _res(pdr_seg, lio_seg, pdr_wp, lio_wp):
    seg = lambda m: {"mean": m, "median": m / 2, "segments": 10, "length_abs_mean": m / 3, "length_mean": 0.0,  # noqa: E731
                     "heading_abs_median_deg": 9.0}
    return {"methods": {"PDR (rotation vector)": {"error_m": {"mean": pdr_wp}, "segment_error_m": seg(pdr_seg)},
                        "LIO": {"error_m": {"mean": lio_wp}, "segment_error_m": seg(lio_seg)},
                        "LIO+map": {"skipped": {"w": "no io_model"}}}}


def test_page_from_results(tmp_path):
    for name, res in (("F1", _res(2.0, 1.5, 4.0, 3.0)), ("B1", _res(1.0, 0.9, 3.0, 3.5)),
                      ("sim_F1", _res(2.0, 2.5, 4.0, 5.0))):
        (tmp_path / name).mkdir()
        (tmp_path / name / "results.json").write_text(json.dumps(res))
    (tmp_path / "runs.json").write_text(json.dumps({"not_F1": {"model": "inertial_tcn", "steps": 30, "stop_reason":
                                                    "max_steps", "fit_wall_s": 12.0, "best_val_error_m": 0.5,
                                                    "baseline_val_error_m": 0.7, "data": {"train": {"walks": 4}}}}))
    page = tmp_path / "page.md"
    assert "2 floors, 1 simulator-only" in write_inertial(tmp_path, page)
    text = page.read_text()
    assert "| F1 | 2.00 / 1.00 | 1.50 / 0.75 | 0.75 | 4.00 | 3.00 | -- | -- | 2.50 / 5.00 |" in text
    assert "| B1 | 1.00 / 0.50 | 0.90 / 0.45 | 0.90 | 3.00 | 3.50 | -- | -- | -- / -- |" in text
    assert "| F1 | LIO | 1.50 | 0.50 | 9.0 deg |" in text
    assert "| not_F1 | inertial_tcn | 30 | max_steps | 12 | 4 | 0.50 | 0.70 |" in text


def test_no_results_is_an_error(tmp_path):
    with pytest.raises(ValueError, match="no <floor>/results.json"):
        write_inertial(tmp_path, tmp_path / "page.md")
