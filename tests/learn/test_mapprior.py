"""Learned map prior (Roy, section 3.2.2): targets, networks, training from the real config (resume), resolution
resampling, the runtime's DMT cache, ONNX export with parity, and clear errors."""

from __future__ import annotations

import json
import re
import shutil
import subprocess
import sys
from pathlib import Path

import lightning as L
import numpy as np
import pytest
import torch
from PIL import Image

from blenav.configs import compose
from blenav.data import FREE, OCCUPIED, Floor
from blenav.features.mapgrid import net_grid, resample_free
from blenav.learn.mapprior.checkpoint import build_net, load_map_prior, load_mapprior
from blenav.learn.mapprior.data import (
    Collate,
    MapPriorDataModule,
    feasible_weights,
    split_sessions,
    target_from_tbar,
    target_tbar,
    unique_weights,
    window_ends,
)
from blenav.learn.mapprior.module import MapPriorModule
from blenav.learn.mapprior.train import mapprior_data_config
from blenav.learn.train import train
from blenav.models.mapprior import MapEncoder, MapPriorNet
from blenav.runtime.map_prior import LOG_FLOOR, MapPrior
from helpers import REPO

TINY = ["trainer.enable_progress_bar=false", "data.samples_per_epoch=96", "data.val_samples=32", "data.batch_size=16",
        "data.crop_px=32", "model.net.unet_channels=[4,8]", "model.net.channels=8", "early_stopping=null"]


def make_floor(tmp_path: Path, occ: np.ndarray, res: float, name: str = "bldg", origin=(0.0, 0.0)) -> Floor:
    """A Floor read from a PNG written under tmp_path/<name>/ (FREE white, OCCUPIED black)."""
    d = tmp_path / name
    d.mkdir(parents=True, exist_ok=True)
    img = np.where(occ == FREE, 255, 0).astype(np.uint8)
    path = d / f"floor_{res:g}.png"
    Image.fromarray(img).save(path)
    return Floor(id=0, image_path=path, resolution=res, origin=origin)


def two_rooms(h: int = 40, w: int = 60) -> np.ndarray:
    """Occupancy (h, w) at any resolution: outer walls, a vertical inner wall at w // 2 with a door."""
    occ = np.full((h, w), FREE, dtype=np.int8)
    occ[:1, :] = occ[-1:, :] = occ[:, :1] = occ[:, -1:] = OCCUPIED
    occ[:, w // 2] = OCCUPIED
    occ[h // 2 - 3: h // 2 + 3, w // 2] = FREE
    return occ


# --- targets ---------------------------------------------------------------------------------------------

def test_target_higher_where_the_window_fits_and_in_range():
    occ = two_rooms()
    free = torch.from_numpy((occ == FREE).astype(np.float32))[None]
    # a straight 10 px walk eastwards ending at the end pixel: offsets (0, -10..0) relative to the END
    offs = torch.stack([torch.zeros(11, dtype=torch.long), torch.arange(-10, 1)], dim=-1)[None]
    o, w = unique_weights(torch.cat([offs, offs[:, :3]], dim=1))  # repeats count once
    assert torch.allclose(w.sum(1), torch.ones(1)) and int((w > 0).sum()) == 11
    tbar = target_tbar(free, o, w)[0]
    T = target_from_tbar(tbar)
    fits = T[5, 20]  # ends in the west room, walk entirely in free space
    crosses = T[5, 35]  # ends east of the inner wall (col 30): the walk crosses it
    assert float(tbar[5, 20]) == pytest.approx(1.0) and float(tbar[5, 35]) < 1.0
    assert float(fits / crosses) == pytest.approx(np.exp(14 / 11), rel=1e-4)  # one of 11 pixels in the wall
    assert float(T.min()) >= 1e-6 * (1 - 1e-6) and float(T.max()) <= 1e-6 * np.exp(14) * (1 + 1e-6)
    assert float(T[0, 0]) < 1e-5  # ends in the outer wall


def test_feasible_weights_inverse_area_per_sample():
    tbar = np.zeros((2, 10, 10), dtype=np.float32)
    tbar[0, :2, :2] = 1.0  # region of 4
    tbar[0, 5:9, 5:9] = 1.0  # region of 16
    tbar[1, 0, 0] = 1.0  # lone pixel in another sample: its own region
    w = feasible_weights(tbar, 0.93)
    assert w[0, 0, 0] == pytest.approx(20 / (2 * 4)) and w[0, 6, 6] == pytest.approx(20 / (2 * 16))
    assert w[0, :2, :2].sum() == pytest.approx(w[0, 5:9, 5:9].sum())  # each region the same total weight
    assert w[1, 0, 0] == pytest.approx(1.0) and w[0, 3, 3] == 1.0


def test_window_ends_skip_gaps():
    t = np.concatenate([np.arange(0, 20, 0.1), np.arange(30, 50, 0.1)])
    ends = window_ends(t, 5.0, 10.0, 1.0)
    assert ends.min() == pytest.approx(5.0) and ends.max() <= 49.9 + 1e-9
    assert not np.any((ends > 19.91) & (ends < 35.0 - 1e-9))  # no window spans the 10 s gap


# --- networks --------------------------------------------------------------------------------------------

@pytest.mark.parametrize("hw", [(37, 53), (1, 1), (16, 9)])
def test_unet_keeps_any_map_size(hw):
    enc = MapEncoder([4, 8, 16], out_channels=6).eval()
    with torch.no_grad():
        out = enc(torch.rand(2, 1, *hw))
    assert out.shape == (2, 6, *hw)


def test_score_at_equals_full_score_map():
    g = torch.Generator().manual_seed(0)
    net = MapPriorNet(channels=8, unet_channels=[4, 8]).eval()
    with torch.no_grad():
        dmt = net.encode_map((torch.rand(1, 1, 21, 30, generator=g) > 0.3).float())
        odo = torch.cumsum(torch.randn(3, 6, 2, generator=g), dim=1)
        dtv = net.encode_trajectory(odo - odo[:, :1])
        full = net.score(dmt.expand(3, -1, -1, -1), dtv)  # (3, H, W)
        ij = torch.stack([torch.randint(0, 21, (3, 50), generator=g), torch.randint(0, 30, (3, 50), generator=g)], -1)
        got = net.score_at(dmt[0], dtv, ij)
    ref = full[torch.arange(3)[:, None], ij[..., 0], ij[..., 1]]
    torch.testing.assert_close(got, ref, rtol=1e-5, atol=1e-6)


def test_short_window_is_a_clear_error():
    net = MapPriorNet(channels=8, unet_channels=[4, 8], n_points=6, step_hz=1.0)
    with pytest.raises(ValueError, match=r"needs 6 .*5 s"):
        net.encode_trajectory(torch.zeros(2, 4, 2))


# --- resolution ------------------------------------------------------------------------------------------

def test_resampling_round_trip_and_walls_survive():
    rng = np.random.default_rng(0)
    coarse = rng.random((13, 17)) > 0.3
    fine = resample_free(coarse, 0.5, 0.25)  # nearest: each coarse pixel -> 2 x 2
    assert fine.shape == (26, 34) and np.array_equal(fine[::2, ::2], coarse)
    assert np.array_equal(resample_free(fine, 0.25, 0.5), coarse)  # exact back for an integer factor
    # a 0.2 m wall at 0.1 m/px survives 0.25 and 0.5 m/px wherever it lies
    for col in range(20, 25):
        occ = np.ones((40, 60), dtype=bool)
        occ[:, col:col + 2] = False
        for res in (0.25, 0.5):
            m = resample_free(occ, 0.1, res)
            assert (~m).any(axis=1).all(), (col, res)


def test_scores_mapped_back_across_floor_resolutions(tmp_path, trained):
    """The same floor at the network's resolution and at half of it gives the same DMT and the same scores."""
    ckpt, _ = trained
    prior = load_map_prior(ckpt)
    res = prior.resolution_m
    occ = two_rooms(48, 64)
    coarse = make_floor(tmp_path, occ, res, "a")
    fine = make_floor(tmp_path, np.repeat(np.repeat(occ, 2, 0), 2, 1), res / 2, "b")
    dtv = prior.dtv(np.cumsum(np.full((1, prior.n_points, 2), 0.5), axis=1) - 0.5)
    prior.bind(coarse)
    dmt_c, s_c = prior.dmt.copy(), prior.log_score_map(dtv[0])
    prior.bind(fine)
    np.testing.assert_array_equal(prior.dmt, dmt_c)
    s_f = prior.log_score_map(dtv[0])  # (96, 128): each coarse pixel's score on its 2 x 2 fine pixels
    assert s_f.shape == (96, 128)
    np.testing.assert_allclose(s_f[::2, ::2], s_c, rtol=1e-6)
    assert np.all(s_f[occ.repeat(2, 0).repeat(2, 1) != FREE] == LOG_FLOOR)


def test_no_free_space_is_a_clear_error(tmp_path):
    floor = make_floor(tmp_path, np.full((20, 20), OCCUPIED, dtype=np.int8), 0.1, "bunker")
    with pytest.raises(ValueError, match=r"building 'bunker' floor 0 has no free space"):
        net_grid(floor, 0.25)


# --- training from the real config -----------------------------------------------------------------------

@pytest.fixture(scope="module")
def small_dataset(three_walks):
    return three_walks  # conftest.py: shared with the other map-prior trainings


@pytest.fixture(scope="module")
def trained(small_dataset, tmp_path_factory):
    """(last.ckpt, train() objects) of a 2-epoch tiny run of `train.py experiment=mapprior`."""
    run = tmp_path_factory.mktemp("mprun") / "run"
    metrics, objs = train(compose("train", "experiment=mapprior", f"data={small_dataset}", f"out={run}", *TINY,
                                  "trainer.max_epochs=2"))
    return run / "last.ckpt", objs


def test_training_leaves_checkpoint_resumes_and_learns(small_dataset, trained, tmp_path):
    ckpt, objs = trained
    trainer = objs["trainer"]
    assert ckpt.is_file() and trainer.current_epoch == 2
    meta = torch.load(ckpt, map_location="cpu", weights_only=True)["blenav"]
    assert meta["kind"] == "mapprior" and meta["window"] == {"window_s": 5.0, "step_hz": 1.0, "n_points": 6}
    assert meta["resolution_m"] == 0.25 and meta["channels"] == 8
    # the loss on fixed validation batches falls from the untrained network's (same seed, same init)
    cfg = compose("train", "experiment=mapprior", f"data={small_dataset}", *TINY)
    dm = objs["datamodule"]
    batches = list(dm.val_dataloader()[0])
    torch.manual_seed(0)
    fresh = MapPriorModule(build_net(dict(cfg.model), 6, 1.0)).eval()
    trained_net, _ = load_mapprior(ckpt)
    with torch.no_grad():
        before = np.mean([float(fresh.model_step(b)["loss"]) for b in batches])
        after = np.mean([float(MapPriorModule(trained_net).model_step(b)["loss"]) for b in batches])
    assert after < before
    # resume: same out, one more epoch -> epochs and steps continue
    run = tmp_path / "run"
    shutil.copytree(ckpt.parent, run)
    steps = trainer.global_step
    _, objs2 = train(compose("train", "experiment=mapprior", f"data={small_dataset}", f"out={run}", *TINY,
                             "trainer.max_epochs=3"))
    assert objs2["trainer"].current_epoch == 3 and objs2["trainer"].global_step == steps * 3 // 2
    assert torch.load(run / "last.ckpt", map_location="cpu", weights_only=True)["global_step"] == steps * 3 // 2


class _Interrupt(L.Callback):
    def on_train_epoch_start(self, trainer, pl_module):
        if trainer.current_epoch == 1:
            raise RuntimeError("interrupted")


def test_interrupted_run_resumes_from_its_last_epoch(small_dataset, tmp_path):
    over = ["experiment=mapprior", f"data={small_dataset}", f"out={tmp_path / 'run'}", *TINY, "trainer.max_epochs=2"]
    with pytest.raises(RuntimeError, match="interrupted"):
        train(compose("train", *over), callbacks=[_Interrupt()])
    ck = torch.load(tmp_path / "run" / "last.ckpt", map_location="cpu", weights_only=True)
    assert ck["global_step"] == 6  # written after epoch 0 (96 windows / 16), before the interruption
    _, objs = train(compose("train", *over))
    assert objs["trainer"].current_epoch == 2 and objs["trainer"].global_step == 12


def test_data_is_deterministic_and_targets_match_the_batch(small_dataset):
    cfg = compose("train", "experiment=mapprior", f"data={small_dataset}", *TINY)
    dm = MapPriorDataModule(mapprior_data_config(cfg), 0.25)
    dm.setup()
    a, b = dm.sets["train"][5], dm.sets["train"][5]
    assert all(np.array_equal(x, y) for x, y in zip(a, b))
    batch = Collate()([dm.sets["train"][i] for i in range(8)])
    tb_end = batch["tbar"][torch.arange(8), batch["end"][:, 0], batch["end"][:, 1]]
    assert float(tb_end.mean()) > 0.9  # the true end is (nearly always) feasible
    assert torch.all(batch["odo"][:, 0] == 0) and batch["odo"].shape == (8, 6, 2)


def test_split_keeps_a_training_session_per_building():
    rng = np.random.default_rng(0)
    got = split_sessions({"a1": "A", "a2": "A", "b1": "B"}, 0.34, rng)
    assert got["b1"] == ["train"] and sorted([got["a1"], got["a2"]]) == [["train"], ["val_seen"]]
    both = ["train", "val_seen"]  # one walk per building: every walk split in time
    assert split_sessions({"a1": "A", "b1": "B"}, 0.2, rng) == {"a1": both, "b1": both}


def test_val_buildings_must_exist(small_dataset):
    cfg = compose("train", "experiment=mapprior", f"data={small_dataset}", *TINY, "data.val_buildings=[nowhere]")
    with pytest.raises(ValueError, match="nowhere"):
        MapPriorDataModule(mapprior_data_config(cfg), 0.25).setup()


# --- runtime ---------------------------------------------------------------------------------------------

def test_dmt_cache_hit_on_second_bind(trained, small_dataset, tmp_path):
    from blenav.data import Dataset

    ckpt, _ = trained
    floor = next(Dataset.open(small_dataset).sessions()).floor
    prior = load_map_prior(ckpt, cache_dir=tmp_path / "cache")
    prior.bind(floor)
    files = list((tmp_path / "cache").glob("dmt_*.npy"))
    assert prior.encode_calls == 1 and len(files) == 1
    prior.bind(floor)
    assert prior.encode_calls == 1
    again = load_map_prior(ckpt, cache_dir=tmp_path / "cache")  # a new process: from disk
    again.bind(floor)
    assert again.encode_calls == 0 and np.array_equal(again.dmt, prior.dmt)
    # K heading hypotheses x N particles, gathered at particle pixels
    xy = floor.free_points()[::50][:40]
    odo = np.cumsum(np.tile([[0.8, 0.0]], (3, prior.n_points, 1)), axis=1) - [0.8, 0.0]
    dtv = prior.dtv(odo)
    ls = prior.log_score_at(xy[None], dtv[:, None, :])
    assert dtv.shape == (3, prior.channels) and ls.shape == (3, len(xy)) and np.all(ls >= LOG_FLOOR)
    assert np.all(prior.log_score_at(np.array([[-100.0, -100.0]]), dtv[0]) == LOG_FLOOR)
    with pytest.raises(ValueError, match=r"needs 6 samples at 1 Hz \(5 s of odometry\)"):
        prior.dtv(odo[:, :3])


@pytest.mark.onnx
def test_onnx_export_two_graphs_with_parity(trained, small_dataset, tmp_path):
    import onnx

    from blenav.data import Dataset
    from blenav.learn.export import export

    ckpt, _ = trained
    out = Path(export(compose("export", f"ckpt={ckpt}", f"out={tmp_path / 'mp'}")))
    meta = json.loads((out / "meta.json").read_text())
    assert meta["kind"] == "mapprior" and meta["resolution_m"] == 0.25 and meta["window"]["n_points"] == 6
    assert max(meta["parity"][k] for k in ("dmt", "dtv", "score")) <= 1e-4
    for name in ("map_encoder.onnx", "trajectory_encoder.onnx"):
        props = {p.key: json.loads(p.value) for p in onnx.load(str(out / name)).metadata_props}
        assert props["resolution_m"] == 0.25 and props["window"]["window_s"] == 5.0
    # the runtime from ONNX agrees with the runtime from the checkpoint (relative to the score scale)
    floor = next(Dataset.open(small_dataset).sessions()).floor
    a, b = load_map_prior(ckpt), MapPrior(out)
    a.bind(floor)
    b.bind(floor)
    odo = np.cumsum(np.random.default_rng(0).normal(0.5, 0.3, (4, 6, 2)), axis=1)
    odo -= odo[:, :1]
    xy = floor.free_points()[::7]
    sa = a.score_at(xy[None], a.dtv(odo)[:, None])
    sb = b.score_at(xy[None], b.dtv(odo)[:, None])
    assert np.max(np.abs(sa - sb)) <= 1e-4 * max(1.0, np.max(np.abs(sa)))


@pytest.mark.slow
def test_cli_train_and_export(small_dataset, tmp_path):
    """The command contract: train.py experiment=mapprior data=DIR out=RUN, then export.py ckpt=... out=DIR2."""
    run, out = tmp_path / "run", tmp_path / "onnx"
    subprocess.run([sys.executable, "train.py", "experiment=mapprior", f"data={small_dataset}", f"out={run}",
                    *TINY, "trainer.max_epochs=1"], cwd=REPO, check=True, capture_output=True)
    assert (run / "last.ckpt").is_file()
    subprocess.run([sys.executable, "export.py", f"ckpt={run / 'last.ckpt'}", f"out={out}"], cwd=REPO, check=True,
                   capture_output=True)
    assert {p.name for p in out.iterdir()} >= {"map_encoder.onnx", "trajectory_encoder.onnx", "meta.json"}


@pytest.mark.onnx
def test_an_export_meta_json_sizes_are_bounded(trained, small_dataset, tmp_path, monkeypatch):
    """Red-team (issue 28 sec. 2): meta.json is not covered by the graphs' hashes, and its resolution_m set the grid
    a floor is resampled to: 1e-4 asked numpy for 27.9 GiB, 0 was a ZeroDivisionError, 'abc' a bare 'could not
    convert string to float'. Now its sizes are ranges named with the file, and the grid's memory is checked."""
    from blenav.data import Dataset
    from blenav.learn.export import export
    from blenav.limits import LimitError, MemoryLimitError

    ckpt, _ = trained
    out = Path(export(compose("export", f"ckpt={ckpt}", f"out={tmp_path / 'mp'}")))
    meta = json.loads((out / "meta.json").read_text())
    for value, words in [(1e-4, "resolution_m = 0.0001 is outside [0.01, 100] m"), (0, "resolution_m = 0 is outside"),
                         ("abc", "resolution_m = 'abc' is not a number")]:
        (out / "meta.json").write_text(json.dumps({**meta, "resolution_m": value}))
        with pytest.raises(LimitError, match=re.escape(f"{out / 'meta.json'}: {words}")):
            MapPrior(out)
    (out / "meta.json").write_text(json.dumps({**meta, "window": {**meta["window"], "n_points": 10**9}}))
    with pytest.raises(LimitError, match=re.escape("window.n_points = 1000000000 is outside [1, 10,000]")):
        MapPrior(out)
    (out / "meta.json").write_text(json.dumps({**meta, "resolution_m": 0.01}))
    monkeypatch.setenv("BLENAV_MAX_MEMORY_GB", "0.001")
    prior = MapPrior(out)
    with pytest.raises(MemoryLimitError, match=r"grid at resolution_m = 0.01 m with 8 channels needs about"):
        prior.bind(next(Dataset.open(small_dataset).sessions()).floor)
