"""``train(cfg)``: build data, networks and the LightningModule from a Hydra config, fit, test, report.

Budget (``trainer.budget``, conf/trainer/cpu.yaml; :func:`budget`). Training runs for a number of optimizer
*steps*, not epochs: ``max_steps``, by default ``auto``, which follows the survey's size (:func:`budget_steps`:
3,000 steps for 2,000 training windows or fewer, growing as the square root of the windows, at most 15,000 --
about 6,700 for 10k windows; with ``data.batch_size: auto`` a survey under 2,560 windows trains at batch 128 for
twice those steps, :func:`blenav.learn.data.auto_batch_size`; a batch given as a number keeps them), validated about every ``val_every_steps`` steps (:func:`_val_cadence`), stopped
early when the validation loss (``val/loss``, the objective of eq. 3.6 on the validation windows) has not
improved by ``min_delta`` for ``patience`` checks (Lightning's ``EarlyStopping``). The learning rate warms up
linearly over ``warmup_steps`` and then follows half a cosine to ``min_lr_ratio`` times ``model.lr`` at
``max_steps`` (``schedule: onecycle`` or ``constant`` instead; :func:`blenav.learn.schedule.lr_factor`).
A finished run keeps the weights of its best validation check (:class:`blenav.learn.trainer.TrainingMonitor`).
``trainer.max_epochs`` still caps the run when set (the thesis' 50 epochs: ``trainer.max_epochs=50
trainer.budget.max_steps=-1 trainer.budget.patience=null``).

Normalisation (stored with the model, nothing to redo at inference): inputs are u / ``U_SCALE`` (u = rssi_dBm
+ 100, 0 = not heard; ``meta.window.u_scale`` in the checkpoint, applied inside the exported ONNX graph);
positions are learnt centred and scaled by the training labels' mean and standard deviation (the networks'
``xy_mean`` / ``xy_scale`` buffers, in the state dict and the ONNX weights), so outputs are metres.

Report (every run, ``train.py`` and ``blenav-eval`` alike): ``OUT/training.json`` (:func:`training_report`:
steps, whether early stopping ended the run and why it stopped, the best validation error in metres beside
KNN's (k = 5, fingerprint means) on the same validation windows, warnings), ``OUT/learning_curves.png``
(``plots: false`` skips it), and a logged warning when the network is worse than KNN on the validation
windows or stopped before its validation loss levelled off. ``OUT/config.yaml`` is the resolved config of
the run (a hyper-parameter sweep's best trial is found beside its checkpoint).

Leaves ``OUT/last.ckpt``, written at the validation cadence (every ``check_val_every_n_epoch`` epochs) and at the
end (and metrics in ``OUT/logs/.../metrics.csv`` via Lightning's CSVLogger, plus
TensorBoard event files when tensorboard is installed). A run interrupted and started again with the same
``out`` resumes from ``OUT/last.ckpt``: optimizer and schedule state, step counters, early-stopping counter
and learning curve included (the run itself, shared with the map prior's training, is
:mod:`blenav.learn.trainer`); a run that already stopped early is not trained further.
Seeding: ``lightning.seed_everything(cfg.seed)`` once, plus the data module's own generators.

Scenario 3 of Roy (``cfg.semi`` set and unlabelled devices given): after the supervised stage (above),
``semi.steps`` more optimizer steps (``semi.epochs``, when set, epochs of labelled + unlabelled windows instead) at the
constant ``semi.lr`` on labelled + unlabelled windows (the semi-supervised objective of eq. 3.6: L_loc on
labelled windows, L_ps, L_ssl and L_ts on all), without early stopping, keeping the final weights. A run
interrupted in either stage resumes where it stopped.
"""

from __future__ import annotations

import dataclasses
import json
import logging
import math
from functools import partial
from pathlib import Path

import numpy as np
import lightning as L
import torch
from omegaconf import DictConfig, OmegaConf

from blenav.features.scale import U_SCALE
from blenav.runtime.signature import building_signature

from .augment import ReceiverAugment
from .checkpoint import build_networks
from .data import WindowDataConfig, WindowDataModule
from .losses import brand_statistics
from .module import CrossPhoneModule
from .trainer import CKPT_EVERY, LAST, StepBudget, TrainingMonitor, fit, start_run, stop_reason

log = logging.getLogger("blenav.train")

#: ``trainer.budget`` defaults (conf/trainer/cpu.yaml repeats them): chosen on validation windows of simulated
#: campus_floor surveys of several sizes (docs/results-003-crossphone.md), never on test walks.
BUDGET = {"max_steps": "auto", "auto_base_steps": 3000, "auto_ref_windows": 2000, "auto_max_steps": 15000,
          "val_every_steps": 50, "patience": 15, "min_delta": 0.0, "warmup_steps": 100,
          "schedule": "cosine", "min_lr_ratio": 0.02}


def budget_steps(b: dict, n_windows: int, scale: float = 1.0) -> int:
    """The run's optimizer-step budget: ``max_steps`` when it is a number (-1 or None: none), else (``auto``)
    ``scale`` * ``auto_base_steps`` * sqrt(n_windows / ``auto_ref_windows``), at least ``scale`` * the base and at
    most ``auto_max_steps``. ``scale`` is 256 / batch for ``data.batch_size: auto`` (2 on a survey under 2,560
    windows, whose batch is 128: :func:`blenav.learn.data.auto_batch_size`), else 1.

    Why it grows with the survey, and as the square root: on simulated campus_floor surveys (validation windows,
    docs/results-003-crossphone.md) 3,000 steps of batch 256 left a 2,340-window survey still improving (the last
    quarter of the checks 4.4 % better, 3,245 steps), where batch 128 for 6,490 steps stopped early at step 5,016;
    a 10k one was still improving at its last step; a step sees a batch, so a survey five times
    larger needs more steps, but not five times more (its windows repeat the same places and phones). A 50k-window
    survey gets 14,984 steps: early stopping ended it at 10,580 (best validation check at 9,605), where a cap of
    10,000 had stopped it still improving (docs/results-003-crossphone.md). The cap bounds larger surveys."""
    m = b["max_steps"]
    if m is None:
        return -1
    if m != "auto":
        return int(m)
    base, ref, cap = float(b["auto_base_steps"]) * float(scale), max(1, int(b["auto_ref_windows"])), int(b["auto_max_steps"])
    return int(min(cap, round(max(base, base * math.sqrt(max(int(n_windows), 1) / ref)))))


def run_budget_steps(b: dict, dm: WindowDataModule) -> int:
    """:func:`budget_steps` of a run on the data module's training windows at its batch (after ``dm.setup()``)."""
    return budget_steps(b, len(dm.sets["train"]), dm.step_scale)


def data_config(cfg: DictConfig) -> WindowDataConfig:
    """The ``data`` node checked against :class:`WindowDataConfig` (a misspelt key fails here)."""
    node = OmegaConf.to_container(cfg.data, resolve=True)  # resolve ${seed} against the root first
    return OmegaConf.to_object(OmegaConf.merge(OmegaConf.structured(WindowDataConfig), node))


def build_module(cfg: DictConfig, dm: WindowDataModule) -> CrossPhoneModule:
    """Networks sized for the data module's beacons, label normalisation, M of eq. 3.1, checkpoint meta."""
    model = OmegaConf.to_container(cfg.model, resolve=True)
    B = len(dm.beacons)
    locnet, transnet = build_networks(model, B)
    locnet.set_normalisation(dm.train_labels())
    M = torch.tensor(brand_statistics(dm.sets["known"].tensors[0].numpy())) if transnet is not None else None
    c = dm.cfg
    meta = {"model": model, "beacons": list(dm.beacons), "building": dm.building.id,
            "window": {**dataclasses.asdict(dm.window), "u_scale": U_SCALE},
            "data_hash": dm.train_hash(),
            "train_devices": sorted({s.device_model for s in dm.groups["train"]}),
            "known_devices": sorted(c.known_devices or {s.device_model for s in dm.groups["train"]}),
            "unlabelled_devices": list(c.unlabelled_devices or []),
            # every session whose windows the model saw (trained on, validated on, or unlabelled for the
            # semi-supervised stage): scoring on them overstates accuracy (blenav-fixes --calibrate warns)
            "train_sessions": sorted({s.id for g in ("train", "val", "unlabelled") for s in dm.groups.get(g) or []}),
            # beacon ids and positions, floor-plan hashes: what a runtime bundle checks a building against
            "building_signature": building_signature(dm.building), "data_path": str(Path(c.path).resolve())}
    module = CrossPhoneModule(locnet, transnet, optimizer=partial(torch.optim.Adam, lr=float(model["lr"])),
                              weights=dict(model.get("weights") or {}), M=M, meta=meta,
                              augment=ReceiverAugment(**(model.get("augment") or {})), seed=int(cfg.seed))
    return module


def budget(cfg: DictConfig) -> dict:
    """``trainer.budget`` over :data:`BUDGET` (unknown keys are an error)."""
    b = dict(BUDGET)
    given = OmegaConf.to_container(cfg.trainer, resolve=True).get("budget") or {}
    unknown = sorted(set(given) - set(BUDGET))
    if unknown:
        raise ValueError(f"trainer.budget: unknown keys {unknown}; known: {sorted(BUDGET)}")
    b.update(given)
    m = b["max_steps"]
    if m is not None and m != "auto" and (isinstance(m, bool) or not isinstance(m, int)):
        raise ValueError(f"trainer.budget.max_steps={m!r}: an integer (-1: none) or auto")
    return b


def _steps_per_epoch(n: int, batch: int) -> int:
    return max(1, math.ceil(n / max(int(batch), 1)))


def _val_cadence(every: int, steps_per_epoch: int) -> dict:
    """Lightning arguments for a validation check about every ``every`` optimizer steps: within an epoch every
    ``every`` batches when an epoch is longer, else at the end of every round(every / steps_per_epoch)-th epoch.
    (``check_val_every_n_epoch=None`` with a step interval would validate across epoch boundaries exactly, but
    a run resumed from its end-of-epoch checkpoint then miscounts the resumed epoch in Lightning 2.6.)"""
    if steps_per_epoch >= every:
        return {"check_val_every_n_epoch": 1, "val_check_interval": int(every)}
    return {"check_val_every_n_epoch": max(1, round(every / steps_per_epoch)), "val_check_interval": 1.0}


def knn_val_error(dm: WindowDataModule, k: int = 5) -> float | None:
    """Mean error (m) of KNN regression (k neighbours, fingerprint means, Roy Table 3.5) fitted on the training
    windows and scored on the validation windows the network is validated on; None without validation windows."""
    if dm.sets.get("val") is None or len(dm.sets["val"]) == 0:
        return None
    from .baselines import make_baseline

    tr, va = dm.sets["train"].tensors, dm.sets["val"].tensors
    knn = make_baseline("KNN", k=min(k, len(tr[0]))).fit(tr[0].numpy() * U_SCALE, tr[2].numpy())
    p = knn.predict(va[0].numpy() * U_SCALE)
    return float(np.linalg.norm(p - va[2].numpy(), axis=1).mean())


def _converged(history: list[dict]) -> bool:
    """The validation loss levelled off: the last quarter of the checks (at least 2) improved the best value of
    the checks before them by less than 1 %."""
    v = [h["val_loss"] for h in history if h.get("val_loss") is not None and math.isfinite(h["val_loss"])]
    if len(v) < 8:
        return False
    q = max(2, len(v) // 4)
    before, after = min(v[:-q]), min(v[-q:])
    return after >= before * (1.0 - 0.01)


def training_report(monitor: TrainingMonitor, reason: str, steps: int, knn_err: float | None,
                    stage: str = "supervised") -> dict:
    """The training dict of a run (results.json ``methods.NAME.training``, OUT/training.json)."""
    best = monitor.best or {}
    last = monitor.history[-1] if monitor.history else {}
    err = best.get("val_err_m") if stage == "supervised" else last.get("val_err_m")
    early = reason == "early_stopping"
    info = {"stage": stage, "steps": int(steps), "early_stopped": early, "stop_reason": reason,
            "best_step": best.get("step"), "best_val_loss": best.get("val_loss"),
            "best_val_error_m": err, "knn_val_error_m": knn_err,
            "converged": early or _converged(monitor.history), "val_checks": len(monitor.history), "warnings": []}
    if err is not None and knn_err is not None and err > knn_err:
        info["warnings"].append(f"worse than KNN on the validation windows: {err:.2f} m vs {knn_err:.2f} m")
    if not info["converged"] and stage == "supervised":
        info["warnings"].append(f"stopped ({reason}) after {steps} steps before the validation loss levelled off "
                                "(raise trainer.budget.max_steps or model.lr)")
    if err is None:
        info["warnings"].append("no validation windows: nothing to stop early on or to compare with KNN "
                                "(data.val_fraction > 0 and more than one labelled training session)")
    return info


def _window_counts(dm: WindowDataModule) -> dict:
    """How many labelled training, validation and unlabelled windows the run had (the survey's size)."""
    return {**{f"{k}_windows": len(dm.sets[k]) if dm.sets.get(k) is not None else 0
               for k in ("train", "val", "unlabelled")}, "batch_size": dm.batch_size}


def _write_report(out: Path, info: dict, monitor: TrainingMonitor, title: str, plots: bool) -> None:
    (out / "training.json").write_text(json.dumps({**info, "history": monitor.history}, indent=1) + "\n",
                                       encoding="utf-8")
    for w in info["warnings"]:
        log.warning("%s: %s", title, w)
    if plots and monitor.history:
        from blenav import plotting

        fig = plotting.figure_learning_curves(monitor.history, info.get("knn_val_error_m"), title)
        plotting.save_figure(fig, out / "learning_curves.png")


def _final_step_checkpoint(trainer, out: Path) -> None:
    """OUT/last.ckpt of the final step (its loop state resumes correctly when the budget is raised later), written
    on *every* rank: under DDP ``Trainer.save_checkpoint`` is a collective (rank 0 writes, all wait), so calling it
    on rank 0 alone hung the run. Unconditional: one write is cheaper than loading the last one to compare steps."""
    trainer.save_checkpoint(out / LAST)


def _finish_checkpoint(module, out: Path, info: dict, monitor: TrainingMonitor) -> None:
    """OUT/last.ckpt of a finished fit (the final step's, :func:`_final_step_checkpoint`) amended with the module's
    weights now (the best validation check's), the training report and the monitor's final curve."""
    from .checkpoint import read_checkpoint

    ck = read_checkpoint(out / LAST, require_meta=False)
    ck["state_dict"] = {k: v.detach().cpu().clone() for k, v in module.state_dict().items()}
    ck["blenav_training"] = info
    ck.setdefault("callbacks", {})[monitor.state_key] = monitor.state_dict()
    tmp = (out / LAST).with_suffix(".tmp")
    torch.save(ck, tmp)
    tmp.replace(out / LAST)


def _prior(out: Path) -> dict:
    """The ``blenav_training`` entry of OUT/last.ckpt ({} without one)."""
    from .checkpoint import read_checkpoint

    ck = out / LAST
    if not ck.is_file():
        return {}
    return dict(read_checkpoint(ck, require_meta=False).get("blenav_training") or {})


TASKS = ("crossphone", "mapprior")


def _trainer_settings(cfg: DictConfig, b: dict, dm: WindowDataModule, module) -> tuple[dict, int]:
    """Lightning Trainer keywords of ``cfg.trainer`` with the step budget ``b`` (max_steps -1: a callback enforces
    it; validation cadence in steps), and the module's LR schedule set; returns (keywords, max_steps or -1)."""
    trainer_kw = OmegaConf.to_container(cfg.trainer, resolve=True)
    trainer_kw.pop("budget", None)
    if trainer_kw.get("max_epochs") is None:
        trainer_kw["max_epochs"] = -1  # the step budget decides (Lightning's default would be 1000 epochs)
    max_steps = run_budget_steps(b, dm)
    trainer_kw["max_steps"] = -1  # the budget is a callback (blenav.learn.trainer.StepBudget)
    spe = _steps_per_epoch(len(dm.sets["train"]), dm.batch_size)
    trainer_kw.update(_val_cadence(int(b["val_every_steps"]), spe))
    # OUT/last.ckpt at the validation cadence too: every epoch on a 2k-window survey (9 steps) cost ~20 % of the run
    trainer_kw[CKPT_EVERY] = trainer_kw["check_val_every_n_epoch"]
    total = [t for t in (max_steps if max_steps > 0 else None,
                         spe * int(trainer_kw["max_epochs"]) if int(trainer_kw["max_epochs"]) > 0 else None) if t]
    if not total:
        raise ValueError("no training budget: set trainer.budget.max_steps or trainer.max_epochs")
    module.schedule = {"kind": b["schedule"], "warmup_steps": int(b["warmup_steps"]), "total_steps": min(total),
                       "min_lr_ratio": float(b["min_lr_ratio"])}
    return trainer_kw, max_steps


def _supervised_stage(module, dm, out: Path, trainer_kw: dict, b: dict, max_steps: int, monitor, knn_err,
                      callbacks, title: str, plots: bool):
    """Fit with the step budget and early stopping; keep the best validation check's weights; write the
    checkpoint and the training report. Returns (training info, trainer)."""
    es = None
    step_budget = StepBudget(max_steps)
    callbacks_1 = [monitor, step_budget, *(callbacks or [])]
    if b["patience"] is not None:
        es = L.pytorch.callbacks.EarlyStopping(monitor="val/loss", patience=int(b["patience"]),
                                               min_delta=float(b["min_delta"]), mode="min",
                                               check_on_train_epoch_end=False)
        callbacks_1.append(es)
    module.training_info = {"stage": "supervised"}
    trainer = fit(module, dm, out, trainer_kw, callbacks_1)
    if monitor.history and monitor.history[-1]["step"] != trainer.global_step or not monitor.history:
        if dm.sets.get("val") is not None:  # the last steps since the previous check are validated too
            trainer.validate(module, datamodule=dm, verbose=False)
    reason = stop_reason(trainer, es, step_budget)
    if monitor.best_state is not None:  # the weights of the best validation check
        module.load_state_dict(monitor.best_state)
    info = training_report(monitor, reason, trainer.global_step, knn_err)
    info.update(_window_counts(dm), budget_steps=int(max_steps))
    module.training_info = info
    _final_step_checkpoint(trainer, out)
    if trainer.is_global_zero:
        _finish_checkpoint(module, out, info, monitor)
    _write_report(out, info, monitor, title, plots)
    return info, trainer


def _semi_stage(module, dm, out: Path, trainer_kw: dict, semi, info: dict, knn_err, callbacks, title: str,
                plots: bool):
    """The semi-supervised stage (scenario 3) for ``semi.steps`` optimizer steps (or ``semi.epochs``) after the
    supervised ones; writes the checkpoint and the report. Returns (training info, trainer)."""
    start = int(info.get("semi_from_step") if info.get("stage") == "semi" else info["steps"])
    n_all = len(dm.sets["train"]) + len(dm.sets["unlabelled"])
    steps = int(semi.get("epochs") or 0) * _steps_per_epoch(n_all, dm.batch_size) or int(semi.get("steps") or 0)
    if steps <= 0:
        raise ValueError("semi: give semi.steps (optimizer steps) or semi.epochs")
    module.stage, module.semi_lr = "semi", float(semi.lr)
    dm.semi_from_epoch = 0  # labelled + unlabelled windows in every epoch of this stage
    kw2 = {**trainer_kw, "max_epochs": -1}
    module.training_info = {**info, "stage": "semi", "semi_from_step": start, "stop_reason": None}
    monitor2 = TrainingMonitor()
    trainer = fit(module, dm, out, kw2, [monitor2, StepBudget(start + steps), *(callbacks or [])])
    if dm.sets.get("val") is not None and (not monitor2.history or monitor2.history[-1]["step"] != trainer.global_step):
        trainer.validate(module, datamodule=dm, verbose=False)
    sup = {k: info.get(k) for k in ("steps", "budget_steps", "early_stopped", "stop_reason", "best_val_error_m")}
    info = {**training_report(monitor2, "semi_steps", trainer.global_step, knn_err, stage="semi"),
            **_window_counts(dm), "semi_from_step": start, "supervised": sup, "early_stopped": bool(sup["early_stopped"]),
            "budget_steps": sup["budget_steps"]}
    module.training_info = info
    _final_step_checkpoint(trainer, out)
    if trainer.is_global_zero:
        _finish_checkpoint(module, out, info, monitor2)
    _write_report(out, info, monitor2, title, plots)
    return info, trainer


def train(cfg: DictConfig, callbacks: list | None = None,
          datamodule: WindowDataModule | None = None) -> tuple[dict, dict]:
    """Returns (metrics, objects) like lightning-hydra-template's train(); ``callbacks`` are added to the
    Trainer's (benchmarks time epochs this way; both tasks). ``datamodule``: an already set-up
    :class:`WindowDataModule` built from the same ``cfg.data`` (crossphone task; blenav-eval trains several
    methods on one split without windowing the dataset again); another data config is an error.

    ``cfg.task`` picks what is fitted: ``crossphone`` (default, this module) or ``mapprior`` (the map prior
    network of Roy section 3.2.2, :func:`blenav.learn.mapprior.train.train_mapprior`; ``experiment=mapprior``)."""
    task = str(cfg.get("task") or "crossphone")
    if task not in TASKS:
        raise ValueError(f"task={task!r} is not one of {TASKS}")
    if cfg.get("threads"):  # e.g. threads=1 on a shared machine: oversubscribed cores slow torch down a lot
        torch.set_num_threads(int(cfg.threads))
    if task == "mapprior":
        from .mapprior.train import train_mapprior  # only this task needs the map prior's data stack

        return train_mapprior(cfg, callbacks=callbacks)
    if (cfg.get("model") or {}).get("kind") == "mapprior":
        raise ValueError("model=mapprior is trained with task=mapprior: use `python train.py experiment=mapprior "
                         "data=DIR out=RUN`")
    out = start_run(cfg.seed, cfg.out)
    dcfg = data_config(cfg)
    if datamodule is not None and datamodule.cfg != dcfg:
        raise ValueError("train(cfg, datamodule=...): the data module was built from another data config")
    dm = datamodule if datamodule is not None else WindowDataModule(dcfg)
    dm.setup()
    dm.semi_from_epoch = None  # set for the semi-supervised stage only
    semi = cfg.get("semi")
    if semi and dm.sets.get("unlabelled") is None:
        here = sorted({s.device_model for group in dm.groups.values() for s in group})
        raise ValueError("semi-supervised stage requested but no unlabelled windows: set "
                         f"data.unlabelled_devices=[...] to device models of this dataset (here: {here})")
    b = budget(cfg)
    module = build_module(cfg, dm)
    trainer_kw, max_steps = _trainer_settings(cfg, b, dm, module)
    title = f"{(cfg.model or {}).get('name', 'model')} ({out})"
    plots = bool(cfg.get("plots", True))
    (out / "config.yaml").write_text(OmegaConf.to_yaml(cfg, resolve=True), encoding="utf-8")
    prior = _prior(out)
    knn_err = knn_val_error(dm)
    monitor = TrainingMonitor()
    # -- supervised stage: skipped when the checkpoint's run stopped early or is in (or past) the semi stage
    trainer = None
    if prior.get("stage") == "semi" or prior.get("stop_reason") == "early_stopping":
        info = prior
    else:
        info, trainer = _supervised_stage(module, dm, out, trainer_kw, b, max_steps, monitor, knn_err, callbacks,
                                          title, plots)
    # -- semi-supervised stage (scenario 3)
    if semi:
        info, trainer = _semi_stage(module, dm, out, trainer_kw, semi, info, knn_err, callbacks, title, plots)
    if trainer is None:  # finished before: the checkpoint's weights, a trainer only to test them
        from .checkpoint import read_checkpoint

        module.load_state_dict(read_checkpoint(out / LAST, require_meta=False)["state_dict"])
        module.training_info = info
        trainer = fit(module, dm, out, trainer_kw, [], run=False)
    metrics = {k: float(v) for k, v in trainer.callback_metrics.items()}
    if info.get("best_val_error_m") is not None:
        metrics["best_val_err_m"] = float(info["best_val_error_m"])
    if dm.sets.get("test") is not None:  # every rank: under DDP the test loop is collective too
        metrics.update({k: float(v) for k, v in trainer.test(module, datamodule=dm, verbose=False)[0].items()})
    if trainer.is_global_zero:
        (out / "beacons.txt").write_text("\n".join(dm.beacons) + "\n", encoding="utf-8")
    return metrics, {"module": module, "datamodule": dm, "trainer": trainer, "training": info,
                     "global_step": int(info["steps"])}
