"""The step budget of a training run (``trainer.budget``, conf/trainer/cpu.yaml; :func:`budget`), and the Lightning
Trainer keywords it makes (:func:`trainer_settings`).

Training runs for a number of optimizer *steps*, not epochs: ``max_steps``, by default ``auto``, which follows the
survey's size (:func:`budget_steps`: 3,000 steps for 2,000 training windows or fewer, growing as the square root of
the windows, at most 15,000 -- about 6,700 for 10k windows; with ``data.batch_size: auto`` a survey under 2,560
windows trains at batch 128 for twice those steps, :func:`blenav.learn.crossphone.data.auto_batch_size`; a batch
given as a number keeps them), validated about every ``val_every_steps`` steps (:func:`val_cadence`), stopped early
when the validation loss (``val/loss``) has not improved by ``min_delta`` for ``patience`` checks (Lightning's
``EarlyStopping``). The learning rate warms up linearly over ``warmup_steps`` and then follows half a cosine to
``min_lr_ratio`` times ``model.lr`` at ``max_steps`` (``schedule: onecycle`` or ``constant`` instead;
:func:`blenav.learn.common.schedule.lr_factor`). ``trainer.max_epochs`` still caps the run when set (the thesis' 50
epochs: ``trainer.max_epochs=50 trainer.budget.max_steps=-1 trainer.budget.patience=null``).

The cross-phone task (:mod:`blenav.learn.crossphone.train`) runs with it; the map prior trains for epochs.
"""

from __future__ import annotations

import math

from omegaconf import DictConfig, OmegaConf

from .trainer import CKPT_EVERY

#: ``trainer.budget`` defaults (conf/trainer/cpu.yaml repeats them): chosen on validation windows of simulated
#: campus_floor surveys of several sizes (docs/results-003-crossphone.md), never on test walks.
BUDGET = {"max_steps": "auto", "auto_base_steps": 3000, "auto_ref_windows": 2000, "auto_max_steps": 15000,
          "val_every_steps": 50, "patience": 15, "min_delta": 0.0, "warmup_steps": 100,
          "schedule": "cosine", "min_lr_ratio": 0.02}


def budget_steps(b: dict, n_windows: int, scale: float = 1.0) -> int:
    """The run's optimizer-step budget: ``max_steps`` when it is a number (-1 or None: none), else (``auto``)
    ``scale`` * ``auto_base_steps`` * sqrt(n_windows / ``auto_ref_windows``), at least ``scale`` * the base and at
    most ``auto_max_steps``. ``scale`` is 256 / batch for ``data.batch_size: auto`` (2 on a survey under 2,560
    windows, whose batch is 128: :func:`blenav.learn.crossphone.data.auto_batch_size`), else 1.

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


def steps_per_epoch(n: int, batch: int) -> int:
    """Optimizer steps of one epoch of ``n`` windows at ``batch``."""
    return max(1, math.ceil(n / max(int(batch), 1)))


def val_cadence(every: int, steps_per_epoch: int) -> dict:
    """Lightning arguments for a validation check about every ``every`` optimizer steps: within an epoch every
    ``every`` batches when an epoch is longer, else at the end of every round(every / steps_per_epoch)-th epoch.
    (``check_val_every_n_epoch=None`` with a step interval would validate across epoch boundaries exactly, but
    a run resumed from its end-of-epoch checkpoint then miscounts the resumed epoch in Lightning 2.6.)"""
    if steps_per_epoch >= every:
        return {"check_val_every_n_epoch": 1, "val_check_interval": int(every)}
    return {"check_val_every_n_epoch": max(1, round(every / steps_per_epoch)), "val_check_interval": 1.0}


def trainer_settings(cfg: DictConfig, b: dict, max_steps: int, n_train: int, batch_size: int) -> tuple[dict, dict]:
    """Lightning Trainer keywords of ``cfg.trainer`` with the step budget ``b`` (``max_steps`` optimizer steps, -1:
    none; Lightning's max_steps -1: the budget is a callback, :class:`blenav.learn.common.trainer.StepBudget`;
    validation cadence in steps for ``n_train`` training windows at ``batch_size``), and the module's LR schedule
    (``{"kind", "warmup_steps", "total_steps", "min_lr_ratio"}``); returns (keywords, schedule)."""
    trainer_kw = OmegaConf.to_container(cfg.trainer, resolve=True)
    trainer_kw.pop("budget", None)
    if trainer_kw.get("max_epochs") is None:
        trainer_kw["max_epochs"] = -1  # the step budget decides (Lightning's default would be 1000 epochs)
    trainer_kw["max_steps"] = -1  # the budget is a callback (blenav.learn.common.trainer.StepBudget)
    spe = steps_per_epoch(n_train, batch_size)
    trainer_kw.update(val_cadence(int(b["val_every_steps"]), spe))
    # OUT/last.ckpt at the validation cadence too: every epoch on a 2k-window survey (9 steps) cost ~20 % of the run
    trainer_kw[CKPT_EVERY] = trainer_kw["check_val_every_n_epoch"]
    total = [t for t in (max_steps if max_steps > 0 else None,
                         spe * int(trainer_kw["max_epochs"]) if int(trainer_kw["max_epochs"]) > 0 else None) if t]
    if not total:
        raise ValueError("no training budget: set trainer.budget.max_steps or trainer.max_epochs")
    schedule = {"kind": b["schedule"], "warmup_steps": int(b["warmup_steps"]), "total_steps": min(total),
                "min_lr_ratio": float(b["min_lr_ratio"])}
    return trainer_kw, schedule
