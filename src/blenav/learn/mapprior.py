"""Training the Map Prior Network (Roy, section 3.2.2): LightningModule, ``train_mapprior(cfg)``, checkpoints.

Notation as in :mod:`blenav.models.mapprior`: M free mask at ``model.resolution_m``, O odometry window,
DMT f(M), DTV g(O), S = f(M)_x . g(O) (eq. 3.8, Roy). Data, targets T = 1e-6 exp(14 T_bar) and loss weights
come from :mod:`blenav.learn.mapprior_data`.

Loss: weighted MSE over every pixel of every crop, sum(w (S - T)^2) / sum(w) (Roy: MSE(T, S) with
feasible regions weighted by the inverse of their area). Logged per stage (``train``, ``val``, and one
prefix per validation split, ``val_seen`` / ``val_unseen``): ``loss``, ``mse`` (unweighted) and ``gt_pct``,
the share of the crop's free pixels whose score beats the score at the true window end (0 best, about 0.5
for a prior that knows nothing). ``val/*`` is the first validation split (held-out sessions of the training
buildings when there are any, else the held-out buildings).

``python train.py experiment=mapprior data=DIR out=RUN`` (``task: mapprior``) runs :func:`train_mapprior`:
Adam (lr 0.01, batch 32 as Roy), ``trainer.max_epochs`` epochs of ``data.samples_per_epoch`` windows,
optional early stopping (``early_stopping`` node), ``RUN/last.ckpt`` written every epoch and resumed from
when present (optimizer, epoch and step counters, and the epoch-indexed data draw included).

Checkpoint meta (``checkpoint["blenav"]``): ``kind: "mapprior"``, ``model`` (the resolved model node),
``resolution_m``, ``window`` {window_s, step_hz, n_points}, ``channels`` c, ``size_multiple`` (the U-Net's),
``target`` {scale, gain, feasible_tbar}, ``buildings`` / ``val_buildings``, ``data_hash``.
:func:`load_mapprior` rebuilds the network from it with no config file.
"""

from __future__ import annotations

import dataclasses
import hashlib
from pathlib import Path

import lightning as L
import numpy as np
import torch
from hydra.utils import instantiate
from omegaconf import DictConfig, OmegaConf

from blenav.models.mapprior import MapPriorNet

from .checkpoint import KEY, data_hash
from .mapprior_data import MapPriorDataConfig, MapPriorDataModule

KIND = "mapprior"


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


# --- config, networks, checkpoints -----------------------------------------------------------------------

def mapprior_data_config(cfg: DictConfig) -> MapPriorDataConfig:
    """The ``data`` node checked against :class:`MapPriorDataConfig` (a misspelt key fails here)."""
    node = OmegaConf.to_container(cfg.data, resolve=True)
    return OmegaConf.to_object(OmegaConf.merge(OmegaConf.structured(MapPriorDataConfig), node))


def build_net(model: dict, n_points: int, step_hz: float) -> MapPriorNet:
    """:class:`MapPriorNet` from a model node's ``net`` (``_target_`` and sizes) for windows of n_points."""
    net = instantiate(model["net"], n_points=int(n_points), step_hz=float(step_hz))
    if not isinstance(net, MapPriorNet):
        raise ValueError(f"model.net must build a MapPriorNet, got {type(net).__name__}")
    return net


def weights_hash(net: torch.nn.Module) -> str:
    """sha256 (first 16 hex) of the map encoder's parameters and buffers: the DMT cache key part."""
    h = hashlib.sha256()
    for k, v in net.map_encoder.state_dict().items():
        h.update(k.encode())
        h.update(v.detach().cpu().contiguous().numpy().tobytes())
    return "pt:" + h.hexdigest()[:16]


def read_checkpoint(path: str | Path) -> dict:
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"checkpoint {path} does not exist")
    ck = torch.load(path, map_location="cpu", weights_only=False)
    if KEY not in ck:
        raise ValueError(f"{path}: not a blenav checkpoint (no '{KEY}' entry); was it written by train.py?")
    return ck


def load_mapprior(path: str | Path) -> tuple[MapPriorNet, dict]:
    """(network in eval mode, meta) from a ``last.ckpt`` of ``train.py experiment=mapprior``."""
    ck = read_checkpoint(path)
    meta = ck[KEY]
    if meta.get("kind") != KIND:
        raise ValueError(f"{path}: a {meta.get('kind', 'crossphone')} checkpoint, not a map prior")
    w = meta["window"]
    net = build_net(meta["model"], w["n_points"], w["step_hz"])
    state = {k[len("net."):]: v for k, v in ck["state_dict"].items() if k.startswith("net.")}
    net.load_state_dict(state)
    return net.eval(), meta


def build_meta(model: dict, dm: MapPriorDataModule, net: MapPriorNet) -> dict:
    c = dm.cfg
    tracks = dm.sets["train"].tracks
    return {"kind": KIND, "model": model, "resolution_m": float(model["resolution_m"]),
            "window": {"window_s": float(c.window_s), "step_hz": float(c.step_hz), "n_points": c.n_points},
            "channels": net.c, "size_multiple": net.map_encoder.size_multiple,
            "target": {"scale": c.target_scale, "gain": c.target_gain, "feasible_tbar": c.feasible_tbar},
            "augment": dataclasses.asdict(c.augment), "crop_px": c.crop_px,
            "buildings": dm.train_buildings, "val_buildings": dm.val_buildings,
            "data_hash": data_hash(*[np.concatenate([tr.t[:, None], tr.xy], axis=1) for tr in tracks])}


def train_mapprior(cfg: DictConfig, callbacks: list | None = None) -> tuple[dict, dict]:
    """``task: mapprior``: fit the MPN from a composed ``train`` config; ``callbacks`` are added to the
    Trainer's (e.g. a timer). Returns (metrics, objects)."""
    from .train import last_checkpoint, loggers

    L.seed_everything(int(cfg.seed), workers=True)
    out = Path(cfg.out)
    out.mkdir(parents=True, exist_ok=True)
    model = OmegaConf.to_container(cfg.model, resolve=True)
    if model.get("kind") != KIND:
        raise ValueError(f"task=mapprior needs a map prior model (model=mapprior), got model {model.get('name')!r}")
    dcfg = mapprior_data_config(cfg)
    dm = MapPriorDataModule(dcfg, float(model["resolution_m"]))
    dm.setup()
    net = build_net(model, dcfg.n_points, dcfg.step_hz)
    module = MapPriorModule(net, lr=float(model["lr"]), meta=build_meta(model, dm, net), val_names=dm.val_names,
                            lr_decay=model.get("lr_decay"))
    callbacks = [last_checkpoint(out),
                 *(callbacks or [])]
    es = cfg.get("early_stopping")
    if es:
        es = OmegaConf.to_container(es, resolve=True)
        if not dm.val_names:
            es["monitor"] = "train/loss"
        callbacks.append(L.pytorch.callbacks.EarlyStopping(**es))
    trainer_kw = OmegaConf.to_container(cfg.trainer, resolve=True)
    if not dm.val_names:
        trainer_kw["limit_val_batches"] = 0
    trainer = L.Trainer(**trainer_kw, default_root_dir=out, callbacks=callbacks, logger=loggers(out),
                        enable_model_summary=False)
    resume = out / "last.ckpt"
    trainer.fit(module, datamodule=dm, ckpt_path=str(resume) if resume.is_file() else None)
    metrics = {k: float(v) for k, v in trainer.callback_metrics.items()}
    return metrics, {"module": module, "datamodule": dm, "trainer": trainer}
