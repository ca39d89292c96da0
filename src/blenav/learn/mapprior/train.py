"""Training the Map Prior Network (Roy, section 3.2.2): ``train_mapprior(cfg)``.

``python train.py experiment=mapprior data=DIR out=RUN`` (``task: mapprior``, dispatched by
:func:`blenav.learn.train.train`) runs :func:`train_mapprior`: Adam (lr 0.01, batch 32 as Roy),
``trainer.max_epochs`` epochs of ``data.samples_per_epoch`` windows, optional early stopping
(``early_stopping`` node), ``RUN/last.ckpt`` written every epoch and resumed from when present (optimizer,
epoch and step counters, and the epoch-indexed data draw included; the run is :mod:`blenav.learn.common.trainer`,
shared with the cross-phone localizer).

Real walks with surveyed waypoints (issue 17, a prior trained on other floors of a mall)::

    python train.py experiment=mapprior_ilc data=data/ilc20/F2 'data.extra_paths=[data/ilc20/B1]' out=RUN \
        "data.sessions=[$(python -m blenav.cli.realwalks train-ids data/ilc20/F2),$(... B1)]"

trains on the train walks (the split of ``blenav-eval experiment=realwalks``) of the imported floors, their
positions between waypoints interpolated linearly at training time (:mod:`blenav.learn.mapprior.data`, "Sparse
ground truth"); the checkpoint meta records the datasets, floors, the sessions read and how many had waypoint
ground truth.

The pieces: data :mod:`blenav.learn.mapprior.data`, module and loss :mod:`blenav.learn.mapprior.module`,
checkpoint meta and loading :mod:`blenav.learn.mapprior.checkpoint` (:func:`build_meta` here writes it).
"""

from __future__ import annotations

import dataclasses

import lightning as L
import numpy as np
from omegaconf import DictConfig, OmegaConf

from blenav.models.mapprior import MapPriorNet

from ..common.checkpoint import data_hash
from ..common.trainer import fit, start_run
from .checkpoint import KIND, build_net
from .data import MapPriorDataModule
from .data_config import MapPriorDataConfig
from .module import MapPriorModule


def mapprior_data_config(cfg: DictConfig) -> MapPriorDataConfig:
    """The ``data`` node checked against :class:`MapPriorDataConfig` (a misspelt key fails here)."""
    node = OmegaConf.to_container(cfg.data, resolve=True)
    return OmegaConf.to_object(OmegaConf.merge(OmegaConf.structured(MapPriorDataConfig), node))


def build_meta(model: dict, dm: MapPriorDataModule, net: MapPriorNet) -> dict:
    """The checkpoint meta (see :mod:`blenav.learn.mapprior.checkpoint`) of a run on ``dm`` with ``net``."""
    c = dm.cfg
    tracks = dm.sets["train"].tracks
    return {"kind": KIND, "model": model, "resolution_m": float(model["resolution_m"]),
            "window": {"window_s": float(c.window_s), "step_hz": float(c.step_hz), "n_points": c.n_points},
            "channels": net.c, "size_multiple": net.map_encoder.size_multiple,
            "target": {"scale": c.target_scale, "gain": c.target_gain, "feasible_tbar": c.feasible_tbar},
            "augment": dataclasses.asdict(c.augment), "crop_px": c.crop_px,
            "buildings": dm.train_buildings, "val_buildings": dm.val_buildings, "floors": dm.train_floors,
            "datasets": c.paths,
            "sessions": sorted({s for g in dm.groups.values() for s in g}),
            "waypoint_sessions": {"sessions": dm.waypoint_sessions, "max_gap_s": c.waypoint_max_gap_s,
                                  "positions": "linear interpolation between consecutive waypoints"},
            "data_hash": data_hash(*[np.concatenate([tr.t[:, None], tr.xy], axis=1) for tr in tracks])}


def train_mapprior(cfg: DictConfig, callbacks: list | None = None) -> tuple[dict, dict]:
    """``task: mapprior``: fit the MPN from a composed ``train`` config; ``callbacks`` are added to the
    Trainer's (e.g. a timer). Returns (metrics, objects)."""
    out = start_run(cfg.seed, cfg.out)
    model = OmegaConf.to_container(cfg.model, resolve=True)
    if model.get("kind") != KIND:
        raise ValueError(f"task=mapprior needs a map prior model (model=mapprior), got model {model.get('name')!r}")
    dcfg = mapprior_data_config(cfg)
    dm = MapPriorDataModule(dcfg, float(model["resolution_m"]))
    dm.setup()
    net = build_net(model, dcfg.n_points, dcfg.step_hz)
    module = MapPriorModule(net, lr=float(model["lr"]), meta=build_meta(model, dm, net), val_names=dm.val_names,
                            lr_decay=model.get("lr_decay"))
    callbacks = list(callbacks or [])
    es = cfg.get("early_stopping")
    if es:
        es = OmegaConf.to_container(es, resolve=True)
        if not dm.val_names:
            es["monitor"] = "train/loss"
        callbacks.append(L.pytorch.callbacks.EarlyStopping(**es))
    trainer_kw = OmegaConf.to_container(cfg.trainer, resolve=True)
    if not dm.val_names:
        trainer_kw["limit_val_batches"] = 0
    trainer = fit(module, dm, out, trainer_kw, callbacks)
    metrics = {k: float(v) for k, v in trainer.callback_metrics.items()}
    return metrics, {"module": module, "datamodule": dm, "trainer": trainer}
