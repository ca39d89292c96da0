"""LocNet on fingerprint windows (blenav.learn.fingerprint.train): the run's config as conf/train.yaml gives it, built
from the training node conf/localizer/fingerprint.yaml composes,
the windows handed to the trainer through the data module's own code (tensors, validation cap), and the
checkpoint's data_path naming the walks' dataset. Synthetic ILC walks (the ``coded`` fixture of tests/conftest.py)."""

from __future__ import annotations

import numpy as np
import pytest

from helpers import training_node


def test_array_windows_use_the_data_module_and_its_validation_cap(coded, tmp_path):
    """ArrayWindows: the run config's data node (path = the walks' dataset), the data module's tensors
    (u / 100, float32) and its seeded validation cap data.val_max_windows (8 windows -> 3, the subset of
    default_rng([seed, 2]), in order)."""
    import torch

    from blenav.learn.fingerprint.train import ArrayWindows, dataset_root, run_config
    from blenav.learn.crossphone.train import data_config

    ss = [coded.session("mall_F1_walkA"), coded.session("mall_F1_walkB")]
    root = dataset_root(ss)
    assert root == coded.root.resolve()
    cfg = run_config(training_node(), "locnet", tmp_path / "run", root, 3, {"lr": 0.002}, {"budget": {"max_steps": 7}},
                     0.5, 4, 1, False, building="mall", sessions=[s.id for s in ss])
    assert cfg.model.lr == 0.002 and cfg.model.name == "locnet" and cfg.trainer.budget.max_steps == 7
    assert cfg.trainer.budget.patience == 15 and cfg.trainer.enable_progress_bar is False and cfg.task == "crossphone"
    assert cfg.data.val_max_windows == 2048  # conf/windows/default.yaml's cap, as every window training
    cfg.data.val_max_windows = 3
    dc = data_config(cfg)
    assert (dc.path, dc.seed, dc.batch_size, dc.val_fraction, dc.building, dc.sessions) == (
        str(root), 3, 4, 0.5, "mall", ["mall_F1_walkA", "mall_F1_walkB"])
    rng = np.random.default_rng(0)
    S = rng.uniform(0.0, 60.0, (12, 4, 5)).astype(np.float32)
    P, xy = S[::-1].copy(), rng.uniform(0.0, 30.0, (12, 2))
    dm = ArrayWindows(dc, {"train": (S[:4], P[:4], xy[:4]), "val": (S[4:], P[4:], xy[4:])}, list("abcd"),
                      ss[0].building, {"train": ss[:1], "val": ss[1:]}, window=None)
    keep = np.sort(np.random.default_rng([3, 2]).choice(8, 3, replace=False))
    va = dm.sets["val"].tensors
    assert len(dm.sets["val"]) == 3 and va[0].dtype == torch.float32 and va[2].dtype == torch.float32
    np.testing.assert_allclose(va[0].numpy(), S[4:][keep] / 100.0, rtol=1e-7)
    np.testing.assert_allclose(va[2].numpy(), xy[4:][keep], rtol=1e-6)
    np.testing.assert_allclose(dm.sets["train"].tensors[1].numpy(), P[:4] / 100.0, rtol=1e-7)
    assert dm.sets["known"] is dm.sets["train"] and len(dm.val_dataloader()) == 1
    with pytest.raises(ValueError, match="one dataset"):
        dataset_root([])
    with pytest.raises(ValueError, match="no training.models.nosuchnet"):
        run_config(training_node(), "nosuchnet", tmp_path / "run", root, 0, None, None, 0.5, 4, 1, False)


@pytest.mark.parametrize("model", ["locnet", "transnet_locnet"])
def test_run_config_is_what_conf_train_yaml_gives(model, tmp_path):
    """The localizer's training node gives the run the config conf/train.yaml composed with model=<model> gives
    (the same resolved YAML, key order included, as OUT/config.yaml holds it), with the same overrides applied."""
    from omegaconf import OmegaConf

    from blenav.configs import compose
    from blenav.learn.fingerprint.train import run_config

    net, trainer = {"lr": 0.002}, {"budget": {"max_steps": 7}}
    new = run_config(training_node(), model, tmp_path / "run", tmp_path, 3, net, trainer, 0.5, 4, 1, False,
                     building="mall", sessions=["a", "b"])
    old = compose("train", f"model={model}")  # what run_config composed before issue 27
    OmegaConf.set_struct(old, False)
    old.model = OmegaConf.merge(old.model, OmegaConf.create(net))
    old.trainer = OmegaConf.merge(old.trainer, OmegaConf.create(trainer), {"enable_progress_bar": False})
    old.seed, old.out, old.threads, old.plots = 3, str(tmp_path / "run"), 1, False
    old.data.path, old.data.batch_size, old.data.val_fraction = str(tmp_path), 4, 0.5
    old.data.building, old.data.sessions = "mall", ["a", "b"]
    assert OmegaConf.to_yaml(new, resolve=True) == OmegaConf.to_yaml(old, resolve=True)
    assert new.model.name == model and new.data.seed == 3


def test_locnet_checkpoint_records_the_walks_dataset(coded, tmp_path):
    """A short LocNet run on WiFi windows: data_path of the checkpoint is the dataset, config.yaml its data node."""
    import yaml

    from blenav.learn.common.checkpoint import read_meta
    from blenav.localizers import RunInputs
    from blenav.localizers.fingerprint import FingerprintLocalizer

    loc = FingerprintLocalizer("LocNet-WiFi", model="locnet", val_fraction=0.5, seed=3, training=training_node(),
                               trainer={"budget": {"max_steps": 4, "val_every_steps": 2, "warmup_steps": 1}})
    with pytest.raises(ValueError, match="needs the networks' training config"):
        FingerprintLocalizer("LocNet-WiFi", model="locnet")
    rep = loc.fit([coded.session("mall_F1_walkA"), coded.session("mall_F1_walkB")], RunInputs(out=tmp_path))
    tr = rep["floors"]["mall/F1"]["training"]
    assert tr["steps"] == 4 and tr["train_windows"] == 5 and tr["val_windows"] == 5
    run = tmp_path / "fingerprint" / "LocNet-WiFi" / "mall_F1"
    assert read_meta(run / "last.ckpt")["data_path"] == str(coded.root.resolve())  # not the run folder
    data = yaml.safe_load((run / "config.yaml").read_text())["data"]
    assert data["path"] == str(coded.root.resolve()) and data["val_max_windows"] == 2048 and data["seed"] == 3


def test_compose_inside_a_running_hydra_app():
    """compose() inside a running Hydra app (a test or tool composing while blenav-eval's app runs) sets the app's
    Hydra aside and gives it back (was: 'GlobalHydra is already initialized')."""
    from hydra import initialize_config_dir
    from hydra.core.global_hydra import GlobalHydra

    from blenav.configs import compose
    from blenav.paths import conf_dir

    with initialize_config_dir(config_dir=str(conf_dir()), version_base="1.3"):
        app = GlobalHydra.instance().hydra
        cfg = compose("train", "model=transnet_locnet", "seed=4")
        assert cfg.model.name == "transnet_locnet" and cfg.data.seed == 4
        assert GlobalHydra.instance().hydra is app
    assert not GlobalHydra.instance().is_initialized()


def test_placenet_refits_on_every_walk_with_the_validation_runs_calibration(coded, tmp_path):
    """``model: placenet, refit: true``: a run holding a walk out for validation, then one on both walks (none held
    out) for as many epochs as the first run's best check, stating the first run's std scale; the fixes' std model is
    fitted on the first run's validation errors."""
    import math

    import torch

    from blenav.learn.crossphone.checkpoint import load_module
    from blenav.localizers import RunInputs
    from blenav.localizers.fingerprint import FingerprintLocalizer

    walks = [coded.session("mall_F1_walkA"), coded.session("mall_F1_walkB")]
    budget = {"budget": {"max_steps": 6, "val_every_steps": 2, "warmup_steps": 1}}
    loc = FingerprintLocalizer("Place", model="placenet", val_fraction=0.5, seed=3, training=training_node(),
                               trainer=budget, refit=True, net_cov="calibrated", batch_size=4,
                               net={"locnet": {"places": 4}})
    info = loc.fit(walks, RunInputs(out=tmp_path))["floors"]["mall/F1"]
    tr, rf = info["training"], info["refit"]
    assert tr["train_windows"] == 5 and tr["val_windows"] == 5
    assert rf["windows"] == 10 and rf["steps"] == math.ceil(tr["best_step"] * 10 / 5)
    run = tmp_path / "fingerprint" / "Place" / "mall_F1"
    first, _ = load_module(run / "last.ckpt")
    final, meta = load_module(run / "refit" / "last.ckpt")
    assert meta["train_sessions"] == sorted(s.id for s in walks)
    assert float(final.locnet.std_scale) == pytest.approx(tr["fix_std"]["scale"])
    assert float(first.locnet.std_scale) == pytest.approx(tr["fix_std"]["scale"])
    assert not torch.equal(first.locnet.mlp[1].weight, final.locnet.mlp[1].weight)
    assert info["fix_std"]["windows"] == 5  # the validation walk's windows, predicted by the first run
    est = loc.run(coded.session("mall_F1_walkC"), 1, 0)
    assert len(est.t) and np.isfinite(est.position).all() and np.isfinite(est.cov).all()


@pytest.mark.onnx
def test_a_fingerprint_placenet_exports_with_its_scan_recipe_and_parity(coded, tmp_path):
    """``python export.py ckpt=RUN/last.ckpt`` of a fingerprint run (here its function): the graph reproduces PyTorch on
    the walk's own windows, states std_m, and its metadata give the WiFi scan recipe, not the BLE beacon one."""
    import json

    import onnx
    import torch

    from blenav.learn.crossphone.checkpoint import load_module
    from blenav.learn.crossphone.export import export_module
    from blenav.localizers import RunInputs
    from blenav.localizers.fingerprint import FingerprintLocalizer
    from blenav.onnx_io import session

    loc = FingerprintLocalizer("Place", model="placenet", val_fraction=0.5, seed=1, training=training_node(),
                               trainer={"budget": {"max_steps": 4, "val_every_steps": 2, "warmup_steps": 1}},
                               batch_size=4, net={"locnet": {"places": 4}}, wifi_age_ref="scan", wifi_time="heard")
    loc.fit([coded.session("mall_F1_walkA"), coded.session("mall_F1_walkB")], RunInputs(out=tmp_path))
    module, meta = load_module(tmp_path / "fingerprint" / "Place" / "mall_F1" / "last.ckpt")
    path = export_module(module, meta, tmp_path / "place.onnx")
    S, _ = loc.heard_windows(coded.session("mall_F1_walkC"), loc.floors["mall/F1"].columns)
    sess = session(path)
    props = {p.key: json.loads(p.value) for p in onnx.load(str(path)).metadata_props
             if p.key in ("window_recipe", "output_frame")}
    h0 = np.zeros((1, len(S), 1), np.float32)
    xy, std = sess.run(["xy", "std_m"], {"S": S.astype(np.float32), "h0": h0, "c0": h0})
    with torch.no_grad():
        ref_xy, ref_std = module.locnet.forward_std(torch.from_numpy(S.astype(np.float32)) / 100.0)
    assert len(S) > 0
    np.testing.assert_allclose(xy, ref_xy.numpy(), atol=1e-4)
    np.testing.assert_allclose(std, ref_std.numpy(), rtol=1e-4)
    assert "WiFi scan" in props["window_recipe"]["step_of_packet"] and "std_m" in props["output_frame"]
    assert props["window_recipe"]["features"] == "wifi"


def test_which_networks_state_a_std_is_read_from_their_nodes():
    """One rule for the export's std_m and the localizer's net_cov check (model_node.states_std): the composed
    PlaceNet node states one, LocNet only with its std head, whatever name the method gives the model."""
    from blenav.learn.crossphone.model_node import states_std
    from blenav.localizers.fingerprint import FingerprintLocalizer

    models = training_node()["models"]
    assert states_std(models["placenet"]) and not states_std(models["locnet"])
    assert states_std({"locnet": {**models["locnet"]["locnet"], "std_head": True}})
    training = {"models": {"locnet": {"locnet": models["placenet"]["locnet"]}}}  # a PlaceNet under another name
    assert FingerprintLocalizer("x", model="locnet", net_cov="calibrated", training=training).net_cov == "calibrated"
