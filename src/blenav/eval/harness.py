"""``evaluate(cfg)``: every method of an experiment on every selected labelled session, R runs each.

Writes ``OUT/results.json`` (schema below), ``OUT/results.md`` (a table like the papers') and, unless
``plots=false``, PNG plots. ``results.json``::

    {"experiment", "title", "dataset", "runs", "sessions": [...], "init_s", "seed", "calibration",
     "methods": {NAME: {"rmse_m": {"mean","std","stderr","ci99"}, "error_m": {"mean","median","p75","p90","max"},
                        "ate_m", "ee_m", "init_error_m", "orientation_rmse_deg" (when the method runs an AHRS
                        and the ground truth has orientation), "wall_s", "realtime_factor", "recoveries",
                        "map_notes", "skipped" (sessions the method could not run, with the reason),
                        "per_session": {SESSION_ID: {the same metrics for that session}}}}}

A method that could run on no session is ``{"skipped": {SESSION_ID: reason}}`` only.

Roy's fusion experiments (``mapprior_003_*``) add: ``model`` (path of a learned map prior, given to every
:class:`~blenav.filters.map_prior.MapPriorLikelihood`; without it those methods are skipped with the
reason), ``fixes`` (named ``fixes.csv`` sources or fixes computed from rssi.csv per role, see
:mod:`blenav.eval.fixes`; ``results.json`` then has a ``fixes`` entry saying what each session used) and
methods with ``score_fixes: ROLE`` (the role's fixes scored directly, Table 3.7's BLE-only rows).

``plan_error`` (:class:`~blenav.sim.plan_errors.PlanErrorConfig`; all zero by default) gives every method a
wrong floor plan -- spurious barriers, a registration offset -- while the sessions are still scored against
their ground truth; the wrong plans are written to ``OUT/plans/`` and ``results.json`` gets a
``plan_error`` entry (the settings and, per building and floor, the barriers drawn).

All methods are built (and so checked) before the first run: a misconfigured method fails at once.
"""

from __future__ import annotations

import json
import logging
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np
from hydra.utils import instantiate
from omegaconf import DictConfig, OmegaConf

from blenav.data import Dataset, DatasetError
from blenav.filters.attitude import AttitudeConfig, misalignment_deg
from blenav.filters.calibration import apply_fit, fit_sessions
from blenav.filters.engine import FilterConfig
from blenav.filters.map_prior import attach_prior
from blenav.filters.runner import MapSpec, Method, MissingStream, RunResult, run_session
from blenav.sim.plan_errors import PlanErrorConfig, perturb_building

from .fixes import FixProvider, FixTrack

from .metrics import cdf_band, pool, session_metrics

log = logging.getLogger("blenav.eval")


class EvalError(ValueError):
    """A bad experiment, dataset or session selection, with a message that says what to fix."""


def build_methods(cfg: DictConfig) -> dict[str, Method]:
    """Instantiate every method of ``cfg.methods`` (fails early on unknown keys or targets)."""
    if "methods" not in cfg or not cfg.methods:
        raise EvalError("the experiment defines no methods")
    out = {}
    fcfg = OmegaConf.to_object(OmegaConf.merge(OmegaConf.structured(FilterConfig), cfg.filter))
    att = OmegaConf.to_object(OmegaConf.merge(OmegaConf.structured(AttitudeConfig), cfg.get("attitude", {})))
    for key, m in cfg.methods.items():
        label = str(m.get("label", key))
        if m.get("score_fixes"):  # a BLE-only row: the role's fixes themselves (Roy, Table 3.7)
            out[label] = FixTrack(label, str(m.score_fixes))
            continue
        out[label] = build_method(label, m, fcfg, att)
    return out


def build_method(label: str, m: DictConfig, fcfg: FilterConfig, att: AttitudeConfig) -> Method:
    """One :class:`Method` from its config node (motion, measurements, map, filter overrides)."""
    try:
        motion = instantiate(m.motion)
        meas = [instantiate(v) for v in (m.get("measurements") or {}).values()]
        spec = OmegaConf.to_object(OmegaConf.merge(OmegaConf.structured(MapSpec), m.get("map") or {}))
        f = OmegaConf.to_object(OmegaConf.merge(OmegaConf.structured(fcfg), m.get("filter") or {}))
    except Exception as exc:  # hydra/omegaconf raise many types; name the method and re-raise ours
        raise EvalError(f"method {label!r}: {exc}") from exc
    return Method(label, f, motion, meas, spec, att)


def model_path(cfg: DictConfig) -> str | None:
    """The learned model's path, ``model_path`` (``model=DIR`` on the command line, see
    :func:`blenav.configs.cli_overrides`: ``model`` names the network config group)."""
    v = cfg.get("model_path")
    return str(v) if v else None


def build_fix_provider(cfg: DictConfig, methods: dict, out: Path) -> FixProvider | None:
    """The experiment's :class:`FixProvider` (``cfg.fixes``), or None when it has no ``fixes`` block."""
    fx = cfg.get("fixes")
    if fx is None:
        return None
    roles = {r: fx.get(r) for r in ("dense", "sparse") if r in fx}
    used = {m.role for m in methods.values() if isinstance(m, FixTrack)}
    used |= {getattr(x, "role", None) for m in methods.values() for x in m.measurements} - {None}
    missing = used - set(roles)
    if missing:
        raise EvalError(f"methods use fix role(s) {sorted(missing)} that the experiment's fixes block does not define")
    localizers = {}
    if fx.get("compute") is not None:
        fcfg = OmegaConf.to_object(OmegaConf.merge(OmegaConf.structured(FilterConfig), cfg.filter))
        att = OmegaConf.to_object(OmegaConf.merge(OmegaConf.structured(AttitudeConfig), cfg.get("attitude", {})))
        for r in roles:
            localizers[r] = build_method(f"BLE fixes ({r})", fx.compute, fcfg, att)
    sb = fx.get("sparse_beacons", 4)
    sb = int(sb) if isinstance(sb, (int, float)) else [str(b) for b in sb]
    try:
        return FixProvider(roles, localizers, sb, out, seed=int(cfg.seed), rate_hz=float(fx.get("rate_hz", 1.0)),
                           write=bool(fx.get("write", False)))
    except ValueError as exc:
        raise EvalError(str(exc)) from exc


def check_session_in_building(s) -> None:
    """A session whose ground truth lies mostly off its building's floor plan names the wrong building."""
    gt = s.groundtruth
    x0, x1, y0, y1 = s.floor.extent
    xy = gt[["x", "y"]].to_numpy()
    off = np.mean((xy[:, 0] < x0) | (xy[:, 0] > x1) | (xy[:, 1] < y0) | (xy[:, 1] > y1))
    if off > 0.5:
        raise EvalError(f"session {s.id}: {off:.0%} of its ground truth lies outside the floor plan of building "
                        f"{s.building.id} (x {x0:.1f}..{x1:.1f}, y {y0:.1f}..{y1:.1f} m); is 'building' in its "
                        f"session.yaml right?")


def select_sessions(ds: Dataset, ids, exclude: set = frozenset()) -> list:
    if ids:
        wanted = [str(i) for i in (ids if not isinstance(ids, str) else ids.split(","))]
        unknown = [i for i in wanted if i not in ds.session_ids]
        if unknown:
            raise EvalError(f"sessions {unknown} are not in {ds.root} (it has {ds.session_ids[:10]}...)")
        sessions = [ds.session(i) for i in wanted]
        unl = [s.id for s in sessions if not s.labelled]
        if unl:
            raise EvalError(f"sessions {unl} are unlabelled: they have no ground truth to score against")
        return sessions
    sessions = [s for s in ds.sessions(labelled=True) if s.id not in exclude]  # calibration sessions are not scored
    if not sessions:
        raise EvalError(f"{ds.root} has no labelled session to evaluate")
    moving = [s for s in sessions if s.carrier != "static"]
    return moving or sessions  # static surveys are calibration data unless they are all there is


def calibrate(methods: dict[str, Method], ds: Dataset, sessions: list, spec) -> dict | None:
    """Fit a_X and gamma for measurement models with ``calibrated: true``.

    ``spec``: 'none' (keep the configured, paper values), 'auto' (labelled static survey sessions of the
    dataset that are not evaluated, else the evaluated sessions themselves: two parameters, said in the
    results), or a list of session ids.
    """
    wanted = [m for meth in methods.values() for m in meth.measurements if getattr(m, "calibrated", False)]
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
        cal = select_sessions(ds, [str(i) for i in spec])
        note = f"fitted on session(s) {', '.join(str(i) for i in spec)} (named by calibration, not evaluated)"
    if not any(s.has("rssi") for s in cal):  # an inertial-only dataset: the radio methods will be skipped anyway
        log.warning("no RSSI readings to calibrate the path-loss model on: configured values kept")
        return None
    fit = fit_sessions(cal)
    for meth in methods.values():
        apply_fit(meth.measurements, fit)
    return {**fit.as_dict(), "note": note}


def plan_error_config(cfg: DictConfig) -> PlanErrorConfig:
    """``cfg.plan_error`` checked against :class:`PlanErrorConfig` (a misspelt key fails here)."""
    try:
        return OmegaConf.to_object(OmegaConf.merge(OmegaConf.structured(PlanErrorConfig), cfg.get("plan_error") or {}))
    except Exception as exc:  # omegaconf's errors for unknown keys / wrong types, or our ValueError
        raise EvalError(f"plan_error: {exc}") from exc


def with_wrong_plans(sessions: list, pe: PlanErrorConfig, out_dir: Path) -> tuple[list, dict]:
    """The sessions with their buildings' plans replaced by wrong ones (one per building, shared by its
    sessions; streams and their caches are kept), and the per-building summaries."""
    wrong, info = {}, {}
    for s in sessions:
        if s.building.id not in wrong:
            wrong[s.building.id], info[s.building.id] = perturb_building(s.building, pe, out_dir)
            log.info("plan errors in %s: %s", s.building.id, info[s.building.id])
    return [s.with_building(wrong[s.building.id]) for s in sessions], info


@dataclass
class MethodOutcome:
    results: dict  # session id -> RunResult
    metrics: dict  # session id -> metrics


def orientation_rmse(res: RunResult, session) -> float | None:
    gt = session.groundtruth
    if res.q_imu is None or gt[["qw", "qx", "qy", "qz"]].isna().all().all():
        return None
    gq = gt[["qw", "qx", "qy", "qz"]].to_numpy()
    gt_t = gt["t"].to_numpy()
    idx = np.clip(np.searchsorted(res.imu_t, gt_t), 0, len(res.imu_t) - 1)
    ok = (gt_t >= res.imu_t[0]) & (gt_t <= res.imu_t[-1])
    ang = misalignment_deg(res.q_imu[idx[ok]], gq[ok])
    return float(np.sqrt(np.mean(ang**2)))


def evaluate(cfg: DictConfig) -> dict:
    """Run the experiment of ``cfg`` and write its outputs; returns the results dictionary.

    Sessions: ``cfg.sessions`` or, by default, every labelled session that is not a static survey
    (surveys calibrate the path-loss model) nor named by ``calibration``; a dataset of surveys only is
    evaluated on its surveys. An experiment of ``kind: crossphone`` (learned localizers scored per window,
    Roy's Tables 3.3-3.5) runs :func:`blenav.eval.crossphone.evaluate_crossphone` instead.
    """
    if cfg.experiment.get("kind") == "crossphone":
        from .crossphone import evaluate_crossphone

        return evaluate_crossphone(cfg)
    try:
        ds = Dataset.open(cfg.data.path)
    except DatasetError as exc:
        raise EvalError(f"cannot open dataset {cfg.data.path}: {exc}") from exc
    methods = build_methods(cfg)
    reason = attach_prior([x for m in methods.values() for x in m.measurements], model_path(cfg))
    cal_spec = cfg.get("calibration", "auto")
    exclude = set(cal_spec) if not isinstance(cal_spec, str) and cal_spec is not None else set()
    sessions = select_sessions(ds, cfg.get("sessions"), exclude=exclude)
    for s in sessions:
        check_session_in_building(s)
    plan_error = plan_error_config(cfg)
    runs = int(cfg.runs)
    if runs < 1:
        raise EvalError(f"runs must be >= 1, got {runs}")
    out = Path(cfg.out)
    plan_info = None
    if plan_error.active:
        sessions, plan_info = with_wrong_plans(sessions, plan_error, out / "plans")
    provider = build_fix_provider(cfg, methods, out)
    calibration = calibrate({**methods, **(provider.methods if provider else {})}, ds, sessions, cal_spec)
    out.mkdir(parents=True, exist_ok=True)
    progress = _progress(bool(cfg.get("progress", False)), len(methods) * len(sessions))
    outcomes: dict[str, MethodOutcome] = {}
    cache: dict = {}  # map geometry per floor, AHRS per session: shared by all methods
    results = {"experiment": cfg.experiment.name, "title": cfg.experiment.get("title", ""), "dataset": str(ds.root),
               "runs": runs, "sessions": [s.id for s in sessions], "init_s": float(cfg.init_s), "seed": int(cfg.seed),
               "calibration": calibration, "methods": {}}
    if reason:
        results["map_prior"] = reason
    if plan_info is not None:
        results["plan_error"] = {**asdict(plan_error), "buildings": plan_info}
    for name, method in methods.items():
        per, res_by = {}, {}
        wall = 0.0
        duration = 0.0
        orient = []
        notes: list[str] = []
        recoveries = 0
        skipped = {}
        for si, s in enumerate(sessions):
            seed = int(cfg.seed) * 1_000_003 + 1000 * si  # the same random stream for every method
            try:
                if isinstance(method, FixTrack):
                    if provider is None:
                        raise EvalError(f"method {name} scores fixes but the experiment has no fixes block")
                    res = method.run(s, runs, provider)
                else:
                    extra = provider.prepare(method, s) if provider is not None else None
                    res = run_session(method, s, runs, seed, cache=cache, fixes=extra)
            except MissingStream as exc:  # e.g. no IMU in a fixed-receiver recording: skip, and say so
                skipped[s.id] = str(exc)
                log.warning("skipping %s on %s: %s", name, s.id, exc)
                progress(f"{name} / {s.id} (skipped)")
                continue
            except (ValueError, DatasetError) as exc:
                raise EvalError(f"method {name}, session {s.id}: {exc}") from exc
            gt = s.groundtruth
            m = session_metrics(res.t, res.position, gt["t"].to_numpy(), gt[["x", "y"]].to_numpy(), float(cfg.init_s))
            o = orientation_rmse(res, s)
            if o is not None:
                m["orientation_rmse_deg"] = o
                orient.append(o)
            m["wall_s"] = res.wall_s
            m["recoveries"] = len(res.events)
            per[s.id], res_by[s.id] = m, res
            wall += res.wall_s
            duration += float(res.t[-1] - res.t[0])
            recoveries += len(res.events)
            notes += [n for n in res.map_notes if n not in notes]
            progress(f"{name} / {s.id}")
        if not per:
            results["methods"][name] = {"skipped": skipped}
            continue
        agg = pool(per)
        if skipped:
            agg["skipped"] = skipped
        agg.update({"wall_s": wall, "realtime_factor": duration * runs / max(wall, 1e-9), "recoveries": recoveries,
                    "map_notes": notes})
        if orient:
            agg["orientation_rmse_deg"] = float(np.mean(orient))
        agg["per_session"] = {k: {kk: vv for kk, vv in v.items() if kk != "_runs"} for k, v in per.items()}
        results["methods"][name] = agg
        outcomes[name] = MethodOutcome(res_by, per)
    if provider is not None:
        results["fixes"] = provider.describe()
    (out / "results.json").write_text(json.dumps(results, indent=1, default=_json_default), encoding="utf-8")
    from .report import write_markdown

    write_markdown(out / "results.md", results, cfg)
    if cfg.get("plots", True):
        _plots(out, results, outcomes, sessions)
    return results


def _plots(out: Path, results: dict, outcomes: dict[str, MethodOutcome], sessions) -> None:
    from blenav import plotting

    grid = np.linspace(0, 15, 301)
    cdfs, rmses, err_t = {}, {}, {}
    outcomes = {k: v for k, v in outcomes.items() if v.results}
    if not outcomes:
        return
    sessions = [s for s in sessions if all(s.id in oc.results for oc in outcomes.values())] or sessions
    for name, oc in outcomes.items():
        R = next(iter(oc.results.values())).position.shape[0]
        per_run = [np.concatenate([oc.metrics[s]["_runs"]["err"][r] for s in oc.metrics]) for r in range(R)]
        cdfs[name] = cdf_band(per_run, grid)
        rmses[name] = np.concatenate([oc.metrics[s]["_runs"]["rmse"] for s in oc.metrics])
        first = sessions[0].id if sessions[0].id in oc.metrics else next(iter(oc.metrics))
        err_t[name] = (oc.metrics[first]["_runs"]["t"], oc.metrics[first]["_runs"]["err_all"])
    plotting.save_figure(plotting.figure_error_cdf(grid, cdfs, results["title"]), out / "error_cdf.png")
    plotting.save_figure(plotting.figure_rmse_box(rmses, results["title"]), out / "rmse_box.png")
    plotting.save_figure(plotting.figure_error_over_time(err_t, results["init_s"], sessions[0].id),
                         out / "error_over_time.png")
    s = sessions[0]
    tracks = {name: (oc.results[s.id].t, oc.results[s.id].position[0]) for name, oc in outcomes.items()
              if s.id in oc.results}
    plotting.save_figure(plotting.figure_trajectories(s, tracks), out / "trajectories.png")


def _progress(enabled: bool, total: int):
    if not enabled:
        return lambda msg: None
    from tqdm import tqdm

    bar = tqdm(total=total, desc="evaluating", unit="method-session")

    def tick(msg: str) -> None:
        bar.set_postfix_str(msg)
        bar.update(1)

    return tick


def _json_default(o):
    if isinstance(o, (np.floating, np.integer)):
        return o.item()
    if isinstance(o, np.ndarray):
        return o.tolist()
    raise TypeError(f"not JSON serialisable: {type(o)}")
