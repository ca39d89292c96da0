"""The step budget of the cross-phone training (issue 16): schedule, early stopping, the training report
(learning curves, best validation error beside KNN's, warnings), resume, and methods.NAME.training in
results.json. Tiny data (the 'small' simulated building), seconds each."""

from __future__ import annotations

import json
from pathlib import Path

import lightning as L
import numpy as np
import pytest
import torch

from blenav.configs import compose
from blenav.learn.common.budget import BUDGET, budget, budget_steps
from blenav.learn.common.report import training_report
from blenav.learn.common.schedule import lr_factor
from blenav.learn.common.trainer import TrainingMonitor
from blenav.learn.train import train

from helpers import REPO

TINY = ["model=locnet", "data.batch_size=32", "trainer.enable_progress_bar=false", "model.locnet.hidden=16",
        "model.locnet.fc_hidden=8", "data.holdout=0", "data.val_fraction=0.3", "plots=false"]


def cfg(data, out, *extra):
    return compose("train", f"data.path={data}", f"out={out}", *TINY, *extra)


def test_schedule_warms_up_then_decays_to_the_floor():
    f = [lr_factor(s, "cosine", warmup_steps=10, total_steps=100, min_lr_ratio=0.02) for s in range(120)]
    assert f[0] == pytest.approx(0.1) and f[9] == pytest.approx(1.0)
    assert np.all(np.diff(f[:10]) > 0)  # linear warm-up
    assert np.all(np.diff(f[10:100]) <= 1e-12) and f[55] == pytest.approx(0.02 + 0.98 * 0.5, abs=0.02)
    assert f[100] == pytest.approx(0.02) and f[119] == pytest.approx(0.02)  # held at the floor after the budget
    one = [lr_factor(s, "onecycle", 0, 100) for s in range(100)]
    assert int(np.argmax(one)) == 29  # one-cycle: 30 % warm-up
    assert lr_factor(50, "constant", 10, 100) == 1.0
    with pytest.raises(ValueError, match="schedule"):
        lr_factor(0, "step", 0, 10)


def test_the_auto_budget_grows_with_the_survey_as_a_square_root_between_base_and_cap():
    b = dict(BUDGET)  # auto: 3000 * sqrt(n / 2000), within [3000, 15000]
    assert [budget_steps(b, n) for n in (50, 2000, 8000, 10_000, 49_896, 50_000, 80_000)] == [3000, 3000, 6000, 6708,
                                                                                               14984, 15000, 15000]
    assert budget_steps({**b, "max_steps": 500}, 50_000) == 500 and budget_steps({**b, "max_steps": None}, 9) == -1
    assert budget_steps({**b, "auto_base_steps": 100, "auto_ref_windows": 100, "auto_max_steps": 250}, 400) == 200
    assert budget_steps(b, 2340, scale=2.0) == 6490 and budget_steps(b, 300, scale=2.0) == 6000  # auto batch 128
    assert budget_steps(b, 49_896, scale=2.0) == 15000  # the cap holds
    c = compose("train", "trainer.budget.max_steps=lots")
    with pytest.raises(ValueError, match="max_steps='lots'"):
        budget(c)
    with pytest.raises(ValueError, match="unknown keys"):
        budget(compose("train", "+trainer.budget.max_step=5"))


def test_the_auto_batch_halves_below_ten_batches_an_epoch_and_a_given_batch_stays():
    from blenav.learn.crossphone.data import WindowDataModule, auto_batch_size
    from blenav.learn.crossphone.data_config import WindowDataConfig

    assert [auto_batch_size(n) for n in (1, 2339, 2559, 2560, 50_000)] == [128, 128, 128, 256, 256]
    small = WindowDataModule(WindowDataConfig(path="x"))
    small.sets = {"train": list(range(2340))}
    assert small.batch_size == 128 and small.step_scale == 2.0
    given = WindowDataModule(WindowDataConfig(path="x", batch_size=32))
    given.sets = {"train": list(range(2340))}
    assert given.batch_size == 32 and given.step_scale == 1.0
    for bad in (0, "big", 2.5, True):
        with pytest.raises(ValueError, match="data.batch_size"):
            WindowDataConfig(path="x", batch_size=bad)
    from blenav.learn.crossphone.train import data_config

    assert data_config(compose("train", "data.path=x")).batch_size == "auto"
    with pytest.raises(ValueError, match="data.batch_size=-3"):
        data_config(compose("train", "data.path=x", "data.batch_size=-3"))


def test_the_learning_rate_follows_the_schedule_in_a_run(two_phones, tmp_path):
    _, objs = train(cfg(two_phones, tmp_path / "r", "model.lr=1e-2", "trainer.budget.max_steps=40",
                        "trainer.budget.warmup_steps=10", "trainer.budget.val_every_steps=2",
                        "trainer.budget.patience=null", "trainer.budget.min_lr_ratio=0.1"))
    hist = json.loads((tmp_path / "r" / "training.json").read_text())["history"]
    lr = {h["step"]: h["lr"] for h in hist}
    assert lr[2] == pytest.approx(1e-2 * 3 / 10)  # LambdaLR steps after each optimizer step: factor of step 2
    assert max(lr.values()) == pytest.approx(1e-2, rel=0.05)
    assert lr[40] == pytest.approx(1e-3, rel=0.05)  # decayed to min_lr_ratio * lr at the budget
    assert objs["training"]["steps"] == 40 and objs["training"]["stop_reason"] == "max_steps"
    assert objs["training"]["early_stopped"] is False


def test_early_stopping_stops_a_run_that_does_not_improve_and_the_report_flags_knn(two_phones, tmp_path):
    out = tmp_path / "r"
    _, objs = train(cfg(two_phones, out, "model.lr=1e-12", "trainer.budget.max_steps=400",
                        "trainer.budget.warmup_steps=0", "trainer.budget.val_every_steps=2",
                        "trainer.budget.patience=3", "plots=true"))
    info = objs["training"]
    assert info["early_stopped"] is True and info["stop_reason"] == "early_stopping"
    assert info["steps"] < 40  # 1 + 3 checks of 2 steps (plus the rest of an epoch), far from 400
    assert info["best_val_error_m"] > info["knn_val_error_m"] > 0  # an untrained net vs KNN, same windows
    assert any("worse than KNN" in w for w in info["warnings"])
    on_disk = json.loads((out / "training.json").read_text())
    assert on_disk["stop_reason"] == "early_stopping" and len(on_disk["history"]) >= 4
    assert (out / "learning_curves.png").stat().st_size > 1000 and (out / "config.yaml").is_file()
    state = torch.load(out / "last.ckpt", map_location="cpu", weights_only=True)
    assert state["blenav_training"]["stop_reason"] == "early_stopping"
    # started again: an early-stopped run is finished, nothing more is trained
    _, again = train(cfg(two_phones, out, "model.lr=1e-12", "trainer.budget.max_steps=400",
                         "trainer.budget.warmup_steps=0", "trainer.budget.val_every_steps=2",
                         "trainer.budget.patience=3"))
    assert again["global_step"] == info["steps"] and again["training"]["stop_reason"] == "early_stopping"


def test_report_warns_when_stopped_before_converging():
    m = TrainingMonitor()
    m.history = [{"step": 10 * i, "val_loss": 1.0 / (i + 1), "val_err_m": 5.0 / (i + 1)} for i in range(12)]
    m.best = dict(m.history[-1])
    info = training_report(m, "max_steps", 110, knn_err=1.0)
    assert not info["converged"] and any("before the validation loss levelled off" in w for w in info["warnings"])
    assert not any("worse than KNN" in w for w in info["warnings"])  # 0.42 m < 1.0 m
    m.history += [{"step": 120 + 10 * i, "val_loss": m.best["val_loss"], "val_err_m": 0.4} for i in range(12)]
    assert training_report(m, "max_steps", 230, knn_err=0.3)["converged"]  # flat for the last quarter
    assert any("worse than KNN" in w for w in training_report(m, "max_steps", 230, knn_err=0.3)["warnings"])
    none = training_report(TrainingMonitor(), "max_steps", 50, knn_err=None)["warnings"]  # a run without validation
    assert len(none) == 1 and "no validation windows" in none[0]  # says so once, not also "levelled off"


class _Crash(Exception):
    pass


def test_an_interrupted_run_resumes_with_its_curve_and_schedule(two_phones, tmp_path):
    class CrashAtEpoch3(L.Callback):
        def on_train_epoch_start(self, trainer, module):
            if trainer.current_epoch == 3:
                raise _Crash()

    over = ["model.lr=3e-3", "trainer.budget.max_steps=24", "trainer.budget.warmup_steps=4",
            "trainer.budget.val_every_steps=2", "trainer.budget.patience=null"]
    with pytest.raises(_Crash):
        train(cfg(two_phones, tmp_path / "r", *over), callbacks=[CrashAtEpoch3()])
    state = torch.load(tmp_path / "r" / "last.ckpt", map_location="cpu", weights_only=True)
    before = state["global_step"]
    assert before > 0 and state["lr_schedulers"]  # the schedule's state is in the checkpoint
    key = next(k for k in state["callbacks"] if k.startswith("TrainingMonitor"))
    n_before = len(state["callbacks"][key]["history"])
    _, objs = train(cfg(two_phones, tmp_path / "r", *over))
    assert objs["training"]["steps"] == 24 and objs["training"]["stop_reason"] == "max_steps"
    hist = json.loads((tmp_path / "r" / "training.json").read_text())["history"]
    steps = [h["step"] for h in hist]
    assert len(hist) > n_before and steps == sorted(steps) and steps[0] < before  # one curve across the restart
    # the resumed schedule continues: the lr at the end is the cosine floor, not a new warm-up
    assert hist[-1]["lr"] == pytest.approx(3e-3 * 0.02, rel=0.05)


def test_the_training_dict_lands_in_results_json(two_phones, tmp_path):
    from blenav.eval.harness import evaluate

    off = [f"experiment.learned.{k}=null" for k in ("locnet_aug", "transnet_locnet", "semi", "dlrnn")] + \
          [f"experiment.baselines.{k}=null" for k in ("bayesian", "krr_kf")]
    c = compose("eval", "experiment=crossphone_003", f"data={two_phones}", f"out={tmp_path / 'o'}", "progress=false",
                "data.train_devices=[iphone-8]", "data.test_devices=[galaxy-s10]", "data.val_fraction=0.5",
                "data.batch_size=32", "trainer.enable_progress_bar=false", "model_path=null", "plots=false",
                "experiment.learned.locnet.model.locnet.hidden=16", "trainer.budget.max_steps=30",
                "trainer.budget.val_every_steps=5", *off)
    evaluate(c)
    res = json.loads((tmp_path / "o" / "results.json").read_text())
    tr = res["methods"]["LocNet"]["training"]
    assert {"steps", "early_stopped", "stop_reason", "best_val_error_m", "knn_val_error_m"} <= set(tr)
    assert tr["steps"] == 30 and tr["stop_reason"] == "max_steps" and tr["early_stopped"] is False
    assert tr["budget_steps"] == 30
    assert tr["best_val_error_m"] > 0 and tr["knn_val_error_m"] > 0
    assert "training" not in res["methods"]["KNN"]
    assert (tmp_path / "o" / "runs" / "locnet" / "training.json").is_file()


@pytest.mark.slow  # scale-out end to end (17-28 s here): make test-slow
def test_optuna_sweep_command_finds_and_records_the_best_trial(two_phones, tmp_path):
    """The documented `-m` command, two tiny trials: each trial's config lies beside its checkpoint and
    best_trial.yaml names the best (lowest best_val_err_m) one."""
    pytest.importorskip("hydra_plugins.hydra_optuna_sweeper", reason="hydra-optuna-sweeper not installed "
                        "(pip install -e '.[sweep]')")
    import subprocess
    import sys
    from pathlib import Path

    import yaml

    repo = REPO
    sweep = tmp_path / "sweep"
    cmd = [sys.executable, str(repo / "train.py"), "-m", "hparams_search=crossphone_optuna", "experiment=crossphone_s2",
           f"data={two_phones}", "data.holdout=0", "data.val_fraction=0.3", "data.test_devices=null",
           "trainer.budget.max_steps=4", "trainer.budget.val_every_steps=2", "trainer.enable_progress_bar=false",
           "plots=false", "hydra.sweeper.n_trials=2", "hydra.sweeper.sampler.n_startup_trials=2",
           f"hydra.sweep.dir={sweep}", f"out={sweep}/" + "${hydra:job.num}"]
    r = subprocess.run(cmd, cwd=tmp_path, capture_output=True, text=True, timeout=600)
    assert r.returncode == 0, r.stdout[-2000:] + r.stderr[-3000:]
    best = yaml.safe_load((sweep / "best_trial.yaml").read_text())
    vals = {}
    for t in (0, 1):
        run = sweep / str(t)
        assert (run / "last.ckpt").is_file() and (run / "config.yaml").is_file()  # config beside checkpoint
        vals[t] = json.loads((run / "training.json").read_text())["best_val_error_m"]
    assert best["trial"] == min(vals, key=vals.get) and best["value"] == pytest.approx(min(vals.values()))
    assert Path(best["config"]).parent == Path(best["checkpoint"]).parent
    assert any(o.startswith("model.lr=") for o in best["overrides"])
    assert (sweep / "optimization_results.yaml").is_file()  # Optuna's own summary


@pytest.mark.parametrize("heard", [0.15, 0.85])
@pytest.mark.parametrize("chunk", [None, 3])
def test_ssl_loss_both_forms_match_the_equations_with_gradients(heard, chunk, monkeypatch):
    """ssl_loss (the compiled loop on CPU tensors, chunk None; the tensor form of other devices in chunks of 3
    windows) gives the value and the gradient of the direct form of eqs. 3.2-3.4."""
    from blenav.learn.crossphone import losses

    gen = torch.Generator().manual_seed(7)
    S = (torch.rand(10, 9, 4, generator=gen) * 0.6 * (torch.rand(10, 9, 4, generator=gen) < heard)).double()
    M = torch.rand(9, 9, generator=gen).double() * 0.5
    g0 = torch.rand(10, 9, 4, generator=gen).double() * 0.6
    apply = losses._SSLDense.apply
    monkeypatch.setattr(losses._SSLDense, "apply", lambda g, w, M_: apply(g, w, M_, chunk))
    out = []
    for f in (losses.ssl_loss, losses.ssl_loss_dense):
        g = g0.clone().requires_grad_()
        L_ = f(g, S, M)
        L_.backward()
        out.append((L_.item(), g.grad))
    assert out[0][0] == pytest.approx(out[1][0], rel=1e-10)
    torch.testing.assert_close(out[0][1], out[1][1], rtol=1e-9, atol=1e-12)
    with torch.no_grad():  # validation: no gradient computed, same value
        assert losses.ssl_loss(g0, S, M).item() == pytest.approx(out[1][0], rel=1e-10)
    g32 = g0.float().requires_grad_()  # float32, the training dtype
    L32 = losses.ssl_loss(g32, S.float(), M.float())
    L32.backward()
    assert L32.item() == pytest.approx(out[1][0], rel=1e-5)
    torch.testing.assert_close(g32.grad.double(), out[1][1], rtol=1e-4, atol=1e-6)


def test_last_checkpoint_follows_the_validation_cadence():
    """OUT/last.ckpt every check_val_every_n_epoch epochs (a checkpoint per 9-step epoch of a 2k survey was waste)."""
    from blenav.learn.common.budget import val_cadence
    from blenav.learn.common.trainer import last_checkpoint

    assert val_cadence(50, 10) == {"check_val_every_n_epoch": 5, "val_check_interval": 1.0}
    assert val_cadence(50, 200) == {"check_val_every_n_epoch": 1, "val_check_interval": 50}
    assert last_checkpoint(Path("x"), 5)._every_n_epochs == 5 and last_checkpoint(Path("x"))._every_n_epochs == 1


def test_validation_windows_are_capped_by_a_seeded_subset(two_phones, tmp_path):
    """data.val_max_windows keeps that many of the validation windows (the same ones for the same seed, labels
    with their windows); KNN's validation error is computed on the same subset."""
    from blenav.learn.crossphone.data import WindowDataModule
    from blenav.learn.crossphone.train import data_config, knn_val_error

    def dm(*extra):
        d = WindowDataModule(data_config(cfg(two_phones, tmp_path, *extra)))
        d.setup()
        return d

    full, a, b = dm("data.val_max_windows=null"), dm("data.val_max_windows=7"), dm("data.val_max_windows=7")
    assert len(full.sets["val"]) > 7 and len(a.sets["val"]) == 7
    S, xy = full.sets["val"].tensors[0], full.sets["val"].tensors[2]
    for s, x in zip(a.sets["val"].tensors[0], a.sets["val"].tensors[2]):  # rows of the full set, label kept
        i = int(torch.nonzero((S == s).all(dim=(1, 2)))[0])
        assert torch.equal(xy[i], x)
    torch.testing.assert_close(a.sets["val"].tensors[0], b.sets["val"].tensors[0])
    assert knn_val_error(a) != knn_val_error(full)


def test_a_finished_run_of_another_budget_is_not_silently_extended(tmp_path):
    """blenav-eval reuses a finished run only when its step budget is this run's: resuming a run that ended at
    3,000 steps to an auto budget of 6,708 would restart its cosine schedule midway."""
    from blenav.eval.crossphone import _check_reuse
    from blenav.errors import EvalError

    class DM:
        sets = {"train": range(10_000)}
        step_scale = 1.0  # batch 256

        @staticmethod
        def train_hash():
            return "h"

    ck = tmp_path / "last.ckpt"
    done = {"stage": "supervised", "stop_reason": "max_steps", "steps": 3000, "budget_steps": 3000}
    torch.save({"blenav": {"data_hash": "h"}, "global_step": 3000, "blenav_training": done}, ck)
    auto = compose("train")  # max_steps: auto -> 6,708 steps for 10,000 windows
    with pytest.raises(EvalError, match="finished a budget of 3000 steps, this run's is 6708"):
        _check_reuse(ck, DM(), None, auto)
    assert _check_reuse(ck, DM(), None, compose("train", "trainer.budget.max_steps=3000")) == 3000
    assert _check_reuse(ck, DM(), None, None) == 3000  # scenario 3 continuing scenario 2's run: no budget check


@pytest.mark.parametrize("where", ["root", "data", "inside"])
def test_a_run_folder_in_a_dataset_or_at_the_root_is_refused(tmp_path, monkeypatch, where):
    """Red-team (issue 28 sec. 3): train.py out=/ wrote last.ckpt, config.yaml, training.json and logs/ into /, and
    out=DATA the run's files into the dataset; start_run now refuses both before seeding or creating anything."""
    from blenav.learn.common.trainer import start_run

    data = tmp_path / "data"
    (data / "sessions").mkdir(parents=True)
    (data / "dataset.yaml").write_text("format: 1\n")
    out = {"root": Path("/"), "data": data, "inside": data / "sessions" / "run"}[where]
    monkeypatch.setattr(L, "seed_everything", lambda *a, **k: pytest.fail("seeded before the check"))
    with pytest.raises(ValueError, match="name a folder of its own" if where == "root" else "lies in the dataset"):
        start_run(0, out)
    assert not (data / "sessions" / "run").exists()
    monkeypatch.undo()
    assert start_run(0, tmp_path / "run") == tmp_path / "run" and (tmp_path / "run").is_dir()  # beside: fine
