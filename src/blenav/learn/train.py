"""``train(cfg)``: build data, networks and the LightningModule from a Hydra config, fit, test.

Leaves ``OUT/last.ckpt`` (and per-epoch metrics in ``OUT/logs/.../metrics.csv`` via Lightning's CSVLogger,
plus TensorBoard event files when tensorboard is installed). A run interrupted and started again with
the same ``out`` resumes from ``OUT/last.ckpt``: optimizer state, epoch and step counters included (the run
itself, shared with the map prior's training, is :mod:`blenav.learn.trainer`).
Seeding: ``lightning.seed_everything(cfg.seed)`` once, plus the data module's own generators.

Scenario 3 of Roy (``cfg.semi`` set and unlabelled devices given): after ``trainer.max_epochs`` supervised
epochs, ``semi.epochs`` more run at ``semi.lr`` on labelled + unlabelled windows (the semi-supervised
objective of eq. 3.6: L_loc on labelled windows, L_ps, L_ssl and L_ts on all). One Trainer runs both
stages, so a run interrupted in either stage resumes where it stopped.
"""

from __future__ import annotations

import dataclasses
from functools import partial

import torch
from omegaconf import DictConfig, OmegaConf

from blenav.features.scale import U_SCALE

from .augment import ReceiverAugment
from .checkpoint import build_networks
from .data import WindowDataConfig, WindowDataModule
from .losses import brand_statistics
from .module import CrossPhoneModule
from .trainer import fit, start_run


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
            "train_sessions": sorted({s.id for g in ("train", "val", "unlabelled") for s in dm.groups.get(g) or []})}
    semi = cfg.get("semi")
    module = CrossPhoneModule(locnet, transnet, optimizer=partial(torch.optim.Adam, lr=float(model["lr"])),
                              weights=dict(model.get("weights") or {}), M=M, meta=meta,
                              augment=ReceiverAugment(**(model.get("augment") or {})), seed=int(cfg.seed))
    if semi and dm.sets.get("unlabelled") is not None:
        module.semi_from_epoch, module.semi_lr = int(cfg.trainer.max_epochs), float(semi.lr)
        dm.semi_from_epoch = int(cfg.trainer.max_epochs)
    return module


TASKS = ("crossphone", "mapprior")


def train(cfg: DictConfig, callbacks: list | None = None,
          datamodule: WindowDataModule | None = None) -> tuple[dict, dict]:
    """Returns (metrics, objects) like lightning-hydra-template's train(); ``callbacks`` are added to the
    Trainer's (benchmarks time epochs this way; both tasks). ``datamodule``: an already set-up
    :class:`WindowDataModule` built from the same ``cfg.data`` (crossphone task; blenav-eval trains several
    methods on one split without windowing the dataset again); another data config is an error.

    ``cfg.task`` picks what is fitted: ``crossphone`` (default, this module) or ``mapprior`` (the map prior
    network of Roy section 3.2.2, :func:`blenav.learn.mapprior_train.train_mapprior`; ``experiment=mapprior``)."""
    task = str(cfg.get("task") or "crossphone")
    if task not in TASKS:
        raise ValueError(f"task={task!r} is not one of {TASKS}")
    if cfg.get("threads"):  # e.g. threads=1 on a shared machine: oversubscribed cores slow torch down a lot
        torch.set_num_threads(int(cfg.threads))
    if task == "mapprior":
        from .mapprior_train import train_mapprior  # only this task needs the map prior's data stack

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
    dm.semi_from_epoch = None  # set again by build_module for a semi-supervised run
    module = build_module(cfg, dm)
    trainer_kw = OmegaConf.to_container(cfg.trainer, resolve=True)
    semi = cfg.get("semi")
    if semi and dm.sets.get("unlabelled") is None:
        here = sorted({s.device_model for group in dm.groups.values() for s in group})
        raise ValueError("semi-supervised stage requested but no unlabelled windows: set "
                         f"data.unlabelled_devices=[...] to device models of this dataset (here: {here})")
    if semi:
        trainer_kw["max_epochs"] = int(cfg.trainer.max_epochs) + int(semi.epochs)
        trainer_kw["reload_dataloaders_every_n_epochs"] = 1
    trainer = fit(module, dm, out, trainer_kw, callbacks or [])
    metrics = {k: float(v) for k, v in trainer.callback_metrics.items()}
    if dm.sets.get("test") is not None:  # every rank: under DDP the test loop is collective too
        metrics.update({k: float(v) for k, v in trainer.test(module, datamodule=dm, verbose=False)[0].items()})
    if trainer.is_global_zero:
        (out / "beacons.txt").write_text("\n".join(dm.beacons) + "\n", encoding="utf-8")
    return metrics, {"module": module, "datamodule": dm, "trainer": trainer}
