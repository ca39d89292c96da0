"""Window data for training: sessions -> normalised RSSI windows, split by device model.

Windows come from :func:`blenav.features.windows.session_windows` on one building (its BLE beacons in sorted
order are the model's rows; ``beacons`` = k or a list keeps only a subset, see
:func:`blenav.features.windows.select_beacons`, and ``sessions`` restricts the sessions used), divided by :data:`blenav.features.scale.U_SCALE`. Each window carries the
previous window of its session (``S_prev``) for the position-smoothness loss. Validation sessions are
a seeded fraction of the training sessions (whole sessions, never windows of one walk on both sides); at most
``val_max_windows`` of their windows are kept (a seeded subset), so a validation check has a bounded cost.
Splits follow :func:`blenav.features.windows.split_by_device`. For the semi-supervised stage (scenario 3 of
Roy) the training loader adds the unlabelled windows (labels NaN) from epoch ``semi_from_epoch`` on.
"""

from __future__ import annotations

import lightning as L
import numpy as np
import torch
from torch.utils.data import ConcatDataset, DataLoader, TensorDataset

from blenav.data import Dataset
from blenav.features.scale import U_SCALE
from blenav.features.windows import WindowConfig, select_beacons, session_windows, split_by_device

from .data_config import WindowDataConfig  # the schema of the data node (torch-free)


#: ``data.batch_size: auto`` (:func:`auto_batch_size`): the batch of a survey with at least
#: AUTO_MIN_BATCHES batches an epoch, else AUTO_SMALL_BATCH with AUTO_BATCH / AUTO_SMALL_BATCH times the auto step
#: budget (blenav.learn.common.budget.budget_steps). Chosen on the validation windows of a simulated 2,340-window
#: campus_floor survey (docs/results-003-crossphone.md, ``benchmarks/crossphone_train.py --sizes small``): batch
#: 256 and 3,245 steps stopped at the budget still improving (3.4 min); batch 128 and 6,490 steps stopped early at
#: step 5,016 (converged, 3.7 min on both cores); a step of 128 costs 35 against 54 ms for 256 (both cores,
#: ``benchmarks/crossphone_step.py data.batch_size=128`` / ``=256``).
AUTO_BATCH, AUTO_SMALL_BATCH, AUTO_MIN_BATCHES = 256, 128, 10


def auto_batch_size(n_windows: int) -> int:
    """The batch of ``data.batch_size: auto`` for ``n_windows`` training windows: 256, or 128 when an epoch of
    256 would be fewer than 10 batches (under 2,560 windows): a small survey needs more, cheaper steps."""
    return AUTO_BATCH if int(n_windows) >= AUTO_MIN_BATCHES * AUTO_BATCH else AUTO_SMALL_BATCH


def _tensors(sessions, beacons, wcfg: WindowConfig, labelled: bool):
    S, P, xy = [], [], []
    for s in sessions:
        w = session_windows(s, beacons, wcfg)
        if len(w.S) < 2:
            continue
        S.append(w.S[1:])
        P.append(w.S[:-1])
        xy.append(w.xy[1:] if labelled else np.full((len(w.S) - 1, 2), np.nan))
    if not S:
        return None
    S, P, xy = (np.concatenate(a) for a in (S, P, xy))
    keep = ~np.isnan(xy).any(axis=1) if labelled else np.ones(len(S), bool)
    return window_dataset(S[keep], P[keep], xy[keep])


class WindowTensors(TensorDataset):
    """The (S, S_prev, xy) tensors of a split. A DataLoader fetches a batch with one indexing of each tensor
    (``__getitems__``) instead of one tuple per window stacked again: 0.3 against 2.7 ms a batch of 256
    (benchmarks/crossphone_step.py)."""

    def __getitems__(self, idx: list[int]) -> dict[str, torch.Tensor]:
        i = torch.as_tensor(idx)
        return dict(zip(("S", "S_prev", "xy"), (t[i] for t in self.tensors)))


def window_dataset(S: np.ndarray, P: np.ndarray, xy: np.ndarray) -> WindowTensors:
    """The tensors of a split: S (N, F, H) and the previous windows P (N, F, H) on the u scale, divided by
    :data:`U_SCALE` (float32), labels xy (N, 2) m (float32)."""
    return WindowTensors(torch.from_numpy(np.ascontiguousarray(S, np.float32) / U_SCALE),
                         torch.from_numpy(np.ascontiguousarray(P, np.float32) / U_SCALE),
                         torch.from_numpy(np.asarray(xy)).float())


def _collate(rows) -> dict[str, torch.Tensor]:
    """A batch dict: as :meth:`WindowTensors.__getitems__` fetched it, or stacked from rows (a ConcatDataset)."""
    if isinstance(rows, dict):
        return rows
    return {"S": torch.stack([r[0] for r in rows]), "S_prev": torch.stack([r[1] for r in rows]),
            "xy": torch.stack([r[2] for r in rows])}


class WindowDataModule(L.LightningDataModule):
    def __init__(self, cfg: WindowDataConfig):
        super().__init__()
        self.cfg = cfg
        self.beacons: list[str] = []
        self.sets: dict[str, WindowTensors | None] = {}
        self.groups: dict[str, list] = {}
        self.building = None
        self.semi_from_epoch: int | None = None  # set by train(cfg) for the semi-supervised stage

    def setup(self, stage: str | None = None) -> None:
        if self.sets:
            return
        c = self.cfg
        ds = Dataset.open(c.path)
        if c.sessions is not None:
            ids = [str(i) for i in c.sessions]
            unknown = sorted(set(ids) - set(ds.session_ids))
            if unknown or not ids:
                raise ValueError(f"{c.path}: data.sessions names sessions not in the dataset: {unknown}"
                                 if unknown else f"{c.path}: data.sessions is empty (null = every session)")
            sessions = list(ds.sessions(ids))
        else:
            sessions = list(ds.sessions())
        buildings = sorted({s.building.id for s in sessions})
        if c.building is not None:
            if c.building not in buildings:
                raise ValueError(f"{c.path}: no session in building {c.building!r}; buildings here: {buildings}")
            sessions = [s for s in sessions if s.building.id == c.building]
        elif len(buildings) != 1:
            raise ValueError(f"{c.path}: window training needs sessions of one building, found {buildings}: "
                             f"choose one with data.building=ID")
        self.building = sessions[0].building
        try:  # a subset is chosen on the floor of the building's sessions, as the evaluation chooses it
            self.beacons, subset = select_beacons(self.building, c.beacons, sessions[0].meta.get("floor"),
                                                  sessions[0].floor)
        except ValueError as exc:
            raise ValueError(f"data.beacons: {exc}") from None
        groups = split_by_device(sessions, c.train_devices, c.test_devices, c.unlabelled_devices,
                                 holdout=c.holdout, unlabelled_share=c.unlabelled_share, seed=c.seed)
        train = [s for s in groups["train"] if s.labelled]
        rng = np.random.default_rng([c.seed, 1])
        n_val = int(round(c.val_fraction * len(train))) if len(train) > 1 else 0
        order = rng.permutation(len(train))
        val = [train[i] for i in order[:n_val]]
        train = [train[i] for i in order[n_val:]]
        self.window = WindowConfig(history=c.history, step_hz=c.step_hz, steps=str(c.steps), beacon_subset=subset)
        wcfg = self.window
        self.groups = {**groups, "train": train, "val": val}
        known = set(c.known_devices) if c.known_devices else {s.device_model for s in train}
        unknown = sorted(known - {s.device_model for s in train})
        if unknown:
            raise ValueError(f"known devices {unknown} have no labelled training session; "
                             f"training devices: {sorted({s.device_model for s in train})}")
        self.sets = {"train": _tensors(train, self.beacons, wcfg, True), "val": _tensors(val, self.beacons, wcfg, True),
                     "test": _tensors([s for s in groups["test"] if s.labelled], self.beacons, wcfg, True),
                     "unlabelled": _tensors(groups["unlabelled"], self.beacons, wcfg, False),
                     "known": _tensors([s for s in train if s.device_model in known], self.beacons, wcfg, True)}
        self.cap_validation()
        if self.sets["train"] is None:
            raise ValueError(f"{c.path}: no labelled training windows for devices {c.train_devices or 'all'}")

    def cap_validation(self) -> None:
        """Keep at most ``val_max_windows`` validation windows (a seeded subset, in their order; None: all)."""
        c, v = self.cfg, self.sets.get("val")
        if v is not None and c.val_max_windows is not None and len(v) > int(c.val_max_windows):
            keep = np.sort(np.random.default_rng([c.seed, 2]).choice(len(v), int(c.val_max_windows), replace=False))
            self.sets["val"] = WindowTensors(*(t[torch.from_numpy(keep)] for t in v.tensors))

    @property
    def batch_size(self) -> int:
        """Windows per step: ``data.batch_size``, or for ``auto`` :func:`auto_batch_size` of the training
        windows (after :meth:`setup`)."""
        b = self.cfg.batch_size
        if b != "auto":
            return int(b)
        if self.sets.get("train") is None:
            return AUTO_BATCH
        return auto_batch_size(len(self.sets["train"]))

    @property
    def step_scale(self) -> float:
        """The factor of the auto step budget for the batch: AUTO_BATCH / batch when the batch is auto (the same
        windows seen as at 256), 1 for a batch given as a number."""
        return AUTO_BATCH / self.batch_size if self.cfg.batch_size == "auto" else 1.0

    def train_hash(self) -> str:
        """Hash of the labelled training windows and labels (stored with a model; reuse checks compare it)."""
        from ..common.checkpoint import data_hash

        tr = self.sets["train"].tensors
        return data_hash(tr[0].numpy(), tr[2].numpy())

    def train_labels(self) -> torch.Tensor:
        return self.sets["train"].tensors[2]

    def _loader(self, name: str, shuffle: bool):
        d = self.sets.get(name)
        if d is None:
            return []
        g = torch.Generator().manual_seed(self.cfg.seed)
        return DataLoader(d, batch_size=self.batch_size, shuffle=shuffle, generator=g, collate_fn=_collate)

    def train_dataloader(self):
        semi = self.semi_from_epoch is not None and self.trainer is not None \
            and self.trainer.current_epoch >= self.semi_from_epoch
        if semi and self.sets.get("unlabelled") is not None:
            both = ConcatDataset([self.sets["train"], self.sets["unlabelled"]])
            g = torch.Generator().manual_seed(self.cfg.seed + self.trainer.current_epoch)
            return DataLoader(both, batch_size=self.batch_size, shuffle=True, generator=g, collate_fn=_collate)
        return self._loader("train", True)

    def val_dataloader(self):
        return self._loader("val", False)

    def test_dataloader(self):
        return self._loader("test", False)
