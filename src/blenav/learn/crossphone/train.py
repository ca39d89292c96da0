"""The cross-phone localizer's training (``task: crossphone``, the default of :func:`blenav.learn.train.train`):
build data, networks and the LightningModule from a Hydra config, fit, test, report (:func:`train_crossphone`).

Budget: the step budget of :mod:`blenav.learn.common.budget` (``trainer.budget``, conf/trainer/cpu.yaml), early
stopping on the validation loss (``val/loss``, the objective of eq. 3.6 on the validation windows). A finished run
keeps the weights of its best validation check (:class:`blenav.learn.common.trainer.TrainingMonitor`).

Normalisation (stored with the model, nothing to redo at inference): inputs are u / ``U_SCALE`` (u = rssi_dBm
+ 100, 0 = not heard; ``meta.window.u_scale`` in the checkpoint, applied inside the exported ONNX graph);
positions are learnt centred and scaled by the training labels' mean and standard deviation (the networks'
``xy_mean`` / ``xy_scale`` buffers, in the state dict and the ONNX weights), so outputs are metres.

Report (every run, ``train.py`` and ``blenav-eval`` alike): ``OUT/training.json`` and ``OUT/learning_curves.png``
(:mod:`blenav.learn.common.report`), the network's best validation error beside KNN's (k = 5, fingerprint means,
:func:`knn_val_error`) on the same validation windows. ``OUT/config.yaml`` is the resolved config of the run (a
hyper-parameter sweep's best trial is found beside its checkpoint).

Leaves ``OUT/last.ckpt``, written at the validation cadence (every ``check_val_every_n_epoch`` epochs) and at the
end (and metrics in ``OUT/logs/.../metrics.csv`` via Lightning's CSVLogger, plus
TensorBoard event files when tensorboard is installed). A run interrupted and started again with the same
``out`` resumes from ``OUT/last.ckpt``: optimizer and schedule state, step counters, early-stopping counter
and learning curve included (the run itself, shared with the map prior's training, is
:mod:`blenav.learn.common.trainer`); a run that already stopped early is not trained further.
Seeding: ``lightning.seed_everything(cfg.seed)`` once, plus the data module's own generators.

Scenario 3 of Roy (``cfg.semi`` set and unlabelled devices given): after the supervised stage (above),
``semi.steps`` more optimizer steps (``semi.epochs``, when set, epochs of labelled + unlabelled windows instead) at the
constant ``semi.lr`` on labelled + unlabelled windows (the semi-supervised objective of eq. 3.6: L_loc on
labelled windows, L_ps, L_ssl and L_ts on all), without early stopping, keeping the final weights. A run
interrupted in either stage resumes where it stopped.
"""

from __future__ import annotations

import dataclasses
from functools import partial
from pathlib import Path

import numpy as np
import torch
from omegaconf import DictConfig, OmegaConf

from blenav.features.scale import U_SCALE
from blenav.runtime.signature import building_signature

from ..common.budget import budget, budget_steps, steps_per_epoch, trainer_settings
from ..common.checkpoint import read_checkpoint
from ..common.report import training_report
from ..common.stage import end_stage, prior_training, supervised_stage, validate_last
from ..common.trainer import LAST, StepBudget, TrainingMonitor, fit, start_run
from .augment import ReceiverAugment
from .checkpoint import build_networks
from .data import WindowDataConfig, WindowDataModule
from .losses import brand_statistics
from .module import CrossPhoneModule


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
    wd = float(model.get("weight_decay") or 0.0)  # AdamW's decoupled weight decay when given (PlaceNet), else Adam
    opt = partial(torch.optim.AdamW, lr=float(model["lr"]), weight_decay=wd) if wd else \
        partial(torch.optim.Adam, lr=float(model["lr"]))
    module = CrossPhoneModule(locnet, transnet, optimizer=opt,
                              weights=dict(model.get("weights") or {}), M=M, meta=meta,
                              augment=ReceiverAugment(**(model.get("augment") or {})), seed=int(cfg.seed))
    return module


def run_budget_steps(b: dict, dm: WindowDataModule) -> int:
    """:func:`budget_steps` of a run on the data module's training windows at its batch (after ``dm.setup()``)."""
    return budget_steps(b, len(dm.sets["train"]), dm.step_scale)


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


def _window_counts(dm: WindowDataModule) -> dict:
    """How many labelled training, validation and unlabelled windows the run had (the survey's size)."""
    return {**{f"{k}_windows": len(dm.sets[k]) if dm.sets.get(k) is not None else 0
               for k in ("train", "val", "unlabelled")}, "batch_size": dm.batch_size}


def _semi_stage(module, dm, out: Path, trainer_kw: dict, semi, info: dict, knn_err, callbacks, title: str,
                plots: bool):
    """The semi-supervised stage (scenario 3) for ``semi.steps`` optimizer steps (or ``semi.epochs``) after the
    supervised ones; writes the checkpoint and the report. Returns (training info, trainer)."""
    start = int(info.get("semi_from_step") if info.get("stage") == "semi" else info["steps"])
    n_all = len(dm.sets["train"]) + len(dm.sets["unlabelled"])
    steps = int(semi.get("epochs") or 0) * steps_per_epoch(n_all, dm.batch_size) or int(semi.get("steps") or 0)
    if steps <= 0:
        raise ValueError("semi: give semi.steps (optimizer steps) or semi.epochs")
    module.stage, module.semi_lr = "semi", float(semi.lr)
    dm.semi_from_epoch = 0  # labelled + unlabelled windows in every epoch of this stage
    kw2 = {**trainer_kw, "max_epochs": -1}
    module.training_info = {**info, "stage": "semi", "semi_from_step": start, "stop_reason": None}
    monitor2 = TrainingMonitor()
    trainer = fit(module, dm, out, kw2, [monitor2, StepBudget(start + steps), *(callbacks or [])])
    validate_last(trainer, module, dm, monitor2)
    sup = {k: info.get(k) for k in ("steps", "budget_steps", "early_stopped", "stop_reason", "best_val_error_m")}
    info = {**training_report(monitor2, "semi_steps", trainer.global_step, knn_err, stage="semi"),
            **_window_counts(dm), "semi_from_step": start, "supervised": sup, "early_stopped": bool(sup["early_stopped"]),
            "budget_steps": sup["budget_steps"]}
    end_stage(module, trainer, out, info, monitor2, title, plots)
    return info, trainer


def train_crossphone(cfg: DictConfig, callbacks: list | None = None,
                     datamodule: WindowDataModule | None = None) -> tuple[dict, dict]:
    """``task: crossphone`` (through :func:`blenav.learn.train.train`): returns (metrics, objects) like
    lightning-hydra-template's train(); ``callbacks`` are added to the Trainer's (benchmarks time epochs this way).
    ``datamodule``: an already set-up :class:`WindowDataModule` built from the same ``cfg.data`` (blenav-eval trains
    several methods on one split without windowing the dataset again); another data config is an error."""
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
    max_steps = run_budget_steps(b, dm)
    trainer_kw, module.schedule = trainer_settings(cfg, b, max_steps, len(dm.sets["train"]), dm.batch_size)
    title = f"{(cfg.model or {}).get('name', 'model')} ({out})"
    plots = bool(cfg.get("plots", True))
    (out / "config.yaml").write_text(OmegaConf.to_yaml(cfg, resolve=True), encoding="utf-8")
    prior = prior_training(out)
    knn_err = knn_val_error(dm)
    monitor = TrainingMonitor()
    # -- supervised stage: skipped when the checkpoint's run stopped early or is in (or past) the semi stage
    trainer = None
    if prior.get("stage") == "semi" or prior.get("stop_reason") == "early_stopping":
        info = prior
    else:
        info, trainer = supervised_stage(module, dm, out, trainer_kw, b, max_steps, monitor, knn_err, callbacks,
                                         title, plots, extra_info=_window_counts(dm))
    # -- semi-supervised stage (scenario 3)
    if semi:
        info, trainer = _semi_stage(module, dm, out, trainer_kw, semi, info, knn_err, callbacks, title, plots)
    if trainer is None:  # finished before: the checkpoint's weights, a trainer only to test them
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
