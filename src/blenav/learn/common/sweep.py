"""Bookkeeping of a hyper-parameter sweep (``python train.py -m hparams_search=crossphone_optuna ...``), torch-free.

Every trial of ``train.py`` leaves its resolved config (``config.yaml``) beside its checkpoint in its own
``out``; :func:`record_trial` keeps ``best_trial.yaml`` in the sweep folder (the parent of the trials' ``out``)
naming the best trial so far: its objective, run folder, checkpoint, config and the overrides that made it.
Lower is better (the search minimises a validation error).
"""

from __future__ import annotations

import math
from pathlib import Path

import yaml
from omegaconf import DictConfig


def record_trial(cfg: DictConfig, value: float) -> Path | None:
    """Update ``<parent of cfg.out>/best_trial.yaml`` when ``value`` (the trial's objective) beats it; inside a Hydra
    multirun only (returns the file's path, or None outside a sweep or when the trial was not the best)."""
    try:
        from hydra.core.hydra_config import HydraConfig

        hc = HydraConfig.get()
    except Exception:  # not under Hydra (tests call train() directly)
        return None
    if str(hc.mode) != "RunMode.MULTIRUN" or not math.isfinite(value):
        return None
    out = Path(str(cfg.out))
    best = out.parent / "best_trial.yaml"
    if best.is_file():
        old = yaml.safe_load(best.read_text(encoding="utf-8")) or {}
        if float(old.get("value", math.inf)) <= value:
            return None
    best.write_text(yaml.safe_dump({
        "value": float(value), "metric": str(cfg.get("optimized_metric")), "trial": int(hc.job.num),
        "out": str(out), "checkpoint": str(out / "last.ckpt"), "config": str(out / "config.yaml"),
        "overrides": list(hc.overrides.task)}, sort_keys=False), encoding="utf-8")
    return best
