"""One place to register the structured config schemas and to compose a config from ``conf/``.

Entry points call :func:`register_configs` before Hydra runs; tests and benchmarks call :func:`compose`
(the real config with overrides) instead of repeating Hydra's initialisation.
"""

from __future__ import annotations

import re

from omegaconf import DictConfig

from .paths import conf_dir


def register_configs() -> None:
    """``sim/schema`` (:class:`blenav.sim.config.SimConfig`) and ``filter/schema``
    (:class:`blenav.filters.engine.FilterConfig`): a misspelt key fails at composition. Idempotent."""
    from hydra.core.config_store import ConfigStore

    from blenav.filters.engine import FilterConfig
    from blenav.sim.config import SimConfig

    cs = ConfigStore.instance()
    cs.store(group="sim", name="schema", node=SimConfig)
    cs.store(group="filter", name="schema", node=FilterConfig)


def cli_overrides(args: list[str], model_is_path: bool = False) -> list[str]:
    """Command-line conveniences shared by the entry points (and :func:`compose`):

    - ``data=DIR`` -> ``data.path=DIR``: ``data`` is a node (the dataset path plus its device split,
      ``data.train_devices=[...]`` etc.), and the short form names the dataset;
    - ``sessions=a,b`` -> ``sessions=[a,b]`` (also ``data.sessions=a,b``, train.py's window data): Hydra
      would read a bare comma list as a sweep;
    - with ``model_is_path`` (blenav-eval): ``model=PATH`` -> ``model_path=PATH``, the trained model to
      evaluate; for train.py ``model=NAME`` stays the choice of a ``conf/model`` network.
    """
    out = []
    for a in args:
        if a.startswith("data=") and not a.startswith("data=["):
            a = "data.path=" + a.split("=", 1)[1]
        elif model_is_path and a.startswith("model="):
            a = "model_path=" + a.split("=", 1)[1]
        elif re.match(r"^(data\.)?sessions=[^\[].*,", a):
            key, value = a.split("=", 1)
            a = f"{key}=[{value}]"
        out.append(a)
    return out


def compose(config_name: str, *overrides: str) -> DictConfig:
    """The composed ``conf/<config_name>.yaml`` with command-line style ``overrides`` (see :func:`cli_overrides`)."""
    from hydra import compose as hydra_compose
    from hydra import initialize_config_dir

    register_configs()
    with initialize_config_dir(config_dir=str(conf_dir()), version_base="1.3"):
        return hydra_compose(config_name=config_name, overrides=cli_overrides(list(overrides), model_is_path=config_name == "eval"))
