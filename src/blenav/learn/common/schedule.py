"""The learning-rate schedule of the step budget (``trainer.budget`` of conf/trainer/cpu.yaml), torch-free.

:func:`lr_factor` is the multiplier of the base learning rate per optimizer step that
:class:`blenav.learn.crossphone.module.CrossPhoneModule` hands to ``torch.optim.lr_scheduler.LambdaLR``.
"""

from __future__ import annotations

import math

SCHEDULES = ("cosine", "onecycle", "constant")


def lr_factor(step: int, kind: str, warmup_steps: int, total_steps: int, min_lr_ratio: float = 0.01) -> float:
    """Multiplier of the base learning rate at optimizer step ``step`` (0-based), for ``LambdaLR``.

    ``cosine``: linear warm-up from ``1 / warmup_steps`` to 1 over ``warmup_steps``, then half a cosine from 1
    down to ``min_lr_ratio`` at ``total_steps`` (held there after). ``onecycle``: the same shape with the
    warm-up taking 30 % of ``total_steps`` (the default ``pct_start`` of torch's OneCycleLR) whatever
    ``warmup_steps`` says. ``constant``: warm-up, then 1."""
    if kind not in SCHEDULES:
        raise ValueError(f"trainer.budget.schedule={kind!r} is not one of {SCHEDULES}")
    total = max(int(total_steps), 1)
    warm = int(round(0.3 * total)) if kind == "onecycle" else max(int(warmup_steps), 0)
    if warm > 0 and step < warm:
        return (step + 1) / warm
    if kind == "constant":
        return 1.0
    t = min(max(step - warm, 0) / max(total - warm, 1), 1.0)
    return float(min_lr_ratio + (1.0 - min_lr_ratio) * 0.5 * (1.0 + math.cos(math.pi * t)))
