"""The evaluators: one class per kind of experiment, named by the experiment's ``evaluator._target_``.

=============================================================  ==============================================
``experiment.evaluator._target_`` (old ``experiment.kind``)    what it does
=============================================================  ==============================================
``blenav.eval.trajectory.TrajectoryEvaluator`` (default)       localizers on sessions, R runs each, scored
                                                               against the ground truth (:mod:`blenav.eval.harness`)
``blenav.eval.leaderboard.LeaderboardEvaluator`` (leaderboard) the same, plus the PCRLB rows, method families and
                                                               the leaderboard's figures
``blenav.eval.crossphone.CrossPhoneEvaluator`` (crossphone)    learned and baseline localizers scored per RSSI window
                                                               and phone (Roy, Tables 3.3-3.5)
=============================================================  ==============================================

Real walks (``conf/experiment/realwalks*.yaml``) are trajectory experiments: their rows are localizers
(fingerprinting, :class:`~blenav.eval.realwalks.RealWalkPF`) and their split / scoring settings are the typed
``split`` and ``scoring`` of :class:`~blenav.eval.config.EvalConfig`.

The class is built through :func:`blenav.trust.safe_instantiate`: an experiment file can name only an allow-listed
evaluator. ``run(cfg)`` takes the parsed :class:`~blenav.eval.config.EvalConfig`, writes ``cfg.out`` and returns
the :class:`~blenav.eval.result.EvalResult`.
"""

from __future__ import annotations

from blenav.errors import EvalError
from .config import EvalConfig
from .result import EvalResult

__all__ = ["Evaluator", "build_evaluator", "evaluate"]


class Evaluator:
    """One kind of experiment: :meth:`run` evaluates ``cfg`` and writes its outputs into ``cfg.out``."""

    def run(self, cfg: EvalConfig) -> EvalResult:
        raise NotImplementedError


def build_evaluator(cfg: EvalConfig) -> Evaluator:
    """The evaluator the experiment names (``experiment.evaluator``, else the one of ``experiment.kind``, else the
    trajectory evaluator), built through the allow-list of :mod:`blenav.trust`."""
    from blenav.trust import safe_instantiate

    node = dict(cfg.experiment.evaluator or {"_target_": cfg.experiment.evaluator_target})
    try:
        ev = safe_instantiate(node, f"experiment {cfg.experiment.name}", "experiment.evaluator", _recursive_=False)
    except ValueError:
        raise
    except Exception as exc:  # Hydra's wrapper around a bad argument: the constructor's own message
        cause = exc.__cause__ or exc
        raise EvalError(f"experiment.evaluator: {str(cause).splitlines()[0]}") from exc
    if not isinstance(ev, Evaluator):
        raise EvalError(f"experiment.evaluator: {node['_target_']} is not a blenav.eval.evaluators.Evaluator")
    return ev


def evaluate(cfg) -> EvalResult:
    """Run the experiment of ``cfg`` (an :class:`EvalConfig`, or the composed DictConfig, parsed here) with its
    evaluator; returns the result (its outputs are in ``cfg.out``)."""
    from .config import parse_eval_config

    cfg = parse_eval_config(cfg)
    return build_evaluator(cfg).run(cfg)
