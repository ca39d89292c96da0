"""One place to register the structured config schemas and to compose a config from ``conf/``.

Entry points call :func:`register_configs` before Hydra runs; tests and benchmarks call :func:`compose`
(the real config with overrides) instead of repeating Hydra's initialisation.
"""

from __future__ import annotations

import re
import warnings

from omegaconf import DictConfig

from .errors import ConfigError
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
    ``beacon_map/schema``     :class:`blenav.eval.beacon_map.BeaconMapConfig`         conf/eval.yaml
    ``windows/schema``        :class:`blenav.learn.crossphone.data_config.WindowDataConfig`      conf/windows/default.yaml
    ``windows/mapprior_schema`` :class:`blenav.learn.mapprior.data_config.MapPriorDataConfig`  conf/windows/mapprior.yaml
    ``windows/inertial_schema`` :class:`blenav.learn.inertial.data_config.InertialDataConfig`  conf/windows/inertial.yaml
    ``backend/schema``        :class:`blenav.backend.config.BackendConfig`            conf/backend/default.yaml
    ========================  ======================================================  =====================

    None of these modules imports torch: registering costs the entry points nothing. Also registers the
    resolvers ``blenav.if_train_devices`` (:func:`if_train_devices`) and ``blenav.dataset_devices``
    (:func:`dataset_devices`).
    """
    from hydra.core.config_store import ConfigStore

    from blenav.backend.config import BackendConfig
    from blenav.eval.beacon_map import BeaconMapConfig
    from blenav.eval.plan_errors import PlanErrorConfig
    from blenav.filters.attitude import AttitudeConfig
    from blenav.filters.engine import FilterConfig
    from blenav.learn.crossphone.data_config import WindowDataConfig
    from blenav.learn.inertial.data_config import InertialDataConfig
    from blenav.learn.mapprior.data_config import MapPriorDataConfig
    from blenav.sim.config import SimConfig

    _register_resolvers()
    cs = ConfigStore.instance()
    cs.store(group="sim", name="schema", node=SimConfig)
    cs.store(group="filter", name="schema", node=FilterConfig)
    cs.store(group="attitude", name="schema", node=AttitudeConfig)
    cs.store(group="plan_error", name="schema", node=PlanErrorConfig)
    cs.store(group="beacon_map", name="schema", node=BeaconMapConfig)
    cs.store(group="windows", name="schema", node=WindowDataConfig)
    cs.store(group="windows", name="mapprior_schema", node=MapPriorDataConfig)
    cs.store(group="windows", name="inertial_schema", node=InertialDataConfig)
    cs.store(group="backend", name="schema", node=BackendConfig)


def if_train_devices(preset_train, value, *, _root_):
    """Resolver ``${blenav.if_train_devices:TRAIN,VALUE}``: ``VALUE`` while ``data.train_devices`` is the
    list ``TRAIN``, else None.

    An experiment written for the simulator's phones (conf/experiment/crossphone_003.yaml) names its known
    and unlabelled devices with it: they follow its train devices, and a command line that names other
    train devices (another dataset's receivers) gets the derived defaults (known = the train devices, no
    unlabelled devices) instead of phone names the dataset does not have, unless it names them too."""
    now = _root_.data.get("train_devices")
    same = now is not None and preset_train is not None and [str(d) for d in now] == [str(d) for d in preset_train]
    return value if same else None


def dataset_devices(devices, *, _root_):
    """Resolver ``${blenav.dataset_devices:LIST}``: the device models of ``LIST`` that sessions of the dataset
    ``data.path`` (of ``data.sessions``, when given) have, in LIST's order; None when it has none of them (or
    LIST is None). LIST unchanged when ``data.path`` is not a readable dataset (the data module then says why).

    The cross-phone experiments name the simulator's phones (conf/experiment/crossphone_s2.yaml); on a dataset
    simulated with another preset (``blenav-sim sim=small``: other receivers) they train on the named phones it
    has, or on every device when it has none of them, instead of failing on phones it lacks."""
    if devices is None:
        return None
    try:
        from blenav.data import Dataset

        data = _root_.data
        ds = Dataset.open(str(data.get("path")))
        ids = data.get("sessions")
        have = {s.device_model for s in ds.sessions([str(i) for i in ids] if ids else None)}
    except Exception:  # no dataset (yet): leave the list to the data module's checks and messages
        return devices
    here = [d for d in devices if str(d) in have]
    return here or None


def _register_resolvers() -> None:
    from omegaconf import OmegaConf

    if not OmegaConf.has_resolver("blenav.if_train_devices"):
        OmegaConf.register_new_resolver("blenav.if_train_devices", if_train_devices)
    if not OmegaConf.has_resolver("blenav.dataset_devices"):
        OmegaConf.register_new_resolver("blenav.dataset_devices", dataset_devices)


def cli_overrides(args: list[str], deprecated_model_path: bool = False) -> list[str]:
    """Command-line conveniences shared by the entry points (and :func:`compose`):

    - ``data=DIR`` -> ``data.path=DIR``: ``data`` is a node (the dataset path plus its device split,
      ``data.train_devices=[...]`` etc.), and the short form names the dataset;
    - ``sessions=a,b`` -> ``sessions=[a,b]`` (also ``data.sessions=a,b``, train.py's window data): Hydra
      would read a bare comma list as a sweep; ``only=a,b`` too, unless the command line sweeps (``-m``: one job
      per method);
    - ``model=`` names a ``conf/model`` network config everywhere; a trained model to evaluate is
      ``model_path=PATH``. With ``deprecated_model_path`` (blenav-eval, for one release) the old spelling
      ``model=PATH`` is still read as ``model_path=PATH``, with a FutureWarning.
    """
    out = []
    sweep = any(a in ("-m", "--multirun") for a in args)
    for a in args:
        if not sweep and re.match(r"^only=[^\[].*,", a):  # one run of several methods; with -m: one job per method
            a = f"only=[{a.split('=', 1)[1]}]"
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
    """The composed ``conf/<config_name>.yaml`` with command-line style ``overrides`` (see :func:`cli_overrides`).
    Entry points (``blenav.cli``, ``train.py``, ``export.py``), tests and benchmarks call it; nothing below them
    does (``tests/test_layers.py``): they hand the composed nodes down. Also inside a running Hydra app: the app's
    Hydra is set aside for the composition and given back after it."""
    from hydra import compose as hydra_compose
    from hydra import initialize_config_dir
    from hydra.core.global_hydra import GlobalHydra

    register_configs()
    over = cli_overrides(list(overrides), deprecated_model_path=config_name == "eval")
    app = GlobalHydra.instance().hydra if GlobalHydra.instance().is_initialized() else None
    if app is not None:
        GlobalHydra.instance().clear()
    try:
        with initialize_config_dir(config_dir=str(conf_dir()), version_base="1.3"):
            return hydra_compose(config_name=config_name, overrides=over)
    finally:
        if app is not None:
            GlobalHydra.instance().hydra = app


# ------------------------------------------------------------------------------------------ strict overrides
#: config groups of conf/ (an override ``GROUP=NAME`` chooses a file; ``GROUP.key=value`` sets a value)
def _groups() -> set[str]:
    return {p.name for p in conf_dir().iterdir() if p.is_dir()} | {"hydra"}


def _nearest(word: str, choices, prefix: str = "") -> str:
    import difflib

    close = difflib.get_close_matches(word, [str(c) for c in choices], n=1, cutoff=0.6)
    return f" (did you mean '{prefix}{close[0]}'?)" if close else ""


def _hydra_message(exc: Exception) -> str:
    """Hydra's error in one line, without its search-path listing; a missing group option names the nearest."""
    msg = " ".join(str(exc).split())
    msg = msg.split(" Config search path:")[0]
    m = re.search(r"Could not find '([^']+)/([^'/]+)' Available options in '[^']+': (.*)$", msg)
    if m:
        group, name, options = m.group(1), m.group(2), m.group(3).split()
        options = [o for o in options if not o.startswith("_")]
        msg = (f"no {group} named '{name}'{_nearest(name, options)}; {group} options: {', '.join(options)}")
    return msg


def _value_overrides(overrides: list[str]) -> list[tuple[str, str, str]]:
    """(prefix '', '+', '++' or '~'; key path; the whole override) of the overrides that set values, not groups."""
    out = []
    groups = _groups()
    for o in overrides:
        m = re.match(r"^(\+\+|\+|~)?([A-Za-z0-9_.\-]+)(=|$)", o)
        if not m:
            continue  # a group with a package (GROUP@PKG=NAME, a/b=c): Hydra checks those itself
        prefix, key = m.group(1) or "", m.group(2)
        if key.split(".")[0] == "hydra" or ("." not in key and key in groups):
            continue
        out.append((prefix, key, o))
    return out


def _check_key(cfg: DictConfig, key: str, override: str) -> None:
    """Raise :class:`ConfigError` when ``key`` may not be set in ``cfg``: it must exist at the top level and
    inside typed (schema) nodes; open nodes (methods, experiment settings) take new keys."""
    from omegaconf import OmegaConf

    parts = key.split(".")
    node = cfg
    for depth, part in enumerate(parts):
        if not isinstance(node, DictConfig):
            return  # a list or value: Hydra reports it
        typed = depth == 0 or OmegaConf.get_type(node) not in (dict, None)
        if part not in node:
            if typed:
                where = ".".join(parts[:depth]) or "the top level"
                prefix = ".".join(parts[:depth]) + "." if depth else ""
                raise ConfigError(f"unknown key '{key}' in {override!r}{_nearest(part, node.keys(), prefix)}: "
                                  f"{where} has {', '.join(sorted(str(k) for k in node.keys()))}")
            return
        node = node._get_node(part)


def check_overrides(config_name: str, overrides: list[str]) -> DictConfig:
    """Compose ``conf/<config_name>.yaml`` with ``overrides`` the way the entry point will, and refuse what
    Hydra would accept silently or explain in a traceback: an unknown key, with or without ``+``, at the top
    level or in a typed node, names the nearest known key. Returns the composed config.

    Raises :class:`ConfigError` (one message; the entry points print it as one line)."""
    from hydra.errors import HydraException
    from omegaconf.errors import OmegaConfBaseException

    values = _value_overrides(overrides)
    base_over = [o for p, _, o in values if p in ("+", "++", "~")]
    base = [o for o in overrides if o not in base_over]
    try:
        cfg = compose(config_name, *base)
    except (HydraException, OmegaConfBaseException) as exc:
        for p, key, o in values:  # the usual cause: a misspelt key; find it and suggest the nearest
            if p == "":
                try:
                    _check_key(compose(config_name, *[x for x in base if x != o]), key, o)
                except ConfigError:
                    raise
                except (HydraException, OmegaConfBaseException):
                    continue
        raise ConfigError(_hydra_message(exc)) from exc
    for p, key, o in values:
        if p in ("+", "++"):
            _check_key(cfg, key, o)
    try:
        return compose(config_name, *overrides)
    except (HydraException, OmegaConfBaseException) as exc:
        raise ConfigError(_hydra_message(exc)) from exc
