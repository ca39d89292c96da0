"""The LightningModule of the Map Prior Network (Roy, section 3.2.2): wraps a built network, one step for
train / validation / test.

Notation as in :mod:`blenav.models.mapprior`: M free mask at ``model.resolution_m``, O odometry window,
DMT f(M), DTV g(O), S = f(M)_x . g(O) (eq. 3.8, Roy). Data, targets T = 1e-6 exp(14 T_bar) and loss weights
come from :mod:`blenav.learn.mapprior.data`.

Loss: weighted MSE over every pixel of every crop, sum(w (S - T)^2) / sum(w) (Roy: MSE(T, S) with
feasible regions weighted by the inverse of their area). Logged per stage (``train``, ``val``, and one
prefix per validation split, ``val_seen`` / ``val_unseen``): ``loss``, ``mse`` (unweighted) and ``gt_pct``,
the share of the crop's free pixels whose score beats the score at the true window end (0 best, about 0.5
for a prior that knows nothing). ``val/*`` is the first validation split (held-out sessions of the training
buildings when there are any, else the held-out buildings).

The module stores its ``meta`` in every checkpoint (see :mod:`blenav.learn.mapprior.checkpoint`).
"""

from __future__ import annotations

import lightning as L
import torch

from blenav.models.mapprior import MapPriorNet

from ..common.checkpoint import KEY


class MapPriorModule(L.LightningModule):
    """Wraps a built :class:`MapPriorNet`; one shared step for train / validation / test."""

    def __init__(self, net: MapPriorNet, lr: float = 0.01, meta: dict | None = None,
                 val_names: tuple[str, ...] | list[str] = ("val_seen",), lr_decay: str | None = None):
        super().__init__()
        if lr_decay not in (None, "none", "cosine"):
            raise ValueError(f"model.lr_decay must be null, none or cosine, got {lr_decay!r}")
        self.net, self.lr, self.lr_decay = net, float(lr), lr_decay
        self.meta = meta or {}
        self.val_names = list(val_names)

    def forward(self, m: torch.Tensor, odo: torch.Tensor) -> torch.Tensor:
        return self.net(m, odo)

    def model_step(self, batch: dict) -> dict[str, torch.Tensor]:
        S = self.net(batch["map"], batch["odo"])  # (b, H, W), eq. 3.8
        T, w = batch["target"], batch["weight"]
        err2 = (S - T) ** 2
        out = {"loss": (w * err2).sum() / w.sum(), "mse": err2.mean()}
        with torch.no_grad():
            b = torch.arange(S.shape[0])
            s_end = S[b, batch["end"][:, 0], batch["end"][:, 1]]
            free = batch["map"][:, 0] > 0.5
            better = ((S > s_end[:, None, None]) & free).flatten(1).sum(1).float()
            out["gt_pct"] = (better / free.flatten(1).sum(1).clamp(min=1).float()).mean()
        return out

    def _log(self, out: dict, prefixes: list[str], batch_size: int) -> None:
        for p in prefixes:
            for k, v in out.items():
                self.log(f"{p}/{k}", v, prog_bar=(p in ("train", "val") and k == "loss"), batch_size=batch_size,
                         add_dataloader_idx=False)

    def training_step(self, batch, batch_idx):
        out = self.model_step(batch)
        self._log(out, ["train"], batch["map"].shape[0])
        return out["loss"]

    def validation_step(self, batch, batch_idx, dataloader_idx: int = 0):
        out = self.model_step(batch)
        name = self.val_names[dataloader_idx] if dataloader_idx < len(self.val_names) else f"val_{dataloader_idx}"
        self._log(out, ["val", name] if dataloader_idx == 0 else [name], batch["map"].shape[0])

    def test_step(self, batch, batch_idx, dataloader_idx: int = 0):
        self._log(self.model_step(batch), ["test"], batch["map"].shape[0])

    def on_save_checkpoint(self, checkpoint: dict) -> None:
        checkpoint[KEY] = self.meta

    def configure_optimizers(self):
        opt = torch.optim.Adam(self.parameters(), lr=self.lr)
        if self.lr_decay != "cosine":
            return opt
        # per epoch, from lr to 0 over trainer.max_epochs (the scheduler state resumes with the run)
        sched = torch.optim.lr_scheduler.CosineAnnealingLR(opt, T_max=max(1, int(self.trainer.max_epochs)))
        return {"optimizer": opt, "lr_scheduler": {"scheduler": sched, "interval": "epoch"}}
