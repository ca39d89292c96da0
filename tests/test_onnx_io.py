"""What an exported model promises an app (issue 19, sections 3-4).

- Weights hash: every export records ``weights_sha256`` (and per-tensor hashes) in its metadata; the loaders
  (:class:`blenav.runtime.OnnxLocalizer`, :class:`blenav.runtime.map_prior.MapPrior`, ``blenav-fixes``) refuse
  a file whose weights were changed after export, naming the tensor; a map prior directory is also checked
  against the file hashes of its meta.json. A model exported before hashes were written only warns.
- Metadata contract: a window built from a session's rssi.csv with pandas and *only* the metadata (a small
  reimplementation here, no blenav windowing code) gives, through onnxruntime, the fixes ``blenav-fixes``
  writes; the metadata's statement that the graph scales its input itself is true of the graph.
"""

from __future__ import annotations

import json
import shutil
import warnings
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from blenav.configs import compose
from blenav.learn.export import export
from blenav.learn.train import train
from blenav.runtime import OnnxLocalizer
from blenav.runtime.map_prior import MapPrior

pytestmark = pytest.mark.onnx

TINY_MP = ["trainer.enable_progress_bar=false", "data.samples_per_epoch=64", "data.val_samples=32",
           "data.batch_size=16", "data.crop_px=32", "model.net.unet_channels=[4,8]", "model.net.channels=8",
           "trainer.max_epochs=1", "early_stopping=null"]


@pytest.fixture(scope="module")
def localizer(two_phones, tmp_path_factory) -> Path:
    """A one-epoch tiny TransNet+LocNet on two_phones, exported."""
    root = tmp_path_factory.mktemp("loc")
    train(compose("train", "model=transnet_locnet", f"data={two_phones}", f"out={root / 'run'}", "data.batch_size=32",
                  "model.lr=3e-3", "trainer.enable_progress_bar=false", "trainer.max_epochs=1",
                  "model.locnet.hidden=16", "model.locnet.fc_hidden=8"))
    return Path(export(compose("export", f"ckpt={root / 'run' / 'last.ckpt'}", f"out={root / 'model.onnx'}")))


@pytest.fixture(scope="module")
def mapprior_dir(three_walks, tmp_path_factory) -> Path:
    root = tmp_path_factory.mktemp("mpx")
    train(compose("train", "experiment=mapprior", f"data={three_walks}", f"out={root / 'run'}", *TINY_MP))
    return Path(export(compose("export", f"ckpt={root / 'run' / 'last.ckpt'}", f"out={root / 'export'}")))


def _edit(src: Path, dst: Path, change) -> Path:
    """Copy of the ONNX file ``src`` at ``dst`` after ``change(model)`` (the onnx package, as a user would)."""
    import onnx

    model = onnx.load(str(src))
    change(model)
    dst.parent.mkdir(parents=True, exist_ok=True)
    onnx.save(model, str(dst))
    return dst


def _bump(name: str, delta: float = 1e-3):
    """A change that adds ``delta`` to the first value of the initializer or Constant named ``name``."""
    from onnx import numpy_helper

    def change(model):
        tensors = {t.name: t for t in model.graph.initializer}
        tensors.update({n.output[0]: n.attribute[0].t for n in model.graph.node if n.op_type == "Constant"})
        t = tensors[name]
        a = numpy_helper.to_array(t).copy()
        a.flat[0] += delta
        t.CopyFrom(numpy_helper.from_array(a, t.name))
    return change


# --- weights hash -----------------------------------------------------------------------------------------

def test_an_intact_export_records_and_passes_its_weights_hash(localizer, mapprior_dir):
    import onnx

    from blenav.onnx_io import weights_digest

    model = onnx.load(str(localizer))
    props = {p.key: json.loads(p.value) for p in model.metadata_props}
    digest, per = weights_digest(model)
    assert props["weights_sha256"] == digest and props["weights_sha256_tensors"] == per
    assert "locnet.head.0.weight" in per and len(per) == len(model.graph.initializer) + sum(
        n.op_type == "Constant" for n in model.graph.node)
    assert OnnxLocalizer(localizer).weights_sha256 == digest
    meta = json.loads((mapprior_dir / "meta.json").read_text())
    for name in ("map_encoder.onnx", "trajectory_encoder.onnx"):
        assert meta["weights_sha256"][name] == weights_digest(onnx.load(str(mapprior_dir / name)))[0]
    MapPrior(mapprior_dir)


def test_a_changed_weight_is_refused_naming_the_tensor(localizer, tmp_path):
    bad = _edit(localizer, tmp_path / "bad.onnx", _bump("locnet.head.0.weight"))
    with pytest.raises(ValueError) as e:
        OnnxLocalizer(bad)
    msg = str(e.value)
    assert str(bad) in msg and "weights are not the ones it was exported with" in msg
    assert "1 of" in msg and "locnet.head.0.weight" in msg and "export it again" in msg
    # the input scale is a Constant node of the graph: covered too
    scale = _edit(localizer, tmp_path / "scale.onnx", _bump("/Constant_output_0", 10.0))
    with pytest.raises(ValueError, match=r"/Constant_output_0"):
        OnnxLocalizer(scale)


def test_blenav_fixes_refuses_a_tampered_model(localizer, two_phones, tmp_path, capsys):
    from blenav.cli.fixes import main as fixes_main

    data = Path(shutil.copytree(two_phones, tmp_path / "d"))
    bad = _edit(localizer, tmp_path / "bad.onnx", _bump("transnet.r.0.bias"))
    assert fixes_main([str(data), str(bad)]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("blenav-fixes: error:") and "transnet.r.0.bias" in err[0]
    assert not list(data.glob("sessions/*/fixes.csv"))  # nothing written


def test_an_export_without_a_hash_warns_and_loads(localizer, tmp_path):
    def strip(model):
        keep = [(p.key, p.value) for p in model.metadata_props if not p.key.startswith("weights_sha256")]
        del model.metadata_props[:]
        for k, v in keep:
            model.metadata_props.add(key=k, value=v)

    old = _edit(localizer, tmp_path / "old.onnx", strip)
    with pytest.warns(UserWarning, match="records no hash of its weights"):
        loc = OnnxLocalizer(old)
    assert loc.weights_sha256 is None


def test_a_changed_map_prior_export_is_refused(mapprior_dir, tmp_path):
    bad = Path(shutil.copytree(mapprior_dir, tmp_path / "bad"))
    _edit(mapprior_dir / "map_encoder.onnx", bad / "map_encoder.onnx", _bump("enc.head.bias"))
    with pytest.raises(ValueError, match=r"map_encoder.onnx: its weights are not the ones.*enc\.head\.bias"):
        MapPrior(bad)
    # weights intact, metadata edited: the file hash of meta.json catches it
    other = Path(shutil.copytree(mapprior_dir, tmp_path / "other"))
    _edit(mapprior_dir / "trajectory_encoder.onnx", other / "trajectory_encoder.onnx",
          lambda m: m.metadata_props.add(key="note", value='"edited"'))
    with pytest.raises(ValueError, match=r"trajectory_encoder.onnx is not the file exported with .*meta.json.*"
                                         r"graph or metadata was changed"):
        MapPrior(other)


# --- the metadata contract --------------------------------------------------------------------------------

def _metadata(path: Path) -> dict:
    import onnxruntime as ort

    sess = ort.InferenceSession(str(path), providers=["CPUExecutionProvider"])
    return {k: json.loads(v) for k, v in sess.get_modelmeta().custom_metadata_map.items()}


def _windows_from_metadata(rssi: pd.DataFrame, md: dict) -> tuple[np.ndarray, np.ndarray]:
    """(t (W,), S (W, B, H)) of one session's rssi.csv, following only the metadata's recipe."""
    beacons, recipe, w = md["beacons"], md["window_recipe"], md["window"]
    hz, H = float(recipe["step_hz"]), int(recipe["history_H"])
    empty = float(md["not_heard"]["value"])
    t0 = float(rssi["t"].iloc[0])  # "t0 = the time of the first packet (any beacon)"
    r = rssi[rssi["anchor_id"].astype(str).isin(beacons)].copy()  # "packets of beacons not in the list are ignored"
    r["k"] = np.floor((r["t"] - t0) * hz).astype(int)
    r["u"] = np.maximum(r["rssi"] + float(w["offset_db"]), float(w["floor_u"]))  # per_packet
    mean = r.groupby(["k", "anchor_id"])["u"].mean().unstack("anchor_id")  # "the mean of u ... in the step"
    K = int(r["k"].max()) + 1
    steps = mean.reindex(index=range(K), columns=beacons).fillna(empty).to_numpy(np.float32)  # (K, B)
    ends = np.arange(H - 1, K)
    S = np.stack([steps[k - H + 1:k + 1].T for k in ends])  # rows beacons, columns oldest..newest
    return t0 + (ends + 1) / hz, S  # "output_time: t0 + (k + 1) / step_hz"


def test_a_window_built_from_the_metadata_alone_gives_blenav_fixes_numbers(localizer, two_phones, tmp_path, capsys):
    import onnxruntime as ort

    from blenav.cli.fixes import main as fixes_main

    data = Path(shutil.copytree(two_phones, tmp_path / "d"))
    sessions = sorted(p for p in (data / "sessions").iterdir() if p.is_dir())
    # a silent stretch in the first session: windows with nothing heard must give no fix on both sides
    f = sessions[0] / "rssi.csv"
    rssi = pd.read_csv(f)
    rssi[(rssi["t"] < 20.0) | (rssi["t"] >= 28.0)].to_csv(f, index=False)
    assert fixes_main([str(data), str(localizer), "--source", "app"]) == 0
    capsys.readouterr()

    md = _metadata(localizer)
    assert md["lstm_state"]["carry"] is False and md["not_heard"]["value"] == 0.0
    sess = ort.InferenceSession(str(localizer), providers=["CPUExecutionProvider"])
    h_shape = sess.get_inputs()[1].shape  # (layers, batch, hidden)
    n_fixes = 0
    for sdir in sessions:
        t, S = _windows_from_metadata(pd.read_csv(sdir / "rssi.csv"), md)
        heard = (S != md["not_heard"]["value"]).any(axis=(1, 2))  # "empty_window: discard"
        z = np.zeros((h_shape[0], int(heard.sum()), h_shape[2]), np.float32)  # "h0_c0: zeros ... every window"
        xy = sess.run(["xy"], {"S": S[heard], "h0": z, "c0": z})[0]
        fixes = pd.read_csv(sdir / "fixes.csv")
        fixes = fixes[fixes["source"] == "app"]
        assert len(fixes) == heard.sum(), sdir.name
        np.testing.assert_allclose(fixes["t"].to_numpy(), t[heard], atol=1e-6)
        np.testing.assert_allclose(fixes[["x", "y"]].to_numpy(), xy, atol=1e-4)
        n_fixes += len(fixes)
        if sdir == sessions[0]:
            assert (~heard).sum() >= 3  # the silent stretch gave windows without a fix
    assert n_fixes > 100


def test_the_metadata_says_what_the_graph_does(localizer):
    """input_units.graph_divides_by is the divisor the graph applies to S; the window omits u_scale."""
    import onnx
    from onnx import numpy_helper

    md = _metadata(localizer)
    model = onnx.load(str(localizer))
    consts = {n.output[0]: numpy_helper.to_array(n.attribute[0].t) for n in model.graph.node if n.op_type == "Constant"}
    consts.update({t.name: numpy_helper.to_array(t) for t in model.graph.initializer})
    div = [n for n in model.graph.node if n.op_type == "Div" and n.input[0] == "S"]
    assert len(div) == 1 and float(consts[div[0].input[1]]) == md["input_units"]["graph_divides_by"] == 100.0
    assert "u_scale" not in md["window"]
    for key in ("input_units", "window_recipe", "not_heard", "lstm_state", "output_frame"):
        assert key in md, key
    r = md["window_recipe"]
    assert (r["history_H"], r["step_hz"], r["step_s"], r["window_s"]) == (5, 1.0, 1.0, 5.0)
    assert md["output_frame"]["building"] == md["building"] == "small"
    loc = OnnxLocalizer(localizer)
    assert (loc.history, loc.n_beacons) == (r["history_H"], len(md["beacons"]))
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # an intact current export loads without a warning
        OnnxLocalizer(localizer)
