"""Training the inertial odometry (issue 31): ``train_inertial(cfg)``.

``python train.py experiment=inertial data=DIR [data.extra_paths=[DIR2,...]] [data.sessions=[...]] out=RUN`` (``task:
inertial``, dispatched by :func:`blenav.learn.train.train`): walks and segments (:mod:`blenav.learn.inertial.data`),
the network of ``model`` (``model=inertial_resnet`` default, ``model=inertial_tcn``), the segment-integral loss
(:mod:`blenav.learn.inertial.module`), the step budget with early stopping on the validation walks and the best
validation check's weights kept (:mod:`blenav.learn.common.stage`, as the cross-phone localizer), ``RUN/last.ckpt``
resumed from when present.

Report (``RUN/training.json``, ``RUN/learning_curves.png``): the best validation segment error (m) beside PDR's on the
same validation segments (:func:`pdr_val_error`: detected steps along the walk's own heading, one step length fitted on
the training walks), and the walks / segments / windows of each split.

Real walks with surveyed waypoints and simulated walks train together, e.g. leave one ILC floor out::

    python train.py experiment=inertial data=data/ilc20/F2 'data.extra_paths=[data/ilc20/B1,data/sim]' out=RUN \\
        "data.sessions=[$(python -m blenav.cli.realwalks train-ids data/ilc20/F2),$(... B1),...]"
"""

from __future__ import annotations

import logging

import numpy as np
from omegaconf import DictConfig, OmegaConf

from blenav.errors import MissingStream
from blenav.features.inertial import CHANNELS, displacement_errors
from blenav.filters.pdr_odometry import fitted_step_length, pdr_odometry

from ..common.budget import budget, budget_steps, trainer_settings
from ..common.checkpoint import data_hash, read_checkpoint
from ..common.stage import prior_training, supervised_stage
from ..common.trainer import LAST, TrainingMonitor, fit, start_run
from .checkpoint import KIND, build_net
from .data import InertialDataModule
from .data_config import InertialDataConfig
from .module import InertialModule

log = logging.getLogger("blenav.train")

FRAME = ("gravity-aligned: device IMU rotated by the attitude (device->world), gravity taken off z; yaw as the "
         "attitude's (rotation vector / AHRS: magnetic north)")


def inertial_data_config(cfg: DictConfig) -> InertialDataConfig:
    """The ``data`` node checked against :class:`InertialDataConfig` (a misspelt key fails here)."""
    node = OmegaConf.to_container(cfg.data, resolve=True)
    return OmegaConf.to_object(OmegaConf.merge(OmegaConf.structured(InertialDataConfig), node))


def build_meta(model: dict, dm: InertialDataModule, counts: dict) -> dict:
    c = dm.cfg
    return {"kind": KIND, "model": model, "grid": dm.grid.as_dict(), "channels": list(CHANNELS), "frame": FRAME,
            "input_frame": c.frame,
            "attitude": {"attitude": c.attitude, "dense_attitude": c.dense_attitude, "yaw": c.yaw},
            "outputs": "velocity (vx, vy) m/s over the window's last stride, log variance (log vx^2, log vy^2)",
            "datasets": c.paths, "sessions": sorted(s.id for v in dm.sessions.values() for s in v),
            "val_sessions": sorted(s.id for s in dm.sessions.get("val", [])),
            "counts": counts,
            # every training sample and every supervised segment (its span and target)
            "data_hash": data_hash(*[w.Xp for w in dm.walks["train"]], dm.segments["train"].span,
                                   dm.segments["train"].target)}


def pdr_val_error(dm: InertialDataModule) -> float | None:
    """Mean segment error (m) of PDR on the validation segments: detected steps along the walk's heading (``auto``:
    the rotation vector, else the AHRS), the step length fitted on the training walks; None without validation walks
    (or when no walk has a PDR track)."""
    if "val" not in dm.segments:
        return None
    cache: dict = {}
    try:
        step = fitted_step_length(dm.sessions["train"], None, cache)["step_length_m"]
    except MissingStream as exc:
        log.info("no PDR baseline: %s", exc)
        return None
    seg, errs = dm.segments["val"], []
    for i, s in enumerate(dm.sessions["val"]):
        m = seg.walk == i
        try:
            odo = pdr_odometry(s, "auto", step, cache=cache)
        except MissingStream:
            continue
        errs.append(displacement_errors(odo["t"].to_numpy(float), odo[["x", "y"]].to_numpy(float), seg.span[m, 0],
                                        seg.span[m, 1], seg.target[m]))
    return float(np.concatenate(errs).mean()) if errs and sum(map(len, errs)) else None


#: what a resumed run must share with the checkpoint it resumes: its weights mean nothing under another contract
RESUME_KEYS = ("grid", "channels", "input_frame", "attitude")


def check_resume(out, meta: dict) -> None:
    """Refuse (ValueError naming the keys) to resume ``out/last.ckpt`` when its meta's input contract or network differ
    from this run's: a TCN's weights load whatever the grid or frame, and the new meta would then describe inputs the
    weights never saw."""
    ck = out / LAST
    if not ck.is_file():
        return
    old = read_checkpoint(ck, "inertial odometry").get("blenav") or {}
    if old.get("kind") != meta.get("kind"):
        raise ValueError(f"{ck}: a {old.get('kind') or 'crossphone'} run, not an inertial odometry one; choose another out=")
    differ = [k for k in RESUME_KEYS if k != "attitude" and old.get(k) != meta.get(k)]
    # a checkpoint from before data.yaw trained on the attitude's own yaw (data.yaw=attitude resumes it)
    was, now = dict(old.get("attitude") or {}), dict(meta.get("attitude") or {})
    was.setdefault("yaw", "attitude")
    differ += [f"data.{k} ({was.get(k)!r}, now {now.get(k)!r})" for k in sorted(set(was) | set(now))
               if was.get(k) != now.get(k)]
    if (old.get("model") or {}).get("net") != (meta.get("model") or {}).get("net"):
        differ.append("model.net")
    if differ:
        raise ValueError(f"{ck} was trained with other {', '.join(differ)} than this run asks for; it cannot be resumed: "
                         "choose another out= (or restore the run's settings)")


def train_inertial(cfg: DictConfig, callbacks: list | None = None) -> tuple[dict, dict]:
    """``task: inertial``: fit the network of ``cfg.model`` on the walks of ``cfg.data``; returns (metrics, objects)."""
    out = start_run(cfg.seed, cfg.out)
    model = OmegaConf.to_container(cfg.model, resolve=True)
    if model.get("kind") != KIND:
        raise ValueError(f"task=inertial needs an inertial odometry model (model=inertial_resnet or inertial_tcn), "
                         f"got model {model.get('name')!r}")
    dcfg = inertial_data_config(cfg)
    dm = InertialDataModule(dcfg)
    dm.setup()
    counts = dm.counts()
    net = build_net(model, dm.grid)
    mean, std = dm.normalisation()
    net.set_normalisation(mean, std)
    module = InertialModule(net, lr=float(model["lr"]), weight_decay=float(model.get("weight_decay", 1e-4)),
                            nll_weight=float(model.get("nll_weight", 0.1)), meta=build_meta(model, dm, counts))
    check_resume(out, module.meta)  # before anything of the run folder is written
    b = budget(cfg)
    has_val = "val" in dm.sets
    if not has_val:
        b["patience"] = None
    max_steps = budget_steps(b, counts["train"]["windows"])  # a number, -1 (none) or auto (grows with the windows)
    trainer_kw, module.schedule = trainer_settings(cfg, b, max_steps, len(dm.sets["train"]), dcfg.batch_segments)
    if not has_val:
        trainer_kw["limit_val_batches"] = 0
    (out / "config.yaml").write_text(OmegaConf.to_yaml(cfg, resolve=True), encoding="utf-8")
    title = f"{model.get('name', 'inertial')} ({out})"
    plots = bool(cfg.get("plots", True))
    prior = prior_training(out)
    if prior.get("stop_reason") == "early_stopping" or (prior and prior.get("steps", 0) >= max_steps > 0):
        info = prior  # finished before: its checkpoint's weights
        module.training_info = info
        module.load_state_dict(read_checkpoint(out / LAST, require_meta=False)["state_dict"])
        trainer = fit(module, dm, out, trainer_kw, [], run=False)
    else:
        base = pdr_val_error(dm)
        info, trainer = supervised_stage(module, dm, out, trainer_kw, b, max_steps, TrainingMonitor(), base,
                                         callbacks, title, plots, extra_info={"data": counts}, baseline="PDR",
                                         timed=True)
    metrics = {k: float(v) for k, v in trainer.callback_metrics.items()}
    if info.get("best_val_error_m") is not None:
        metrics["best_val_err_m"] = float(info["best_val_error_m"])
    return metrics, {"module": module, "datamodule": dm, "trainer": trainer, "training": info}
