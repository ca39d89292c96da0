"""The stages of a training run with a step budget, shared by the cross-phone localizer
(:mod:`blenav.learn.crossphone.train`) and the inertial odometry (:mod:`blenav.learn.inertial.train`): the supervised
stage (step budget, early stopping on ``val/loss``, the best validation check's weights kept), its end (OUT/last.ckpt of
the final step amended with those weights and the training report) and what a resumed run reads of a finished one.
A data module here has ``sets`` with an optional ``"val"``.
"""

from __future__ import annotations

import time
from pathlib import Path

import lightning as L
import torch

from .checkpoint import read_checkpoint
from .report import training_report, write_report
from .trainer import LAST, StepBudget, TrainingMonitor, fit, stop_reason


def final_step_checkpoint(trainer, out: Path) -> None:
    """OUT/last.ckpt of the final step (its loop state resumes correctly when the budget is raised later), written
    on *every* rank: under DDP ``Trainer.save_checkpoint`` is a collective (rank 0 writes, all wait), so calling it
    on rank 0 alone hung the run. Unconditional: one write is cheaper than loading the last one to compare steps."""
    trainer.save_checkpoint(out / LAST)


def finish_checkpoint(module, out: Path, info: dict, monitor: TrainingMonitor) -> None:
    """OUT/last.ckpt of a finished fit (the final step's, :func:`final_step_checkpoint`) amended with the module's
    weights now (the best validation check's), the training report and the monitor's final curve."""
    ck = read_checkpoint(out / LAST, require_meta=False)
    ck["state_dict"] = {k: v.detach().cpu().clone() for k, v in module.state_dict().items()}
    ck["blenav_training"] = info
    ck.setdefault("callbacks", {})[monitor.state_key] = monitor.state_dict()
    tmp = (out / LAST).with_suffix(".tmp")
    torch.save(ck, tmp)
    tmp.replace(out / LAST)


def prior_training(out: Path) -> dict:
    """The ``blenav_training`` entry of OUT/last.ckpt ({} without one)."""
    ck = out / LAST
    if not ck.is_file():
        return {}
    return dict(read_checkpoint(ck, require_meta=False).get("blenav_training") or {})


def validate_last(trainer, module, dm, monitor: TrainingMonitor) -> None:
    """Validate the steps since the monitor's last check (none when the fit ended on one, or without validation
    windows), so that the report and the best weights see the final step."""
    if dm.sets.get("val") is not None and (not monitor.history or monitor.history[-1]["step"] != trainer.global_step):
        trainer.validate(module, datamodule=dm, verbose=False)


def end_stage(module, trainer, out: Path, info: dict, monitor: TrainingMonitor, title: str, plots: bool) -> None:
    """A stage's end: the module's own calibration on the data module, when it has one (``module.calibrate(dm)``:
    e.g. LocNet's std head, its report added to ``info``), ``info`` on the module, OUT/last.ckpt of the final step
    amended on rank 0 with the module's weights and ``info`` (:func:`finish_checkpoint`), and the training report."""
    calibrate = getattr(module, "calibrate", None)
    dm = getattr(trainer, "datamodule", None)
    if calibrate is not None and dm is not None:
        info.update(calibrate(dm))
    module.training_info = info
    final_step_checkpoint(trainer, out)
    if trainer.is_global_zero:
        finish_checkpoint(module, out, info, monitor)
    write_report(out, info, monitor, title, plots)


def supervised_stage(module, dm, out: Path, trainer_kw: dict, b: dict, max_steps: int, monitor, knn_err,
                     callbacks, title: str, plots: bool, extra_info: dict | None = None, baseline: str = "KNN",
                     timed: bool = False):
    """Fit with the step budget and early stopping (on ``val/loss``); keep the best validation check's weights; write
    the checkpoint and the training report (``knn_err``: the ``baseline``'s validation error, m, beside the network's;
    ``extra_info`` added to the report; ``timed``: the fit's wall time as ``fit_wall_s``, since the resume for a resumed
    run). Returns (training info, trainer)."""
    es = None
    step_budget = StepBudget(max_steps)
    callbacks_1 = [monitor, step_budget, *(callbacks or [])]
    if b["patience"] is not None:
        es = L.pytorch.callbacks.EarlyStopping(monitor="val/loss", patience=int(b["patience"]),
                                               min_delta=float(b["min_delta"]), mode="min",
                                               check_on_train_epoch_end=False)
        callbacks_1.append(es)
    module.training_info = {"stage": "supervised"}
    t0 = time.perf_counter()
    trainer = fit(module, dm, out, trainer_kw, callbacks_1)
    validate_last(trainer, module, dm, monitor)
    reason = stop_reason(trainer, es, step_budget)
    if monitor.best_state is not None:  # the weights of the best validation check
        module.load_state_dict(monitor.best_state)
    info = training_report(monitor, reason, trainer.global_step, knn_err, baseline=baseline)
    info.update(extra_info or {}, budget_steps=int(max_steps))
    if timed:
        info["fit_wall_s"] = time.perf_counter() - t0
    end_stage(module, trainer, out, info, monitor, title, plots)
    return info, trainer
