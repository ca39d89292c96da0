"""train(cfg): fits from the real config shrunk to seconds, leaves last.ckpt, and resumes from it."""

from __future__ import annotations

import pytest
import torch
from blenav.configs import compose

from blenav.learn.train import train


def cfg(*overrides):
    return compose("train", *overrides)


def _finite_metrics(metrics):
    """Every logged metric is a finite number (NaN and +-inf fail; ``x == x`` would let inf through)."""
    assert metrics
    for k, v in metrics.items():
        v = torch.as_tensor(v)
        assert torch.isfinite(v).all(), (k, v)


def _finite_checkpoint(path):
    """The checkpoint's weights and buffers are all finite floats; returns the loaded state."""
    state = torch.load(path, map_location="cpu", weights_only=True)
    tensors = {k: v for k, v in state["state_dict"].items() if torch.is_tensor(v) and v.is_floating_point()}
    assert tensors
    for k, v in tensors.items():
        assert torch.isfinite(v).all(), k
    return state


@pytest.mark.parametrize("model", ["locnet", "transnet_locnet"])
def test_train_leaves_a_checkpoint_and_resumes(two_phones, tmp_path, model):
    common = [f"model={model}", f"data.path={two_phones}", f"out={tmp_path / 'run'}", "data.batch_size=32",
              "model.lr=3e-3", "trainer.enable_progress_bar=false", "data.test_devices=[galaxy-s10]",
              "model.locnet.hidden=16", "model.locnet.fc_hidden=8"]
    metrics, objs = train(cfg(*common, "trainer.max_epochs=2"))
    ck = tmp_path / "run" / "last.ckpt"
    assert ck.is_file() and objs["trainer"].current_epoch == 2
    assert "test/err_m" in metrics
    _finite_metrics(metrics)
    assert 0.0 < metrics["test/err_m"] < 25.0  # metres on the 20 m x 15 m 'small' floor (diagonal 25 m)
    _finite_checkpoint(ck)
    steps = objs["trainer"].global_step
    metrics2, objs2 = train(cfg(*common, "trainer.max_epochs=3"))  # same out: resumes, one more epoch
    assert objs2["trainer"].current_epoch == 3 and objs2["trainer"].global_step == steps * 3 // 2
    _finite_metrics(metrics2)
    state = _finite_checkpoint(ck)
    assert state["global_step"] == objs2["trainer"].global_step  # last.ckpt now holds the resumed run's end


class _Crash(Exception):
    pass


def test_a_run_interrupted_mid_way_resumes_from_its_last_epoch(two_phones, tmp_path):
    import lightning as L

    class CrashAtEpoch1(L.Callback):
        def on_train_epoch_start(self, trainer, module):
            if trainer.current_epoch == 1:
                raise _Crash()

    common = ["model=locnet", f"data.path={two_phones}", f"out={tmp_path / 'run'}", "data.batch_size=32",
              "trainer.enable_progress_bar=false", "model.locnet.hidden=16", "model.locnet.fc_hidden=8",
              "trainer.max_epochs=3", "trainer.budget.val_every_steps=1"]  # last.ckpt at the validation cadence
    with pytest.raises(_Crash):
        train(cfg(*common), callbacks=[CrashAtEpoch1()])
    state = _finite_checkpoint(tmp_path / "run" / "last.ckpt")
    assert state["epoch"] == 0 and state["global_step"] > 0  # epoch 0 finished and was saved
    metrics, objs = train(cfg(*common))
    _finite_metrics(metrics)
    assert objs["trainer"].current_epoch == 3 and objs["trainer"].global_step == 3 * state["global_step"]
