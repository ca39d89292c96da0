"""tools/rename_dataset.py: a dataset copied under other building, session and phone names stays a valid dataset with
the same data (the contract checks on non-default names)."""

from __future__ import annotations

import subprocess
import sys

from helpers import REPO, simulate_small

from blenav.data import Dataset


def test_renamed_copy_opens_with_the_new_names_and_the_same_readings(tmp_path):
    src = simulate_small(tmp_path / "src", 3, 20, 2)
    dst = tmp_path / "dst"
    p = subprocess.run([sys.executable, str(REPO / "tools" / "rename_dataset.py"), str(src), str(dst)],
                       capture_output=True, text=True, timeout=120)
    assert p.returncode == 0, p.stderr
    a, b = Dataset.open(src), Dataset.open(dst)
    assert b.session_ids == ["walk-00-rx3", "walk-01-rx10"]
    for i, (sa, sb) in enumerate(zip(a.session_ids, b.session_ids)):
        x, y = a.session(sa), b.session(sb)
        assert y.building.id == "Annex West" and y.meta["device_model"] == f"handset-{i}"
        assert x.rssi.equals(y.rssi) and x.groundtruth.equals(y.groundtruth)
    p2 = subprocess.run([sys.executable, str(REPO / "tools" / "rename_dataset.py"), str(src), str(dst)],
                        capture_output=True, text=True, timeout=120)
    assert p2.returncode != 0 and "exists" in p2.stderr
