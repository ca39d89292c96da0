"""``train(cfg)``: build data, networks and the LightningModule from a Hydra config, fit, test.

Leaves ``OUT/last.ckpt`` (and per-epoch metrics in ``OUT/metrics.csv`` via Lightning's CSVLogger). A run
interrupted and started again with the same ``out`` resumes from ``OUT/last.ckpt``: optimizer state,
epoch and step counters included. Seeding: ``lightning.seed_everything(cfg.seed)`` once, plus the data
module's own generators.
"""

from __future__ import annotations

from functools import partial
from pathlib import Path

import lightning as L
import torch
from hydra.utils import instantiate
from omegaconf import DictConfig, OmegaConf

from .data import WindowDataConfig, WindowDataModule
from .losses import brand_statistics
from .module import CrossPhoneModule


def train(cfg: DictConfig) -> tuple[dict, dict]:
    """Returns (metrics, objects) like lightning-hydra-template's train()."""
    L.seed_everything(int(cfg.seed), workers=True)
    out = Path(cfg.out)
    out.mkdir(parents=True, exist_ok=True)
    data_node = OmegaConf.to_container(cfg.data, resolve=True)  # resolve ${seed} against the root first
    dcfg = OmegaConf.to_object(OmegaConf.merge(OmegaConf.structured(WindowDataConfig), data_node))
    dm = WindowDataModule(dcfg)
    dm.setup()
    B = len(dm.beacons)
    locnet = instantiate(cfg.model.locnet, n_beacons=B)
    locnet.set_normalisation(dm.train_labels())
    transnet = instantiate(cfg.model.transnet, n_beacons=B) if cfg.model.get("transnet") else None
    M = torch.tensor(brand_statistics(dm.sets["train"].tensors[0].numpy())) if transnet is not None else None
    module = CrossPhoneModule(locnet, transnet, optimizer=partial(torch.optim.Adam, lr=float(cfg.model.lr)),
                              weights=dict(cfg.model.get("weights") or {}), M=M)
    ckpt = L.pytorch.callbacks.ModelCheckpoint(dirpath=out, save_last=True, save_top_k=0)
    trainer = L.Trainer(**cfg.trainer, default_root_dir=out, callbacks=[ckpt],
                        logger=L.pytorch.loggers.CSVLogger(out, name="logs"), enable_model_summary=False)
    resume = out / "last.ckpt"
    trainer.fit(module, datamodule=dm, ckpt_path=str(resume) if resume.is_file() else None)
    metrics = {k: float(v) for k, v in trainer.callback_metrics.items()}
    if dm.sets.get("test") is not None:
        metrics.update({k: float(v) for k, v in trainer.test(module, datamodule=dm, verbose=False)[0].items()})
    (out / "beacons.txt").write_text("\n".join(dm.beacons) + "\n", encoding="utf-8")
    return metrics, {"module": module, "datamodule": dm, "trainer": trainer}
