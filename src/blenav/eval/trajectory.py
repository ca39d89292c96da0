"""The trajectory evaluator: every method of an experiment on every selected labelled session, R runs each, scored
against the ground truth -- the default kind of experiment (:mod:`blenav.eval.evaluators`).

The steps are the functions of :mod:`blenav.eval.harness` (whose module doc gives the results.json schema): build
the methods, select the sessions, attach models, fixes and calibration, train what learns from the dataset, run and
score, aggregate into :class:`~blenav.eval.result.TrajectoryResult`, write. :meth:`TrajectoryEvaluator.finish` is
the hook a kind adds its rows with (the leaderboard's bounds, :class:`blenav.eval.leaderboard.LeaderboardEvaluator`).
"""

from __future__ import annotations

from dataclasses import asdict
from pathlib import Path

from blenav.data import Dataset
from blenav.errors import EvalError
from blenav.limits import LimitError, check_range
from blenav.localizers.inputs import RunInputs

from . import batch as B
from . import beacon_map as BM
from . import harness as H
from . import sessions as S
from .common import check_output_names
from .config import EvalConfig
from .evaluators import Evaluator
from .memory import PeakMemory
from .result import TrajectoryResult

__all__ = ["TrajectoryEvaluator"]


class TrajectoryEvaluator(Evaluator):
    """Localizers on sessions (module doc). Sessions: ``cfg.sessions`` or every labelled session that is not a static
    survey (surveys calibrate the path-loss model) nor named by ``calibration``; a dataset of surveys only is evaluated
    on its surveys."""

    def run(self, cfg: EvalConfig) -> TrajectoryResult:
        ds = S.open_dataset(cfg)
        methods = H.build_methods(cfg)
        check_output_names(methods, "method")  # OUT/<session>/trajectories/<method>.tum: one file per method
        model_info = H.attach_models(methods, cfg.model_path or None, cfg.io_model or None)
        selected = S.scored_sessions(cfg, ds)
        try:  # bounded before any work (blenav.limits: 1..100,000; runs x particles: the filter's memory check)
            runs = check_range(cfg.runs, "runs", "eval config")
        except LimitError as exc:
            raise EvalError(str(exc)) from None
        out = Path(cfg.out)
        plan_info = None
        if cfg.plan_error.active:  # every method gets the wrong plans; scored against the true ground truth
            selected, plan_info = S.with_wrong_plans(selected, cfg.plan_error, out / "plans")
        train, test = S.train_test(cfg, ds, selected)
        check_output_names([s.id for s in train + test], "session")  # OUT/<session>/, OUT/fixes/<session>/
        sessions, bmap_info = BM.with_source(test, cfg.beacon_map)  # the scored sessions, with the beacon map given
        provider = H.build_fix_provider(cfg, methods, out)
        own = {k: m for k, m in (provider.methods if provider else {}).items()
               if all(m is not x for x in methods.values())}
        every = {**methods, **own}  # the fix localizers are calibrated and trained too (a row's own one: once)
        calibration = H.calibrate(every, ds, sessions, cfg.calibration)
        out.mkdir(parents=True, exist_ok=True)
        inputs = RunInputs(cache={}, out=out)  # map geometry per floor, AHRS per session: shared
        training = H.fit_trained(every, train, inputs) if train else {}
        res = TrajectoryResult(cfg.experiment.name, cfg.experiment.title, str(ds.root), runs, [s.id for s in sessions],
                               cfg.seed, init_s=cfg.init_s, calibration=calibration, model=model_info)
        if plan_info is not None:
            res.plan_error = {**asdict(cfg.plan_error), "buildings": plan_info}
        bmap = cfg.beacon_map
        if bmap.source != "given" or bmap.perturbed:
            res.beacon_map = {**asdict(bmap), "buildings": bmap_info}
        if train:
            res.split = {**cfg.split.given, "train": [s.id for s in train]}
        res.floor_accuracy = S.floor_accuracy_of(cfg, train, sessions)
        # every stream and floor plan read before the first method: no method's memory counts them
        res.dropped = H.dropped_rows(sessions)
        outcomes: dict[str, H.MethodOutcome] = {}
        prepared: dict[int, dict | None] = {}  # the transductive localizers prepared so far (blenav.eval.batch)
        with H.Progress(cfg.progress, len(methods) * len(sessions)) as progress:
            for name, method in methods.items():
                B.prepare_transductive(name, method, provider, outcomes, sessions, inputs, prepared, set(res.methods))
                with PeakMemory(cfg.peak_memory) as mem:  # rss | tracemalloc | none
                    oc = H.run_method(name, method, sessions, runs, cfg.seed, cfg.init_s, inputs, progress, bmap,
                                      hold_ends=cfg.scoring.hold_ends, fixes=provider)
                m = res.methods[name] = H.aggregate(oc, runs)
                if mem.result() is not None and oc.metrics:
                    m.peak_memory = mem.result()
                m.training = training.get(name)
                if oc.metrics:
                    outcomes[name] = oc
        key_of = {id(m): k for k, m in every.items()}  # every role under its own source, shared localizers too
        for oid, info in prepared.items():  # what each crowd was built from, beside its training report
            if info is not None and isinstance(training.get(key_of.get(oid)), dict):
                training[key_of[oid]]["crowd"] = info
        if provider is not None:
            res.fixes = provider.describe()
            fix_training = {provider.computed_source(r): training[key_of[id(m)]]
                            for r, m in provider.localizers.items() if training.get(key_of.get(id(m))) is not None}
            if fix_training:
                res.fixes["training"] = fix_training
        extra = self.finish(res, ds, sessions, cfg)
        H.write_outputs(out, res, outcomes, sessions, cfg, self.figures(extra))
        return res

    def finish(self, res: TrajectoryResult, ds: Dataset, sessions: list, cfg: EvalConfig):
        """Add a kind's own rows to ``res`` after the methods ran; returns what its figures need (None: none)."""
        return None

    def figures(self, extra):
        """The kind's own figures, ``f(out, res, outcomes, sessions, grid, cdfs)`` drawn after the error CDFs
        (:func:`blenav.eval.harness.write_outputs`), from what :meth:`finish` returned; None: none."""
        return None
