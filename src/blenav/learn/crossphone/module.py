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

A LocNet with a std head (``std_head: true``, issue 29) adds the term ``nll`` (weight ``weights.nll``, 1 by default):
the Gaussian negative log-likelihood of the labels under its positions (detached) and sigma. It is added to the loss
the optimizer steps on in training, and logged beside ``loss`` -- which stays the positions' objective, so the early
stopping on ``val/loss`` and the kept weights are the plain network's; the head reads detached features, so its
gradients reach no other weight. At a stage's end :meth:`CrossPhoneModule.calibrate` scales its sigma on the
validation windows (the training windows' errors, which the head learns, are smaller than a new walk's).

A place classifier (:class:`blenav.models.PlaceNet`, issue 29) in LocNet's seat steps on the cross-entropy of its place
scores (the term ``place``, logged); ``loss`` stays the positions' objective (L_loc of its softmax-weighted positions),
so ``val/loss``, the early stopping and the kept weights follow the positions the rows are scored on, not the
cross-entropy. Its sigma is the scores' spread, calibrated alike.
"""

from __future__ import annotations

from functools import partial

import lightning as L
import torch

from blenav.runtime.calibration import std_scale_fit

from ..common.schedule import lr_factor
from ..common.trainer import logs_this_step
from .augment import ReceiverAugment
from .losses import (gaussian_nll, localization_loss, position_smoothness_loss, ssl_loss, temporal_smoothness_loss,
                     total_loss)


class CrossPhoneModule(L.LightningModule):
    def __init__(self, locnet: torch.nn.Module, transnet: torch.nn.Module | None = None,
                 optimizer=partial(torch.optim.Adam, lr=1e-4), weights: dict | None = None,
                 M: torch.Tensor | None = None, tau: float = 0.1, meta: dict | None = None,
                 augment: ReceiverAugment | None = None, seed: int = 0, schedule: dict | None = None):
        super().__init__()
        self.locnet, self.transnet = locnet, transnet
        self.optimizer_factory = optimizer
        self.weights = {"loc": 1.0, "ps": 0.0, "ssl": 0.0, "ts": 0.0, "nll": 1.0, **(weights or {})}
        self.std_head = bool(getattr(locnet, "std_head", False))
        self.places = hasattr(locnet, "place_loss")  # PlaceNet: trained by cross-entropy over places
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
        scores = None
        if self.places:  # a place classifier (PlaceNet): its scores give the positions and its training objective
            scores = self.locnet.logits(g_all)
            f_all, sigma = self.locnet.position_std(scores)
        elif self.std_head:
            f_all, sigma = self.locnet.forward_std(g_all)
        else:
            f_all, sigma = self.locnet(g_all), None
        g, f = g_all[:n], f_all[:n]
        terms = {}
        labelled = ~torch.isnan(batch["xy"]).any(dim=1)
        if scores is not None and labelled.any():
            terms["place"] = self.locnet.place_loss(scores[:n][labelled], batch["xy"][labelled])
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
        terms["loss"] = total_loss({k: v for k, v in terms.items() if k != "place"}, self.weights)
        if sigma is not None and scores is None and labelled.any():  # the std head's term: beside the monitored loss
            terms["nll"] = gaussian_nll(f[labelled].detach(), batch["xy"][labelled], sigma[:n][labelled])
        with torch.no_grad():
            if labelled.any():
                terms["err_m"] = (f[labelled] - batch["xy"][labelled]).norm(dim=1).mean()
        return terms

    def _log_step(self, batch, stage: str) -> dict[str, torch.Tensor]:
        out = self.model_step(batch)
        if stage == "train" and not logs_this_step(self._trainer):  # a value no logger would keep
            return out
        for k, v in out.items():
            self.log(f"{stage}/{k}", v, prog_bar=k in ("loss", "err_m"), batch_size=batch["S"].shape[0],
                     sync_dist=stage != "train")  # epoch metrics averaged over DDP ranks
        return out

    def training_step(self, batch, batch_idx):
        if self.augment is not None:  # training windows only: validation and test see the phones as they are
            keys = [k for k in ("S", "S_prev") if k in batch]
            batch = {**batch, **dict(zip(keys, self.augment([batch[k] for k in keys], self.aug_generator)))}
        out = self._log_step(batch, "train")
        if "place" in out:  # a place classifier steps on its cross-entropy; the curve shows the positions' loss
            return {"loss": out["place"], "monitored": out["loss"].detach()}
        if "nll" not in out:
            return out["loss"]
        # the optimizer steps on both; "monitored" is the positions' loss the learning curve shows beside val/loss
        return {"loss": out["loss"] + self.weights["nll"] * out["nll"], "monitored": out["loss"].detach()}

    def validation_step(self, batch, batch_idx):
        return self._log_step(batch, "val")["loss"]

    def test_step(self, batch, batch_idx):
        return self._log_step(batch, "test")["loss"]

    def calibrate(self, dm) -> dict:
        """With a std head: set LocNet's ``std_scale`` to the maximum-likelihood scale c of its sigma on the data
        module's validation windows (:func:`blenav.runtime.calibration.std_scale_fit`) and return
        ``{"fix_std": {model, scale, windows, coverage_1sigma, coverage_2sigma, median_std_m, rank_correlation}}``;
        without validation windows the scale is the data module's ``std_scale`` when it has one (a refit on every
        walk: :func:`blenav.learn.fingerprint.train.train_network`), else 1 and the report says so. {} without a std
        head. Called by :func:`blenav.learn.common.stage.end_stage`."""
        if not self.std_head:
            return {}
        val = dm.sets.get("val") if hasattr(dm, "sets") else None
        S, xy = (val.tensors[0], val.tensors[-1]) if val is not None and len(val) else (None, None)
        ok = ~torch.isnan(xy).any(dim=1) if xy is not None else None
        if ok is None or not ok.any():
            given = getattr(dm, "std_scale", None)  # a refit's data module: the scale of the run it refits
            self.locnet.std_scale.fill_(1.0 if given is None else float(given))
            if given is not None:
                return {"fix_std": {"scale": float(given), "model": "the scale fitted on the validation windows of "
                                                                    "the run this one refits (it has none)"}}
            return {"fix_std": "uncalibrated (scale 1): no labelled validation windows"}
        was = self.training
        self.eval()
        with torch.no_grad():
            self.locnet.std_scale.fill_(1.0)
            f, sigma = self.locnet.forward_std(self.translate(S[ok].to(self.device)))
            err = (f - xy[ok].to(self.device)).norm(dim=1)
        self.train(was)
        c, rep = std_scale_fit(err.double().cpu().numpy(), sigma.double().cpu().numpy())
        self.locnet.std_scale.fill_(c)
        if "uncalibrated" in rep:
            return {"fix_std": f"uncalibrated ({rep['uncalibrated']})"}
        what = "the place scores' spread" if self.places else "sigma of LocNet's std head (Gaussian NLL)"
        return {"fix_std": {"model": f"{what} x scale, the scale fitted by maximum likelihood on the validation "
                                     "windows", **rep}}

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
