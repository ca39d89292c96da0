"""The evaluation's settings as one typed object: :class:`EvalConfig`, parsed once from the composed ``conf/eval.yaml``.

``blenav-eval`` composes ``conf/eval.yaml`` with Hydra and hands the result to :func:`parse_eval_config`; from then
on the harness and the evaluators read typed fields (``cfg.split.train_fraction``, ``cfg.fixes.rate_hz``), never
the DictConfig. Parsing resolves every interpolation once and checks every key against the schema below: a
misspelt key (also one added with Hydra's ``+``, which bypasses composition's checks) fails here, naming the
nearest known key. Free-form nodes are those that belong to someone else and are checked there: ``methods.*``
(each localizer's constructor), ``floor_classifier`` (:func:`blenav.eval.floors.classify_floors`), ``trainer``,
``experiment.learned`` / ``baselines`` / ``paper`` (the cross-phone evaluator, results.md), and the
interpolation sources ``sim_devices``, ``fix_sources``, ``experiment.fix_source`` / ``roy_filter``.

The schema (``conf/eval.yaml`` and every root key an experiment of ``conf/experiment/`` sets)::

    EvalConfig
      data: WindowDataConfig           (blenav.learn.data_config; data.path = the dataset)
      experiment: ExperimentConfig     name, title, evaluator {_target_}, kind (old spelling), paper, families, ...
      methods: {LABEL: localizer node}   filter, attitude (the FilterConfig / AttitudeConfig every localizer starts from)
      sessions, runs, seed, out, overwrite, init_s, calibration, model_path, io_model, threads, plots, progress, peak_memory
      split: SplitConfig | None        fixes: FixesConfig | None      scoring: ScoringConfig
      plan_error: PlanErrorConfig      beacon_map: BeaconMapConfig    bound: BoundSettings | None
      floor_classifier, trainer, sim_devices, fix_sources (free-form)

Nothing here imports torch or Hydra; OmegaConf only to read the composed config and to check the nodes whose
dataclasses were OmegaConf schemas before (plan_error, beacon_map, bound, data, filter, attitude), so their
values are converted exactly as they were.
"""

from __future__ import annotations

import difflib
import types
import typing
from dataclasses import dataclass, field, fields, is_dataclass
from typing import Any

from blenav.errors import EvalError
from blenav.eval.beacon_map import BeaconMapConfig
from blenav.eval.pcrlb import BoundSettings
from blenav.eval.plan_errors import PlanErrorConfig
from blenav.filters.attitude import AttitudeConfig
from blenav.filters.engine import FilterConfig
from blenav.learn.crossphone.data_config import WindowDataConfig

__all__ = ["EvalConfig", "ExperimentConfig", "SplitConfig", "FixesConfig", "ScoringConfig", "parse_eval_config",
           "parse_node", "FIXES_OPTIONS"]

#: a field with this metadata is derived while parsing, not a key of the config
_DERIVED = {"derived": True}
#: dataclasses that were OmegaConf structured schemas: converted by OmegaConf (its coercions, its __post_init__)
_OMEGACONF_SCHEMAS = (PlanErrorConfig, BeaconMapConfig, BoundSettings, WindowDataConfig, FilterConfig, AttitudeConfig)
#: old ``experiment.kind`` values -> the evaluator they name (``experiment.evaluator._target_`` is the new spelling)
KINDS = {"trajectory": "blenav.eval.trajectory.TrajectoryEvaluator",
         "crossphone": "blenav.eval.crossphone.CrossPhoneEvaluator",
         "leaderboard": "blenav.eval.leaderboard.LeaderboardEvaluator"}


@dataclass
class SplitConfig:
    """``split``: ``train`` names the train walks (not scored); else each floor's walks are split by a seeded
    permutation, ``train_fraction`` of them train (:func:`blenav.eval.sessions.split_sessions`). ``given``: the
    keys as the experiment gave them (results.json repeats them, with the train walks chosen)."""

    train: list[str] | None = None
    train_fraction: float = 0.5
    seed: int = 0
    given: dict = field(default_factory=dict, metadata=_DERIVED)

    def __post_init__(self):
        if self.train is not None:
            self.train = [str(i) for i in self.train]


@dataclass
class ScoringConfig:
    """``scoring``: ``hold_ends``: waypoints outside an estimate's span are scored against its first / last estimate
    (:func:`blenav.eval.metrics.waypoint_metrics`)."""

    hold_ends: bool = False


#: the keys of an experiment's ``fixes`` block that are not roles
FIXES_OPTIONS = ("compute", "sparse_beacons", "rate_hz", "write")


@dataclass
class FixesConfig:
    """``fixes`` (:mod:`blenav.eval.fixes`): every key but the options is a role, whose value names a ``fixes.csv``
    source (or null: computed). ``compute``: one localizer node for every role, or ``{role: node}``;
    ``sparse_beacons``: k (anchors chosen to cover the floor) or a list of anchor ids; ``rate_hz``: fixes per second
    taken from a BLE filter; ``write``: write computed fixes into the dataset's fixes.csv."""

    roles: dict[str, str | None] = field(default_factory=dict, metadata=_DERIVED)
    compute: Any = None
    sparse_beacons: Any = 4
    rate_hz: float = 1.0
    write: bool = False

    @property
    def per_role(self) -> bool:
        """Whether ``compute`` maps roles to nodes (else one node, with a ``_target_``, for every role)."""
        return self.compute is not None and "_target_" not in self.compute

    @classmethod
    def parse(cls, node: dict, path: str = "fixes") -> "FixesConfig":
        roles = {str(r): v for r, v in node.items() if r not in FIXES_OPTIONS}
        for r, v in roles.items():  # a misspelt option (fixes.rate: 2, fixes.sparse_beacon: 6) must not become a role
            if v is not None and not isinstance(v, str):
                near = difflib.get_close_matches(r, FIXES_OPTIONS, n=1)
                hint = f" (did you mean {path}.{near[0]}?)" if near else ""
                raise EvalError(f"{path}.{r}={v!r}: not a role (a role's value is a fixes.csv source name or null) "
                                f"and not an option of the fixes block {list(FIXES_OPTIONS)}{hint}")
        sb = node.get("sparse_beacons", 4)
        if isinstance(sb, bool) or not isinstance(sb, (int, float, list, tuple)):
            raise EvalError(f"{path}.sparse_beacons={sb!r}: a number of anchors or a list of anchor ids")
        sb = int(sb) if isinstance(sb, (int, float)) else [str(b) for b in sb]
        comp = node.get("compute")
        if comp is not None and not isinstance(comp, dict):
            raise EvalError(f"{path}.compute: a localizer node (with _target_) or {{role: node}}, got {comp!r}")
        out = cls(roles=roles, compute=comp, sparse_beacons=sb,
                  rate_hz=_convert(float, node.get("rate_hz", 1.0), f"{path}.rate_hz"),
                  write=_convert(bool, node.get("write", False), f"{path}.write"))
        if out.per_role and set(comp) - set(roles):
            raise EvalError(f"{path}.compute names role(s) {sorted(set(comp) - set(roles))} that the fixes block does "
                            f"not define (roles: {sorted(roles)})")
        return out


@dataclass
class ExperimentConfig:
    """``experiment``: its ``name`` (results.json, the default output folder) and ``title``; ``evaluator``: the
    class that runs it (``{_target_: ...}``, an allow-listed target of :mod:`blenav.trust`; default the trajectory
    evaluator); ``kind``: the old spelling (``crossphone``, ``leaderboard``); ``paper``: the published numbers
    results.md compares with; ``families``: the leaderboard's method families; ``learned`` / ``baselines`` /
    ``runs_dir``: the cross-phone comparison's methods; ``fix_source``, ``roy_filter``: values other nodes
    interpolate."""

    name: str = ""
    title: str = ""
    evaluator: dict | None = None
    kind: str | None = None
    paper: dict | None = None
    families: dict | None = None
    learned: dict | None = None
    baselines: dict | None = None
    runs_dir: str | None = None
    fix_source: Any = None
    roy_filter: Any = None

    def __post_init__(self):
        if self.kind is not None and self.kind not in KINDS:
            raise EvalError(f"experiment.kind={self.kind!r}: known kinds {sorted(KINDS)} (or name the class: "
                            f"experiment.evaluator._target_)")
        if self.evaluator is not None and not (isinstance(self.evaluator, dict) and self.evaluator.get("_target_")):
            raise EvalError(f"experiment.evaluator: a node with a _target_ (e.g. {KINDS['trajectory']}), got "
                            f"{self.evaluator!r}")

    @property
    def evaluator_target(self) -> str:
        """The evaluator's class path: ``evaluator._target_``, else the one ``kind`` names, else the trajectory one."""
        if self.evaluator is not None:
            return str(self.evaluator["_target_"])
        return KINDS[self.kind or "trajectory"]

    @property
    def is_leaderboard(self) -> bool:
        return self.evaluator_target == KINDS["leaderboard"]


@dataclass
class EvalConfig:
    """The root of ``conf/eval.yaml`` (module doc). Units: ``init_s`` s; ``runs`` runs per method and session."""

    data: WindowDataConfig = field(default_factory=WindowDataConfig)
    experiment: ExperimentConfig = field(default_factory=ExperimentConfig)
    methods: dict | None = None
    filter: dict = field(default_factory=dict)
    attitude: dict = field(default_factory=dict)
    sessions: Any = None
    split: SplitConfig | None = None
    fixes: FixesConfig | None = None
    scoring: ScoringConfig = field(default_factory=ScoringConfig)
    floor_classifier: dict | None = None
    model_path: str | None = None
    io_model: str | None = None  # a learned inertial odometry export directory (issue 31)
    runs: int = 100
    seed: int = 0
    threads: int | None = 1
    out: str = "data/eval"
    overwrite: bool = False
    calibration: Any = "auto"
    init_s: float = 10.0
    plots: bool = True
    report: bool = True  # OUT/report.html (blenav.eval.report_html), with or without the PNG plots
    progress: bool = False
    peak_memory: str = "none"
    plan_error: PlanErrorConfig = field(default_factory=PlanErrorConfig)
    beacon_map: BeaconMapConfig = field(default_factory=BeaconMapConfig)
    bound: BoundSettings | None = None
    trainer: dict | None = None
    sim_devices: dict | None = None
    fix_sources: dict | None = None
    only: Any = None  # run only these methods (labels or config keys): one job of a fan-out over methods

    def __post_init__(self):
        if isinstance(self.sessions, (int, float)) and not isinstance(self.sessions, bool):
            self.sessions = [str(self.sessions)]  # sessions=7: one id that Hydra read as a number
        if self.sessions is not None and not isinstance(self.sessions, (str, list)):
            raise EvalError(f"sessions={self.sessions!r}: session ids, a list or comma-separated")
        if self.peak_memory is None:  # peak_memory=null: not measured, as before
            self.peak_memory = "none"
        cal = self.calibration
        if not (cal is None or isinstance(cal, str) or isinstance(cal, list)):
            raise EvalError(f"calibration={cal!r}: auto, none or a list of session ids")
        if isinstance(cal, str) and cal not in ("auto", "none"):
            raise EvalError(f"calibration={cal!r}: auto, none or a list of session ids")
        if self.peak_memory not in ("rss", "tracemalloc", "none"):
            raise EvalError(f"peak_memory must be rss, tracemalloc or none, got {self.peak_memory!r}")

    @property
    def session_ids(self) -> list[str] | None:
        """``sessions`` as a list of ids (``a,b`` or ``[a, b]``), or None: every labelled session."""
        ids = self.sessions
        if not ids:
            return None
        return [str(i) for i in (ids.split(",") if isinstance(ids, str) else ids)]

    @property
    def calibration_sessions(self) -> set[str]:
        """The sessions ``calibration`` names (not scored); empty for auto / none."""
        return {str(i) for i in self.calibration} if isinstance(self.calibration, list) else set()

    def shared(self):
        """The experiment-wide settings every localizer receives as ``shared`` (``filter``, ``attitude``): a
        DictConfig, as localizers merge it into their own schemas."""
        from omegaconf import OmegaConf

        return OmegaConf.create({"filter": self.filter or {}, "attitude": self.attitude or {}})


# ------------------------------------------------------------------------------------------ parsing
def parse_eval_config(cfg, require_data: bool = True) -> EvalConfig:
    """The composed eval config (a DictConfig, or a plain mapping) as :class:`EvalConfig`; an
    :class:`EvalConfig` is returned as it is. Every interpolation is resolved here, once; a missing dataset path,
    an unknown key or a value of the wrong type is an :class:`~blenav.errors.EvalError` naming the key.
    ``require_data=False``: a config without ``data.path`` is parsed with an empty path (to build its methods)."""
    if isinstance(cfg, EvalConfig):
        return cfg
    from omegaconf import DictConfig, OmegaConf

    no_path = False
    if isinstance(cfg, DictConfig):
        if "data" in cfg and isinstance(cfg.data, DictConfig) and OmegaConf.is_missing(cfg.data, "path"):
            if require_data:
                raise EvalError("name the dataset to evaluate on: data=DIR (a format-v1 dataset folder)")
            no_path = True
        try:
            node = OmegaConf.to_container(cfg, resolve=True)
        except Exception as exc:  # an interpolation that cannot be resolved: OmegaConf names the key
            raise EvalError(f"eval config: {str(exc).splitlines()[0]}") from exc
    else:
        node = dict(cfg)
    if no_path:
        node["data"]["path"] = ""
    if node.get("experiment") is None or not node["experiment"].get("name"):
        raise EvalError("the experiment has no name (experiment.name)")
    out = parse_node(EvalConfig, node, "")
    out.methods = select_methods(out.methods, out.only)
    for key, schema in (("filter", FilterConfig), ("attitude", AttitudeConfig)):  # checked now, used by each localizer
        parse_node(schema, getattr(out, key) or {}, key)
    return out


def select_methods(methods: dict | None, only) -> dict | None:
    """``methods`` restricted to ``only`` (labels or config keys: a list, or one name; ``A,B`` in one string for the
    command line), in their order; None: all. A name that matches no method is an EvalError listing the names. The
    methods run as they would among all the others (each method's runs depend on the seed and the session only), so
    jobs of ``-m only=A,B`` merged (``blenav merge``) give the serial run's numbers."""
    if only is None or not methods:
        return methods
    names = [str(n).strip() for n in (only.split(",") if isinstance(only, str) else only) if str(n).strip()]
    if not names:
        raise EvalError("only=: name at least one method (a label or a config key)")
    live = {k: v for k, v in methods.items() if v is not None}
    label = {k: str(v.get("label", k)) if isinstance(v, dict) else k for k, v in live.items()}
    known = set(live) | set(label.values())
    unknown = [n for n in names if n not in known]
    if unknown:
        raise EvalError(f"only={','.join(unknown)}: no such method in this experiment; its methods are "
                        f"{', '.join(label.values())} (labels) or {', '.join(live)} (keys)")
    return {k: v for k, v in live.items() if k in names or label[k] in names}


def parse_node(schema, node, path: str):
    """``node`` (a plain mapping) as the dataclass ``schema``: unknown keys fail with the nearest known key, each
    field converted by its annotation (nested dataclasses recursively; ``dict`` / ``Any`` fields kept as given)."""
    if node is None:
        node = {}
    if not isinstance(node, dict):
        raise EvalError(f"{path or 'eval config'}: a mapping of settings, got {node!r}")
    if schema is FixesConfig:
        return FixesConfig.parse(node, path)
    known = [f.name for f in fields(schema) if not f.metadata.get("derived")]
    for k in node:
        if k not in known:
            near = difflib.get_close_matches(str(k), known, n=1)
            hint = f" (did you mean {_join(path, near[0])}?)" if near else ""
            raise EvalError(f"{path or 'eval config'}: unknown key {k!r}{hint}; known: {', '.join(known)}")
    if schema in _OMEGACONF_SCHEMAS:
        return _omegaconf_node(schema, node, path)
    hints = typing.get_type_hints(schema)
    kw = {}
    for f in fields(schema):
        if f.metadata.get("derived") or f.name not in node:
            continue
        kw[f.name] = _field(hints[f.name], node[f.name], _join(path, f.name))
    if schema is SplitConfig:
        kw["given"] = dict(node)
    try:
        return schema(**kw)
    except EvalError:
        raise
    except (TypeError, ValueError) as exc:
        raise EvalError(f"{path or 'eval config'}: {exc}") from exc


def _join(path: str, key: str) -> str:
    return f"{path}.{key}" if path else key


def _omegaconf_node(schema, node: dict, path: str):
    from omegaconf import OmegaConf

    try:
        return OmegaConf.to_object(OmegaConf.merge(OmegaConf.structured(schema), node))
    except Exception as exc:  # omegaconf's errors for wrong types, or the schema's ValueError
        raise EvalError(f"{path}: {str(exc).splitlines()[0]}") from exc


def _field(tp, value, path: str):
    """``value`` converted to the annotation ``tp`` (primitives, Optional, list, dict, Any, dataclasses)."""
    origin, args = typing.get_origin(tp), typing.get_args(tp)
    if origin in (typing.Union, types.UnionType):
        inner = [a for a in args if a is not type(None)]
        if value is None:
            return None
        return _field(inner[0], value, path) if len(inner) == 1 else value
    if tp is Any or value is None and not is_dataclass(tp):
        return value
    if is_dataclass(tp):
        return parse_node(tp, value, path)
    if origin is list or tp is list:
        if not isinstance(value, (list, tuple)):
            raise EvalError(f"{path}={value!r}: a list")
        return list(value)
    if origin is dict or tp is dict:
        if not isinstance(value, dict):
            raise EvalError(f"{path}={value!r}: a mapping")
        return value
    return _convert(tp, value, path)


def _convert(tp, value, path: str):
    """A primitive: bool must be a bool; int / float / str converted as the harness did (``int(cfg.runs)``), but a
    float that is not whole is refused for an int (never truncated)."""
    if tp is bool:
        if not isinstance(value, bool):
            raise EvalError(f"{path}={value!r}: true or false")
        return value
    if tp in (int, float):
        if isinstance(value, bool) or not isinstance(value, (int, float, str)):
            raise EvalError(f"{path}={value!r}: a number")
        if tp is int and isinstance(value, float) and not value.is_integer():  # not truncated: 2.5 runs is an error
            raise EvalError(f"{path}={value!r}: a whole number")
        try:
            return tp(value)
        except (ValueError, OverflowError) as exc:
            raise EvalError(f"{path}={value!r}: a {'whole ' if tp is int else ''}number") from exc
    if tp is str:
        if isinstance(value, (dict, list)):
            raise EvalError(f"{path}={value!r}: a string")
        return str(value)
    return value

