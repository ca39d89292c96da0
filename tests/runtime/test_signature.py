"""Issue 18, section 4: a bundle refuses a building whose beacons or floor plan are not its own, with a message that
says what differs (blenav.runtime.signature; the bundle calls :func:`check_building` in ``Bundle.check_building``,
``localizer`` and ``run_session``, see tests/runtime/test_bundle.py for the refusal through a real bundle).

No ONNX graph is needed: the signature is the building's, the refusal compares signatures."""

from __future__ import annotations

import json
import shutil

import numpy as np
import pandas as pd
import pytest
import yaml
from PIL import Image

from blenav.data import Dataset
from blenav.runtime import BuildingMismatch
from blenav.runtime.signature import building_signature, check_building

B = "buildings/house"


@pytest.fixture
def bundle_sig(tiny_dataset):
    """The signature a bundle made for the tiny house stores (building.json), as it reads it back."""
    return json.loads(json.dumps(building_signature(Dataset.open(tiny_dataset).building("house"))))


def _refusal(sig, root) -> str:
    with pytest.raises(BuildingMismatch) as e:
        check_building(sig, Dataset.open(root).building("house"), what="bundle B")
    return str(e.value)


def test_the_same_building_passes_even_copied(bundle_sig, tiny_dataset, tmp_path):
    check_building(bundle_sig, Dataset.open(tiny_dataset).building("house"))
    copy = shutil.copytree(tiny_dataset, tmp_path / "copy")
    png = copy / B / "floor_0.png"
    Image.fromarray(np.asarray(Image.open(png))).save(png, optimize=True)  # re-encoded: the same plan
    check_building(bundle_sig, Dataset.open(copy).building("house"))


def test_beacons_added_removed_and_moved_are_named(bundle_sig, tiny_dataset):
    p = tiny_dataset / B / "anchors.csv"
    a = pd.read_csv(p)
    a = a[a["anchor_id"] != "b1"]
    a.loc[a["anchor_id"] == "b2", "x"] += 2.0
    a = pd.concat([a, a[a["anchor_id"] == "b4"].assign(anchor_id="b9", x=3.0)])
    a.to_csv(p, index=False)
    msg = _refusal(bundle_sig, tiny_dataset)
    assert "bundle B was made for building 'house' (4 beacons" in msg
    assert "1 beacon(s) of the bundle missing from the building: b1" in msg
    assert "1 beacon(s) the bundle does not know: b9" in msg
    assert "1 beacon(s) moved: b2 (2.00 m)" in msg
    assert "floor" not in msg.split("differs:")[1].split("Export")[0]  # the plan is the same: not mentioned


def test_a_new_wall_says_which_pixels_changed(bundle_sig, tiny_dataset):
    png = tiny_dataset / B / "floor_0.png"
    im = np.asarray(Image.open(png)).copy()
    row = im.shape[0] // 3
    n = int((im[row] == 254).sum())  # free pixels across the floor at that row
    im[row, :] = 0
    Image.fromarray(im).save(png)
    msg = _refusal(bundle_sig, tiny_dataset)
    assert "floor 0: another floor plan (plan hash" in msg
    assert f"same size, resolution and origin; {n} px more occupied, {n} px fewer free" in msg, msg


@pytest.mark.parametrize("key, value, words", [
    ("resolution", 0.05, "resolution 0.1 -> 0.05 m/px"),
    ("origin", [0.5, 0.0, 0.0], "origin (0, 0) -> (0.5, 0) m"),
])
def test_another_scale_or_origin_is_said(bundle_sig, tiny_dataset, key, value, words):
    y = tiny_dataset / B / "building.yaml"
    doc = yaml.safe_load(y.read_text())
    doc["floors"][0][key] = value
    y.write_text(yaml.safe_dump(doc, sort_keys=False))
    if key == "resolution":  # keep the beacons inside the smaller plan: only the plan differs
        a = tiny_dataset / B / "anchors.csv"
        df = pd.read_csv(a)
        df[["x", "y"]] /= 2
        df.to_csv(a, index=False)
    msg = _refusal(bundle_sig, tiny_dataset)
    assert words in msg, msg


def test_a_bundle_without_floor_facts_still_names_the_hashes(bundle_sig, tiny_dataset):
    """Bundles exported before floor_facts: the plan hash, as before."""
    del bundle_sig["floor_facts"]
    png = tiny_dataset / B / "floor_0.png"
    im = np.asarray(Image.open(png)).copy()
    im[im.shape[0] // 3, :] = 0
    Image.fromarray(im).save(png)
    msg = _refusal(bundle_sig, tiny_dataset)
    assert "floor 0: another floor plan (plan hash" in msg and "bundle's" in msg and "same size" not in msg
