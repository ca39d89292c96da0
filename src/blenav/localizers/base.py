"""The one interface every localization method implements; the result every method returns is
:class:`blenav.filters.estimate.Estimate` (the particle filter's runners return it too).

A :class:`Localizer` is built from its config node (``_target_`` plus its settings, see
:func:`build_localizer`) and run on one session at a time::

    est = localizer.run(session, n_runs, seed, inputs)   # -> Estimate

The evaluation harness knows nothing else about a method: it scores ``est.position`` against the
session's ground truth, counts ``est.events``, and writes ``est.outputs`` where they are documented.
Methods that need something from the evaluation declare it by deriving from a capability class:

* :class:`PathLossCalibrated`: path-loss parameters fitted on labelled data (``calibration=``);
* :class:`FixConsumer`: position fixes of named roles (``dense``, ``sparse``) from the experiment's
  ``fixes`` block, resolved for the session before the run and handed over as arrays in ``inputs.fixes``
  (:class:`~blenav.localizers.inputs.Fixes`): a localizer never calls back into the evaluation;
* :class:`ModelConsumer`: a trained model given by path (``model_path``);
* :class:`InertialModelConsumer`: a learned inertial odometry given by path (``io_model``);
* :class:`Trained`: a method that learns from the dataset's own labelled train sessions (fingerprinting:
  KNN, LocNet on WiFi/BLE scans) before it is run on the scored ones (the experiment's ``split``);
* :class:`Transductive`: a method (or the localizer of a fix role) that reads another row's estimates on the scored
  sessions, never their ground truth, before it runs (the crowd-sourced survey, :mod:`blenav.localizers.crowd`).

A method that cannot run on a session (a stream it needs is absent, a model was not given) raises
:class:`~blenav.errors.MissingStream` with the reason; the harness then lists the session under
the method's ``skipped``. Bad settings or data raise ``ValueError``.
"""

from __future__ import annotations

from typing import Any, Callable

from blenav.filters.estimate import Estimate

from .inputs import Fixes, RoleFixes, RunInputs

__all__ = ["Estimate", "RunInputs", "Fixes", "RoleFixes", "Localizer", "PathLossCalibrated",
           "FixConsumer", "ModelConsumer", "InertialModelConsumer", "Trained", "Transductive", "batch_settings",
           "build_localizer", "attach_inertial", "NO_IO_MODEL"]

class Localizer:
    """Base of every localization method: a name, and ``run``.

    Constructors take ``name`` (the label in results) and ``shared`` (the experiment-wide settings node:
    ``filter``, ``attitude``, which a method may use as its defaults and is free to ignore), then the
    method's own settings from its config node."""

    #: whether the method uses the floor plan (free space, walls); a map-free method's estimates are not
    #: moved into free space by the evaluation (see :mod:`blenav.localizers.confine`)
    uses_floor_plan: bool = True
    #: whether the method's covariance is a stated uncertainty of its own fixes (fingerprints), scored by the
    #: evaluation as ``fix_coverage`` {"own": ...}: the share of waypoints inside its 1-sigma / 2-sigma regions
    states_fix_std: bool = False

    def __init__(self, name: str, shared=None):
        self.name = str(name)

    def run(self, session, n_runs: int, seed: int, inputs: RunInputs | None = None) -> Estimate:
        """All ``n_runs`` runs on ``session``, seeded by ``seed`` (a method without randomness returns R
        identical runs); ``inputs``: what the run gives it besides the session (:class:`RunInputs`)."""
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
    """A method that weighs position fixes of named roles of the experiment's ``fixes`` block; its run finds them in
    ``inputs.fixes[role]`` (:class:`~blenav.localizers.inputs.RoleFixes`). ``fix_roles_are_alternatives``: the
    roles are alternatives (the run gets the first one the session has), not all needed."""

    fix_roles_are_alternatives: bool = False

    def fix_roles(self) -> list[str]:
        """The roles, in the order the method reads them (the first that a session lacks is the reason it is
        skipped there)."""
        raise NotImplementedError


class ModelConsumer:
    """A method that uses a trained model given by path (``model_path=``)."""

    def attach_model(self, path: str | None, load: Callable[[str, Callable], Any]) -> str | None:
        """Attach the model of ``path``; returns why the method cannot run (no path, no runtime), or None.

        ``load(path, loader)``: the evaluation's shared loader, so that methods of one experiment load the
        same file once (``loader(path)`` does the actual loading)."""
        raise NotImplementedError


class InertialModelConsumer:
    """A method that can run on a learned inertial odometry given by path (``io_model=``, an export directory of
    ``python export.py`` on a run of ``train.py experiment=inertial``)."""

    def attach_io_model(self, path: str | None, load: Callable[[str, Callable], Any]) -> str | None:
        """Attach the inertial odometry of ``path`` (None: none given); returns why the method cannot run, or None.
        ``load(path, loader)``: the evaluation's shared loader (:meth:`ModelConsumer.attach_model`)."""
        raise NotImplementedError


NO_IO_MODEL = ("no learned inertial odometry was given: pass io_model=IO_DIR (python export.py ckpt=RUN/last.ckpt "
               "out=IO_DIR on a run of train.py experiment=inertial)")


def load_inertial_model(path: str):
    """The inertial odometry export directory ``path`` in onnxruntime (:class:`blenav.runtime.inertial.InertialModel`)."""
    from blenav.runtime.inertial import InertialModel  # noqa: PLC0415 (optional: onnxruntime)

    return InertialModel(str(path))


def attach_inertial(path: str | None, load) -> tuple[object | None, str | None]:
    """(model, None) of ``io_model`` ``path`` through the evaluation's shared ``load``, or (None, why not)."""
    if not path:
        return None, NO_IO_MODEL
    try:
        return load(path, load_inertial_model), None
    except (OSError, ValueError, ImportError) as exc:
        return None, f"io_model={path} cannot be used: {exc}"


class Transductive:
    """A method, or the localizer of a fix role, that reads the estimates another row made on the scored sessions
    (never their ground truth) before it runs: :attr:`batch_labels` is that row's label. The evaluation calls
    :meth:`prepare_batch` once, after that row ran on every scored session and before anything reads this one."""

    batch_labels: str = ""

    def prepare_batch(self, sessions: list, estimates: dict, inputs: RunInputs | None = None) -> dict | None:
        """Take the labels row's ``estimates`` (session id -> :class:`Estimate`) of the scored ``sessions``; returns
        a report (or None)."""
        raise NotImplementedError


def batch_settings(name: str, key: str, node: Any, allowed: set[str], example: str) -> tuple[dict, str]:
    """A :class:`Transductive` method's settings node ``key`` checked: its keys among ``allowed`` and ``labels``,
    ``labels`` given (the row it reads, ``example`` in the message). Returns (the node as a dict, labels)."""
    node = dict(node or {})
    takes = set(allowed) | {"labels"}
    unknown = set(node) - takes
    if unknown:
        raise ValueError(f"method {name!r}: {key} has keys {sorted(unknown)}; it takes {', '.join(sorted(takes))}")
    labels = str(node.get("labels") or "")
    if not labels:
        raise ValueError(f"method {name!r}: {key}.labels must name the row whose estimates of the scored walks it "
                         f"reads, run before it (e.g. {example})")
    return node, labels


class Trained:
    """A method that is trained on labelled sessions of the dataset it is evaluated on (the train walks of
    the experiment's ``split``), before it runs on the scored (test) sessions."""

    def fit(self, sessions: list, inputs: RunInputs) -> dict | None:
        """Train on ``sessions`` (labelled; a session whose ground truth is sparse waypoints,
        ``session.groundtruth_sparse``, gives labels only at or between its waypoints, and the method says how it
        used them). Returns a JSON-able report for ``methods.NAME.training`` in results.json, or None.
        Raises :class:`MissingStream` when the train sessions lack what the method needs."""
        raise NotImplementedError


def build_localizer(label: str, node, shared=None) -> Localizer:
    """The localizer of config ``node`` (``_target_`` plus its settings; ``label`` is not passed on).

    Nested nodes are handed over unconverted (``_recursive_=False``): a localizer builds its own
    components, so a misspelt key fails inside the method that owns it, with its name. Every ``_target_`` of
    the node, at any depth, must be one of blenav's classes (:func:`blenav.trust.check_targets`, before
    anything is imported): the node may come from a file or the command line."""
    from hydra.errors import InstantiationException
    from omegaconf import DictConfig, OmegaConf

    from blenav.trust import safe_instantiate

    kw = OmegaConf.to_container(node, resolve=True) if isinstance(node, DictConfig) else dict(node)
    kw.pop("label", None)
    target = kw.get("_target_")
    if not target:
        raise ValueError(f"method {label!r} has no _target_ (the class of its localizer, e.g. "
                         f"blenav.localizers.ParticleFilterLocalizer: see conf/localizer/)")
    try:
        loc = safe_instantiate(OmegaConf.create(kw), f"method {label!r}", f"methods.{label}", name=label,
                               shared=shared, _recursive_=False)
    except InstantiationException as exc:  # hydra wraps the constructor's own error: keep only that
        cause = exc.__cause__
        raise ValueError(str(cause) if cause is not None else f"method {label!r}: {exc}") from exc
    if not isinstance(loc, Localizer):
        raise ValueError(f"method {label!r}: {target} is not a blenav.localizers.Localizer")
    return loc
