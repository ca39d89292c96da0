"""The training report of a run (``train.py`` and ``blenav-eval`` alike): ``OUT/training.json``
(:func:`training_report`: steps, whether early stopping ended the run and why it stopped, the best validation error
in metres beside KNN's on the same validation windows, warnings), ``OUT/learning_curves.png`` (``plots: false``
skips it), and a logged warning (logger ``blenav.train``) when the network is worse than KNN on the validation
windows or stopped before its validation loss levelled off. The curves come from
:class:`blenav.learn.common.trainer.TrainingMonitor`.
"""

from __future__ import annotations

import json
import logging
import math
from pathlib import Path

from .trainer import TrainingMonitor

log = logging.getLogger("blenav.train")


def _converged(history: list[dict]) -> bool:
    """The validation loss levelled off: the last quarter of the checks (at least 2) improved the best value of
    the checks before them by less than 1 %."""
    v = [h["val_loss"] for h in history if h.get("val_loss") is not None and math.isfinite(h["val_loss"])]
    if len(v) < 8:
        return False
    q = max(2, len(v) // 4)
    before, after = min(v[:-q]), min(v[-q:])
    return after >= before * (1.0 - 0.01)


def training_report(monitor: TrainingMonitor, reason: str, steps: int, knn_err: float | None,
                    stage: str = "supervised", baseline: str = "KNN") -> dict:
    """The training dict of a run (results.json ``methods.NAME.training``, OUT/training.json); ``knn_err`` is the
    validation error (m) of the simplest ``baseline`` on the same validation data (KNN for a fingerprint network,
    PDR for the inertial odometry), stored as ``knn_val_error_m`` for KNN, else as ``baseline_val_error_m`` with
    ``baseline`` naming it."""
    best = monitor.best or {}
    last = monitor.history[-1] if monitor.history else {}
    err = best.get("val_err_m") if stage == "supervised" else last.get("val_err_m")
    early = reason == "early_stopping"
    info = {"stage": stage, "steps": int(steps), "early_stopped": early, "stop_reason": reason,
            "best_step": best.get("step"), "best_val_loss": best.get("val_loss"),
            "best_val_error_m": err, **({"knn_val_error_m": knn_err} if baseline == "KNN" else
                                        {"baseline": baseline, "baseline_val_error_m": knn_err}),
            "converged": early or _converged(monitor.history), "val_checks": len(monitor.history), "warnings": []}
    if err is not None and knn_err is not None and err > knn_err:
        info["warnings"].append(f"worse than {baseline} on the validation data: {err:.2f} m vs {knn_err:.2f} m")
    if not info["converged"] and stage == "supervised" and monitor.history:  # without checks: the warning below
        info["warnings"].append(f"stopped ({reason}) after {steps} steps before the validation loss levelled off "
                                "(raise trainer.budget.max_steps or model.lr)")
    if err is None:
        info["warnings"].append(f"no validation windows: nothing to stop early on or to compare with {baseline} "
                                "(data.val_fraction > 0 and more than one labelled training session)")
    return info


def write_report(out: Path, info: dict, monitor: TrainingMonitor, title: str, plots: bool) -> None:
    """OUT/training.json (``info`` and the monitor's curve), the warnings logged, OUT/learning_curves.png."""
    (out / "training.json").write_text(json.dumps({**info, "history": monitor.history}, indent=1) + "\n",
                                       encoding="utf-8")
    for w in info["warnings"]:
        log.warning("%s: %s", title, w)
    if plots and monitor.history:
        from blenav import plotting

        base = info.get("baseline", "KNN")
        fig = plotting.figure_learning_curves(monitor.history, info.get(f"{base.lower()}_val_error_m",
                                                                         info.get("baseline_val_error_m")), title, base)
        plotting.save_figure(fig, out / "learning_curves.png")
