"""LocNet and TransNet+LocNet trained on fingerprint windows of real walks (WiFi / BLE / both), through the
project's one training pipeline (:func:`blenav.learn.train.train`: the step budget with early stopping of
``conf/trainer/cpu.yaml``, the best validation check's weights, the training report beside KNN's validation
error).

The windows are made by :mod:`blenav.features.fingerprints` (S (N, F, H) on the u scale, features = WiFi
access points and/or BLE anchors instead of the BLE beacons of the cross-phone windows); :class:`ArrayWindows`
hands them to the trainer as the :class:`~blenav.learn.data.WindowDataModule` it expects (same loaders,
batch layout and seeded ``torch.Generator``), already set up. Validation windows are those of a seeded
``val_fraction`` of the training walks (whole walks, as the data module's own split).
"""

from __future__ import annotations

import dataclasses
import shutil
from pathlib import Path

import numpy as np
import torch
from omegaconf import OmegaConf
from torch.utils.data import TensorDataset

from blenav.features.scale import U_SCALE
from blenav.paths import conf_dir

from .data import WindowDataModule
from .data_config import WindowDataConfig


def _dataset(S: np.ndarray, P: np.ndarray, xy: np.ndarray) -> TensorDataset | None:
    if not len(S):
        return None
    return TensorDataset(torch.from_numpy(np.ascontiguousarray(S, np.float32) / U_SCALE),
                         torch.from_numpy(np.ascontiguousarray(P, np.float32) / U_SCALE),
                         torch.from_numpy(np.asarray(xy, np.float32)))


class ArrayWindows(WindowDataModule):
    """A :class:`WindowDataModule` over given windows: per split (``train``, ``val``) a tuple (S (N, F, H) u
    scale, S_prev (N, F, H) the window one step earlier of the same walk, xy (N, 2) m); ``features``: the F
    feature names (the model's rows, ``beacons`` of the checkpoint meta); ``groups``: the walks of each split;
    ``window``: the dataclass that describes how the windows were made (stored with the model)."""

    def __init__(self, splits: dict, features: list[str], building, groups: dict, window, batch_size: int,
                 seed: int, path: str):
        super().__init__(WindowDataConfig(path=path, batch_size=int(batch_size), seed=int(seed), val_fraction=0.0))
        self.beacons = list(features)
        self.building = building
        self.window = window
        self.groups = {"train": list(groups.get("train", [])), "val": list(groups.get("val", [])), "test": [],
                       "unlabelled": []}
        tr = _dataset(*splits["train"])
        if tr is None:
            raise ValueError("no labelled training windows")
        va = _dataset(*splits["val"]) if "val" in splits else None
        self.sets = {"train": tr, "val": va, "test": None, "unlabelled": None, "known": tr}


def split_walks(walk_of: np.ndarray, val_fraction: float, seed: int) -> np.ndarray:
    """(N,) bool, True for the windows of the validation walks: a seeded ``val_fraction`` of the distinct walks
    in ``walk_of`` (N,) (at least one walk left to train on; none with fewer than two walks)."""
    walks = np.unique(walk_of)
    n_val = int(round(val_fraction * len(walks))) if len(walks) > 1 else 0
    n_val = min(n_val, len(walks) - 1)
    val = np.random.default_rng([int(seed), 1]).permutation(walks)[:n_val]
    return np.isin(walk_of, val)


def train_network(S: np.ndarray, P: np.ndarray, xy: np.ndarray, walk_of: np.ndarray, sessions: list,
                  features: list[str], window, model: str, out: Path, seed: int = 0, net: dict | None = None,
                  trainer: dict | None = None, val_fraction: float = 0.2, batch_size: int = 256,
                  threads: int | None = 1, plots: bool = False):
    """Train ``model`` (``locnet`` | ``transnet_locnet``: ``conf/model/<model>.yaml`` with ``net`` merged over
    it; trainer ``conf/trainer/cpu.yaml`` with ``trainer`` merged over it) on windows S (N, F, H) u scale,
    previous windows P (N, F, H), labels xy (N, 2) m, walk index ``walk_of`` (N,) into ``sessions``.

    The run folder ``out`` is emptied first (the trainer would resume a run of other data from its
    last.ckpt). Returns (predict: S (K, F, H) u scale -> (K, 2) m, the training report of
    :func:`blenav.learn.train.training_report` plus ``train_windows`` / ``val_windows`` / ``val_walks``)."""
    from .train import train

    base = conf_dir()
    mpath = base / "model" / f"{model}.yaml"
    if not mpath.is_file():
        raise ValueError(f"model {model!r}: no {mpath}")
    mcfg = OmegaConf.merge(OmegaConf.load(mpath), OmegaConf.create(net or {}))
    tcfg = OmegaConf.merge(OmegaConf.load(base / "trainer" / "cpu.yaml"), OmegaConf.create(trainer or {}),
                           {"enable_progress_bar": False})
    val = split_walks(walk_of, val_fraction, seed)
    splits = {"train": (S[~val], P[~val], xy[~val])}
    if val.any():
        splits["val"] = (S[val], P[val], xy[val])
    in_val = set(np.unique(walk_of[val]).tolist())
    groups = {"train": [s for i, s in enumerate(sessions) if i not in in_val],
              "val": [s for i, s in enumerate(sessions) if i in in_val]}
    out = Path(out)
    if out.exists():
        shutil.rmtree(out)
    dm = ArrayWindows(splits, features, sessions[0].building, groups, window, batch_size, seed, str(out))
    cfg = OmegaConf.create({"seed": int(seed), "out": str(out), "threads": threads, "plots": bool(plots),
                            "data": dataclasses.asdict(dm.cfg), "model": mcfg, "trainer": tcfg})
    _, objs = train(cfg, datamodule=dm)
    module = objs["module"].eval()

    def predict(Sq: np.ndarray) -> np.ndarray:
        with torch.no_grad():
            x = torch.from_numpy(np.ascontiguousarray(Sq, np.float32) / U_SCALE)
            return module(x).numpy().astype(float)

    report = {**objs["training"], "val_walks": len(in_val), "run": str(out)}  # window counts: train._window_counts
    return predict, report
