"""A bundle's settings.json: its defaults, the checks it passes before anything is built, and the filter method it
builds.

The pipeline (Roy, section 3.2): per filter step (``filter.rate_hz``) a particle filter with the odometry increment
motion model (eq. 3.7), weighted by the localizer's BLE fix (eq. 3.9, N(||x - z||; 0, sigma)) and, when the bundle
has one, by the learned map prior's score (eq. 3.8). Settings that name a class other than blenav's
(:data:`blenav.trust.TARGETS`; the motion model one of :data:`MOTION_TARGETS`) are refused by name before any import,
and every size they set is bounded (:data:`blenav.limits.RANGES`).
"""

from __future__ import annotations

import importlib
import math
import numbers
from dataclasses import fields

from blenav.limits import LimitError, check_range
from blenav.trust import TARGETS, UntrustedTargetError, check_targets

from .format import FIX_SOURCE, SETTINGS

#: the pipeline of Roy's Table 3.7 (sparse-BLE+IO+map) as a live app runs it: no ground truth, heading from the fixes
DEFAULT_SETTINGS = {
    "filter": {"n_particles": 1000, "rate_hz": 1.0, "resampling": "low_variance", "ess_threshold": 1.0,
               "estimate": "median", "divergence_sigma": float("inf"), "reinit_fraction": 0.9, "reinit_radius_m": 5.0},
    "motion": {"_target_": "blenav.filters.motion.OdometryIncrement", "sigma2_per_s": 0.1, "sigma_theta": 0.01},
    "fix": {"sigma_m": 3.0},
    "prior": {"heading_bins": 36, "window_dt_s": None},
    "map": {"init": "fix", "heading": "motion", "init_sigma_m": 0.01},
    "attitude": {},
    "steps": {},
}

#: the motion models a bundle's settings may name (``motion._target_``): blenav's, by their dotted names
MOTION_TARGETS = frozenset(t for t in TARGETS if t.startswith("blenav.filters.motion."))


def check_targets_of(settings: dict, where: str) -> None:
    """A bundle's settings name no class but blenav's (:func:`blenav.trust.check_targets`), and ``motion._target_``
    one of :data:`MOTION_TARGETS`: a one-line :class:`blenav.trust.UntrustedTargetError` naming ``where`` (the
    settings file) and the field, before anything is imported."""
    motion = settings.get("motion") if isinstance(settings, dict) else None
    if not isinstance(motion, dict):
        raise ValueError(f"{where}: motion must be an object with a _target_ (a motion model), got "
                         f"{type(motion).__name__}")
    target = motion.get("_target_")
    if not isinstance(target, str) or target not in MOTION_TARGETS:
        raise UntrustedTargetError(f"{where}: motion._target_ = {str(target)[:120]!r} is not one of blenav's motion "
                                   f"models ({', '.join(sorted(MOTION_TARGETS))})")
    check_targets(settings, where)


def _motion_class(node: dict, where: str = SETTINGS):
    """The class ``node['_target_']`` names (one of :data:`MOTION_TARGETS`, checked by name before it is imported)."""
    check_targets_of({"motion": node}, where)
    mod, _, name = str(node["_target_"]).rpartition(".")
    return getattr(importlib.import_module(mod), name)


def motion_needs(node: dict, where: str = SETTINGS) -> tuple[str, ...]:
    """The streams the motion model of ``node`` (a settings' ``motion``) reads, its class's ``needs`` (``odo``,
    ``imu``, ...): the class is imported, not built."""
    return tuple(getattr(_motion_class(node, where), "needs", ()))


def _instantiate(node: dict, where: str = SETTINGS):
    """An object of ``node['_target_']`` (one of :data:`MOTION_TARGETS`, checked by name before anything is
    imported: :func:`check_targets_of`) with the other keys as arguments; ``where``: the settings file, named in a
    refusal (ValueError also for arguments the class does not take)."""
    cls = _motion_class(node, where)
    node = dict(node)
    name = node.pop("_target_").rpartition(".")[2]
    try:
        return cls(**node)
    except TypeError as exc:  # an argument the class does not take
        raise ValueError(f"{where}: motion ({name}): {exc}") from None


def _dataclass(cls, node: dict | None, where: str):
    node = dict(node or {})
    known = {f.name for f in fields(cls)}
    unknown = sorted(set(node) - known)
    if unknown:
        raise ValueError(f"bundle settings: {where} has unknown key(s) {unknown} (known: {sorted(known)})")
    return cls(**node)


#: fields of a bundle's settings that are not numbers (enums, the motion model's name)
_TEXT_FIELDS = frozenset({"filter.resampling", "filter.estimate", "map.init", "map.heading", "motion._target_"})
#: numbers that may be negative (an angle, a log-weight) / infinite (a check that is off)
_SIGNED = frozenset({"motion.theta0", "filter.wall_log_penalty"})
_INFINITE = frozenset({"filter.divergence_sigma", "filter.wall_log_penalty", "filter.patience_s",
                       "filter.global_after_s"})


def _not_numbers() -> frozenset[str]:
    """Fields of the filter, map and fix nodes whose type is not a number (bool flags, names, enums), from the
    classes they build (annotations are strings here: ``from __future__ import annotations``)."""
    from blenav.filters.engine import FilterConfig
    from blenav.filters.measurement import FixLikelihood
    from blenav.filters.method import MapSpec

    return frozenset(f"{node}.{f.name}" for node, cls in (("filter", FilterConfig), ("map", MapSpec),
                                                          ("fix", FixLikelihood))
                     for f in fields(cls) if not any(t in str(f.type) for t in ("float", "int")))


def _check_numbers(settings: dict, where: str) -> None:
    """Every other scalar of the ``filter``, ``fix``, ``map`` and ``motion`` nodes (noise scales, radii, fractions)
    is a number, not NaN, not negative and finite (but :data:`_SIGNED` / :data:`_INFINITE`); ``null`` keeps the
    default. Else :class:`LimitError` naming ``where`` and the field: a string or a NaN there would otherwise end
    as numpy's own message deep in the filter, or as a NaN track."""
    skip = _TEXT_FIELDS | _not_numbers() | {"filter.n_particles"}  # n_particles: check_range's, in check_settings
    for node in ("filter", "fix", "map", "motion"):
        values = settings.get(node)
        if not isinstance(values, dict):
            continue
        for key, v in values.items():
            field = f"{node}.{key}"
            if field in skip or v is None or isinstance(v, (dict, list)):
                continue  # nested nodes: check_targets_of names a class in them; the constructor refuses the rest
            if not isinstance(v, numbers.Real) or isinstance(v, bool) or math.isnan(v):
                raise LimitError(f"{where}: {field} = {v!r} is not a number")
            if v < 0 and field not in _SIGNED:
                raise LimitError(f"{where}: {field} = {v!r} is negative")
            if math.isinf(v) and field not in _INFINITE:
                raise LimitError(f"{where}: {field} = {v!r} is infinite")


def check_settings(settings: dict, where: str) -> None:
    """Every size the settings set lies in its documented range (:data:`blenav.limits.RANGES`), and the particle
    filter they ask for fits the memory limit (one run, as the push API runs it), before anything is built:
    :class:`blenav.limits.LimitError` naming ``where`` (the settings.json) and the field."""
    from blenav.filters.engine import FilterConfig, check_size

    if not isinstance(settings, dict):
        raise LimitError(f"{where}: expected a JSON object, got {type(settings).__name__}")
    f = settings.get("filter") if isinstance(settings.get("filter"), dict) else {}
    if "rate_hz" in f:
        check_range(f["rate_hz"], "rate_hz", where, field="filter.rate_hz")
    n = f.get("n_particles", FilterConfig.n_particles)
    check_range(n, "n_particles", where, field="filter.n_particles")
    prior = settings.get("prior") if isinstance(settings.get("prior"), dict) else {}
    if prior.get("heading_bins") is not None:
        check_range(prior["heading_bins"], "heading_bins", where, field="prior.heading_bins")
    if prior.get("window_dt_s") is not None:
        check_range(prior["window_dt_s"], "window_s", where, field="prior.window_dt_s")
    _check_numbers(settings, where)
    try:
        dim = int(_instantiate(settings["motion"]).state_dim)
    except Exception:  # a bad motion node is refused where the method is built, with its own message
        return
    check_size(1, n, dim, where, field="filter.n_particles")


def build_method(settings: dict, prior=None, where: str = SETTINGS):
    """The :class:`blenav.filters.method.Method` of a bundle's settings; ``prior``: a map prior (or None);
    ``where``: the settings file, named in errors. Every ``_target_`` of the settings must be blenav's
    (:func:`blenav.trust.check_targets`), the motion model's one of :data:`MOTION_TARGETS`."""
    from blenav.filters.attitude import AttitudeConfig
    from blenav.filters.engine import EstimateMode, FilterConfig, Resampling
    from blenav.filters.map_prior import MapPriorLikelihood
    from blenav.filters.measurement import FixLikelihood
    from blenav.filters.method import HeadingMode, InitMode, MapSpec, Method
    from blenav.filters.steps import StepDetectorConfig

    check_targets_of(settings, where)
    f = _dataclass(FilterConfig, settings.get("filter"), "filter")
    f.resampling, f.estimate = Resampling(f.resampling), EstimateMode(f.estimate)
    f.divergence_sigma = float(f.divergence_sigma)
    spec = _dataclass(MapSpec, settings.get("map"), "map")
    spec.init, spec.heading = InitMode(spec.init), HeadingMode(spec.heading)
    meas = [FixLikelihood(source=FIX_SOURCE, **dict(settings.get("fix") or {}))]
    if prior is not None and settings.get("prior") is not None:
        meas.append(MapPriorLikelihood(prior=prior, **dict(settings["prior"])))
    return Method("bundle", f, _instantiate(settings.get("motion"), where), meas, spec,
                  _dataclass(AttitudeConfig, settings.get("attitude"), "attitude"),
                  _dataclass(StepDetectorConfig, settings.get("steps"), "steps"))
