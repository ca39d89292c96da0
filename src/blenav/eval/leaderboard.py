"""The leaderboard experiment (``experiment.evaluator._target_: blenav.eval.leaderboard.LeaderboardEvaluator``, old
spelling ``experiment.kind: leaderboard``; conf/experiment/leaderboard.yaml).

:class:`LeaderboardEvaluator` runs the methods as the trajectory evaluator does, each inside
:class:`~blenav.eval.memory.PeakMemory` (``peak_memory``), then adds what the leaderboard shows:

- :meth:`LeaderboardEvaluator.finish`: the ``PCRLB`` rows (:mod:`blenav.eval.pcrlb`, ``kind: bound``, on simulated
  data; skipped with the reason elsewhere) and every method's ``family``.
- :func:`plot`: the leaderboard CDF (one colour per family, from the CDFs the harness draws error_cdf.png
  with), the bound over time and the best method per family.
- results.md: :func:`blenav.eval.report.write_markdown` (one table sorted by RMSE, the skipped methods with
  their reasons, how far the best method is from the bound, and the notes every experiment prints).
"""

from __future__ import annotations

import logging
from dataclasses import replace
from pathlib import Path

import numpy as np

from .metrics import best_against_bound
from .pcrlb import BoundSettings, bound_entries
from .result import BoundStats, MethodResult, TrajectoryResult
from .trajectory import TrajectoryEvaluator

log = logging.getLogger("blenav.eval")


# ------------------------------------------------------------------------------------------ families
def families(experiment) -> dict[str, str]:
    """{method label: family} from ``experiment.families`` ({family: [labels]};
    :class:`~blenav.eval.config.ExperimentConfig`)."""
    fam = (experiment.families if experiment is not None else None) or {}
    return {str(label): str(f) for f, labels in fam.items() for label in (labels or [])}


def family_of(name: str, fam: dict[str, str]) -> str:
    return fam.get(name, "other")


# ------------------------------------------------------------------------------------------ finish
def bound_result(entry: dict) -> MethodResult:
    """A bound's results.json entry (:func:`blenav.eval.pcrlb.bound_entries`, its plot arrays popped) as a row."""
    metrics = {k: entry[k] for k in ("rmse_m", "error_m", "ate_m") if k in entry}
    return MethodResult(kind="bound", metrics=metrics, per_session=entry.get("per_session", {}),
                        skipped=entry.get("skipped", {}),
                        bound=BoundStats(entry.get("settings"), entry.get("no_position", {})))


class LeaderboardEvaluator(TrajectoryEvaluator):
    """The trajectory evaluator plus the bound rows and the families (module doc)."""

    def finish(self, res: TrajectoryResult, ds, sessions: list, cfg) -> dict:
        """Add the bound rows and the families to ``res``; returns what the leaderboard's plots need of the bounds
        (``{"curves": {variant: {session: {t, bound_m}}}, "errors": {variant: efficient-estimator errors}}``, for
        :func:`plot`).

        ``PCRLB``: the bound with every measurement the ``bound`` block switches on (BLE RSSI, RTT, visual fixes);
        ``PCRLB-BLE``: the same with BLE RSSI alone, the information the BLE-only filters have (only when the
        first uses more than BLE); each session's information is computed once for both
        (:func:`blenav.eval.pcrlb.bound_entries`). Each has ``best``: the best method's RMSE and its ratio to the
        bound."""
        st = cfg.bound if cfg.bound is not None else BoundSettings()
        variants = {"PCRLB": st}
        if st.rssi and (st.rtt or st.visual):
            variants["PCRLB-BLE"] = replace(st, rtt=False, visual=False)
        curves, errors = {}, {}
        for name, entry in bound_entries(ds.meta, sessions, cfg.init_s, variants, seed=cfg.seed).items():
            curves[name], errors[name] = entry.pop("_curves", {}), entry.pop("_errors", None)
            res.methods[name] = bound_result(entry)
        fam = families(cfg.experiment)
        for name, m in res.methods.items():
            m.family = "bound" if m.kind == "bound" else family_of(name, fam)
        ran = {n: m.metrics["rmse_m"]["mean"] for n, m in res.methods.items() if m.ran and m.kind != "bound"}
        for name in variants:  # how far the best method is from what any estimator could do
            m = res.methods[name]
            if m.ran and ran:
                m.best = best_against_bound(ran, m.metrics["rmse_m"]["mean"])
        return {"curves": curves, "errors": errors}

    def figures(self, bounds: dict):
        return lambda out, res, outcomes, sessions, grid, cdfs: plot(out, res, outcomes, sessions, grid, cdfs, bounds)


# ------------------------------------------------------------------------------------------ plots
def plot(out: Path, res: TrajectoryResult, outcomes: dict, sessions: list, grid: np.ndarray,
         cdfs: dict[str, np.ndarray], bounds: dict) -> None:
    """The leaderboard's figures, from the error CDFs the harness drew error_cdf.png with (``cdfs[name]`` (G,)
    the median over runs on ``grid``) and :func:`finish`'s ``bounds``: leaderboard_cdf.png (one colour per
    family, the bounds as the error CDF of an estimator that attains them), pcrlb_over_time.png (simulated
    data), leaderboard_trajectories.png."""
    from blenav import plotting

    errors, curves = bounds.get("errors", {}), bounds.get("curves", {})
    b_cdfs = {}
    for name, e in errors.items():  # an efficient estimator's error CDF (errors ~ N(0, J^-1) per step)
        if e is not None and len(e):
            b_cdfs[name] = (res.methods[name].metrics["rmse_m"]["mean"],
                            np.searchsorted(np.sort(e), grid, side="right") / len(e))
    fam = {n: m.family or "other" for n, m in res.methods.items()}
    rmse = {n: m.metrics["rmse_m"]["mean"] for n, m in res.methods.items() if m.ran}
    fig = plotting.figure_leaderboard_cdf(grid, cdfs, fam, res.title, rmse=rmse, bounds=b_cdfs)
    plotting.save_figure(fig, out / "leaderboard_cdf.png")
    if curves.get("PCRLB"):
        plotting.save_figure(plotting.figure_bound_over_time(curves["PCRLB"], curves.get("PCRLB-BLE")),
                             out / "pcrlb_over_time.png")
    _plot_best_tracks(out, res, outcomes, sessions)


def _plot_best_tracks(out: Path, res: TrajectoryResult, outcomes: dict, sessions: list) -> None:
    """leaderboard_trajectories.png: the first session with the best method of each family (first run), a
    picture one reads at a glance (trajectories.png draws every method)."""
    from blenav import plotting

    ms = res.methods
    best: dict[str, str] = {}
    for n, m in ms.items():
        if m.ran and m.kind != "bound" and n in outcomes:
            f = m.family or "other"
            if f not in best or m.metrics["rmse_m"]["mean"] < ms[best[f]].metrics["rmse_m"]["mean"]:
                best[f] = n
    s = next((s for s in sessions if any(s.id in outcomes[n].results for n in best.values())), None)
    if s is None:
        return
    tracks = {f"{n} ({f})": (outcomes[n].results[s.id].t, outcomes[n].results[s.id].position[0])
              for f, n in best.items() if s.id in outcomes[n].results}
    fig = plotting.figure_trajectories(s, tracks, title="best method per family")
    plotting.save_figure(fig, out / "leaderboard_trajectories.png")
