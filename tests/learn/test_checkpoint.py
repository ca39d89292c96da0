"""Files from strangers (issue 19, section 3): checkpoints are read with ``torch.load(weights_only=True)``.

- every kind of checkpoint train.py writes loads that way with the allow-list
  :data:`blenav.learn.common.checkpoint.SAFE_GLOBALS` (and names nothing outside torch's own allow-list, so the
  list can stay empty; a type added to a checkpoint later fails here first);
- a checkpoint whose pickle would run code (a callable that writes a marker file) is refused by every
  loader -- the cross-phone loader, the map prior loader, ``export.py`` and a resumed ``train.py`` run --
  with a message naming the file and the callable, and the marker is never written;
- a file that is not a checkpoint is one clear ValueError naming it.
"""

from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

import pytest
import torch

from blenav.configs import compose
from blenav.learn.common.checkpoint import SAFE_GLOBALS, UnsafeCheckpointError, load_file, read_checkpoint
from blenav.learn.crossphone.checkpoint import load_module
from blenav.learn.mapprior.checkpoint import load_map_prior, load_mapprior
from blenav.learn.train import train
from helpers import REPO

TINY_CP = ["data.batch_size=32", "trainer.enable_progress_bar=false", "trainer.max_epochs=1",
           "model.locnet.hidden=16", "model.locnet.fc_hidden=8"]
TINY_MP = ["trainer.enable_progress_bar=false", "data.samples_per_epoch=64", "data.val_samples=32",
           "data.batch_size=16", "data.crop_px=32", "model.net.unet_channels=[4,8]", "model.net.channels=8",
           "trainer.max_epochs=1", "model.lr_decay=cosine"]


def _write_marker(path: str) -> dict:
    """The 'code' a malicious checkpoint runs when unpickled: it leaves a file behind."""
    Path(path).write_text("this ran while a checkpoint was loaded\n")
    return {}


class _Payload:
    """Pickles as a call of :func:`_write_marker` (what ``__reduce__`` returns is called by the unpickler)."""

    def __init__(self, marker: Path):
        self.marker = str(marker)

    def __reduce__(self):
        return (_write_marker, (self.marker,))


@pytest.fixture(scope="module")
def checkpoints(two_phones, three_walks, tmp_path_factory):
    """kind -> last.ckpt of tiny real runs: scenario 3 (TransNet+LocNet, semi-supervised stage, augmentation
    generator state), DL-RNN, and the map prior with early stopping and the cosine schedule."""
    root = tmp_path_factory.mktemp("ckpts")
    train(compose("train", "experiment=crossphone_s3", f"data={two_phones}", f"out={root / 's3'}", *TINY_CP,
                  "data.train_devices=[iphone-8]", "data.unlabelled_devices=[galaxy-s10]", "semi.epochs=1"))
    train(compose("train", "model=dlrnn", f"data={two_phones}", f"out={root / 'dlrnn'}", "data.batch_size=32",
                  "trainer.enable_progress_bar=false", "trainer.max_epochs=1", "model.locnet.hidden=8"))
    train(compose("train", "experiment=mapprior", f"data={three_walks}", f"out={root / 'mp'}", *TINY_MP))
    return {k: root / k / "last.ckpt" for k in ("s3", "dlrnn", "mp")}


def _poisoned(src: Path, dst: Path, marker: Path) -> Path:
    """A copy of the real checkpoint ``src`` whose blenav meta carries the payload."""
    ck = torch.load(src, map_location="cpu", weights_only=True)
    ck["blenav"]["model"] = _Payload(marker)
    dst.parent.mkdir(parents=True, exist_ok=True)
    torch.save(ck, dst)
    return dst


def test_real_checkpoints_need_nothing_beyond_the_allow_list(checkpoints):
    assert SAFE_GLOBALS == ()
    for kind, path in checkpoints.items():
        assert torch.serialization.get_unsafe_globals_in_checkpoint(path) == [], kind
        ck = load_file(path)
        assert "blenav" in ck and ck["state_dict"], kind
        assert torch.equal(ck["state_dict"][next(iter(ck["state_dict"]))],
                           torch.load(path, map_location="cpu", weights_only=True)["state_dict"][
                               next(iter(ck["state_dict"]))])
    module, meta = load_module(checkpoints["s3"])
    assert module.transnet is not None and meta["unlabelled_devices"] == ["galaxy-s10"]
    assert "blenav_aug_rng" in load_file(checkpoints["s3"])
    net, meta = load_mapprior(checkpoints["mp"])
    assert meta["kind"] == "mapprior"
    assert any(k.startswith("EarlyStopping") for k in load_file(checkpoints["mp"])["callbacks"])


def test_the_payload_is_live(checkpoints, tmp_path):
    """Control: without weights_only the poisoned file does run its code (so the refusals below mean something)."""
    marker = tmp_path / "ran.txt"
    path = _poisoned(checkpoints["s3"], tmp_path / "evil.ckpt", marker)
    torch.load(path, map_location="cpu", weights_only=False)
    assert marker.is_file()


@pytest.mark.parametrize("kind", ["s3", "mp"])
def test_a_checkpoint_that_would_run_code_is_refused_by_every_loader(checkpoints, tmp_path, kind):
    marker = tmp_path / "ran.txt"
    path = _poisoned(checkpoints[kind], tmp_path / "evil" / "last.ckpt", marker)
    loaders = [read_checkpoint, load_file]
    loaders += [load_module] if kind == "s3" else [load_mapprior, load_map_prior]
    for load in loaders:
        with pytest.raises(UnsafeCheckpointError) as e:
            load(path)
        msg = str(e.value)
        assert str(path) in msg and "_write_marker" in msg and "refused" in msg and "train.py" in msg
        assert not marker.exists(), load.__name__
    # export.py: one line naming the file, exit 1, nothing written, no code run
    out = tmp_path / ("m.onnx" if kind == "s3" else "mp_export")
    r = subprocess.run([sys.executable, "export.py", f"ckpt={path}", f"out={out}"], cwd=REPO, capture_output=True,
                       text=True, timeout=300)
    assert r.returncode == 1, r.stderr[-2000:]
    line = r.stderr.strip().splitlines()[-1]
    assert line.startswith("export.py: error:") and str(path) in line and "Traceback" not in r.stderr
    assert not marker.exists() and not out.exists()


@pytest.mark.parametrize("fmt", ["legacy-torch", "bare-pickle"])
def test_older_formats_with_a_payload_are_refused_too(tmp_path, fmt):
    import pickle

    marker = tmp_path / "ran.txt"
    path = tmp_path / "evil.ckpt"
    obj = {"state_dict": {"w": torch.zeros(2)}, "blenav": {"model": _Payload(marker)}}
    if fmt == "legacy-torch":
        torch.save(obj, path, _use_new_zipfile_serialization=False)
    else:
        path.write_bytes(pickle.dumps(obj, protocol=4))
    with pytest.raises(UnsafeCheckpointError, match=r"_write_marker"):
        read_checkpoint(path)
    assert not marker.exists()


def test_resuming_from_a_poisoned_last_ckpt_is_refused(checkpoints, two_phones, tmp_path):
    marker = tmp_path / "ran.txt"
    run = tmp_path / "run"
    path = _poisoned(checkpoints["s3"], run / "last.ckpt", marker)
    with pytest.raises(UnsafeCheckpointError, match="_write_marker"):
        train(compose("train", "model=locnet", f"data={two_phones}", f"out={run}", *TINY_CP))
    assert not marker.exists()
    assert path.is_file()  # left as it was for the user to inspect


def test_a_file_that_is_no_checkpoint_is_one_clear_error(tmp_path):
    junk = tmp_path / "junk.ckpt"
    junk.write_bytes(b"not a checkpoint at all")
    with pytest.raises(ValueError, match="junk.ckpt is not a PyTorch checkpoint") as e:
        read_checkpoint(junk)
    assert not isinstance(e.value, UnsafeCheckpointError)
    with pytest.raises(FileNotFoundError):
        read_checkpoint(tmp_path / "missing.ckpt")
    plain = tmp_path / "list.ckpt"
    torch.save([1, 2, 3], plain)
    with pytest.raises(ValueError, match="not a blenav checkpoint"):
        read_checkpoint(plain)


def _refused_with_changed_meta(ckpt, tmp_path, change, words, load):
    """``ckpt`` with its blenav meta edited by ``change``: ``load`` refuses it in one line naming the checkpoint and
    the field (``words``)."""
    ck = torch.load(ckpt, map_location="cpu", weights_only=True)
    change(ck["blenav"])
    torch.save(ck, tmp_path / "big.ckpt")
    with pytest.raises(ValueError) as e:
        load(tmp_path / "big.ckpt")
    msg = str(e.value)
    assert "\n" not in msg and msg.startswith(f"checkpoint {tmp_path / 'big.ckpt'}: blenav.") and words in msg


@pytest.mark.parametrize("change, words", [
    (lambda m: m.__setitem__("beacons", [f"b{i}" for i in range(200_000)]), "locnet.lstm.weight_ih_l0 of shape"),
    (lambda m: m["model"]["locnet"].update(hidden=10**6), "the meta does not describe these weights"),
    (lambda m: m["model"]["locnet"].update(hidden=-1), "build no network: Error in call to target"),
    (lambda m: m["model"]["transnet"].update(channels=[10**6, 10**6]), "build no network"),
    (lambda m: m["window"].update(history=10**9), "window.history = 1000000000 is outside [1, 10,000]"),
    (lambda m: m["window"].update(step_hz=0.0), "window.step_hz = 0.0 is outside"),
])
def test_sizes_in_the_meta_are_checked_against_the_weights_before_building(checkpoints, tmp_path, change, words):
    """Red-team (issue 28 sec. 2): the meta's beacon list and model sizes are the sizes the networks are built with;
    200,000 beacons built 100,000 x 8 x ... weights before load_state_dict failed (2,000,000: 7.9 GB RSS, then a
    RuntimeError traceback), hidden=10**6 asked for terabytes, hidden=-1 was Hydra's InstantiationException. Now
    each is one ValueError naming the checkpoint, before memory is claimed (the shapes come from the meta device).
    window.history=10**9 made export.py allocate 64 GB for its sample inputs, step_hz=0 a ZeroDivisionError."""
    _refused_with_changed_meta(checkpoints["s3"], tmp_path, change, words, load_module)


def test_a_meta_that_is_not_a_table_is_one_clear_error(checkpoints, tmp_path):
    ck = torch.load(checkpoints["s3"], map_location="cpu", weights_only=True)
    ck["blenav"] = [1]
    torch.save(ck, tmp_path / "list.ckpt")
    with pytest.raises(ValueError, match="'blenav' is a list, not a table"):
        read_checkpoint(tmp_path / "list.ckpt")


@pytest.mark.parametrize("value, words", [
    ("${oc.create:{_target_: numpy.savetxt, fname: MARKER, X: [1, 2]}}", "blenav.model.locnet.hidden = '${oc.create"),
    ('${oc.decode:"{_target_: numpy.savetxt, fname: MARKER, X: [1]}"}', "is an interpolation"),
])
def test_an_interpolation_in_the_meta_builds_nothing(checkpoints, tmp_path, value, words):
    """Red-team (issue 28 sec. 1): check_targets walks the meta as written, but Hydra resolves the node before it
    builds it, so ``hidden: ${oc.create:{_target_: numpy.savetxt, ...}}`` built and called numpy.savetxt (the marker
    file was written; LocNet then failed on hidden=None). Refused when the file is read, nothing written."""
    marker = tmp_path / "marker.txt"
    ck = torch.load(checkpoints["s3"], map_location="cpu", weights_only=True)
    ck["blenav"]["model"]["locnet"]["hidden"] = value.replace("MARKER", str(marker))
    torch.save(ck, tmp_path / "interp.ckpt")
    with pytest.raises(ValueError, match=re.escape(words)):
        load_module(tmp_path / "interp.ckpt")
    assert not marker.exists()


def test_a_partial_network_in_the_meta_is_refused(checkpoints, tmp_path):
    ck = torch.load(checkpoints["s3"], map_location="cpu", weights_only=True)
    ck["blenav"]["model"]["locnet"]["_partial_"] = True  # was AttributeError: '_DeferredTarget' ... 'state_dict'
    torch.save(ck, tmp_path / "partial.ckpt")
    with pytest.raises(ValueError, match=r"blenav.model.locnet._partial_ is set"):
        load_module(tmp_path / "partial.ckpt")


@pytest.mark.parametrize("change, words", [
    (lambda m: m["model"]["net"].update(unet_channels=[4, 60_000]), "blenav.model ask for net.map_encoder"),
    (lambda m: m["model"]["net"].update(channels=3 * 10**7), "the meta does not describe these weights"),
    (lambda m: m["model"]["net"].update(channels=-1), "blenav.model build no network"),
    (lambda m: m["window"].update(n_points=10**9), "blenav.window.n_points = 1000000000 is outside [1, 10,000]"),
    (lambda m: m["window"].update(step_hz=0.0), "blenav.window.step_hz = 0.0 is outside"),
    (lambda m: m.__setitem__("resolution_m", 0.0), "blenav.resolution_m = 0.0 is outside"),
    (lambda m: m.pop("window"), "blenav.window.n_points = None is not a number"),
])
def test_map_prior_sizes_in_the_meta_are_bounded_before_building(checkpoints, tmp_path, change, words):
    """The map prior's meta as the cross-phone one's: unet_channels=[4, 60000] asked torch for 130 GB (Hydra's
    InstantiationException traceback), window.n_points=10**9 made export.py allocate 16 GB for its sample inputs, a
    missing window was a KeyError. Now one ValueError naming the checkpoint and the field, before memory is claimed."""
    _refused_with_changed_meta(checkpoints["mp"], tmp_path, change, words, load_mapprior)
