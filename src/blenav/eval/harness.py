"""The steps of a trajectory evaluation: every method of an experiment on every selected labelled session, R runs
each (:class:`blenav.eval.trajectory.TrajectoryEvaluator` runs them in order; ``evaluate(cfg)`` runs any experiment
with its evaluator, :mod:`blenav.eval.evaluators`).

Every method is a :class:`~blenav.localizers.Localizer` built from its config node (``_target_``, see
``conf/localizer/``); the harness runs it through that interface alone and scores the
:class:`~blenav.localizers.Estimate` it returns. The steps, each a function of the typed
:class:`~blenav.eval.config.EvalConfig`: build the methods, select the sessions, attach the models and fixes the
methods declare they want (the fixes resolved per session into :class:`~blenav.localizers.inputs.Fixes` before
the method runs), calibrate, run, aggregate into :class:`~blenav.eval.result.MethodResult`, write.

Writes ``OUT/results.json`` (schema below), ``OUT/results.md`` (a table like the papers') and, unless
``plots=false``, PNG plots. ``results.json``::

    {"experiment", "title", "dataset", "runs", "sessions": [...], "init_s", "seed", "calibration",
     "methods": {NAME: {"rmse_m": {"mean","std","stderr","ci99","n"}, "error_m": {"mean","median","p75","p90","max"},
                        "ate_m", "ee_m", "init_error_m", "orientation_rmse_deg" (when the method runs an AHRS
                        and the ground truth has orientation), "wall_s", "realtime_factor", "recoveries",
                        "map_notes", "confined": {"bbox", "off_free", "free", "estimates"} (estimates kept on
                        the floor, :mod:`blenav.localizers.confine`), "skipped" (sessions the method could
                        not run, with the reason), "per_session": {SESSION_ID: {the same metrics}}}},
     "dropped": {SESSION_ID: {STREAM: {REASON: rows}}} (rows the readers dropped; only when any were)}

A method that could run on no session is ``{"skipped": {SESSION_ID: reason}}`` only.

Methods that declare they want a trained model (:class:`~blenav.localizers.ModelConsumer`) get
``model_path`` (``model_path=DIR``; without it they are skipped with the reason, and ``results.json`` has
``model: {"path", "unavailable": {METHOD: reason}}``). Methods that weigh position fixes
(:class:`~blenav.localizers.FixConsumer`) get them from the experiment's ``fixes`` block (named
``fixes.csv`` sources or fixes computed from rssi.csv per role, see :mod:`blenav.eval.fixes`;
``results.json`` then has a ``fixes`` entry saying what each session used), e.g. the BLE-only rows of
Roy's Table 3.7 (:class:`~blenav.localizers.FixTrackLocalizer`). Methods with path-loss models that ask
for calibration (:class:`~blenav.localizers.PathLossCalibrated`) get the fit of ``calibration``.

``plan_error`` (:class:`~blenav.eval.plan_errors.PlanErrorConfig`; all zero by default) gives every method a
wrong floor plan -- spurious barriers, a registration offset -- while the sessions are still scored against
their ground truth; the wrong plans are written to ``OUT/plans/`` and ``results.json`` gets a
``plan_error`` entry (the settings and, per building and floor, the barriers drawn).

All methods are built (and so checked) before the first run: a misconfigured method fails at once.
"""

from __future__ import annotations

import json
import logging
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from blenav.data import Dataset
from blenav.errors import DatasetError, EvalError, MissingStream, missing_extra
from blenav.filters.attitude import misalignment_deg
from blenav.filters.calibration import fit_sessions
from blenav.localizers import (Estimate, FixConsumer, InertialModelConsumer, Localizer, ModelConsumer,
                               PathLossCalibrated, Trained, build_localizer)
from blenav.localizers.confine import confine
from blenav.localizers.inputs import RunInputs
from blenav.eval import beacon_map as BM

from .common import output_name
from .config import EvalConfig, parse_eval_config
from .evaluators import evaluate
from .fixes import FixProvider
from .metrics import (cdf_band, convergence_times, fix_coverage_counts, pool, pool_convergence, pool_fix_coverage,
                      pool_segment_errors, public, segment_errors, session_metrics, waypoint_metrics)
from .result import MethodResult, TrajectoryResult, write_results
from .sessions import select_sessions

log = logging.getLogger("blenav.eval")

__all__ = ["build_methods", "evaluate", "calibrate", "run_method", "aggregate"]


# ------------------------------------------------------------------------------------------ build
def build_methods(cfg: EvalConfig) -> dict[str, Localizer]:
    """Every method of ``cfg.methods``, keyed by its label (fails early on unknown keys or targets); each receives the
    experiment-wide ``filter`` / ``attitude`` settings (:meth:`EvalConfig.shared`). A composed DictConfig (scripts,
    tests) is parsed first, a dataset path not needed."""
    cfg = parse_eval_config(cfg, require_data=False)
    if not cfg.methods:
        raise EvalError("the experiment defines no methods")
    shared = cfg.shared()
    out = {}
    for key, node in cfg.methods.items():
        if node is None:  # switched off by an override (methods.KEY=null)
            continue
        label = str(node.get("label", key))
        try:
            out[label] = build_localizer(label, node, shared)
        except EvalError:
            raise
        except Exception as exc:  # hydra/omegaconf/our ValueError: name the method
            msg = str(exc)
            raise EvalError(msg if label in msg else f"method {label!r}: {msg}") from exc
    return out


def attach_models(methods: dict[str, Localizer], path: str | None, io_path: str | None = None) -> dict | None:
    """Give every :class:`ModelConsumer` the model of ``path`` and every :class:`InertialModelConsumer` the inertial
    odometry of ``io_path`` (each file loaded once); returns ``{"path", "io_model", "unavailable": {method: reason}}``
    when a consumer cannot run, else None."""
    loaded: dict = {}

    def load(p: str, loader):
        key = (p, loader)
        if key not in loaded:
            loaded[key] = loader(p)
        return loaded[key]

    unavailable = {}
    for name, m in methods.items():
        why = []
        if isinstance(m, ModelConsumer):
            why.append(m.attach_model(path, load))
        if isinstance(m, InertialModelConsumer):
            why.append(m.attach_io_model(io_path, load))
        why = [w for w in why if w]
        if why:
            unavailable[name] = "; ".join(why)
    if not unavailable:
        return None
    return {"path": path, **({"io_model": io_path} if io_path else {}), "unavailable": unavailable}


def build_fix_provider(cfg: EvalConfig, methods: dict[str, Localizer], out: Path) -> FixProvider | None:
    """The experiment's :class:`FixProvider` (``cfg.fixes``), or None when it has no ``fixes`` block."""
    fx = cfg.fixes
    if fx is None:
        return None
    used = set().union(*[m.fix_roles() for m in methods.values() if isinstance(m, FixConsumer)])
    missing = used - set(fx.roles)
    if missing:
        raise EvalError(f"methods use fix role(s) {sorted(missing)} that the experiment's fixes block does not define")
    localizers = fix_localizers(cfg, methods)
    try:
        return FixProvider(fx.roles, localizers, fx.sparse_beacons, out, seed=cfg.seed, rate_hz=fx.rate_hz,
                           write=fx.write)
    except ValueError as exc:
        raise EvalError(str(exc)) from exc


def fix_localizers(cfg: EvalConfig, methods: dict[str, Localizer]) -> dict[str, Localizer]:
    """role -> the localizer computing its fixes (:mod:`blenav.eval.fixes`): ``fixes.compute`` is one node for every
    role or ``{role: node}``; roles with equal nodes share one instance, and a node equal to a ``methods`` row is that
    row's localizer (so ``${methods.knn_wifi}`` is trained and kept once, not twice)."""
    fx = cfg.fixes
    if fx.compute is None:
        return {}
    as_key = lambda node: json.dumps(node, sort_keys=True, default=str)
    by_node = {as_key(node): methods[str(node.get("label", k))] for k, node in (cfg.methods or {}).items()
               if node is not None and str(node.get("label", k)) in methods}
    shared, out = cfg.shared(), {}
    for r in fx.roles:
        node = fx.compute.get(r) if fx.per_role else fx.compute
        if node is None:
            continue
        key = as_key(node)
        if key not in by_node:
            try:
                by_node[key] = build_localizer(f"BLE fixes ({r})" if not fx.per_role else f"fixes ({r})", node, shared)
            except Exception as exc:
                raise EvalError(f"fixes.compute: {exc}") from exc
        out[r] = by_node[key]
    return out


def fit_trained(methods: dict[str, Localizer], train: list, inputs: RunInputs) -> dict:
    """Train the methods that learn from the dataset (:class:`Trained`) on ``train``; their reports by name
    (a method whose training data lacks what it needs is reported, and then skipped at run time)."""
    reports = {}
    for name, m in methods.items():
        if isinstance(m, Trained):
            try:
                reports[name] = m.fit(train, inputs)
            except MissingStream as exc:
                reports[name] = {"unavailable": str(exc)}
                log.warning("%s cannot be trained: %s", name, exc)
            except ImportError as exc:  # training needs an extra this install lacks (torch): say which
                if missing_extra(exc) is None:
                    raise
                reports[name] = {"unavailable": f"{exc}: training it needs pip install 'blenav[{missing_extra(exc)}]'"}
                log.warning("%s cannot be trained: %s", name, reports[name]["unavailable"])
            except ValueError as exc:
                raise EvalError(f"method {name}, training: {exc}") from exc
    return reports


# ------------------------------------------------------------------------------------------ calibrate
def calibrate(methods: dict[str, Localizer], ds: Dataset, sessions: list, spec) -> dict | None:
    """Fit a_X and gamma for the methods that ask for it (:class:`PathLossCalibrated`).

    ``spec``: 'none' (keep the configured, paper values), 'auto' (labelled static survey sessions of the
    dataset that are not evaluated, else the evaluated sessions themselves: two parameters, said in the
    results), or a list of session ids.
    """
    wanted = [m for m in methods.values() if isinstance(m, PathLossCalibrated) and m.wants_path_loss_fit()]
    if not wanted or spec in (None, "none"):
        return None
    evaluated = {s.id for s in sessions}
    if spec == "auto":
        cal = [s for s in ds.sessions(labelled=True) if s.carrier == "static" and s.id not in evaluated]
        note = "fitted on the dataset's labelled static survey sessions (not evaluated)"
        if not cal:
            cal = sessions
            note = "no separate survey session: fitted on the evaluated sessions' own readings (2 parameters)"
    else:
        try:
            cal = select_sessions(ds, [str(i) for i in spec])
        except DatasetError as exc:
            raise EvalError(f"calibration: {exc}") from exc
        note = f"fitted on session(s) {', '.join(str(i) for i in spec)} (named by calibration, not evaluated)"
    if not any(s.has("rssi") for s in cal):  # an inertial-only dataset: the radio methods will be skipped anyway
        log.warning("no RSSI readings to calibrate the path-loss model on: configured values kept")
        return None
    fit = fit_sessions(cal)
    for m in wanted:
        m.apply_path_loss_fit(fit)
    return {**fit.as_dict(), "note": note}


# ------------------------------------------------------------------------------------------ run
@dataclass
class MethodOutcome:
    """One method on every session: its estimates and metrics per session id, and the sessions it could
    not run on (id -> reason)."""

    results: dict = field(default_factory=dict)  # session id -> Estimate
    metrics: dict = field(default_factory=dict)  # session id -> metrics
    skipped: dict = field(default_factory=dict)


def orientation_rmse(est: Estimate, session) -> float | None:
    """RMSE (deg) of the method's AHRS orientation (``outputs["attitude"]``) against the ground truth's, or
    None when either is absent."""
    att = est.outputs.get("attitude")
    gt = session.groundtruth
    if att is None or gt[["qw", "qx", "qy", "qz"]].isna().all().all():
        return None
    imu_t, q = np.asarray(att["t"]), np.asarray(att["q"])
    gq = gt[["qw", "qx", "qy", "qz"]].to_numpy()
    gt_t = gt["t"].to_numpy()
    idx = np.clip(np.searchsorted(imu_t, gt_t), 0, len(imu_t) - 1)
    ok = (gt_t >= imu_t[0]) & (gt_t <= imu_t[-1])
    if not ok.any():  # the IMU's time span holds no ground-truth time: nothing to compare (not NaN)
        return None
    ang = misalignment_deg(q[idx[ok]], gq[ok])
    return float(np.sqrt(np.mean(ang**2)))


def method_inputs(method: Localizer, session, inputs: RunInputs, fixes: FixProvider | None) -> RunInputs:
    """The inputs of one run of ``method`` on ``session``: ``inputs`` with, for a :class:`FixConsumer`, the session's
    fixes of its roles (:meth:`FixProvider.resolve`; None without a ``fixes`` block)."""
    if fixes is None or not isinstance(method, FixConsumer):
        return inputs
    if method.fix_roles_are_alternatives:
        return inputs.with_fixes(fixes.resolve_first(method.fix_roles(), session))
    return inputs.with_fixes(fixes.resolve(method.fix_roles(), session))


def session_seed(seed: int, index: int) -> int:
    """The seed of the ``index``-th session: the same random stream for every method."""
    return int(seed) * 1_000_003 + 1000 * index


def run_method(name: str, method: Localizer, sessions: list, runs: int, seed: int, init_s: float, inputs: RunInputs,
               progress, beacon_map: BM.BeaconMapConfig | None = None, hold_ends: bool = False,
               fixes: FixProvider | None = None) -> MethodOutcome:
    """``method`` on every session (R runs each), scored against the ground truth; sessions where it cannot
    run (:class:`MissingStream`) are skipped with the reason, other errors name the method and session.
    ``inputs``: what every run shares (the cache, the output folder); a :class:`FixConsumer` gets the session's
    fixes of its roles from ``fixes`` with them (:meth:`FixProvider.resolve`, for the session it runs on).
    ``beacon_map`` with ``noise_m > 0``: every run on its own perturbed map (:mod:`blenav.eval.beacon_map`).
    ``hold_ends`` (the experiment's ``scoring.hold_ends``): waypoints outside an estimate's span are scored against
    its first / last estimate (:func:`~blenav.eval.metrics.waypoint_metrics`)."""
    oc = MethodOutcome()
    inputs_for = lambda session: method_inputs(method, session, inputs, fixes)  # noqa: E731
    for si, s in enumerate(sessions):
        try:
            inp = None  # the run's inputs (one map); per-run perturbed maps resolve their own
            if beacon_map is not None and beacon_map.perturbed:
                est = BM.run_per_run_maps(method, s, si, runs, session_seed(seed, si), inputs_for, beacon_map)
            else:
                inp = inputs_for(s)
                est = method.run(s, runs, session_seed(seed, si), inp)
        except MissingStream as exc:  # e.g. no IMU in a fixed-receiver recording: skip, and say so
            oc.skipped[s.id] = str(exc)
            log.warning("skipping %s on %s: %s", name, s.id, exc)
            progress(f"{name} / {s.id} (skipped)")
            continue
        except ImportError as exc:  # a method of an extra this install lacks (gtsam, torch): skip it, say which
            extra = missing_extra(exc)
            if extra is None:
                raise
            oc.skipped[s.id] = f"{exc}: this method needs pip install 'blenav[{extra}]'"
            log.warning("skipping %s on %s: %s", name, s.id, oc.skipped[s.id])
            progress(f"{name} / {s.id} (skipped)")
            continue
        except (ValueError, DatasetError) as exc:
            raise EvalError(f"method {name}, session {s.id}: {exc}") from exc
        est, moved = confine(est, s.floor, snap_free=method.uses_floor_plan, cache=inputs.cache)  # stay on the floor
        gt = s.groundtruth
        try:
            if s.groundtruth_sparse:  # sparse surveyed waypoints: the estimate interpolated at each waypoint time
                m = waypoint_metrics(est.t, est.position, gt["t"].to_numpy(), gt[["x", "y"]].to_numpy(), hold_ends)
                # its displacement over each waypoint segment (the measure of an odometry, issue 31)
                m["_segment_err"] = segment_errors(est.t, est.position, gt["t"].to_numpy(), gt[["x", "y"]].to_numpy())
            else:
                m = session_metrics(est.t, est.position, gt["t"].to_numpy(), gt[["x", "y"]].to_numpy(), init_s)
        except ValueError as exc:  # e.g. ground truth of one row, or all at one time: name the file
            raise EvalError(f"method {name}, session {s.id}: {exc} ({s.root / 'groundtruth.csv'}: t "
                            f"{gt['t'].min():g}..{gt['t'].max():g} s)") from exc
        m["confined"] = moved
        o = orientation_rmse(est, s)
        if o is not None:
            m["orientation_rmse_deg"] = o
        m["wall_s"] = est.wall_s
        m["recoveries"] = len(est.events)
        err = beacon_errors(est, s)
        if err is not None:
            m["beacon_error_m"] = err
        if inp is not None and inp.fixes is not None and inp.fixes.roles:  # the fixes' stated std vs the ground truth
            cov = {r: fix_coverage_counts(f.t, f.xy, f.std, gt["t"].to_numpy(), gt[["x", "y"]].to_numpy())
                   for r, f in inp.fixes.roles.items()}
            if any(c is not None for c in cov.values()):
                m["fix_coverage"] = {r: c for r, c in cov.items() if c is not None}
            # no known start: how long until the track settles within CONVERGED_M
            m["_convergence_s"] = convergence_times(m["_runs"]["err_all"], m["_runs"]["t"])
        elif method.states_fix_std and est.cov is not None:  # a fingerprint's own fixes and their stated std
            c = fix_coverage_counts(est.t, est.position[0], est.std[0], gt["t"].to_numpy(), gt[["x", "y"]].to_numpy())
            if c is not None:
                m["fix_coverage"] = {"own": c}
        oc.metrics[s.id], oc.results[s.id] = m, est
        progress(f"{name} / {s.id}")
    return oc


def beacon_errors(est: Estimate, session) -> dict | None:
    """``{prior, optimized}`` mean horizontal beacon errors (m) of a method that returns a beacon map."""
    if est.outputs.get("beacon_map") is None:
        return None
    per_run = est.outputs.get("beacon_error")
    if per_run is not None:
        vals = {k: [x for x in v if x is not None] for k, v in per_run.items()}
        out = {k: float(np.mean(v)) if v else None for k, v in vals.items()}
        if est.outputs.get("beacon_rows") is not None:
            out["_rows"] = est.outputs["beacon_rows"]  # per beacon and run, pooled by aggregate() into by_heard
        return out
    truth = BM.true_xy(session.building.anchors)
    given = BM.given_map(session.building)
    return {"prior": BM.map_error(given, truth), "optimized": BM.map_error(est.outputs["beacon_map"], truth),
            "_rows": BM.beacon_rows(given, est.outputs["beacon_map"], truth, BM.heard_counts(session))}


# ------------------------------------------------------------------------------------------ aggregate
def aggregate(oc: MethodOutcome, runs: int) -> MethodResult:
    """One method's row: pooled metrics, timing, recoveries, notes, per session."""
    if not oc.metrics:
        return MethodResult(skipped=oc.skipped)
    ests = list(oc.results.values())
    wall = sum(e.wall_s for e in ests)
    duration = sum(float(e.t[-1] - e.t[0]) for e in ests)
    notes: list[str] = []
    for e in ests:
        notes += [n for n in e.notes if n not in notes]
    res = MethodResult(metrics=pool(oc.metrics), skipped=oc.skipped, wall_s=wall,
                       realtime_factor=duration * runs / max(wall, 1e-9), recoveries=sum(len(e.events) for e in ests),
                       map_notes=notes, confined={k: sum(m["confined"][k] for m in oc.metrics.values())
                                                  for k in ("bbox", "off_free", "free", "estimates")})
    errs = [m["beacon_error_m"] for m in oc.metrics.values() if "beacon_error_m" in m]
    if errs:
        res.beacon_error_m = {k: float(np.mean([e[k] for e in errs if e[k] is not None]))
                              if any(e[k] is not None for e in errs) else None for k in ("prior", "optimized")}
        rows = [e["_rows"] for e in errs if e.get("_rows") is not None]
        if rows:
            res.beacon_error_m["by_heard"] = BM.by_heard(rows)
    res.fix_coverage = pool_fix_coverage([m["fix_coverage"] for m in oc.metrics.values() if "fix_coverage" in m])
    res.segment_error_m = pool_segment_errors([m["_segment_err"] for m in oc.metrics.values() if "_segment_err" in m])
    res.convergence = pool_convergence([m["_convergence_s"] for m in oc.metrics.values() if "_convergence_s" in m])
    orient = [m["orientation_rmse_deg"] for m in oc.metrics.values() if "orientation_rmse_deg" in m]
    if orient:
        res.orientation_rmse_deg = float(np.mean(orient))
    res.per_session = {k: {kk: public(vv) for kk, vv in v.items() if not kk.startswith("_")} for k, v in oc.metrics.items()}
    return res


def dropped_rows(sessions: list) -> dict:
    """``{session id: {stream: {reason: rows}}}`` of the rows the readers dropped (e.g. RSSI of an anchor
    that anchors.csv lacks), for the sessions that dropped any: every stream is read, so nothing a method
    did not happen to read goes unreported."""
    out = {}
    for s in sessions:
        try:
            d = s.load_all().dropped
        except DatasetError as exc:  # a stream no method read is broken: say so, do not hide it
            raise EvalError(f"session {s.id}: {exc}") from exc
        if d:
            out[s.id] = d
    return out


def write_outputs(out: Path, res: TrajectoryResult, outcomes: dict[str, MethodOutcome], sessions, cfg: EvalConfig,
                  more_plots=None) -> None:
    """results.json and results.md (:func:`blenav.eval.result.write_results`), the per-session files and (unless
    ``plots=false``) the plots; ``more_plots(out, res, outcomes, sessions, grid, cdfs)``: an evaluator's own figures
    (the leaderboard's, :meth:`blenav.eval.leaderboard.LeaderboardEvaluator.figures`), drawn with the same error
    CDFs (``cdfs[name]``: the median over runs on ``grid``)."""
    write_results(out, res, cfg.experiment)
    write_session_files(out, outcomes, sessions)
    if cfg.plots:
        _plots(out, res, outcomes, sessions, more_plots)


def write_session_files(out: Path, outcomes: dict[str, MethodOutcome], sessions) -> None:
    """Per session: every method's trajectory (run 0) in TUM format, ``OUT/<session>/trajectories/<method>.tum``
    (``evo_ape tum groundtruth.tum <method>.tum``; the ground truth written beside them), and the corrected
    anchors of the first method that returns a beacon map, ``OUT/<session>/anchors_optimized.csv`` (anchors.csv
    columns with the new x, y, z, plus std_m and status), with its IMU bias series ``bias_<method>.csv``."""
    from blenav.data.writer import write_tum

    by_id = {s.id: s for s in sessions}
    mapped: set[str] = set()
    for name, oc in outcomes.items():
        for sid, est in oc.results.items():
            s = by_id.get(sid)
            if s is None:
                continue
            d = out / output_name(sid)
            write_tum(d / "trajectories" / f"{output_name(name)}.tum", est.t, est.position[0])
            gt = s.groundtruth
            if len(gt) and not (d / "trajectories" / "groundtruth.tum").exists():
                write_tum(d / "trajectories" / "groundtruth.tum", gt["t"].to_numpy(float), gt[["x", "y"]].to_numpy(float))
            bmap = est.outputs.get("beacon_map")
            if bmap is not None and sid not in mapped:
                BM.optimized_anchors(s.building, bmap).to_csv(d / "anchors_optimized.csv", index=False)
                mapped.add(sid)
                bias = est.outputs.get("bias")
                if bias is not None:
                    cols = ["ax_bias", "ay_bias", "az_bias", "gx_bias", "gy_bias", "gz_bias"]
                    import pandas as pd

                    pd.DataFrame(np.column_stack([est.t, bias[0]]), columns=["t"] + cols).to_csv(
                        d / f"bias_{output_name(name)}.csv", index=False)


def _plots(out: Path, res: TrajectoryResult, outcomes: dict[str, MethodOutcome], sessions, more_plots=None) -> None:
    from blenav import plotting

    grid = np.linspace(0, 15, 301)
    cdfs, rmses, err_t = {}, {}, {}
    outcomes = {k: v for k, v in outcomes.items() if v.results}
    for name, oc in outcomes.items():  # the error CDFs, built once: error_cdf.png and the leaderboard's
        R = next(iter(oc.results.values())).position.shape[0]
        cdfs[name] = cdf_band([np.concatenate([oc.metrics[s]["_runs"]["err"][r] for s in oc.metrics]) for r in range(R)], grid)
    if more_plots is not None:
        more_plots(out, res, outcomes, sessions, grid, {n: c[1] for n, c in cdfs.items()})  # the medians
    if not outcomes:
        return
    for s in sessions:  # every scored session, with the methods that ran on it
        per = {name: (oc.metrics[s.id]["_runs"]["t"], oc.metrics[s.id]["_runs"]["err_all"])
               for name, oc in outcomes.items() if s.id in oc.metrics}
        if per:
            err_t[s.id] = per
    sessions = [s for s in sessions if all(s.id in oc.results for oc in outcomes.values())] or sessions
    for name, oc in outcomes.items():
        rmses[name] = np.concatenate([oc.metrics[s]["_runs"]["rmse"] for s in oc.metrics])
    plotting.save_figure(plotting.figure_error_cdf(grid, cdfs, res.title), out / "error_cdf.png")
    plotting.save_figure(plotting.figure_rmse_box(rmses, res.title), out / "rmse_box.png")
    plotting.save_figure(plotting.figure_error_over_time(err_t, res.init_s, methods=list(outcomes)),
                         out / "error_over_time.png")
    s = sessions[0]
    tracks = {name: (oc.results[s.id].t, oc.results[s.id].position[0]) for name, oc in outcomes.items()
              if s.id in oc.results}
    families = {n: m.family for n, m in res.methods.items() if n in tracks and m.family}
    plotting.save_figure(plotting.figure_trajectories(s, tracks, groups=families or None), out / "trajectories.png")


class Progress:
    """A tqdm bar over method x session (or nothing); closed before any error is printed, so the error line
    is never drawn over by the bar."""

    def __init__(self, enabled: bool, total: int):
        self.bar = None
        if enabled:
            from tqdm import tqdm

            self.bar = tqdm(total=total, desc="evaluating", unit="method-session")

    def __call__(self, msg: str) -> None:
        if self.bar is not None:
            self.bar.set_postfix_str(msg)
            self.bar.update(1)

    def __enter__(self):
        return self

    def __exit__(self, *exc) -> None:
        if self.bar is not None:
            self.bar.close()
