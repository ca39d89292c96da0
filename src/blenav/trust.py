"""What a config may ask blenav to build: an allow-list of ``_target_`` names, checked before anything is imported.

A ``_target_`` in a config node names a callable that ``hydra.utils.instantiate`` imports and calls. Configs come
from files blenav did not write (a checkpoint's ``blenav.model`` node, a bundle's settings.json, an experiment file
from ``--config-dir``) and from the command line, so a ``_target_`` is data like any other value: it must be one of
the classes blenav builds from its own configs, :data:`TARGETS` (spelt exactly as in conf/), or one that code
trusted already added with :func:`register`. :func:`check_targets` walks a node (plain dicts and lists, omegaconf
``DictConfig`` / ``ListConfig``) to any depth, including ``_args_`` lists, and raises
:class:`UntrustedTargetError` naming the file or source and the key path of the first ``_target_`` that is not
allowed (a name not in the list, or a value that is not a string) -- by string membership, before any module of
that name is imported. :func:`safe_instantiate` checks, then instantiates (Hydra, imported on call: only the upper
layers call it; ``blenav.runtime`` builds its bundle's motion model itself after the same check).

``_partial_``, ``_args_`` and ``_recursive_`` need no rule of their own: every node below the checked one is walked,
whatever Hydra would do with it (a ``_target_`` in an ``_args_`` list, or below a node built with
``_recursive_: false`` that its class instantiates later, is refused all the same), and a trusted class stays
trusted when built partially. Callers keep their ``_recursive_`` as before, so legitimate configs build the same
objects.

Only the standard library is imported here (``omegaconf`` only when handed one of its nodes, which means it is
loaded already), so every layer may use the check.
"""

from __future__ import annotations

import re
from collections.abc import Mapping
from typing import Any

KEY = "_target_"

#: Every class blenav builds from a config: the ``_target_`` names of conf/**/*.yaml and of the configs code writes
#: (the bundle's default settings), and the other public components of the same kinds (motion and measurement models,
#: localizers, networks). Re-exported classes are listed under both spellings. tests/test_trust.py checks that every
#: ``_target_`` of conf/ is here and that every name here imports to a class under ``blenav``: a new class that a
#: YAML file of conf/ names is added here too.
TARGETS: frozenset[str] = frozenset({
    # localizers (conf/localizer, conf/experiment): built by blenav.localizers.build_localizer
    "blenav.localizers.ParticleFilterLocalizer", "blenav.localizers.particle.ParticleFilterLocalizer",
    "blenav.localizers.FixTrackLocalizer", "blenav.localizers.fixtrack.FixTrackLocalizer",
    "blenav.localizers.centroid.WeightedCentroidLocalizer",
    "blenav.localizers.crf.CrfLocalizer",
    "blenav.localizers.fingerprint.FingerprintLocalizer", "blenav.localizers.crowd.CrowdFingerprint",
    "blenav.localizers.ranging.GridL1Localizer", "blenav.localizers.ranging.GridL2Localizer",
    "blenav.localizers.ranging.SrlsLocalizer",
    "blenav.backend.localizer.BackendLocalizer", "blenav.backend.pooled.PooledMapBackend",
    "blenav.localizers.realwalk.RealWalkPF",
    "blenav.localizers.fusedwalk.FusedWalk",
    # evaluators (conf/experiment: experiment.evaluator; blenav.eval.evaluators)
    "blenav.eval.trajectory.TrajectoryEvaluator", "blenav.eval.leaderboard.LeaderboardEvaluator",
    "blenav.eval.crossphone.CrossPhoneEvaluator",
    # a particle filter's motion models (conf/filter/motion, the bundle's settings.json)
    "blenav.filters.motion.RandomWalk", "blenav.filters.motion.DeadReckoning", "blenav.filters.motion.ImuProposal",
    "blenav.filters.motion.OdometryIncrement", "blenav.filters.motion.Pdr",
    # ... and its measurement models (conf/filter/measurement, conf/experiment)
    "blenav.filters.measurement.PathLossRange", "blenav.filters.measurement.RssiDomain",
    "blenav.filters.measurement.FixLikelihood",
    "blenav.filters.offset.RssiDomainOffset", "blenav.filters.offset.PathLossRangeOffset",
    "blenav.filters.map_prior.MapPriorLikelihood", "blenav.filters.map_prior.FeasibilityPrior",
    # networks (conf/model; a checkpoint's blenav.model node)
    "blenav.models.LocNet", "blenav.models.locnet.LocNet", "blenav.models.PlaceNet", "blenav.models.placenet.PlaceNet",
    "blenav.models.TransNet", "blenav.models.transnet.TransNet",
    "blenav.models.DLRNN", "blenav.models.dlrnn.DLRNN",
    "blenav.models.mapprior.MapPriorNet",
    "blenav.models.inertial.ResNet1D", "blenav.models.inertial.TCN",
})

#: What Hydra itself may build from its own ``hydra`` node before a task runs (launchers, sweepers, the Optuna
#: sweeper's sampler of conf/hparams_search): checked by the entry points (:func:`check_hydra_node`).
HYDRA_TARGETS: frozenset[str] = frozenset({
    "hydra._internal.core_plugins.basic_launcher.BasicLauncher",
    "hydra._internal.core_plugins.basic_sweeper.BasicSweeper",
    "hydra_plugins.hydra_joblib_launcher.joblib_launcher.JoblibLauncher",
    "hydra_plugins.hydra_submitit_launcher.submitit_launcher.LocalLauncher",
    "hydra_plugins.hydra_submitit_launcher.submitit_launcher.SlurmLauncher",
    "hydra_plugins.hydra_optuna_sweeper.optuna_sweeper.OptunaSweeper",
    "optuna.samplers.TPESampler", "optuna.samplers.RandomSampler", "optuna.samplers.GridSampler",
    "optuna.samplers.CmaEsSampler", "optuna.samplers.NSGAIISampler", "optuna.samplers.MOTPESampler",
})

_registered: set[str] = set()
_DOTTED = re.compile(r"[A-Za-z_][A-Za-z0-9_]*(\.[A-Za-z_][A-Za-z0-9_]*)+")


class UntrustedTargetError(ValueError):
    """A config names something to build that blenav does not build from configs: refused before it is imported."""


def register(*classes) -> None:
    """Allow more ``_target_`` names: classes (their ``module.qualname``) or dotted strings. For code that runs
    already and adds its own components -- a test module's localizer, an application's -- never for names read
    from a file: whoever may call this may run code anyway."""
    for c in classes:
        name = c if isinstance(c, str) else f"{c.__module__}.{c.__qualname__}"
        if not _DOTTED.fullmatch(name):
            raise ValueError(f"register: {name!r} is not a dotted name module.Class")
        _registered.add(name)


def trusted(name: Any, extra: frozenset[str] = frozenset()) -> bool:
    """Whether ``name`` is a string in :data:`TARGETS`, in ``extra`` or registered (nothing is imported)."""
    return isinstance(name, str) and (name in TARGETS or name in _registered or name in extra)


def _omegaconf_container(node) -> bool:
    return type(node).__module__.startswith("omegaconf") and type(node).__name__ in ("DictConfig", "ListConfig")


def _walk(node, where: str, extra: frozenset[str], prefix: str = "") -> None:
    """Raise for the first untrusted ``_target_`` below ``node`` (plain containers; depth first, no recursion)."""
    stack: list[tuple[Any, str]] = [(node, prefix)]
    seen: set[int] = set()
    while stack:
        n, path = stack.pop()
        if _omegaconf_container(n):
            from omegaconf import OmegaConf  # loaded already: n is one of its nodes

            n = OmegaConf.to_container(n, resolve=False)  # interpolations stay "${...}" strings
        if isinstance(n, (str, bytes)) or id(n) in seen:
            continue
        if isinstance(n, Mapping):
            seen.add(id(n))
            items = list(n.items())
            for k, v in items:
                if k == KEY and not trusted(v, extra):
                    raise _refusal(where, f"{path}.{KEY}" if path else KEY, v)
            stack.extend((v, f"{path}.{k}" if path else str(k)) for k, v in reversed(items))
        elif isinstance(n, (list, tuple)):
            seen.add(id(n))
            stack.extend((v, f"{path}[{i}]") for i, v in reversed(list(enumerate(n))))


def _refusal(where: str, path: str, value) -> UntrustedTargetError:
    shown = repr(value if len(str(value)) <= 120 else str(value)[:117] + "...")
    shown = shown if isinstance(value, str) else f"{shown} (of type {type(value).__name__}, not a name)"
    return UntrustedTargetError(
        f"{where}: {path} = {shown} is not a class blenav builds from a config; a config may only name blenav's own "
        "components (blenav.trust.TARGETS), so a file or command line cannot make blenav run other code")


def check_targets(node, where: str, extra: frozenset[str] = frozenset(), prefix: str = "",
                  resolve: bool = True) -> None:
    """Raise :class:`UntrustedTargetError` (naming ``where`` and the key path from ``prefix``, e.g.
    ``model.locnet.init._target_``) for any ``_target_`` below ``node``, at any depth, that is not a string in
    :data:`TARGETS`, in ``extra`` or :func:`register`-ed. Checked by membership of the string: nothing is imported.

    An omegaconf node, or a plain container holding an interpolation (Hydra makes it one), is walked as written (an
    interpolation in ``_target_`` is refused: it is not a name) and, when it resolves, as resolved, so a node that an interpolation pulls in (``${oc.decode:...}``) is walked too;
    one that does not resolve is not instantiated either (Hydra resolves the whole node before it builds anything).
    ``resolve=False``: as written only (no resolver runs; a check before the one at the place that builds).
    """
    _walk(node, where, extra, prefix)
    if not resolve or not (_omegaconf_container(node) or _has_interpolation(node)):
        return
    try:  # a plain container with "${...}" is resolved too: Hydra's instantiate makes it an omegaconf node first
        from omegaconf import OmegaConf
    except ImportError:  # nothing here can resolve it: nothing builds from it either
        return
    try:
        resolved = OmegaConf.to_container(node if _omegaconf_container(node) else OmegaConf.create(node), resolve=True)
    except Exception:  # noqa: BLE001 -- unresolvable: Hydra fails on it before it imports anything
        return
    _walk(resolved, where, extra, prefix)


def _has_interpolation(node) -> bool:
    """Whether a plain container holds a string with an interpolation (``${``) at any depth (iterative walk)."""
    stack, seen = [node], set()
    while stack:
        n = stack.pop()
        if isinstance(n, str):
            if "${" in n:
                return True
        elif isinstance(n, Mapping) and id(n) not in seen:
            seen.add(id(n))
            stack.extend(n.keys())
            stack.extend(n.values())
        elif isinstance(n, (list, tuple)) and id(n) not in seen:
            seen.add(id(n))
            stack.extend(n)
    return False


def check_hydra_node(hydra_node, where: str) -> None:
    """Check a composed ``hydra`` node (what Hydra builds before the task runs): its ``_target_`` names must be in
    :data:`HYDRA_TARGETS` or :data:`TARGETS`; callbacks must name them too; the logging configs (Python's
    ``logging.config.dictConfig`` calls ``()`` factories and ``class`` names) may name only ``logging.`` classes;
    the Optuna sweeper's ``custom_search_space`` (a function it calls) is refused."""
    if hydra_node is None:
        return
    _walk(hydra_node, where, HYDRA_TARGETS, "hydra")
    node = hydra_node
    if _omegaconf_container(node):
        from omegaconf import OmegaConf

        node = OmegaConf.to_container(node, resolve=False)
    if not isinstance(node, Mapping):
        return
    sweeper = node.get("sweeper")
    if isinstance(sweeper, Mapping) and sweeper.get("custom_search_space") is not None:
        raise UntrustedTargetError(f"{where}: hydra.sweeper.custom_search_space names a function for Hydra to call; "
                                   "blenav's configs never set it: remove it")
    job = node.get("job")
    env = job.get("env_set") if isinstance(job, Mapping) else None
    if isinstance(env, Mapping) and env:  # LD_PRELOAD / PYTHONSTARTUP for child processes, BLENAV_MAX_* limits off
        raise UntrustedTargetError(f"{where}: hydra.job.env_set sets {', '.join(sorted(map(str, env)))[:120]}: "
                                   "blenav's configs never set environment variables; set them in your shell")
    for key in ("job_logging", "hydra_logging"):
        stack = [(node.get(key), f"hydra.{key}")]
        while stack:
            n, path = stack.pop()
            if isinstance(n, Mapping):
                for k, v in n.items():
                    if k == "()" or (k == "class" and not (isinstance(v, str) and v.startswith("logging."))):
                        raise UntrustedTargetError(
                            f"{where}: {path}.{k} = {str(v)[:80]!r}: a logging config may only name logging.* "
                            "classes (no '()' factories): a file cannot make blenav run other code")
                    stack.append((v, f"{path}.{k}"))
            elif isinstance(n, (list, tuple)):
                stack.extend((v, f"{path}[{i}]") for i, v in enumerate(n))


def safe_instantiate(node, where: str, prefix: str = "", /, **kw):
    """``hydra.utils.instantiate(node, **kw)`` after :func:`check_targets` of ``node`` (key paths from ``prefix``)
    and of ``kw`` (Hydra merges them into the node and builds their nodes too). Upper layers only: imports Hydra
    when called."""
    check_targets(node, where, prefix=prefix)
    check_targets(kw, where)
    from hydra.utils import instantiate

    return instantiate(node, **kw)
