"""The cross-phone comparison of Roy, section 3.1.4 (Tables 3.3-3.5): :class:`CrossPhoneEvaluator`
(``experiment.evaluator._target_: blenav.eval.crossphone.CrossPhoneEvaluator``, old spelling ``kind: crossphone``).

Every method sees the same split (:func:`blenav.features.windows.split_by_device` with ``cfg.data``): the
learned methods train through :func:`blenav.learn.train.train` into ``OUT/runs/<key>`` (a run that is
already complete is reused, an interrupted one resumes, one trained on other data is refused), the
baselines of Table 3.5 fit on the same labelled windows. All are scored on the same test windows: every
window of a labelled test session whose end lies inside the ground truth and in which at least one
beacon was heard (a window with no beacon heard gives no fix; how many there were is reported).

``results.json`` follows the shared schema (``experiment``, ``title``, ``dataset``, ``sessions``,
``seed``, ``methods``) with per method::

    {"error_m": {"mean","std","median","p75","p90","max"}, "rmse_m": {summary over sessions},
     "per_device": {device_model: {"mean","std","median","p90","max","n"}},
     "per_brand": {brand: {...}}, "per_session": {SESSION_ID: {"error_m": {...}, "device_model"}},
     "train_s" (null when a complete run was reused), "predict_s", "n_windows",
     "source" ("trained: OUT/runs/KEY" | "reused: OUT/runs/KEY" | "model: FILE.onnx" | "fitted"),
     "training" (learned methods trained here): {"steps", "budget_steps" (the step budget of the run:
                 trainer.budget.max_steps, or its auto value for the survey's size), "early_stopped", "stop_reason", "best_val_error_m",
                 "knn_val_error_m" (KNN, k = 5, on the same validation windows), "converged", "best_step",
                 "train_windows", "val_windows" (labelled windows trained / validated on), "batch_size" (windows
                 per step: data.batch_size, or its auto value for the survey's size),
                 "warnings" (worse than KNN on validation, stopped before converging), "learning_curves" (png)}}

Every learned method's run also leaves ``OUT/runs/KEY/training.json`` and ``learning_curves.png`` (the training
report of :mod:`blenav.learn.common.report`); its warnings are logged.

A method is named by its label (``LocNet``, ``TransNet+LocNet``, ``TransNet+LocNet+semi``, ``DL-RNN``,
``KNN``, ``Bayesian``, ``KRR+KF``). ``model_path=FILE.onnx`` replaces the training of ``TransNet+LocNet`` by an
exported model (its beacon list must match the building).
"""

from __future__ import annotations

import dataclasses
import logging
import shutil
import time
from pathlib import Path

import numpy as np
import torch
from omegaconf import DictConfig, OmegaConf

from blenav.errors import DatasetError, EvalError

from .config import EvalConfig
from .evaluators import Evaluator
from .result import MethodResult, WindowResult, WindowStats, write_results

log = logging.getLogger("blenav.eval")


def _error_stats(e: np.ndarray) -> dict:
    e = np.asarray(e, float)
    if e.size == 0:
        return {k: float("nan") for k in ("mean", "std", "median", "p75", "p90", "max")} | {"n": 0}
    return {"mean": float(e.mean()), "std": float(e.std()), "median": float(np.median(e)),
            "p75": float(np.percentile(e, 75)), "p90": float(np.percentile(e, 90)), "max": float(e.max()),
            "n": int(e.size)}


class TestWindows:
    """Windows of the test sessions, scored ones only: S (K, B, H) thesis scale, xy (K, 2), t (K,) per session."""

    def __init__(self, dm):
        from blenav.features.windows import session_windows

        self.sessions, self.windows, self.no_fix = [], {}, {}
        for s in dm.groups["test"]:
            if not s.labelled:
                continue
            w = session_windows(s, dm.beacons, dm.window)
            ok = ~np.isnan(w.xy).any(axis=1)
            heard = (w.S > 0).any(axis=(1, 2))
            self.no_fix[s.id] = int((ok & ~heard).sum())
            keep = ok & heard
            if keep.any():
                self.sessions.append(s)
                self.windows[s.id] = (w.S[keep], w.xy[keep], w.t[keep])
        if not self.sessions:
            raise EvalError("no labelled test windows: name test devices with labelled sessions "
                            "(data.test_devices=[...]) or keep data.holdout > 0")


def _train_run(cfg: EvalConfig, key: str, spec: dict, run_dir: Path, dm) -> tuple[Path, bool, dict]:
    """Train (or resume, or reuse) one learned method (``spec``: its ``experiment.learned`` node); returns its
    last.ckpt, whether it was reused without a training step, and its training report. The training config is built
    from the typed settings (:func:`blenav.learn.train.train` takes a DictConfig)."""
    from blenav.learn.train import train

    tcfg = OmegaConf.create({"seed": cfg.seed, "out": str(run_dir), "semi": spec.get("semi"),
                             "threads": cfg.threads, "plots": cfg.plots, "data": dataclasses.asdict(cfg.data),
                             "model": spec["model"],
                             "trainer": {**(cfg.trainer or {}), "enable_progress_bar": cfg.progress}})
    init = spec.get("init_from")
    ck = run_dir / "last.ckpt"
    copied = False
    if init and not ck.exists():  # scenario 3 continues scenario 2's run: start from its checkpoint
        src = run_dir.parent / str(init) / "last.ckpt"
        run_dir.mkdir(parents=True, exist_ok=True)
        shutil.copyfile(src, ck)
        copied = True
    before = _check_reuse(ck, dm, None if copied else tcfg.model, None if copied else tcfg)
    _, objs = train(tcfg, datamodule=dm)  # the split windowed once for every method
    training = {k: objs["training"].get(k) for k in TRAINING_KEYS}
    training["learning_curves"] = str(run_dir / "learning_curves.png")
    return ck, before == objs["global_step"], training  # (checkpoint, reused without a training step, report)


#: ``methods.NAME.training`` of a learned method (blenav.learn.common.report.training_report)
TRAINING_KEYS = ("steps", "budget_steps", "early_stopped", "stop_reason", "best_val_error_m", "knn_val_error_m",
                 "converged", "best_step", "train_windows", "val_windows", "batch_size", "warnings")


def _check_reuse(ck: Path, dm, model: DictConfig | None = None, tcfg: DictConfig | None = None) -> int | None:
    """The existing run's global step (None without a checkpoint); refuses one trained on other data or,
    when ``model`` is given, with another model config (sizes, lr, loss weights, augmentation), or, when the
    training config ``tcfg`` is given, a run that ended at another step budget (resuming it to this one would
    restart its learning-rate schedule midway: not the run this budget makes)."""
    from blenav.learn.common.checkpoint import KEY, read_checkpoint

    if not ck.is_file():
        return None
    state = read_checkpoint(ck, require_meta=False)
    meta = state.get(KEY, {})
    stored, now = meta.get("data_hash"), dm.train_hash()
    if stored not in (None, now):
        raise EvalError(f"{ck} was trained on other data (hash {stored} != {now}); "
                        f"delete {ck.parent} or choose another out=")
    if model is not None and meta.get("model") is not None:
        want = OmegaConf.to_container(model, resolve=True)
        diff = sorted(k for k in set(want) | set(meta["model"]) if want.get(k) != meta["model"].get(k))
        if diff:
            raise EvalError(f"{ck} was trained with another model config (differs in {', '.join(diff)}); "
                            f"delete {ck.parent} or choose another out=")
    done = state.get("blenav_training") or {}
    if tcfg is not None and done.get("stage") == "supervised" and done.get("stop_reason") == "max_steps":
        from blenav.learn.common.budget import budget
        from blenav.learn.crossphone.train import run_budget_steps

        had = int(done.get("budget_steps") or done.get("steps") or 0)
        want = run_budget_steps(budget(tcfg), dm)
        if had != want:
            raise EvalError(f"{ck} finished a budget of {had} steps, this run's is {want} (trainer.budget); "
                            f"delete {ck.parent}, choose another out= or set trainer.budget.max_steps={had}")
    return state["global_step"]


def _predict_module(ck: Path):
    from blenav.features.scale import U_SCALE
    from blenav.learn.crossphone.checkpoint import load_module

    module, _ = load_module(ck)

    def predict(S: np.ndarray) -> np.ndarray:
        with torch.no_grad():
            return module(torch.from_numpy(np.ascontiguousarray(S, np.float32) / U_SCALE)).numpy().astype(float)

    return predict


def _predict_onnx(path: str, building):
    from blenav.runtime import OnnxLocalizer

    try:
        model = OnnxLocalizer(path, building=building)
    except (ValueError, FileNotFoundError) as exc:  # another building's model, a missing file: say so
        raise EvalError(str(exc)) from exc
    return model.predict


class CrossPhoneEvaluator(Evaluator):
    """Learned and baseline localizers scored per RSSI window and phone (module doc)."""

    def run(self, cfg: EvalConfig) -> WindowResult:
        return evaluate_crossphone(cfg)


def evaluate_crossphone(cfg: EvalConfig) -> WindowResult:
    """Train-if-needed, fit, predict, score; writes OUT/results.json, results.md and plots."""
    from blenav.learn.crossphone.baselines import make_baseline
    from blenav.learn.crossphone.data import WindowDataModule

    out = Path(cfg.out)
    try:
        dm = WindowDataModule(dataclasses.replace(cfg.data))  # its own copy: the data module may fill in settings
        dm.setup()
    except (ValueError, DatasetError, FileNotFoundError) as exc:
        raise EvalError(str(exc)) from exc
    test = TestWindows(dm)
    runs_dir = Path(cfg.experiment.runs_dir or out / "runs")
    train_S, train_xy = (t.numpy() for t in (dm.sets["train"].tensors[0], dm.sets["train"].tensors[2]))
    from blenav.features.scale import U_SCALE

    train_S = train_S * U_SCALE  # baselines read the thesis scale
    onnx_model = cfg.model_path
    predictors, sources, train_s, trainings = {}, {}, {}, {}
    for key, spec in (cfg.experiment.learned or {}).items():
        if spec is None:  # switched off by an experiment (`learned.semi: null`)
            continue
        label = str(spec.get("label", key))
        if spec.get("needs_unlabelled") and dm.sets.get("unlabelled") is None:
            log.info("%s: no unlabelled devices (data.unlabelled_devices), not run", label)
            continue
        if onnx_model and label == "TransNet+LocNet":
            predictors[label], sources[label], train_s[label] = _predict_onnx(onnx_model, dm.building), \
                f"model: {onnx_model}", 0.0
            continue
        t0 = time.perf_counter()
        ck, reused, trainings[label] = _train_run(cfg, key, spec, runs_dir / key, dm)
        train_s[label] = None if reused else time.perf_counter() - t0
        predictors[label] = _predict_module(ck)
        sources[label] = f"{'reused' if reused else 'trained'}: {ck.parent}"
    for key, spec in (cfg.experiment.baselines or {}).items():
        if spec is None:
            continue
        kw = dict(spec or {})
        name = str(kw.pop("label", key))
        t0 = time.perf_counter()
        b = make_baseline(name, **kw)
        b.fit(train_S, train_xy)
        train_s[name] = time.perf_counter() - t0
        predictors[name], sources[name] = b.predict_sequence, "fitted"
    res = WindowResult(cfg.experiment.name, cfg.experiment.title, str(Path(cfg.data.path)), 1,
                       [s.id for s in test.sessions], cfg.seed,
                       split={k: sorted({s.device_model for s in v}) for k, v in dm.groups.items()},
                       train_sessions=[s.id for s in dm.groups["train"]], no_fix_windows=test.no_fix)
    errors: dict[str, dict[str, np.ndarray]] = {}
    for name, predict in predictors.items():
        t0 = time.perf_counter()
        errs = {}
        for s in test.sessions:
            S, xy, _ = test.windows[s.id]
            p = predict(S)
            if not np.isfinite(p).all():
                raise EvalError(f"{name} gave a non-finite position on session {s.id}")
            errs[s.id] = np.linalg.norm(p - xy, axis=1)
        errors[name] = errs
        res.methods[name] = _method_result(errs, test.sessions, time.perf_counter() - t0, train_s[name], sources[name])
        res.methods[name].training = trainings.get(name)
    out.mkdir(parents=True, exist_ok=True)
    write_results(out, res, cfg.experiment)
    if cfg.plots:
        _plots(out, res, errors)
    return res


def brand_of(session) -> str:
    """The receiver brand (session.yaml ``receiver_brand``, a simulator extension) or the device model."""
    return str(session.meta.get("receiver_brand") or session.device_model)


def _method_result(errs: dict[str, np.ndarray], sessions, predict_s: float, train_s: float | None,
                   source: str) -> MethodResult:
    by_dev: dict[str, list] = {}
    by_brand: dict[str, list] = {}
    for s in sessions:
        by_dev.setdefault(s.device_model, []).append(errs[s.id])
        by_brand.setdefault(brand_of(s), []).append(errs[s.id])
    allerr = np.concatenate(list(errs.values()))
    from .metrics import summary

    rmse = np.array([np.sqrt(np.mean(e ** 2)) for e in errs.values()])
    windows = WindowStats(per_device={d: _error_stats(np.concatenate(v)) for d, v in sorted(by_dev.items())},
                          per_brand={b: _error_stats(np.concatenate(v)) for b, v in sorted(by_brand.items())},
                          train_s=train_s, predict_s=predict_s, n_windows=int(allerr.size), source=source)
    return MethodResult(kind="windows", metrics={"error_m": _error_stats(allerr), "rmse_m": summary(rmse)},
                        per_session={s.id: {"error_m": _error_stats(errs[s.id]), "device_model": s.device_model}
                                     for s in sessions}, windows=windows)


def _plots(out: Path, res: WindowResult, errors: dict[str, dict[str, np.ndarray]]) -> None:
    from blenav import plotting

    from .metrics import cdf_band

    grid = np.linspace(0, 15, 301)
    cdfs = {n: cdf_band([np.concatenate(list(e.values()))], grid, q=(0.5, 0.5, 0.5)) for n, e in errors.items()}
    plotting.save_figure(plotting.figure_error_cdf(grid, cdfs, res.title), out / "error_cdf.png")
    per_dev = {n: {d: v["mean"] for d, v in m.windows.per_device.items()} for n, m in res.methods.items()}
    plotting.save_figure(plotting.figure_per_device(per_dev, res.title), out / "per_device.png")
