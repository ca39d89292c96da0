"""LocNet and TransNet+LocNet trained on fingerprint windows of real walks (WiFi / BLE / both), through the
project's one training pipeline (:func:`blenav.learn.train.train`: the step budget with early stopping of
``conf/trainer/cpu.yaml``, the best validation check's weights, the training report beside KNN's validation
error).

The windows are made by :mod:`blenav.features.fingerprints` (S (N, F, H) on the u scale, features = WiFi
access points and/or BLE anchors instead of the BLE beacons of the cross-phone windows); :class:`ArrayWindows`
hands them to the trainer as the :class:`~blenav.learn.crossphone.data.WindowDataModule` it expects, already set
up: the data module's tensors (:func:`~blenav.learn.crossphone.data.window_dataset`), loaders, batch layout, seeded
``torch.Generator`` and validation cap (``data.val_max_windows``,
:meth:`~blenav.learn.crossphone.data.WindowDataModule.cap_validation`). Validation windows are those of a seeded
``val_fraction`` of the training walks (whole walks, as the data module's own split).
The run's config is the one ``conf/train.yaml`` with ``model=<model>`` gives, built from the ``training`` node the
localizer is handed (``conf/localizer/fingerprint.yaml`` composes conf/train.yaml's data, trainer and model nodes
there: nothing below the entry points composes a config), the ``net`` / ``trainer`` overrides merged over it and
``data.path`` = the walks' dataset (the checkpoint's ``data_path``).
"""

from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np
import torch
from omegaconf import DictConfig, OmegaConf

from blenav.features.scale import U_SCALE

from ..crossphone.data import WindowDataModule, window_dataset
from ..crossphone.data_config import WindowDataConfig


class ArrayWindows(WindowDataModule):
    """A :class:`WindowDataModule` over given windows: per split (``train``, ``val``) a tuple (S (N, F, H) u
    scale, S_prev (N, F, H) the window one step earlier of the same walk, xy (N, 2) m); ``features``: the F
    feature names (the model's rows, ``beacons`` of the checkpoint meta); ``groups``: the walks of each split;
    ``window``: the dataclass that describes how the windows were made (stored with the model); ``std_scale``: the
    std scale :meth:`~blenav.learn.crossphone.module.CrossPhoneModule.calibrate` states without validation windows
    (a refit keeps its first run's). ``cfg``: the data
    node (its ``path`` the walks' dataset, ``batch_size``, ``seed``, ``val_max_windows``); the validation windows
    are capped as the data module caps its own."""

    def __init__(self, cfg: WindowDataConfig, splits: dict, features: list[str], building, groups: dict, window,
                 std_scale: float | None = None):
        super().__init__(cfg)
        self.std_scale = std_scale  # the std calibration when there are no validation windows (a refit)
        self.beacons = list(features)
        self.building = building
        self.window = window
        self.groups = {"train": list(groups.get("train", [])), "val": list(groups.get("val", [])), "test": [],
                       "unlabelled": []}
        if not len(splits["train"][0]):
            raise ValueError("no labelled training windows")
        tr = window_dataset(*splits["train"])
        va = window_dataset(*splits["val"]) if "val" in splits and len(splits["val"][0]) else None
        self.sets = {"train": tr, "val": va, "test": None, "unlabelled": None, "known": tr}
        self.cap_validation()


def dataset_root(sessions: list) -> Path:
    """The dataset folder of ``sessions`` (DATASET/sessions/ID); ValueError when they come from several."""
    roots = sorted({str(Path(s.root).resolve().parent.parent) for s in sessions})
    if len(roots) != 1:
        raise ValueError(f"fingerprint training walks must come from one dataset, got {roots or 'no walk'}")
    return Path(roots[0])


def run_config(training: dict, model: str, out: Path, data_path: Path, seed: int, net: dict | None,
               trainer: dict | None, val_fraction: float, batch_size: int, threads: int | None, plots: bool,
               building: str | None = None, sessions: list[str] | None = None) -> DictConfig:
    """The config ``conf/train.yaml`` composed with ``model=<model>`` gives (the same keys, order and values), built
    from ``training``: the ``data``, ``trainer`` and ``models`` nodes ``conf/localizer/fingerprint.yaml`` composes
    (ValueError for a model not under ``models``); ``net`` merged over the model and ``trainer`` over the trainer
    (the progress bar off); the crossphone task without a semi-supervised stage (train.yaml's defaults); the run's
    seed (``data.seed`` follows it, ``${seed}``), out, threads, plots and data node (path, building, sessions, batch
    size, val_fraction)."""
    models = dict(training.get("models") or {})
    if model not in models:
        raise ValueError(f"model {model!r}: no training.models.{model} (conf/localizer/fingerprint.yaml composes "
                         f"conf/model/<model>.yaml there; it has {sorted(models)})")
    cfg = OmegaConf.create({"data": training["data"], "model": models[model], "trainer": training["trainer"],
                            "task": "crossphone", "seed": int(seed), "plots": bool(plots), "threads": threads,
                            "semi": None, "out": str(out)})
    cfg.model = OmegaConf.merge(cfg.model, OmegaConf.create(net or {}))
    cfg.trainer = OmegaConf.merge(cfg.trainer, OmegaConf.create(trainer or {}), {"enable_progress_bar": False})
    cfg.data.path, cfg.data.batch_size, cfg.data.val_fraction = str(data_path), int(batch_size), float(val_fraction)
    cfg.data.seed, cfg.data.building, cfg.data.sessions = "${seed}", building, sessions
    return cfg


def split_walks(walk_of: np.ndarray, val_fraction: float, seed: int) -> np.ndarray:
    """(N,) bool, True for the windows of the validation walks: a seeded ``val_fraction`` of the distinct walks
    in ``walk_of`` (N,) (at least one walk left to train on; none with fewer than two walks)."""
    walks = np.unique(walk_of)
    n_val = int(round(val_fraction * len(walks))) if len(walks) > 1 else 0
    n_val = min(n_val, len(walks) - 1)
    val = np.random.default_rng([int(seed), 1]).permutation(walks)[:n_val]
    return np.isin(walk_of, val)


def train_network(S: np.ndarray, P: np.ndarray, xy: np.ndarray, walk_of: np.ndarray, sessions: list,
                  features: list[str], window, model: str, training: dict, out: Path, seed: int = 0,
                  net: dict | None = None, trainer: dict | None = None, val_fraction: float = 0.2,
                  batch_size: int = 256, threads: int | None = 1, plots: bool = False,
                  std_scale: float | None = None):
    """Train ``model`` (``locnet`` | ``transnet_locnet``: ``training.models.<model>``, conf/model/<model>.yaml, with
    ``net`` merged over it; trainer ``training.trainer``, conf/trainer/cpu.yaml, with ``trainer`` merged over it;
    :func:`run_config`) on windows S (N, F, H) u scale,
    previous windows P (N, F, H), labels xy (N, 2) m, walk index ``walk_of`` (N,) into ``sessions``.

    The run folder ``out`` is emptied first (the trainer would resume a run of other data from its
    last.ckpt). Returns (predict: S (K, F, H) u scale -> (xy (K, 2) m, std (K,) m or None), the training report of
    :func:`blenav.learn.common.report.training_report` plus ``train_windows`` / ``val_windows`` / ``val_walks``); std
    is the calibrated sigma of a LocNet with a std head (``net.locnet.std_head: true``; its scale in the report's
    ``fix_std``) or of a :class:`~blenav.models.PlaceNet`, None without one. ``std_scale``: that scale, given (a run
    without validation walks, refitted after one that had them, keeps the first run's calibration)."""
    from ..crossphone.train import data_config
    from ..train import train

    out = Path(out)
    cfg = run_config(training, model, out, dataset_root(sessions), seed, net, trainer, val_fraction, batch_size,
                     threads, plots, building=sessions[0].building.id, sessions=[s.id for s in sessions])
    val = split_walks(walk_of, val_fraction, seed)
    splits = {"train": (S[~val], P[~val], xy[~val])}
    if val.any():
        splits["val"] = (S[val], P[val], xy[val])
    in_val = set(np.unique(walk_of[val]).tolist())
    groups = {"train": [s for i, s in enumerate(sessions) if i not in in_val],
              "val": [s for i, s in enumerate(sessions) if i in in_val]}
    if out.exists():
        shutil.rmtree(out)
    dm = ArrayWindows(data_config(cfg), splits, features, sessions[0].building, groups, window, std_scale=std_scale)
    _, objs = train(cfg, datamodule=dm)
    module = objs["module"].eval()
    report = {**objs["training"], "val_walks": len(in_val), "run": str(out)}  # window counts: train._window_counts

    def predict(Sq: np.ndarray):
        with torch.no_grad():
            x = torch.from_numpy(np.ascontiguousarray(Sq, np.float32) / U_SCALE)
            if not module.std_head:
                return module(x).numpy().astype(float), None
            xy_q, std = module.locnet.forward_std(module.translate(x))
            return xy_q.numpy().astype(float), std.numpy().astype(float)

    return predict, report
