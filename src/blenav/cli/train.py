"""``python train.py`` / ``blenav-train``: train a learned localizer from a Hydra config (see conf/train.yaml);
``model=NAME`` chooses the network config (conf/model/NAME.yaml), as everywhere. The work is
:func:`blenav.learn.train.train`; errors the user can fix print one line (``--debug`` shows the traceback); an
interrupted run resumes from OUT/last.ckpt."""

from __future__ import annotations

import sys

from omegaconf import DictConfig, OmegaConf

from .common import run_hydra


def task(cfg: DictConfig) -> float | None:
    """Train; returns ``metrics[cfg.optimized_metric]`` when that is set (the objective of a hyper-parameter
    sweep, ``hparams_search=crossphone_optuna``), else None."""
    from blenav.learn.train import train

    if OmegaConf.is_missing(cfg.data, "path") or not cfg.data.get("path"):
        raise ValueError("name the dataset to train on: data=DIR (a format-v1 dataset folder)")
    metrics, _ = train(cfg)
    print({k: round(v, 4) for k, v in metrics.items()})
    key = cfg.get("optimized_metric")
    if key:
        if key not in metrics:
            raise ValueError(f"optimized_metric={key!r} was not measured; measured: {sorted(metrics)}")
        from blenav.learn.common.sweep import record_trial

        record_trial(cfg, float(metrics[key]))
        return float(metrics[key])
    return None


def main(argv: list[str] | None = None) -> None:
    from blenav.configs import cli_overrides

    prog = "train.py" if sys.argv[0].endswith("train.py") else "blenav-train"
    run_hydra(prog, "train", task, sys.argv[1:] if argv is None else list(argv), convert=cli_overrides)  # data=DIR -> data.path=DIR
