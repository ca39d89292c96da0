"""Beacons without a position (an imported survey such as ILC 2.0, before blenav-map): the range filters skip
them with the reason, or use the placed ones and say how many were left out; never NaN."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest


def _dataset(tmp_path, blank):
    from helpers import make_tiny_dataset

    root = make_tiny_dataset(tmp_path / "tiny")
    path = next((root / "buildings").glob("*/anchors.csv"))
    a = pd.read_csv(path)
    ble = np.flatnonzero((a["kind"] == "ble").to_numpy())[:blank]
    a["x"] = a["x"].astype(object)
    a["y"] = a["y"].astype(object)
    a["z"] = a["z"].astype(object)
    a.loc[ble, ["x", "y", "z"]] = ""
    a.to_csv(path, index=False)
    return root


def _pf_pl(root):
    from blenav.configs import compose
    from blenav.eval.harness import build_methods

    return build_methods(compose("eval", "experiment=mapfusion_002", f"data={root}", "filter.n_particles=50"))["PF-PL"]


def test_no_placed_beacon_skips_with_the_reason(tmp_path):
    from blenav.data import Dataset
    from blenav.errors import MissingStream

    root = _dataset(tmp_path, blank=99)
    s = Dataset.open(root).session("walk0")
    with pytest.raises(MissingStream, match="blenav-map"):
        _pf_pl(root).run(s, 1, 0)


def test_some_placed_beacons_are_used_and_the_rest_reported(tmp_path):
    from blenav.data import Dataset

    root = _dataset(tmp_path, blank=1)
    s = Dataset.open(root).session("walk0")
    est = _pf_pl(root).run(s, 2, 0)
    assert np.isfinite(est.position).all()
    assert any("have no position and are not used" in n for n in est.notes), est.notes
