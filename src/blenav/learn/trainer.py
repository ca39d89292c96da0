"""The Lightning run both training tasks share (:func:`blenav.learn.train.train` for the cross-phone localizer,
:func:`blenav.learn.mapprior_train.train_mapprior` for the map prior): seeding and the run folder, loggers,
``OUT/last.ckpt`` after every epoch, and resuming from it.

A run started again with the same ``out`` resumes from ``OUT/last.ckpt``: optimizer and scheduler states,
epoch and step counters (and whatever the module saves in ``on_save_checkpoint``).
"""

from __future__ import annotations

from importlib.util import find_spec
from pathlib import Path

import lightning as L
import torch

from .checkpoint import SAFE_GLOBALS, load_file

LAST = "last.ckpt"


def start_run(seed: int, out: str | Path) -> Path:
    """``lightning.seed_everything(seed)`` (workers too) and the run folder ``out`` (created); returns it."""
    L.seed_everything(int(seed), workers=True)
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    return out


def last_checkpoint(out: Path) -> L.Callback:
    """OUT/last.ckpt after *every* epoch, so an interrupted run resumes from its last finished epoch
    (Lightning 2.6 writes ``save_last`` only with a top-k checkpoint, i.e. with save_top_k=0 only when fit
    ends); no version counter: a resumed or copied-in run (scenario 3 from scenario 2) overwrites it."""
    return L.pytorch.callbacks.ModelCheckpoint(dirpath=out, filename="last", save_top_k=1, monitor=None,
                                               every_n_epochs=1, enable_version_counter=False)


def loggers(out: Path) -> list:
    """CSVLogger into OUT/logs, plus TensorBoard into OUT/tb when tensorboard is installed."""
    log = [L.pytorch.loggers.CSVLogger(out, name="logs")]
    if find_spec("tensorboard") is not None or find_spec("tensorboardX") is not None:
        log.append(L.pytorch.loggers.TensorBoardLogger(out, name="tb"))
    return log


def fit(module: L.LightningModule, datamodule: L.LightningDataModule, out: Path, trainer_kw: dict,
        callbacks: list | tuple = ()) -> L.Trainer:
    """A Trainer with ``trainer_kw``, :func:`last_checkpoint` first and then ``callbacks``, :func:`loggers`;
    fit, resuming from OUT/last.ckpt when it exists. Returns the trainer."""
    trainer = L.Trainer(**trainer_kw, default_root_dir=out, callbacks=[last_checkpoint(out), *callbacks],
                        logger=loggers(out), enable_model_summary=False)
    resume = out / LAST
    if resume.is_file():
        load_file(resume)  # a last.ckpt that would run code is refused here, before Lightning unpickles it
    with torch.serialization.safe_globals(list(SAFE_GLOBALS)):
        trainer.fit(module, datamodule=datamodule, ckpt_path=str(resume) if resume.is_file() else None,
                    weights_only=True)
    return trainer
