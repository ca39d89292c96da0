"""ONNX export of trained localizers and the onnxruntime loader: metadata, parity with PyTorch incl. the
streaming state, refusal of another building, no fix without a beacon, the ``export.py`` entry point."""

from __future__ import annotations

import dataclasses
import json
import subprocess
import sys
from importlib import metadata as importlib_metadata
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
import torch

from blenav.cli.sim import run as sim_run
from blenav.configs import compose
from blenav.data import Dataset
from blenav.features.windows import WindowConfig, session_windows
from blenav.learn.crossphone import export as export_mod
from blenav.learn.crossphone.checkpoint import load_module
from blenav.learn.crossphone.export import INPUT_TRANSFORM, random_inputs
from blenav.learn.export import export
from blenav.learn.train import train
from blenav.runtime import OnnxLocalizer

from helpers import REPO

pytestmark = pytest.mark.onnx

MODELS = ["locnet", "transnet_locnet"]
TOL = 1e-4


@pytest.fixture(scope="module")
def dataset(two_phones):
    return two_phones


@pytest.fixture(scope="module")
def runs(dataset, tmp_path_factory):
    """model name -> (last.ckpt, exported .onnx) of a one-epoch tiny training run, exported with export(cfg)."""
    root = tmp_path_factory.mktemp("runs")
    out = {}
    for model in MODELS:
        run = root / model
        train(compose("train", f"model={model}", f"data.path={dataset}", f"out={run}", "data.batch_size=32",
                      "model.lr=3e-3", "trainer.enable_progress_bar=false", "trainer.max_epochs=1",
                      "model.locnet.hidden=16", "model.locnet.fc_hidden=8"))
        ckpt = run / "last.ckpt"
        path = export(compose("export", f"ckpt={ckpt}", f"out={root / (model + '.onnx')}"))
        out[model] = (ckpt, Path(path))
    return out


def first_session_windows(dataset, meta):
    """The first session's windows (S (K, B, H) thesis scale, xy (K, 2) truth, ...) in the model's beacon order."""
    w = meta["window"]
    s = next(Dataset.open(dataset).sessions())
    cfg = WindowConfig(history=w["history"], step_hz=w["step_hz"], offset_db=w["offset_db"], floor_u=w["floor_u"])
    return session_windows(s, meta["beacons"], cfg)


def real_windows(dataset, meta) -> np.ndarray:
    """(K, B, H) thesis-scale windows of the first session, in the model's beacon order."""
    return first_session_windows(dataset, meta).S


def torch_state_step(module, meta, S: np.ndarray, h0, c0):
    """The checkpoint's networks on thesis-scale S with an explicit state, as training sees them (u / u_scale)."""
    with torch.no_grad():
        g = module.translate(torch.from_numpy(S) / meta["window"]["u_scale"])
        return module.locnet.forward_state(g, h0, c0)


@pytest.mark.parametrize("model", MODELS)
def test_metadata_round_trip_and_graph(runs, model):
    import onnx

    ckpt, path = runs[model]
    _, meta = load_module(ckpt)
    props = {p.key: json.loads(p.value) for p in onnx.load(str(path)).metadata_props}
    for k in ("beacons", "building", "data_hash", "model", "train_devices", "known_devices", "unlabelled_devices"):
        assert props[k] == meta[k], k
    # the graph divides by u_scale itself: the export's window leaves it out (input_units says so)
    assert props["window"] == {k: v for k, v in meta["window"].items() if k != "u_scale"}
    assert props["input_units"]["graph_divides_by"] == meta["window"]["u_scale"]
    assert props["model_name"] == model and props["input_transform"] == INPUT_TRANSFORM
    assert props["blenav_version"] == importlib_metadata.version("blenav")
    loc = OnnxLocalizer(path)
    assert loc.meta == props and loc.beacons == meta["beacons"] and loc.building == meta["building"]
    assert (loc.n_beacons, loc.history) == (len(meta["beacons"]), meta["window"]["history"])
    assert (loc.layers, loc.hidden) == (2, 16)
    shapes = {i.name: i.shape for i in loc.session.get_inputs() + loc.session.get_outputs()}
    B, H = loc.n_beacons, loc.history
    assert shapes["S"][1:] == [B, H] and isinstance(shapes["S"][0], str)  # fixed B, H; dynamic batch
    assert shapes["h0"][0] == 2 and isinstance(shapes["h0"][1], str) and shapes["xy"][1] == 2


@pytest.mark.parametrize("model", MODELS)
def test_onnxruntime_matches_pytorch_incl_streaming_state(runs, dataset, model):
    ckpt, path = runs[model]
    module, meta = load_module(ckpt)
    loc = OnnxLocalizer(path)
    S = real_windows(dataset, meta)
    assert len(S) > 10 and loc.heard(S).all()
    rnd = random_inputs(loc.n_beacons, loc.history, 2, 16, batch=6, seed=3)[0].numpy()
    for X in (S, rnd, S[:1]):  # several batch sizes through the dynamic axis
        h0, c0 = module.locnet.initial_state(len(X))
        ref = torch_state_step(module, meta, X, h0, c0)[0].numpy()
        np.testing.assert_allclose(loc.predict(X), ref, atol=TOL, rtol=0)
        with torch.no_grad():
            np.testing.assert_allclose(ref, module(torch.from_numpy(X) / 100.0).numpy(), atol=1e-6)
    # streaming: two steps with the state carried equal forward_state twice
    loc.reset()
    a, b = loc.step(S[0:1]), loc.step(S[1])  # (1, B, H) and (B, H) both accepted
    h, c = module.locnet.initial_state(1)
    x1, h, c = torch_state_step(module, meta, S[0:1], h, c)
    x2, h, c = torch_state_step(module, meta, S[1:2], h, c)
    np.testing.assert_allclose(a, x1.numpy(), atol=TOL, rtol=0)
    np.testing.assert_allclose(b, x2.numpy(), atol=TOL, rtol=0)
    for got, ref in zip(loc.state, (h, c)):
        np.testing.assert_allclose(got, ref.numpy(), atol=TOL, rtol=0)
    assert np.abs(b - loc.predict(S[1:2])).max() > 1e-6  # the carried state matters
    loc.reset()
    np.testing.assert_allclose(loc.step(S[0:1]), a, atol=1e-6)


def test_no_beacon_heard_gives_no_fix(runs, dataset):
    ckpt, path = runs["transnet_locnet"]
    _, meta = load_module(ckpt)
    loc = OnnxLocalizer(path)
    S = real_windows(dataset, meta)[:4].copy()
    S[[1, 3]] = 0.0
    assert loc.heard(S).tolist() == [True, False, True, False]
    xy = loc.predict(S)
    assert np.isnan(xy[[1, 3]]).all() and np.isfinite(xy[[0, 2]]).all()
    loc.reset()
    assert np.isnan(loc.step(S[1:2])).all()
    assert np.abs(loc.state[0]).max() > 0  # the network still read the window: state advanced
    assert loc.predict(S[:0]).shape == (0, 2)


def test_input_checks_and_dbm_conversion(runs):
    loc = OnnxLocalizer(runs["locnet"][1])
    B, H = loc.n_beacons, loc.history
    with pytest.raises(ValueError, match=rf"\(K, {B}, {H}\)"):
        loc.predict(np.zeros((2, B + 1, H)))
    with pytest.raises(ValueError, match="dBm"):
        loc.predict(np.full((1, B, H), -70.0))
    with pytest.raises(ValueError, match="NaN"):
        loc.predict(np.full((1, B, H), np.nan))
    with pytest.raises(ValueError, match="one window"):
        loc.step(np.zeros((2, B, H)))
    np.testing.assert_allclose(loc.to_u([-60.0, np.nan, -120.0]), [40.0, 0.0, 0.5])
    with pytest.raises(FileNotFoundError):
        OnnxLocalizer(runs["locnet"][1].with_name("missing.onnx"))


def test_loader_refuses_another_building(runs, dataset, tmp_path):
    path = runs["transnet_locnet"][1]
    own = Dataset.open(dataset)
    building = own.building(own.building_ids[0])
    assert OnnxLocalizer(path, building=building).beacons == sorted(building.anchors_of("ble")["anchor_id"])
    # another simulated building: more beacons, another id
    other = tmp_path / "annex"
    sim_run(compose("sim", "sim=small", "sim.name=annex", "sim.n_beacons=10", "seed=9", f"out={other}",
                    "duration_s=5", "sessions=1", "progress=false", "sim.carriers=[static]",
                    "sim.receivers=[iphone-8]"))
    annex = Dataset.open(other).building("annex")
    with pytest.raises(ValueError) as e:
        OnnxLocalizer(path, building=annex)
    msg = str(e.value)
    assert str(path) in msg and "building 'small' with 8 beacons" in msg and "this building 'annex'" in msg
    assert "has 2 unknown (ble-008, ble-009)" in msg and "lacks" not in msg
    # the same id with a changed beacon list: 2 missing, 7 unknown (5 examples shown)
    a = building.anchors
    ble = a[a["kind"] == "ble"]
    extra = ble.iloc[[0] * 7].assign(anchor_id=[f"x-{i:03d}" for i in range(7)])
    changed = dataclasses.replace(building, anchors=pd.concat([a.drop(ble.index[:2]), extra], ignore_index=True))
    with pytest.raises(ValueError) as e:
        OnnxLocalizer(path, building=changed)
    msg = str(e.value)
    assert "lacks 2 of them (ble-000, ble-001)" in msg
    assert "has 7 unknown (x-000, x-001, x-002, x-003, x-004, ... (2 more))" in msg
    # identical beacon ids but another building
    with pytest.raises(ValueError, match="'elsewhere' has the same beacon ids but is another building"):
        OnnxLocalizer(path, building=dataclasses.replace(building, id="elsewhere"))


def test_export_errors(runs, tmp_path, monkeypatch):
    with pytest.raises(FileNotFoundError):
        export(compose("export", f"ckpt={tmp_path / 'none.ckpt'}", f"out={tmp_path / 'm.onnx'}"))
    monkeypatch.setattr(export_mod, "onnx_max_diff", lambda *a, **k: 1.0)  # a broken runtime
    out = tmp_path / "bad.onnx"
    with pytest.raises(RuntimeError, match="differs from PyTorch"):
        export(compose("export", f"ckpt={runs['locnet'][0]}", f"out={out}"))
    assert not out.exists()


def test_entry_point(runs, tmp_path):
    ckpt, ref = runs["transnet_locnet"]
    out = tmp_path / "cli" / "MODEL.onnx"
    r = subprocess.run([sys.executable, "export.py", f"ckpt={ckpt}", f"out={out}"], cwd=REPO,
                       capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stderr[-2000:]
    assert f"wrote {out}" in r.stdout
    S = random_inputs(8, 5, 2, 16, batch=4, seed=1)[0].numpy()
    np.testing.assert_allclose(OnnxLocalizer(out).predict(S), OnnxLocalizer(ref).predict(S), atol=1e-6)


def test_model_fixes_feed_the_particle_filter(dataset, runs, tmp_path):
    """blenav-fixes writes the exported model's fixes; fused_003 filters them (eq. 3.9) beside PF-PS+MAP."""
    import shutil

    from blenav.cli.fixes import main as fixes_main
    from blenav.data.validate import validate
    from blenav.eval.harness import evaluate

    data = tmp_path / "d"
    shutil.copytree(dataset, data)
    sid = Dataset.open(data).session_ids[0]
    assert fixes_main([str(data), str(runs["transnet_locnet"][1]), "--sessions", sid]) == 0
    fx = Dataset.open(data).session(sid).fixes
    assert len(fx) > 30 and set(fx["source"]) == {"TransNet+LocNet"} and np.isfinite(fx[["x", "y"]].to_numpy()).all()
    assert fx["std"].isna().all()  # a model without a std head states none
    assert not [i for i in validate(data) if i.severity == "error"]
    res = evaluate(compose("eval", "experiment=fused_003", f"data={data}", f"sessions=[{sid}]", "runs=2",
                           f"out={tmp_path / 'o'}", "plots=false", "progress=false", "filter.n_particles=200"))
    assert {"PF-PS+MAP", "PF-FIX", "PF-FIX+MAP"} <= set(res["methods"])
    assert np.isfinite(res["methods"]["PF-FIX"]["rmse_m"]["mean"])
    assert fixes_main([str(data), str(tmp_path / "missing.onnx")]) == 1  # a clear error, no traceback


def test_calibrate_prints_the_error_statistics_and_writes_nothing(dataset, runs, capsys):
    from blenav.cli.fixes import main as fixes_main
    from blenav.runtime.fixes import calibrate_model_fixes

    sid = Dataset.open(dataset).session_ids[0]
    before = sorted(p.name for p in (Path(dataset) / "sessions" / sid).iterdir())
    assert fixes_main([str(dataset), str(runs["transnet_locnet"][1]), "--sessions", sid, "--calibrate"]) == 0
    last = capsys.readouterr().out.strip().splitlines()[-1]
    st = calibrate_model_fixes(Dataset.open(dataset), runs["transnet_locnet"][1], [sid])
    assert last == f"sigma_eff_m={st['sigma_eff_m']:.2f}" and st["sessions"] == [sid]
    assert st["sigma_eff_m"] >= st["sigma_m"] > 0 and st["rmse_m"] == pytest.approx(np.sqrt(2) * st["sigma_m"])
    assert sorted(p.name for p in (Path(dataset) / "sessions" / sid).iterdir()) == before  # nothing written


@pytest.mark.parametrize("where", ["ckpt", "dataset", "root"])
def test_export_refuses_an_out_that_replaces_its_checkpoint_or_lands_in_a_dataset(tmp_path, where):
    """Red-team (issue 28 sec. 3): export.py ckpt=RUN/last.ckpt out=RUN/last.ckpt replaced the checkpoint with the
    ONNX graph, and out=DATA/sessions/S/rssi.csv a session's readings; refused before the checkpoint is read (the
    file here is no checkpoint at all, so nothing past the check could pass)."""
    from types import SimpleNamespace

    ckpt = tmp_path / "run" / "last.ckpt"
    ckpt.parent.mkdir()
    ckpt.write_bytes(b"not read")
    data = tmp_path / "data"
    (data / "sessions" / "s0").mkdir(parents=True)
    (data / "dataset.yaml").write_text("format: 1\n")
    (data / "sessions" / "s0" / "rssi.csv").write_text("t,anchor_id,rssi\n")
    out = {"ckpt": ckpt, "dataset": data / "sessions" / "s0" / "rssi.csv", "root": Path("/")}[where]
    words = {"ckpt": "is the checkpoint itself", "dataset": "lies in the dataset", "root": "name a folder"}[where]
    with pytest.raises(ValueError, match=words):
        export(SimpleNamespace(ckpt=str(ckpt), out=str(out), opset=None))
    assert ckpt.read_bytes() == b"not read"
    assert (data / "sessions" / "s0" / "rssi.csv").read_text() == "t,anchor_id,rssi\n"


def test_the_run_folders_config_yaml_is_read_as_data(tmp_path):
    """A bundle export without data= finds the dataset in RUN/config.yaml beside the checkpoint, a file that may be a
    stranger's: read with the dataset YAML reader (alias bombs refused in one line naming the file; a 444-byte file of
    aliases of aliases kept OmegaConf.load busy for more than a minute), data.path as written."""
    from omegaconf import OmegaConf

    from blenav.learn.bundle import _data_path

    cfg = OmegaConf.create({"ckpt": str(tmp_path / "last.ckpt"), "data": {"path": None}})
    (tmp_path / "config.yaml").write_text("data:\n  path: /some/dataset\n  history: 5\nmodel: {name: locnet}\n")
    assert _data_path(cfg, {}) == "/some/dataset"
    assert _data_path(cfg, {"data_path": "/recorded"}) == "/recorded"
    lines = ["a0: &a0 [x, x, x, x, x, x, x, x, x]"]
    lines += [f"a{i}: &a{i} [" + ", ".join([f"*a{i - 1}"] * 9) + "]" for i in range(1, 8)]
    (tmp_path / "config.yaml").write_text("\n".join(lines) + "\ndata: {path: null, bomb: *a7}\n")
    with pytest.raises(ValueError, match=r"config.yaml: \[yaml-size\] the document expands to more than"):
        _data_path(cfg, {})


def test_a_std_head_trains_calibrates_and_exports_its_sigma(dataset, tmp_path):
    """train.py with LocNet's std head (issue 29): the checkpoint's training report holds the validation scale that
    the weights carry (std_scale), and the export adds output std_m, equal to PyTorch's on real windows."""
    from blenav.onnx_io import session

    run = tmp_path / "run"
    train(compose("train", "model=locnet", f"data.path={dataset}", f"out={run}", "data.batch_size=32",
                  "model.lr=3e-3", "trainer.enable_progress_bar=false", "trainer.max_epochs=1",
                  "model.locnet.hidden=16", "model.locnet.fc_hidden=8", "+model.locnet.std_head=true",
                  "data.val_fraction=0.5"))
    module, meta = load_module(run / "last.ckpt")
    info = torch.load(run / "last.ckpt", weights_only=False)["blenav_training"]
    assert isinstance(info["fix_std"], dict), info["fix_std"]
    assert info["fix_std"]["scale"] == pytest.approx(float(module.locnet.std_scale), rel=1e-6)
    path = Path(export(compose("export", f"ckpt={run / 'last.ckpt'}", f"out={tmp_path / 'm.onnx'}")))
    sess = session(path)
    assert [o.name for o in sess.get_outputs()] == ["xy", "h", "c", "std_m"]
    S = real_windows(dataset, meta)[:16].astype(np.float32)
    h0 = np.zeros((module.locnet.layers, len(S), module.locnet.hidden), np.float32)
    xy, std = sess.run(["xy", "std_m"], {"S": S, "h0": h0, "c0": h0})
    with torch.no_grad():
        ref_xy, ref_std = module.locnet.forward_std(torch.from_numpy(S) / meta["window"]["u_scale"])
    np.testing.assert_allclose(xy, ref_xy.numpy(), atol=TOL)
    np.testing.assert_allclose(std, ref_std.numpy(), rtol=1e-4)
    loader = OnnxLocalizer(path)  # reads xy (and steps its state) as before, the extra output left alone
    np.testing.assert_allclose(loader.predict_windows(S), xy, atol=TOL)
    np.testing.assert_allclose(loader.step(S[:1]), xy[:1], atol=TOL)
    assert "std_m" in loader.meta["output_frame"] and loader.has_std
    got_xy, got_std = loader.predict_std(S)
    np.testing.assert_allclose(got_std, std, rtol=1e-6)
    assert np.array_equal(np.isnan(got_xy[:, 0]), ~loader.heard(S)) and np.array_equal(np.isnan(got_std), ~loader.heard(S))
    # blenav-fixes writes each fix's own std (the std column) for such a model; a plain model leaves it empty
    import shutil

    from blenav.cli.fixes import main as fixes_main

    data = tmp_path / "d"
    shutil.copytree(dataset, data)
    sid = Dataset.open(data).session_ids[0]
    assert fixes_main([str(data), str(path), "--sessions", sid, "--source", "net"]) == 0
    fx = Dataset.open(data).session(sid).fixes
    fx = fx[fx["source"] == "net"]
    win = real_windows(dataset, meta)
    ref_xy, ref_std = loader.predict_std(win)
    ok = np.isfinite(ref_xy).all(axis=1)
    np.testing.assert_allclose(fx["std"].to_numpy(float), ref_std[ok], rtol=1e-6)
    assert len(fx) == ok.sum() and (fx["std"] > 0).all()
    assert not OnnxLocalizer(path).predict_std(win[:0])[0].size
    # --calibrate says how the stated std covers labelled walks' errors
    from blenav.runtime.fixes import calibrate_model_fixes

    st = calibrate_model_fixes(Dataset.open(dataset), path, [sid])["stated_std"]
    ok = np.isfinite(ref_xy).all(axis=1) & np.isfinite(win_xy := first_session_windows(dataset, meta).xy).all(axis=1)
    e = np.linalg.norm(ref_xy[ok] - win_xy[ok], axis=1)
    assert st["fixes"] == ok.sum() and st["coverage_1sigma"] == pytest.approx(np.mean(e <= ref_std[ok]))
    assert st["coverage_2sigma"] == pytest.approx(np.mean(e <= 2 * ref_std[ok]))
    assert st["ml_scale"] == pytest.approx(np.sqrt(np.mean((e / ref_std[ok]) ** 2) / 2), rel=1e-6)
