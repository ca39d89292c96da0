"""``train(cfg)``: the one training entry (``python train.py``, ``blenav-eval``, the fingerprint localizer), which
hands a composed ``train`` config to the task it names.

``cfg.task`` picks what is fitted: ``crossphone`` (default; Roy section 3.1,
:func:`blenav.learn.crossphone.train.train_crossphone`) or ``mapprior`` (the map prior network of Roy section
3.2.2, :func:`blenav.learn.mapprior.train.train_mapprior`; ``experiment=mapprior``). ``cfg.threads`` sets torch's
intra-op threads first (``threads: 1`` suits small networks on a shared CPU).
"""

from __future__ import annotations

import torch
from omegaconf import DictConfig

from .crossphone.data import WindowDataModule
from .crossphone.train import train_crossphone

TASKS = ("crossphone", "mapprior", "inertial")


def train(cfg: DictConfig, callbacks: list | None = None,
          datamodule: WindowDataModule | None = None) -> tuple[dict, dict]:
    """Returns (metrics, objects) like lightning-hydra-template's train(); ``callbacks`` are added to the
    Trainer's (benchmarks time epochs this way; both tasks). ``datamodule``: an already set-up
    :class:`WindowDataModule` built from the same ``cfg.data`` (crossphone task; blenav-eval trains several
    methods on one split without windowing the dataset again); another data config is an error."""
    task = str(cfg.get("task") or "crossphone")
    if task not in TASKS:
        raise ValueError(f"task={task!r} is not one of {TASKS}")
    if cfg.get("threads"):  # e.g. threads=1 on a shared machine: oversubscribed cores slow torch down a lot
        torch.set_num_threads(int(cfg.threads))
    try:
        if task == "mapprior":
            from .mapprior.train import train_mapprior  # only this task needs the map prior's data stack

            return train_mapprior(cfg, callbacks=callbacks)
        if task == "inertial":
            from .inertial.train import train_inertial  # the learned inertial odometry (issue 31)

            return train_inertial(cfg, callbacks=callbacks)
        return train_crossphone(cfg, callbacks=callbacks, datamodule=datamodule)
    finally:
        release_process_group()


def release_process_group() -> None:
    """A multi-process run's (``trainer.strategy=ddp``) process group destroyed when its training ends, in every
    rank: left to the interpreter's exit, gloo's threads could abort a finished run ("terminate called without an
    active exception", exit status -6, seen once in tests/learn/test_scaleout.py). Nothing for a single process."""
    if torch.distributed.is_available() and torch.distributed.is_initialized():
        torch.distributed.destroy_process_group()
