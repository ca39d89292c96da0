"""One place to register the structured config schemas and to compose a config from ``conf/``.

Entry points call :func:`register_configs` before Hydra runs; tests and benchmarks call :func:`compose`
(the real config with overrides) instead of repeating Hydra's initialisation.
"""

from __future__ import annotations

import re
import warnings

from omegaconf import DictConfig

from .paths import conf_dir


def register_configs() -> None:
    """Store the structured config schemas in Hydra's ConfigStore (idempotent): each config of a group
    that lists ``- schema`` in its defaults (``conf/filter/pf.yaml``, ``conf/sim/*.yaml``, ...) is merged
    into the dataclass, so a misspelt key or a mode outside its Enum fails at composition, naming it.

    ========================  ======================================================  =====================
    group/name                dataclass                                               used by
    ========================  ======================================================  =====================
    ``sim/schema``            :class:`blenav.sim.config.SimConfig`                    conf/sim/*.yaml
    ``filter/schema``         :class:`blenav.filters.engine.FilterConfig`             conf/filter/pf.yaml
    ``attitude/schema``       :class:`blenav.filters.attitude.AttitudeConfig`         conf/attitude/*.yaml
    ``plan_error/schema``     :class:`blenav.eval.plan_errors.PlanErrorConfig`        conf/eval.yaml
    ``windows/schema``        :class:`blenav.learn.data_config.WindowDataConfig`      conf/windows/default.yaml
    ``windows/mapprior_schema`` :class:`blenav.learn.data_config.MapPriorDataConfig`  conf/windows/mapprior.yaml
    ========================  ======================================================  =====================

    None of these modules imports torch: registering costs the entry points nothing. Also registers the
    resolver ``blenav.if_train_devices`` (:func:`if_train_devices`).
    """
    from hydra.core.config_store import ConfigStore

    from blenav.eval.plan_errors import PlanErrorConfig
    from blenav.filters.attitude import AttitudeConfig
    from blenav.filters.engine import FilterConfig
    from blenav.learn.data_config import MapPriorDataConfig, WindowDataConfig
    from blenav.sim.config import SimConfig

    _register_resolvers()
    cs = ConfigStore.instance()
    cs.store(group="sim", name="schema", node=SimConfig)
    cs.store(group="filter", name="schema", node=FilterConfig)
    cs.store(group="attitude", name="schema", node=AttitudeConfig)
    cs.store(group="plan_error", name="schema", node=PlanErrorConfig)
    cs.store(group="windows", name="schema", node=WindowDataConfig)
    cs.store(group="windows", name="mapprior_schema", node=MapPriorDataConfig)


def if_train_devices(preset_train, value, *, _root_):
    """Resolver ``${blenav.if_train_devices:TRAIN,VALUE}``: ``VALUE`` while ``data.train_devices`` is the
    list ``TRAIN``, else None.

    An experiment written for the simulator's phones (conf/experiment/crossphone_003.yaml) names its known
    and unlabelled devices with it: they follow its train devices, and a command line that names other
    train devices (another dataset's receivers) gets the derived defaults (known = the train devices, no
    unlabelled devices) instead of phone names the dataset does not have, unless it names them too."""
    now = _root_.data.get("train_devices")
    same = now is not None and [str(d) for d in now] == [str(d) for d in preset_train]
    return value if same else None


def _register_resolvers() -> None:
    from omegaconf import OmegaConf

    if not OmegaConf.has_resolver("blenav.if_train_devices"):
        OmegaConf.register_new_resolver("blenav.if_train_devices", if_train_devices)


def cli_overrides(args: list[str], deprecated_model_path: bool = False) -> list[str]:
    """Command-line conveniences shared by the entry points (and :func:`compose`):

    - ``data=DIR`` -> ``data.path=DIR``: ``data`` is a node (the dataset path plus its device split,
      ``data.train_devices=[...]`` etc.), and the short form names the dataset;
    - ``sessions=a,b`` -> ``sessions=[a,b]`` (also ``data.sessions=a,b``, train.py's window data): Hydra
      would read a bare comma list as a sweep;
    - ``model=`` names a ``conf/model`` network config everywhere; a trained model to evaluate is
      ``model_path=PATH``. With ``deprecated_model_path`` (blenav-eval, for one release) the old spelling
      ``model=PATH`` is still read as ``model_path=PATH``, with a FutureWarning.
    """
    out = []
    for a in args:
        if a.startswith("data=") and not a.startswith("data=["):
            a = "data.path=" + a.split("=", 1)[1]
        elif deprecated_model_path and a.startswith("model="):
            a = "model_path=" + a.split("=", 1)[1]
            warnings.warn(f"blenav-eval: model=PATH is deprecated (model= names a conf/model network config, as in "
                          f"train.py): use {a}", FutureWarning, stacklevel=2)
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
    over = cli_overrides(list(overrides), deprecated_model_path=config_name == "eval")
    with initialize_config_dir(config_dir=str(conf_dir()), version_base="1.3"):
        return hydra_compose(config_name=config_name, overrides=over)
