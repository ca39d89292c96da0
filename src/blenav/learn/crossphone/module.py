"""The LightningModule of the cross-phone localizer: wraps built networks, one step for train/val/test.

Batches are dicts: ``S`` (b, B, H) windows on the normalised scale u / 100 (see
:mod:`blenav.learn.crossphone.losses`), ``xy`` (b, 2) metres (NaN rows for unlabelled windows), optionally
``S_prev`` (b, B, H) the window one step earlier for the position-smoothness loss. With ``transnet`` None
the module is plain LocNet (scenario 1 and the baselines 1/2 of Roy). Loss weights follow eq. 3.6;
``M`` (B, B) is the known brand's statistics matrix (eq. 3.1) when the SSL term is used. ``augment``
(:class:`blenav.learn.crossphone.augment.ReceiverAugment`) re-receives training windows by random phones.

Learning rate: Adam at ``optimizer``'s lr times :func:`blenav.learn.common.schedule.lr_factor` of the optimizer step
when ``schedule`` is given (``{"kind", "warmup_steps", "total_steps", "min_lr_ratio"}``: linear warm-up, then
cosine or one-cycle; a ``LambdaLR`` stepped every optimizer step, its state resumes with the checkpoint),
else constant. ``stage = "semi"`` (the semi-supervised stage of scenario 3) trains at the constant
``semi_lr`` instead, whatever the optimizer state restored from the supervised stage held.
"""

from __future__ import annotations

from functools import partial

import lightning as L
import torch

from ..common.schedule import lr_factor
from .augment import ReceiverAugment
from .losses import localization_loss, position_smoothness_loss, ssl_loss, temporal_smoothness_loss, total_loss


class CrossPhoneModule(L.LightningModule):
    def __init__(self, locnet: torch.nn.Module, transnet: torch.nn.Module | None = None,
                 optimizer=partial(torch.optim.Adam, lr=1e-4), weights: dict | None = None,
                 M: torch.Tensor | None = None, tau: float = 0.1, meta: dict | None = None,
                 augment: ReceiverAugment | None = None, seed: int = 0, schedule: dict | None = None):
        super().__init__()
        self.locnet, self.transnet = locnet, transnet
        self.optimizer_factory = optimizer
        self.weights = {"loc": 1.0, "ps": 0.0, "ssl": 0.0, "ts": 0.0, **(weights or {})}
        self.tau = tau
        self.meta = meta or {}  # stored in checkpoints under "blenav" (see blenav.learn.crossphone.checkpoint)
        self.schedule = dict(schedule) if schedule else None
        self.training_info: dict = {}  # training report so far (crossphone.train), saved with the checkpoint
        self.stage = "supervised"  # "semi": scenario 3's stage, constant lr semi_lr
        self.semi_lr = 1e-4
        self.augment = augment if augment is not None and augment.active else None
        self.aug_generator = torch.Generator().manual_seed(seed)  # its state is saved with the checkpoint
        self.register_buffer("M", M if M is not None else torch.zeros(0, 0), persistent=True)

    def translate(self, S: torch.Tensor) -> torch.Tensor:
        return self.transnet(S) if self.transnet is not None else S

    def forward(self, S: torch.Tensor) -> torch.Tensor:
        """Positions (b, 2) in metres."""
        return self.locnet(self.translate(S))

    def model_step(self, batch: dict) -> dict[str, torch.Tensor]:
        S = batch["S"]
        with_prev = bool(self.weights["ps"]) and "S_prev" in batch
        n = S.shape[0]
        # the previous windows (position smoothness) go through the networks in the same pass
        g_all = self.translate(torch.cat([S, batch["S_prev"]]) if with_prev else S)
        f_all = self.locnet(g_all)
        g, f = g_all[:n], f_all[:n]
        terms = {}
        labelled = ~torch.isnan(batch["xy"]).any(dim=1)
        if labelled.any() and self.weights["loc"]:
            terms["loc"] = localization_loss(f[labelled], batch["xy"][labelled])
        if with_prev:
            terms["ps"] = position_smoothness_loss(f, f_all[n:])
        if self.transnet is not None and self.weights["ssl"] and self.M.numel():
            terms["ssl"] = ssl_loss(g, S, self.M, self.tau)
        if self.transnet is not None and self.weights["ts"]:
            terms["ts"] = temporal_smoothness_loss(g)
        if not terms:
            raise ValueError("no loss term applies to this batch (no labels and no unsupervised term enabled)")
        terms["loss"] = total_loss({k: v for k, v in terms.items()}, self.weights)
        with torch.no_grad():
            if labelled.any():
                terms["err_m"] = (f[labelled] - batch["xy"][labelled]).norm(dim=1).mean()
        return terms

    def _log_step(self, batch, stage: str) -> torch.Tensor:
        out = self.model_step(batch)
        for k, v in out.items():
            self.log(f"{stage}/{k}", v, prog_bar=k in ("loss", "err_m"), batch_size=batch["S"].shape[0],
                     sync_dist=stage != "train")  # epoch metrics averaged over DDP ranks
        return out["loss"]

    def training_step(self, batch, batch_idx):
        if self.augment is not None:  # training windows only: validation and test see the phones as they are
            keys = [k for k in ("S", "S_prev") if k in batch]
            batch = {**batch, **dict(zip(keys, self.augment([batch[k] for k in keys], self.aug_generator)))}
        return self._log_step(batch, "train")

    def validation_step(self, batch, batch_idx):
        return self._log_step(batch, "val")

    def test_step(self, batch, batch_idx):
        return self._log_step(batch, "test")

    def on_train_batch_start(self, batch, batch_idx) -> None:
        if self.stage == "semi":  # the optimizer state restored from the supervised stage carries its lr
            for opt in self.trainer.optimizers:
                for group in opt.param_groups:
                    group["lr"] = self.semi_lr

    def on_save_checkpoint(self, checkpoint: dict) -> None:
        checkpoint["blenav"] = self.meta
        checkpoint["blenav_aug_rng"] = self.aug_generator.get_state()
        checkpoint["blenav_training"] = self.training_info

    def on_load_checkpoint(self, checkpoint: dict) -> None:
        if "blenav_aug_rng" in checkpoint:  # a resumed run continues the augmentation stream
            self.aug_generator.set_state(checkpoint["blenav_aug_rng"])
        if "blenav_training" in checkpoint:
            self.training_info = dict(checkpoint["blenav_training"] or {})

    def configure_optimizers(self):
        opt = self.optimizer_factory(self.parameters())
        if self.stage == "semi" or not self.schedule:
            return opt
        sc = self.schedule
        fn = partial(lr_factor, kind=str(sc.get("kind", "cosine")), warmup_steps=int(sc.get("warmup_steps", 0)),
                     total_steps=int(sc["total_steps"]), min_lr_ratio=float(sc.get("min_lr_ratio", 0.01)))
        sched = torch.optim.lr_scheduler.LambdaLR(opt, fn)
        return {"optimizer": opt, "lr_scheduler": {"scheduler": sched, "interval": "step", "frequency": 1}}
