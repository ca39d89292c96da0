"""Train a learned localizer from a Hydra config: ``python train.py [overrides]`` (see conf/train.yaml);
``model=NAME`` chooses the network config (conf/model/NAME.yaml), as everywhere. Errors the user can fix
print one line (``--debug`` shows the traceback); an interrupted run resumes from OUT/last.ckpt."""

import sys

from omegaconf import DictConfig, OmegaConf

from blenav.cli.common import run_hydra
from blenav.configs import cli_overrides


def task(cfg: DictConfig) -> None:
    from blenav.learn.train import train

    if OmegaConf.is_missing(cfg.data, "path") or not cfg.data.get("path"):
        raise ValueError("name the dataset to train on: data=DIR (a format-v1 dataset folder)")
    metrics, _ = train(cfg)
    print({k: round(v, 4) for k, v in metrics.items()})


def main() -> None:
    run_hydra("train.py", "train", task, sys.argv[1:], convert=cli_overrides)  # data=DIR -> data.path=DIR


if __name__ == "__main__":
    main()
