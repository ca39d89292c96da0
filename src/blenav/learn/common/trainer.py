"""The Lightning run both training tasks share (:func:`blenav.learn.crossphone.train.train_crossphone` for the
cross-phone localizer, :func:`blenav.learn.mapprior.train.train_mapprior` for the map prior): seeding and the run
folder, loggers, ``OUT/last.ckpt`` after every epoch, and resuming from it.

A run started again with the same ``out`` resumes from ``OUT/last.ckpt``: optimizer and scheduler states,
epoch and step counters (and whatever the module saves in ``on_save_checkpoint``).

The cross-phone task also uses the pieces of a step budget defined here: :class:`TrainingMonitor` (learning
curves, the best validation check and its weights, all resumable with the checkpoint), :class:`StepBudget` and
:func:`stop_reason` (why a fit ended); the budget itself is :mod:`blenav.learn.common.budget`, the learning-rate
schedule :func:`blenav.learn.common.schedule.lr_factor`.
"""

from __future__ import annotations

import copy
import math
from importlib.util import find_spec
from pathlib import Path

import lightning as L
import torch

from .checkpoint import SAFE_GLOBALS, load_file

LAST = "last.ckpt"
CKPT_EVERY = "ckpt_every_n_epochs"  # a key of fit()'s trainer_kw: OUT/last.ckpt every so many epochs


def start_run(seed: int, out: str | Path) -> Path:
    """``lightning.seed_everything(seed)`` (workers too) and the run folder ``out`` (created); returns it."""
    out = Path(out)
    check_run_folder(out)
    L.seed_everything(int(seed), workers=True)
    out.mkdir(parents=True, exist_ok=True)
    return out


def check_run_folder(out: Path, what: str = "a run") -> None:
    """Refuse (ValueError, one line) a run folder that is a file system root or lies in a dataset (a folder with
    dataset.yaml and sessions/, or below one): out=/ wrote last.ckpt, config.yaml, logs/ into /, and out=DATA mixed
    the run into the dataset it reads. A folder of an earlier run is fine: the run resumes from its last.ckpt."""
    resolved = out.resolve()
    if resolved == Path(resolved.anchor):
        raise ValueError(f"out={out}: name a folder of its own for {what}")
    for d in (resolved, *resolved.parents):
        if (d / "dataset.yaml").is_file() and (d / "sessions").is_dir():
            raise ValueError(f"out={out} lies in the dataset {d}: {what} would mix its files into it; choose "
                             "another out=")


def last_checkpoint(out: Path, every_n_epochs: int = 1) -> L.Callback:
    """OUT/last.ckpt after every ``every_n_epochs``-th epoch (default every epoch), so an interrupted run resumes
    from its last saved epoch (Lightning 2.6 writes ``save_last`` only with a top-k checkpoint, i.e. with
    save_top_k=0 only when fit ends); no version counter: a resumed or copied-in run (scenario 3 from scenario 2)
    overwrites it. The cross-phone task saves with its validation cadence: on a small survey an epoch is a few
    steps, and a checkpoint per epoch cost about a fifth of the run (issue 16)."""
    return L.pytorch.callbacks.ModelCheckpoint(dirpath=out, filename="last", save_top_k=1, monitor=None,
                                               every_n_epochs=max(1, int(every_n_epochs)),
                                               enable_version_counter=False,
                                               save_on_train_epoch_end=True)  # whatever the validation cadence


def loggers(out: Path) -> list:
    """CSVLogger into OUT/logs, plus TensorBoard into OUT/tb when tensorboard is installed."""
    log = [L.pytorch.loggers.CSVLogger(out, name="logs")]
    if find_spec("tensorboard") is not None or find_spec("tensorboardX") is not None:
        log.append(L.pytorch.loggers.TensorBoardLogger(out, name="tb"))
    return log


def fit(module: L.LightningModule, datamodule: L.LightningDataModule, out: Path, trainer_kw: dict,
        callbacks: list | tuple = (), run: bool = True) -> L.Trainer:
    """A Trainer with ``trainer_kw``, :func:`last_checkpoint` first and then ``callbacks``, :func:`loggers`;
    fit, resuming from OUT/last.ckpt when it exists (``run`` False: the trainer only, nothing fitted, e.g. to
    test a finished run). ``trainer_kw["ckpt_every_n_epochs"]`` (blenav's, not Lightning's): the checkpoint's
    cadence in epochs (default 1). Returns the trainer."""
    every = int(trainer_kw.get(CKPT_EVERY) or 1)
    trainer_kw = {k: v for k, v in trainer_kw.items() if k not in ("budget", CKPT_EVERY)}  # blenav's, not Lightning's
    trainer = L.Trainer(**trainer_kw, default_root_dir=out, callbacks=[last_checkpoint(out, every), *callbacks],
                        logger=loggers(out), enable_model_summary=False)
    if not run:
        return trainer
    resume = out / LAST
    if resume.is_file():
        load_file(resume)  # a last.ckpt that would run code is refused here, before Lightning unpickles it
    with torch.serialization.safe_globals(list(SAFE_GLOBALS)):
        trainer.fit(module, datamodule=datamodule, ckpt_path=str(resume) if resume.is_file() else None,
                    weights_only=True)
    return trainer


class TrainingMonitor(L.Callback):
    """Learning curves and the best validation check of a run, kept in the checkpoint (a resumed run continues
    its curve and still knows its best weights).

    ``history``: one row per validation check, ``{"step", "epoch", "train_loss"`` (mean training loss since the
    previous check), ``"val_loss", "val_err_m", "lr"}``. ``best``: the row with the lowest ``monitor`` value;
    ``best_state``: a CPU copy of the module's state dict at that check (restored by the caller when the fit
    ends, so a finished run keeps the weights of its best validation check, not of its last step)."""

    def __init__(self, monitor: str = "val/loss", err_key: str = "val/err_m"):
        self.monitor, self.err_key = monitor, err_key
        self.history: list[dict] = []
        self.best: dict | None = None
        self.best_state: dict | None = None
        self._sum, self._n = 0.0, 0

    @property
    def state_key(self) -> str:
        return f"TrainingMonitor{{monitor={self.monitor}}}"

    def on_train_batch_end(self, trainer, module, outputs, batch, batch_idx):
        # a step may return {"loss": what the optimizer steps on, "monitored": the loss its validation counterpart
        # measures} (LocNet's std head trains on loss + NLL; the curve shows the positions' loss)
        loss = outputs.get("monitored", outputs["loss"]) if isinstance(outputs, dict) else outputs
        if loss is not None:
            self._sum += float(loss.detach())
            self._n += 1

    def on_validation_end(self, trainer, module):
        if trainer.sanity_checking:
            return
        m = trainer.callback_metrics
        if self.monitor not in m:
            return
        step = int(trainer.global_step)
        if self.history and self.history[-1]["step"] == step:  # a second validation of the same weights
            return
        opt = trainer.optimizers[0] if trainer.optimizers else None
        row = {"step": step, "epoch": int(trainer.current_epoch),
               "train_loss": self._sum / self._n if self._n else None,
               "val_loss": float(m[self.monitor]),
               "val_err_m": float(m[self.err_key]) if self.err_key in m else None,
               "lr": float(opt.param_groups[0]["lr"]) if opt is not None else None}
        self._sum, self._n = 0.0, 0
        self.history.append(row)
        if math.isfinite(row["val_loss"]) and (self.best is None or row["val_loss"] < self.best["val_loss"]):
            self.best = dict(row)
            self.best_state = {k: v.detach().cpu().clone() for k, v in module.state_dict().items()}

    def state_dict(self) -> dict:
        return {"history": copy.deepcopy(self.history), "best": dict(self.best) if self.best else None,
                "best_state": self.best_state}

    def load_state_dict(self, state: dict) -> None:
        self.history = list(state.get("history") or [])
        self.best = state.get("best")
        self.best_state = state.get("best_state")


class StepBudget(L.Callback):
    """Stops the fit after ``max_steps`` optimizer steps (``trainer.should_stop``, as early stopping does).

    Lightning's own ``max_steps`` would do the same, but with it set, a run resumed from its end-of-epoch
    checkpoint (Lightning 2.6) runs one batch of the resumed epoch and counts the epoch finished; with the
    budget here, resuming behaves as with epochs alone."""

    def __init__(self, max_steps: int):
        self.max_steps = int(max_steps)
        self.reached = False

    def _check(self, trainer) -> None:
        if self.max_steps > 0 and trainer.global_step >= self.max_steps:
            self.reached = True
            trainer.should_stop = True

    def on_train_start(self, trainer, module):  # a resumed run that already used its budget
        self._check(trainer)

    def on_train_batch_end(self, trainer, module, outputs, batch, batch_idx):
        self._check(trainer)


def logs_this_step(trainer: L.Trainer | None) -> bool:
    """Whether a training step's ``self.log`` values (on_step, Lightning's default in ``training_step``) reach
    anything: the loggers get them every ``trainer.log_every_n_steps`` steps and when the fit stops (Lightning drops
    the others), the progress bar whenever it is shown. A module skips its ``self.log`` calls on the other steps:
    each costs Lightning about 0.6 ms on this CPU, where a tiny model's whole step is 2 ms
    (``benchmarks/lightning_log.py``), and the logs come out the same.
    True outside a fit (``trainer`` None). The last step of a :class:`StepBudget` logs; the step before an early
    stop at a validation check may not (``callback_metrics``' ``train/*`` are then the last logged step's)."""
    if trainer is None or trainer.progress_bar_callback is not None or trainer.fast_dev_run:
        return True
    every = int(trainer.log_every_n_steps)
    step = int(trainer.global_step) + 1  # this step's number once it is taken (Lightning's should_update_logs)
    if every <= 0:  # no step values are logged at all
        return False
    if step % every == 0 or trainer.should_stop:
        return True
    return any(isinstance(c, StepBudget) and 0 < c.max_steps <= step for c in trainer.callbacks)


def stop_reason(trainer: L.Trainer, early_stopping: L.Callback | None, budget: StepBudget | None = None) -> str:
    """Why a fit ended: ``early_stopping`` (validation loss did not improve for ``patience`` checks),
    ``max_steps``, ``max_epochs``, ``max_time`` or ``interrupted``."""
    if early_stopping is not None and (getattr(early_stopping, "stopped_epoch", 0) > 0
                                       or early_stopping.wait_count >= early_stopping.patience):
        return "early_stopping"
    if budget is not None and budget.max_steps > 0 and trainer.global_step >= budget.max_steps:
        return "max_steps"
    if trainer.max_steps is not None and trainer.max_steps > 0 and trainer.global_step >= trainer.max_steps:
        return "max_steps"
    if trainer.max_epochs is not None and trainer.max_epochs > 0 and trainer.current_epoch >= trainer.max_epochs:
        return "max_epochs"
    if getattr(trainer, "interrupted", False):
        return "interrupted"
    return "max_time" if trainer.should_stop else "interrupted"
