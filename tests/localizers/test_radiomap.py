"""The radio map of the fused rows (blenav.localizers.radiomap): expected fingerprints per cell from the train walks."""

from __future__ import annotations

import numpy as np
import pytest

from blenav.crf.grid import build_grid
from blenav.localizers.radiomap import RadioMapConfig, build_radio_map


def test_the_likelihood_peaks_where_the_scan_was_heard_and_unsurveyed_cells_are_flat(coded):
    """Position-coded walks (a new access point every 4 m along x): walkC's scans, scored on the map of walkA and
    walkB, peak within a few metres of where they were heard; the map's support is highest on the walks and the
    expected fingerprint of a far, unsurveyed cell is the floor's mean (the shrinkage)."""
    train, test = [coded.session("mall_F1_walkA"), coded.session("mall_F1_walkB")], coded.session("mall_F1_walkC")
    g = build_grid(test.floor, cell_m=1.0, max_step_m=3.0)
    rm = build_radio_map(g, train, RadioMapConfig(bandwidth_m=2.0, min_count=1))
    assert rm is not None and rm.fp.features == "both" and rm.n_train > 0
    t, Q = rm.scans(test)
    LL = rm.log_likelihood(Q)
    np.testing.assert_allclose(np.logaddexp.reduce(LL, axis=1), 0.0, atol=1e-9)
    truth = test.positions_at(t)[:, :2]
    ok = np.isfinite(truth).all(axis=1)
    best = g.xy[LL.argmax(axis=1)]
    assert np.median(np.linalg.norm(best[ok] - truth[ok], axis=1)) < 4.0
    d = np.min([np.linalg.norm(g.xy - p, axis=1) for p in ([5.0, 6.0], [25.0, 6.0], [15.0, 6.0])], axis=0)
    far = np.flatnonzero(d > 13.0)[:2]  # two cells far from every train fingerprint (x 5..25 m, y 5 / 7 m)
    assert len(far) == 2 and (rm.support[far] < 1e-6).all()
    np.testing.assert_allclose(rm.m[far[0]], rm.m[far[1]], atol=1e-6)
    assert not np.allclose(rm.m[far[0]], rm.m[g.cell_of(np.array([[5.0, 5.0]]))[0]], atol=1e-3)
    on = g.cell_of(np.array([[15.0, 5.0]]))[0]
    assert rm.support[on] > 1.0


def test_a_floor_without_scans_has_no_map_and_bad_settings_are_refused(coded, tmp_path):
    g = build_grid(coded.session("mall_F1_walkA").floor, cell_m=1.0, max_step_m=3.0)
    assert build_radio_map(g, [], RadioMapConfig()) is None
    with pytest.raises(ValueError, match="tau"):
        RadioMapConfig(tau=0.0)
    with pytest.raises(ValueError, match="metric"):
        RadioMapConfig(metric="euclidean")
