"""Train a learned localizer from a Hydra config: ``python train.py [overrides]`` (see conf/train.yaml);
``model=NAME`` chooses the network config (conf/model/NAME.yaml), as everywhere."""

import sys

import hydra
from omegaconf import DictConfig

from blenav.configs import cli_overrides, register_configs
from blenav.learn.train import train
from blenav.paths import conf_dir

register_configs()  # the data node's schema (windows/schema): a misspelt key fails at composition


@hydra.main(config_path=str(conf_dir()), config_name="train", version_base="1.3")
def main(cfg: DictConfig) -> None:
    metrics, _ = train(cfg)
    print({k: round(v, 4) for k, v in metrics.items()})


if __name__ == "__main__":
    sys.argv = [sys.argv[0]] + cli_overrides(sys.argv[1:])  # data=DIR -> data.path=DIR
    main()
