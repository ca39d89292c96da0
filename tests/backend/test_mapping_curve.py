"""Beacon-map error against walking time (blenav.backend.mapping_curve): the cut views of the sessions and the
table on a short simulated walk."""

from __future__ import annotations

import numpy as np
import pytest

pytest.importorskip("gtsam")

from blenav.backend import load_backend_config  # noqa: E402
from blenav.backend.mapping_curve import COLUMNS, cut_sessions, error_vs_time, markdown_table, walking_time_s  # noqa: E402


@pytest.fixture(scope="module")
def walks(tmp_path_factory):
    from helpers import simulate_small

    from blenav.data import Dataset

    ds = Dataset.open(simulate_small(tmp_path_factory.mktemp("curve") / "sim", 11, 120.0, 2))
    return [ds.session(i) for i in ds.session_ids]


def test_cut_sessions_take_the_first_minutes_in_total(walks):
    spans = [walking_time_s(s) for s in walks]
    assert spans[0] > 100.0
    cut = cut_sessions(walks, 60.0)  # within the first walk
    assert len(cut) == 1 and walking_time_s(cut[0]) == pytest.approx(60.0, abs=0.2)
    t_end = float(cut[0].groundtruth["t"].iloc[0]) + 60.0
    assert cut[0].rssi["t"].max() <= t_end and cut[0].imu["t"].max() <= t_end
    assert len(cut[0].rssi) < len(walks[0].rssi) and cut[0].id == walks[0].id
    both = cut_sessions(walks, spans[0] + 30.0)  # the first whole, 30 s of the second
    assert [s.id for s in both] == [s.id for s in walks]
    assert walking_time_s(both[0]) == pytest.approx(spans[0]) and walking_time_s(both[1]) == pytest.approx(30.0, abs=0.2)
    assert sum(walking_time_s(s) for s in cut_sessions(walks, 1e6)) == pytest.approx(sum(spans))


def test_error_vs_time_table(walks):
    """Two walking times on the small office: the table's columns, finite errors of the placed beacons, and more
    walking does not place markedly fewer beacons."""
    cfg = load_backend_config().mapping
    df = error_vs_time(walks, walks[0].building.anchors, cfg, [1.0, 4.0])
    print(markdown_table(df))
    assert list(df.columns) == COLUMNS and len(df) == 2
    assert df["walk_min"].iloc[0] == pytest.approx(1.0, abs=0.01)
    assert df["walk_min"].iloc[1] == pytest.approx(sum(walking_time_s(s) for s in walks) / 60.0, abs=0.01)  # data end
    assert (df["total"] == len(walks[0].building.anchors.query("kind == 'ble'"))).all()
    assert df["placed"].iloc[1] >= 3 and df["placed"].iloc[1] >= df["placed"].iloc[0] - 1
    ok = df["placed"] > 0
    assert np.isfinite(df.loc[ok, ["mean_err_m", "median_err_m", "within_1std", "within_2std", "wall_s"]]
                       .to_numpy(float)).all()
    assert ((df["within_1std"] <= df["within_2std"]) | ~ok).all()
    assert "| T (min) |" in markdown_table(df)


def test_error_vs_time_needs_the_true_positions(walks):
    anchors = walks[0].building.anchors.drop(columns=["x_true", "y_true"], errors="ignore")
    with pytest.raises(ValueError, match="x_true"):
        error_vs_time(walks, anchors, load_backend_config().mapping, [1.0])
