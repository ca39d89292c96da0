"""The map prior trained on real walks with surveyed waypoints (issue 17: a prior trained on other mall floors):
the train walks of the realwalks split only (data.sessions), positions between waypoints interpolated linearly at
training time, a few training steps, the checkpoint meta, and misspelt keys / unknown ids failing early."""

from __future__ import annotations

import tarfile

import numpy as np
import pytest
from hydra.errors import ConfigCompositionException

from blenav.configs import compose
from helpers import RAW

TINY = ["trainer.enable_progress_bar=false", "data.samples_per_epoch=32", "data.val_samples=16", "data.batch_size=16",
        "data.crop_px=32", "model.net.unet_channels=[4,8]", "model.net.channels=8", "early_stopping=null",
        "trainer.max_epochs=1", "plots=false"]


def _unpack(raw_dir, tmp_path, floor: str = "F1", n: int = 3):
    """The floor's plan and its first ``n`` walks, read from the archive into tmp_path/raw (stops once it has them)."""
    tgz = raw_dir / "ilc20" / f"site1_{floor}.tar.gz"
    if not tgz.is_file():
        pytest.skip(f"{tgz} is absent")
    root, walks, plan = tmp_path / "raw", 0, 0
    with tarfile.open(tgz, "r|gz") as tf:
        for mem in tf:
            is_plan = mem.name.endswith(("floor_info.json", "geojson_map.json"))
            if mem.isfile() and (is_plan or (mem.name.endswith(".txt") and walks < n)):
                p = root / mem.name
                p.parent.mkdir(parents=True, exist_ok=True)
                p.write_bytes(tf.extractfile(mem).read())
                walks += mem.name.endswith(".txt")
                plan += is_plan
            if walks >= n and plan >= 2:
                break
    return root / "site1" / floor


@pytest.fixture(scope="module")
def ilc_walks(tmp_path_factory):
    """Three ILC 2.0 F1 walks imported into a temporary folder (once for the module; not conftest's simulated
    ``three_walks``)."""
    from blenav.importers import run_import

    if not RAW.is_dir():
        pytest.skip(f"public recordings not found at {RAW} (../shared/data/raw is absent)")
    tmp = tmp_path_factory.mktemp("ilc3")
    data = tmp / "ds"
    run_import("ilc20", _unpack(RAW, tmp), data)
    return data


@pytest.mark.realdata
def test_trains_on_the_train_walks_with_interpolated_waypoints(ilc_walks, tmp_path):
    from blenav.data import Dataset
    from blenav.cli.realwalks import train_ids_of
    from blenav.learn.train import train

    train_walks = set(train_ids_of(str(ilc_walks)))  # the realwalks split, as make realwalks-tables passes it
    cfg = compose("train", "experiment=mapprior_ilc", f"data={ilc_walks}", f"out={tmp_path / 'run'}", *TINY,
                  f"data.sessions=[{','.join(sorted(train_walks))}]")
    metrics, objs = train(cfg)
    dm = objs["datamodule"]
    ds = Dataset.open(ilc_walks)
    assert 0 < len(train_walks) < len(ds.session_ids)  # the split keeps a test walk out
    used = set().union(*map(set, dm.groups.values()))
    assert used and used <= train_walks  # no test walk is read, not even for validation
    for tr in dm.sets["train"].tracks:
        gt = ds.session(tr.session).groundtruth
        assert ds.session(tr.session).groundtruth_sparse and len(gt) == len(tr.t)
        # at the waypoint times the interpolated trajectory is the waypoints; halfway, the segment's midpoint
        np.testing.assert_allclose(tr.at(gt["t"].to_numpy()), gt[["x", "y"]].to_numpy(), atol=1e-9)
        mid = 0.5 * (tr.t[:-1] + tr.t[1:])
        np.testing.assert_allclose(tr.at(mid), 0.5 * (tr.xy[:-1] + tr.xy[1:]), atol=1e-9)
        assert np.diff(tr.t).max() > cfg.data.max_gap_s  # only the waypoint gap rule lets these windows exist
    meta = objs["module"].meta
    assert meta["floors"] == ["site1/F1"] and meta["sessions"] == sorted(used)
    assert meta["waypoint_sessions"]["sessions"] == len(used)
    assert "linear interpolation" in meta["waypoint_sessions"]["positions"]
    assert np.isfinite(metrics["train/loss"]) and (tmp_path / "run" / "last.ckpt").is_file()


@pytest.mark.realdata
def test_misspelt_keys_fail_early(ilc_walks, tmp_path):
    from blenav.learn.mapprior.data import MapPriorDataModule
    from blenav.learn.mapprior.train import mapprior_data_config

    with pytest.raises(ConfigCompositionException, match="extra_path"):
        compose("train", "experiment=mapprior_ilc", f"data={ilc_walks}", "data.extra_path=[x]")
    cfg = compose("train", "experiment=mapprior_ilc", f"data={ilc_walks}", "data.sessions=[site1_F1_nowhere]")
    with pytest.raises(ValueError, match="site1_F1_nowhere"):  # an id of no dataset
        MapPriorDataModule(mapprior_data_config(cfg), 0.25).setup()
    cfg = compose("train", "experiment=mapprior_ilc", f"data={ilc_walks}", f"data.extra_paths=[{ilc_walks}]")
    with pytest.raises(ValueError, match="in both"):  # the same walks twice
        MapPriorDataModule(mapprior_data_config(cfg), 0.25).setup()


def test_priors_table_puts_both_priors_beside_the_heuristic_pf(tmp_path):
    """blenav.reporting.realwalks_priors: the rows of both runs per floor, the verdicts, the page and README splices."""
    import json

    from blenav.reporting.realwalks_priors import OTHER, write_priors

    def res(rows):
        return {"methods": {k: {"error_m": {"mean": m, "p90": 2 * m}} for k, m in rows.items()}}

    main, other = tmp_path / "main", tmp_path / "other"
    for d, rows in ((main / "F1", {"PDR+map": 4.0, "PDR+learned-map": 3.0, "WiFi+PDR+map": 9.0}),
                    (other / "F1", {"PDR+learned-map" + OTHER: 2.5}), (main / "floors", {})):
        d.mkdir(parents=True)
        (d / "results.json").write_text(json.dumps(res(rows)))
    page, readme = tmp_path / "page.md", tmp_path / "README.md"
    readme.write_text("a\n<!-- realwalks-priors-table -->\nold\n<!-- /realwalks-priors-table -->\nb\n")
    body = write_priors(str(main), str(other), str(tmp_path / "prior_{floor}"), str(page), str(readme))
    assert "| PDR+learned-map, other-floors prior | 2.50 / 5.00 |" in body
    assert "| PDR+map (heuristic map PF) | 4.00 / 8.00 |" in body and "| BLE+PDR+map | - |" in body
    assert ("F1, PDR odometry: heuristic map PF 4.00 m, procedural prior 3.00 m, other-floors prior 2.50 m -> "
            "other-floors prior best") in body
    assert "F1, WiFi fixes + PDR: not all three rows ran" in body and "no prior meta" in body
    text = readme.read_text()
    assert text.startswith("a\n") and text.endswith("b\n") and "old" not in text and "2.50 / 5.00" in text
    assert "<!-- realwalks-priors-table -->" in page.read_text()
