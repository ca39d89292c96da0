"""The particle filters of 000, 002 and Roy (section 3.2) as one :class:`~blenav.localizers.base.Localizer`.

Config node (``conf/localizer/particle_filter.yaml`` gives the target)::

    _target_: blenav.localizers.ParticleFilterLocalizer
    motion: {_target_: ..., ...}            # a blenav.filters.motion.MotionModel
    measurements: {NAME: {_target_: ...}}   # blenav.filters.measurement.MeasurementModel objects
    map: {...}                              # blenav.filters.method.MapSpec
    filter: {...}                           # overrides of the experiment's filter (FilterConfig)
    attitude: {...}                         # overrides of the experiment's AHRS settings (AttitudeConfig)
    steps: {...}                            # step detector (StepDetectorConfig)
    beacons: [ID, ...]                      # BLE anchors the models may use (null: all)

``filter`` and ``attitude`` start from the experiment-wide ``filter`` / ``attitude`` nodes (``shared``);
``steps`` from :class:`~blenav.filters.steps.StepDetectorConfig`'s defaults. Every node is checked
against its schema: a misspelt key fails when the method is built, naming the method.
"""

from __future__ import annotations

from typing import Any, Callable

import pandas as pd
from omegaconf import DictConfig, OmegaConf

from blenav.filters.attitude import AttitudeConfig
from blenav.filters.calibration import apply_fit
from blenav.filters.engine import FilterConfig
from blenav.filters import map_prior
from blenav.filters.measurement import FixLikelihood, MeasurementModel
from blenav.filters.method import MapSpec, Method
from blenav.filters.runner import run_session
from blenav.filters.steps import StepDetectorConfig
from blenav.trust import UntrustedTargetError, safe_instantiate

from .base import Estimate, FixConsumer, Localizer, ModelConsumer, PathLossCalibrated
from .inputs import Fixes, RunInputs


def _schema(cls, *nodes):
    """``cls`` (a dataclass) from its defaults merged with ``nodes`` (dicts / DictConfigs / None) in order."""
    merged = OmegaConf.merge(OmegaConf.structured(cls), *[n for n in nodes if n is not None])
    return OmegaConf.to_object(merged)


def _component(node, where: str = "component", path: str = ""):
    """A component from its config node (``_target_``), or the object itself when already built. Every
    ``_target_`` of the node must be one of :data:`blenav.trust.TARGETS`, checked before anything is imported
    (a refusal names ``where`` and the key path from ``path``)."""
    if isinstance(node, (dict, DictConfig)):
        return safe_instantiate(node, where, path)
    return node


def _reason(exc: Exception) -> str:
    """The first line of what went wrong: the constructor's own error rather than hydra's wrapper."""
    while type(exc).__name__ == "InstantiationException" and exc.__cause__ is not None:
        exc = exc.__cause__
    return str(exc).splitlines()[0] if str(exc) else type(exc).__name__


def load_prior(path: str):
    """The learned map prior of the export directory ``path`` (:class:`blenav.runtime.map_prior.MapPrior`,
    onnxruntime), the loader :meth:`ParticleFilterLocalizer.attach_model` hands to
    :func:`blenav.filters.map_prior.attach_prior`; ImportError when that runtime is not installed in this tree."""
    from blenav.runtime.map_prior import MapPrior  # noqa: PLC0415 (optional: onnxruntime)

    return MapPrior(str(path))


class ParticleFilterLocalizer(Localizer, PathLossCalibrated, FixConsumer, ModelConsumer):
    """A SIR particle filter (:class:`blenav.filters.method.Method` run by
    :func:`blenav.filters.runner.run_session`): R runs batched, estimates at every filter step.

    ``outputs``: ``n_eff`` (R, K) and, when the motion model runs an AHRS, ``attitude`` (its orientation)."""

    def __init__(self, name: str, shared=None, motion: Any = None, measurements: Any = None, map: Any = None,
                 filter: Any = None, attitude: Any = None, steps: Any = None, beacons: Any = None):
        super().__init__(name, shared)
        if motion is None:
            raise ValueError(f"method {name!r}: a particle filter needs a motion model (motion: {{_target_: ...}})")
        shared = shared or {}
        def build(node: str, make):
            try:
                return make()
            except UntrustedTargetError:
                raise  # names the method and the key path already
            except Exception as exc:  # hydra/omegaconf raise many types: name the method and its node
                raise ValueError(f"method {name!r}, {node}: {_reason(exc)}") from exc

        where = f"method {name!r}"
        motion_model = build("motion", lambda: _component(motion, where, "motion"))
        if isinstance(measurements, (dict, DictConfig)):
            meas = [build(f"measurements.{k}", lambda k=k, v=v: _component(v, where, f"measurements.{k}"))
                    for k, v in measurements.items()]
        else:
            meas = [build("measurements", lambda i=i, v=v: _component(v, where, f"measurements[{i}]"))
                    for i, v in enumerate(measurements or [])]
        spec = build("map", lambda: _schema(MapSpec, map))
        fcfg = build("filter", lambda: _schema(FilterConfig, shared.get("filter"), filter))
        att = build("attitude", lambda: _schema(AttitudeConfig, shared.get("attitude"), attitude))
        step_cfg = build("steps", lambda: _schema(StepDetectorConfig, steps))
        self.method = Method(self.name, fcfg, motion_model, meas, spec, att, step_cfg,
                             beacons=None if beacons is None else tuple(str(b) for b in beacons))

    @property
    def uses_floor_plan(self) -> bool:
        """Whether the filter uses the floor plan: free space at the start (``map.init`` uniform or map),
        map conditioning, walls, or Roy's obstacle re-initialisation; the map-prior likelihood counts too."""
        spec, f = self.method.map, self.method.filter
        return (spec.init in ("uniform", "map") or spec.condition or spec.walls or f.reinit_fraction is not None
                or any(m.bind_floor.__func__ is not MeasurementModel.bind_floor for m in self.method.measurements))

    # ------------------------------------------------------------------ capabilities
    def wants_path_loss_fit(self) -> bool:
        return any(m.calibrated for m in self.method.measurements)

    def apply_path_loss_fit(self, fit) -> None:
        apply_fit(self.method.measurements, fit)

    def fix_roles(self) -> list[str]:
        """The fix roles of the filter's fix likelihoods, in the order it reads them (once each)."""
        return list(dict.fromkeys(m.role for m in self.method.measurements
                                  if isinstance(m, FixLikelihood) and m.role is not None))

    def attach_model(self, path: str | None, load: Callable[[str, Callable], Any]) -> str | None:
        # this module's loader looked up at call time (tests and other runtimes replace it)
        return map_prior.attach_prior(self.method.measurements, path, loader=lambda p: load(p, load_prior))

    # ------------------------------------------------------------------ run
    def odometry_for(self, session, inputs: RunInputs):
        """An odometry track (DataFrame t, x, y) to use in place of the session's odometry.csv, or None (use it); a
        subclass computes one (e.g. PDR odometry on phone walks, :class:`blenav.localizers.realwalk.RealWalkPF`)."""
        return None

    def use_fixes(self, fixes: Fixes | None) -> pd.DataFrame | None:
        """Point every fix likelihood that has a ``role`` at that role's fixes (its ``source``); returns the fixes to
        add to the session's fixes.csv in memory (those computed for this run, once per source), or None."""
        if fixes is None:
            return None
        extra, added = [], set()
        for m in self.method.measurements:
            if not isinstance(m, FixLikelihood) or m.role is None:
                continue
            f = fixes[m.role]  # MissingStream when the session has none
            m.source = f.source
            if f.computed and f.source not in added:
                added.add(f.source)
                extra.append(pd.DataFrame({"t": f.t, "x": f.xy[:, 0], "y": f.xy[:, 1], "std": f.std,
                                           "source": f.source}))
        return pd.concat(extra, ignore_index=True) if extra else None

    def run(self, session, n_runs: int, seed: int, inputs: RunInputs | None = None) -> Estimate:
        inputs = inputs or RunInputs()
        extra = self.use_fixes(inputs.fixes)
        return run_session(self.method, session, n_runs, seed, cache=inputs.cache, fixes=extra,
                           odometry=self.odometry_for(session, inputs))
