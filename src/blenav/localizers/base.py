"""The one interface every localization method implements, and the result every method returns.

A :class:`Localizer` is built from its config node (``_target_`` plus its settings, see
:func:`build_localizer`) and run on one session at a time::

    est = localizer.run(session, n_runs, seed, ctx)   # -> Estimate

The evaluation harness knows nothing else about a method: it scores ``est.position`` against the
session's ground truth, counts ``est.events``, and writes ``est.outputs`` where they are documented.
Methods that need something from the evaluation declare it by deriving from a capability class:

* :class:`PathLossCalibrated`: path-loss parameters fitted on labelled data (``calibration=``);
* :class:`FixConsumer`: position fixes of named roles (``dense``, ``sparse``) from the experiment's
  ``fixes`` block, handed over in ``ctx.fixes``;
* :class:`ModelConsumer`: a trained model given by path (``model_path``);
* :class:`Trained`: a method that learns from the dataset's own labelled train sessions (fingerprinting:
  KNN, LocNet on WiFi/BLE scans) before it is run on the scored ones (the experiment's ``split``).

A method that cannot run on a session (a stream it needs is absent, a model was not given) raises
:class:`~blenav.errors.MissingStream` with the reason; the harness then lists the session under
the method's ``skipped``. Bad settings or data raise ``ValueError``.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable

import numpy as np

from blenav.errors import MissingStream
from blenav.filters.engine import Event

__all__ = ["Estimate", "RunContext", "Localizer", "PathLossCalibrated", "FixConsumer", "ModelConsumer",
           "Trained", "build_localizer", "OUTPUT_KEYS"]

#: The documented keys of :attr:`Estimate.outputs` (a method may add others; these are the ones the
#: harness and the plots read).
OUTPUT_KEYS = {
    "n_eff": "(R, K) effective sample size per run and step (particle filters)",
    "attitude": "{'t': (T,) s, 'q': (T, 4) w, x, y, z}: the AHRS orientation, device to world (for "
                "orientation RMSE against the ground truth)",
    "beacon_map": "DataFrame anchor_id, x, y, z, std_m: beacon positions a method estimated",
    "smoothed": "(R, K, 2) world m: a smoothed trajectory at the same times as position",
    "probability": "per-step probability maps over a grid (method-specific layout, documented by the method)",
}


@dataclass
class Estimate:
    """R runs of one localizer on one session.

    t (K,) s; position (R, K, 2) world m; cov (R, K, 2, 2) m^2 or None when the method gives no
    uncertainty; events: per-run events (``Event.run`` is the run index: recoveries, re-initialisations);
    outputs: method-specific results under the keys of :data:`OUTPUT_KEYS`; wall_s: the method's
    wall-clock time on this session, all runs; notes: remarks for the report (e.g. what a map was derived
    from).
    """

    method: str
    session: str
    t: np.ndarray
    position: np.ndarray
    cov: np.ndarray | None = None
    events: list[Event] = field(default_factory=list)
    outputs: dict[str, Any] = field(default_factory=dict)
    wall_s: float = 0.0
    notes: list[str] = field(default_factory=list)

    def __post_init__(self):
        self.t = np.asarray(self.t, float)
        self.position = np.asarray(self.position, float)
        if self.position.ndim != 3 or self.position.shape[1:] != (len(self.t), 2):
            raise ValueError(f"{self.method} on {self.session}: position must be (R, K, 2) with K = len(t) = "
                             f"{len(self.t)}, got {self.position.shape}")
        if self.cov is not None and self.cov.shape != self.position.shape + (2,):
            raise ValueError(f"{self.method} on {self.session}: cov must be (R, K, 2, 2), got {self.cov.shape}")

    @property
    def n_runs(self) -> int:
        return int(self.position.shape[0])

    @property
    def std(self) -> np.ndarray | None:
        """(R, K) m: sqrt of the covariance's trace / 2 (the mean per-axis standard deviation), or None."""
        if self.cov is None:
            return None
        return np.sqrt(np.maximum(np.trace(self.cov, axis1=-2, axis2=-1), 0.0) / 2.0)


@dataclass
class RunContext:
    """What the evaluation shares with every method of one experiment.

    ``cache``: a dict shared by all methods on the same sessions (per-floor map geometry, per-session AHRS;
    keys are the methods' own); ``fixes``: the experiment's fix provider (:class:`blenav.eval.fixes.FixProvider`)
    or None; ``out``: the evaluation's output folder (None outside an evaluation)."""

    cache: dict = field(default_factory=dict)
    fixes: Any = None
    out: Path | None = None


class Localizer:
    """Base of every localization method: a name, and ``run``.

    Constructors take ``name`` (the label in results) and ``shared`` (the experiment-wide settings node:
    ``filter``, ``attitude``, which a method may use as its defaults and is free to ignore), then the
    method's own settings from its config node."""

    #: whether the method uses the floor plan (free space, walls); a map-free method's estimates are not
    #: moved into free space by the evaluation (see :mod:`blenav.localizers.confine`)
    uses_floor_plan: bool = True

    def __init__(self, name: str, shared=None):
        self.name = str(name)

    def run(self, session, n_runs: int, seed: int, ctx: RunContext | None = None) -> Estimate:
        """All ``n_runs`` runs on ``session``, seeded by ``seed`` (a method without randomness returns R
        identical runs)."""
        raise NotImplementedError

    def __repr__(self) -> str:
        return f"{type(self).__name__}({self.name!r})"


class PathLossCalibrated:
    """A method with path-loss models that want parameters fitted on labelled data."""

    def wants_path_loss_fit(self) -> bool:
        raise NotImplementedError

    def apply_path_loss_fit(self, fit) -> None:
        """Use ``fit`` (:class:`blenav.filters.calibration.PathLossFit`) in the models that asked for it."""
        raise NotImplementedError


class FixConsumer:
    """A method that weighs position fixes of named roles of the experiment's ``fixes`` block."""

    def fix_roles(self) -> set[str]:
        raise NotImplementedError


class ModelConsumer:
    """A method that uses a trained model given by path (``model_path=``)."""

    def attach_model(self, path: str | None, load: Callable[[str, Callable], Any]) -> str | None:
        """Attach the model of ``path``; returns why the method cannot run (no path, no runtime), or None.

        ``load(path, loader)``: the evaluation's shared loader, so that methods of one experiment load the
        same file once (``loader(path)`` does the actual loading)."""
        raise NotImplementedError


class Trained:
    """A method that is trained on labelled sessions of the dataset it is evaluated on (the train walks of
    the experiment's ``split``), before it runs on the scored (test) sessions."""

    def fit(self, sessions: list, ctx: RunContext) -> dict | None:
        """Train on ``sessions`` (labelled; a session whose ground truth is sparse waypoints,
        ``session.groundtruth_sparse``, gives labels only at or between its waypoints, and the method says how it
        used them). Returns a JSON-able report for ``methods.NAME.training`` in results.json, or None.
        Raises :class:`MissingStream` when the train sessions lack what the method needs."""
        raise NotImplementedError


def build_localizer(label: str, node, shared=None) -> Localizer:
    """The localizer of config ``node`` (``_target_`` plus its settings; ``label`` is not passed on).

    Nested nodes are handed over unconverted (``_recursive_=False``): a localizer builds its own
    components, so a misspelt key fails inside the method that owns it, with its name."""
    from hydra.errors import InstantiationException
    from hydra.utils import instantiate
    from omegaconf import DictConfig, OmegaConf

    kw = OmegaConf.to_container(node, resolve=True) if isinstance(node, DictConfig) else dict(node)
    kw.pop("label", None)
    target = kw.get("_target_")
    if not target:
        raise ValueError(f"method {label!r} has no _target_ (the class of its localizer, e.g. "
                         f"blenav.localizers.ParticleFilterLocalizer: see conf/localizer/)")
    try:
        loc = instantiate(OmegaConf.create(kw), name=label, shared=shared, _recursive_=False)
    except InstantiationException as exc:  # hydra wraps the constructor's own error: keep only that
        cause = exc.__cause__
        raise ValueError(str(cause) if cause is not None else f"method {label!r}: {exc}") from exc
    if not isinstance(loc, Localizer):
        raise ValueError(f"method {label!r}: {target} is not a blenav.localizers.Localizer")
    return loc
