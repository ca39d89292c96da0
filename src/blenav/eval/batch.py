"""Methods that read other rows' estimates on the scored walks (:class:`~blenav.localizers.base.Transductive`: the
crowd-sourced survey of :mod:`blenav.localizers.crowd`): prepared once, in the order the rows run, before the first
method that needs them (:class:`blenav.eval.trajectory.TrajectoryEvaluator`). Only estimates pass: a scored walk's
ground truth never reaches them."""

from __future__ import annotations

from blenav.errors import EvalError
from blenav.localizers import FixConsumer, Localizer, Transductive
from blenav.localizers.inputs import RunInputs

from .fixes import FixProvider

__all__ = ["transductive_of", "prepare_transductive"]


def transductive_of(method: Localizer, fixes: FixProvider | None) -> list[Transductive]:
    """What must be prepared before ``method`` runs (:class:`Transductive`): the method itself, and the localizers of
    the fix roles it reads."""
    objs = [method] if isinstance(method, Transductive) else []
    if fixes is not None and isinstance(method, FixConsumer):
        objs += [loc for r in method.fix_roles() if isinstance(loc := fixes.localizers.get(r), Transductive)]
    return objs


def prepare_transductive(name: str, method: Localizer, fixes: FixProvider | None, outcomes: dict, sessions: list,
                         inputs: RunInputs, prepared: dict, ran: set | frozenset = frozenset()) -> None:
    """Prepare (once) every :class:`Transductive` that ``method`` needs with its labels row's estimates on the scored
    ``sessions`` (``outcomes``: the rows run so far with a result, by label; ``ran``: every row run so far, those
    skipped on every session too, whose estimates are then none); ``prepared``: id -> report, filled in. EvalError
    when the labels row has not run before ``name``."""
    for obj in transductive_of(method, fixes):
        if id(obj) in prepared:
            continue
        src = obj.batch_labels
        if src in ran and src not in outcomes:  # run, but skipped on every session: nothing to read
            prepared[id(obj)] = obj.prepare_batch(sessions, {}, inputs)
            continue
        if src not in outcomes:
            raise EvalError(f"method {name}: {obj.name} reads the estimates of row {src!r} on the scored walks "
                            f"(its labels setting), which has not run before it: keep {src!r} in only= and before "
                            f"{name!r} in methods")
        try:
            prepared[id(obj)] = obj.prepare_batch(sessions, outcomes[src].results, inputs)
        except ValueError as exc:
            raise EvalError(f"method {name}, preparing {obj.name}: {exc}") from exc
