"""The LightningModule of the inertial odometry (issue 31): wraps a built :class:`blenav.models.inertial.InertialNet`;
one step for train / validation.

The segment-integral loss. A batch is B segments (:mod:`blenav.learn.inertial.data`); their N windows run through the
network at once, giving velocities v_k and log variances l_k (turned back from each window's heading frame by its psi_k,
:func:`to_attitude_frame`). Segment j's predicted displacement and its variance
(windows taken as independent) are

    D_j = sum_k w_jk v_k,          V_j = sum_k w_jk^2 exp(l_k)        (per axis; w_jk seconds)

against the surveyed displacement d_j (between two waypoints, or along a dense trajectory). The loss is

    mse = mean_j |D_j - d_j|^2 / T_j^2                  (T_j = sum_k w_jk: the error as a mean velocity, (m/s)^2)
    nll = mean_j 1/2 sum_axes [ (D_j - d_j)^2 / V_j + log V_j ]   with D_j detached
    loss = mse + nll_weight * nll

so the velocity is fitted by the MSE (TLIO trains its mean first) and the covariance head by the Gaussian likelihood of
the residual it cannot remove. Logged: ``loss``, ``mse``, ``nll``, ``err_m`` (mean |D_j - d_j|, m: the challenge's
segment error when the segments are waypoint segments).
"""

from __future__ import annotations

from functools import partial

import lightning as L
import torch

from blenav.models.inertial import InertialNet, to_attitude_frame

from ..common.checkpoint import KEY
from ..common.schedule import lr_factor


def segment_integral(out: torch.Tensor, segment: torch.Tensor, weight: torch.Tensor, n_segments: int,
                     psi: torch.Tensor | None = None) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """(D (B, 2) m, V (B, 2) m^2, T (B,) s) of the network outputs ``out`` (N, 4) over the segments (module doc), the
    outputs first turned back by the windows' headings ``psi`` (N,) when given."""
    if psi is None:
        v, var = out[:, :2], torch.exp(out[:, 2:])
    else:
        v, var = to_attitude_frame(out, psi)
    w = weight[:, None]
    D = out.new_zeros(n_segments, 2).index_add(0, segment, w * v)  # on the outputs' device
    V = out.new_zeros(n_segments, 2).index_add(0, segment, w * w * var)
    T = out.new_zeros(n_segments).index_add(0, segment, weight.to(out.dtype))
    return D, V, T


def segment_loss(out: torch.Tensor, batch: dict, nll_weight: float = 0.1) -> dict[str, torch.Tensor]:
    """The loss terms of a batch (module doc)."""
    B = batch["target"].shape[0]
    D, V, T = segment_integral(out, batch["segment"], batch["weight"], B, batch.get("psi"))
    r = D - batch["target"]
    mse = ((r ** 2).sum(dim=1) / T.clamp(min=1e-3) ** 2).mean()
    rd = D.detach() - batch["target"]
    nll = 0.5 * (rd ** 2 / V + torch.log(V)).sum(dim=1).mean()
    return {"loss": mse + float(nll_weight) * nll, "mse": mse, "nll": nll, "err_m": r.norm(dim=1).mean()}


class InertialModule(L.LightningModule):
    """Wraps a built :class:`InertialNet`; AdamW at ``lr`` with the step budget's schedule (``schedule``, set by the
    trainer from ``trainer.budget``); ``meta`` goes into every checkpoint."""

    def __init__(self, net: InertialNet, lr: float = 1e-3, weight_decay: float = 1e-4, nll_weight: float = 0.1,
                 meta: dict | None = None):
        super().__init__()
        self.net, self.lr, self.weight_decay, self.nll_weight = net, float(lr), float(weight_decay), float(nll_weight)
        self.meta = meta or {}
        self.schedule: dict | None = None
        self.training_info: dict = {}

    def forward(self, imu: torch.Tensor) -> torch.Tensor:
        return self.net(imu)

    def _step(self, batch: dict, stage: str) -> torch.Tensor:
        out = segment_loss(self.net(batch["windows"]), batch, self.nll_weight)
        B = batch["target"].shape[0]
        for k, v in out.items():
            self.log(f"{stage}/{k}", v, prog_bar=(k == "loss"), batch_size=B, on_step=False, on_epoch=True)
        return out["loss"]

    def on_train_epoch_start(self) -> None:
        dm = getattr(self.trainer, "datamodule", None)
        if dm is not None and "train" in getattr(dm, "sets", {}):
            dm.sets["train"].set_epoch(self.current_epoch)  # a new augmentation draw per epoch, resumable

    def training_step(self, batch, batch_idx):
        return self._step(batch, "train")

    def validation_step(self, batch, batch_idx):
        self._step(batch, "val")

    def on_save_checkpoint(self, checkpoint: dict) -> None:
        checkpoint[KEY] = self.meta

    def configure_optimizers(self):
        opt = torch.optim.AdamW(self.parameters(), lr=self.lr, weight_decay=self.weight_decay)
        if not self.schedule:
            return opt
        sc = self.schedule
        fn = partial(lr_factor, kind=str(sc.get("kind", "cosine")), warmup_steps=int(sc.get("warmup_steps", 0)),
                     total_steps=int(sc["total_steps"]), min_lr_ratio=float(sc.get("min_lr_ratio", 0.01)))
        return {"optimizer": opt, "lr_scheduler": {"scheduler": torch.optim.lr_scheduler.LambdaLR(opt, fn),
                                                   "interval": "step", "frequency": 1}}
