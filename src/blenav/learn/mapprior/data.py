"""Training data of the Map Prior Network (Roy, section 3.2.2): windows of ground truth, map crops, targets.

Notation as in :mod:`blenav.models.mapprior` (M free mask at ``resolution_m``, O odometry window in pixels,
S = f(M)_x . g(O), eq. 3.8).

Only floor plans and ground-truth trajectories are read (``groundtruth.csv`` of labelled sessions), so
trajectory-only sessions are valid training data. A sample, drawn with ``numpy.random.default_rng([seed,
split, index])`` (so any index is reproducible, and a resumed run sees the same data):

1. a window end time t uniformly over the split's windows (sessions weighted by their usable length; a window
   must not span a ground-truth gap longer than ``max_gap_s``);
2. O: ground truth at ``n_points`` = window_s * step_hz + 1 times ending at t, minus its first point
   ("to look like odometry", Roy), in pixels, then augmented: velocities times a bias ~ N(1, bias_std)
   (clipped to >= ``bias_min``), optional rotation ~ N(0, rot_std_deg), noise ~ N(0, noise_px) on each point,
   re-based to start at zero;
3. a ``crop_px`` square of M around the window's end pixel, the end placed uniformly within
   +-``crop_jitter`` * crop_px of the centre (outside the map = obstacle): the map branch sees small
   segments "to avoid overfitting to the most commonly feasible areas of the full map" (Roy);
4. the kernel: the ground truth densified at ``kernel_hz``, as pixel offsets relative to the window's END
   (the score is for where the window ends), each distinct pixel once.

The collate function (:class:`Collate`) builds the targets on the batch, vectorised:
T_bar(x) = sum_d K(d) M(x + d) (cross-correlation of the kernel with the crop, zero outside; the fraction
of the kernel's pixels in free space if the window ended at x), T = 1e-6 exp(14 T_bar) (Roy), and loss
weights: 1 for pixels that are not feasible; feasible pixels (T_bar >= ``feasible_tbar``, i.e. T within
about a factor e of its maximum at the default 0.93) weighted by the inverse area of their connected
region (8-connectivity), scaled so a crop's feasible pixels keep their total weight (each of its R regions
gets total weight F / R, F its feasible pixel count) -- "we weight feasible regions by the inverse of their
pixel area in our loss to improve small area prediction" (Roy).

Sparse ground truth. A session whose ground truth is surveyed waypoints (``groundtruth_kind: waypoints``, e.g.
a walk imported by ``blenav-import ilc20``) is used with the positions between its waypoints interpolated
LINEARLY (:meth:`Track.at`, straight lines at constant speed between consecutive waypoints), at training time
only: nothing is written to the dataset. Its windows may span waypoint gaps up to ``waypoint_max_gap_s``
(``max_gap_s`` applies to trajectory ground truth). Both O and the kernel of such a window are then made of
those straight segments, so the prior learns from the surveyed route, not the walker's exact path.

Datasets. ``path`` plus ``extra_paths`` (e.g. two imported mall floors, or a floor and a simulated set) are
read together (their session ids and (building, floor) pairs must not repeat); with ``sessions`` only those
session ids are read, e.g. the train walks of ``blenav-eval experiment=realwalks`` (``python -m
blenav.cli.realwalks train-ids DIR`` per dataset: that experiment's own split, so no walk it scores is trained on).

Splits: sessions of ``val_buildings`` (never seen in training) form ``val_unseen``; of the other buildings'
labelled sessions a seeded ``val_fraction`` goes whole to ``val_seen``, each building keeping at least one
training session; when no session can go (one walk per building) the last ``val_fraction`` of every walk's
time validates instead (:func:`split_sessions`).
"""

from __future__ import annotations

from dataclasses import dataclass

import lightning as L
import numpy as np
import torch
import torch.nn.functional as F
from scipy import ndimage
from torch.utils.data import DataLoader, Dataset as TorchDataset, Sampler

from blenav.features.mapgrid import NetGrid, net_grid

from ..common.sessions import labelled_sessions
from .data_config import MapPriorDataConfig  # the schema of the data node (torch-free)

SPLITS = {"train": 0, "val_seen": 1, "val_unseen": 2}


# --- targets (vectorised over the batch) -----------------------------------------------------------------

def unique_weights(offsets: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Kernel offsets (b, P, 2) int64 (drow, dcol) -> (offsets (b, P', 2), weights (b, P')): each sample's
    distinct pixels first with weight 1 / (their number), then repeats with weight 0 (the kernel is an
    indicator of the pixels the walk touched); P' = the batch's largest number of distinct pixels."""
    span = int(offsets.abs().max()) if offsets.numel() else 0
    w2 = 2 * span + 1
    key = (offsets[..., 0] + span) * w2 + (offsets[..., 1] + span)
    key, order = torch.sort(key, dim=1)
    offs = torch.gather(offsets, 1, order[..., None].expand(-1, -1, 2))
    first = torch.ones_like(key, dtype=torch.bool)
    first[:, 1:] = key[:, 1:] != key[:, :-1]
    _, order = torch.sort((~first).to(torch.int8), dim=1, stable=True)  # distinct pixels first
    n = int(first.sum(1).max()) if first.numel() else 0
    offs = torch.gather(offs, 1, order[:, :n, None].expand(-1, -1, 2))
    w = torch.gather(first, 1, order[:, :n]).float()
    return offs, w / w.sum(dim=1, keepdim=True)


def target_tbar(free: torch.Tensor, offsets: torch.Tensor, weights: torch.Tensor) -> torch.Tensor:
    """T_bar (b, H, W) = sum_p weights[p] * free[x + offsets[p]]: the kernel cross-correlated with the map.

    ``free`` (b, H, W) float on [0, 1] (zero beyond the crop), ``offsets`` (b, P, 2) int64 (drow, dcol) of the
    trajectory pixels relative to the window's end, ``weights`` (b, P) summing to 1. Cost b * P * H * W.
    """
    b, H, W = free.shape
    R = int(offsets.abs().max()) if offsets.numel() else 0
    Wp = W + 2 * R
    flat = F.pad(free, (R, R, R, R)).reshape(b, -1)
    base = (torch.arange(H)[:, None] + R) * Wp + (torch.arange(W)[None, :] + R)  # (H, W)
    shift = offsets[..., 0] * Wp + offsets[..., 1]  # (b, P)
    idx = (base[None, None] + shift[..., None, None]).reshape(b, -1)
    vals = torch.gather(flat, 1, idx).reshape(b, -1, H, W)
    return torch.einsum("bphw,bp->bhw", vals, weights).clamp_(0.0, 1.0)


def target_from_tbar(tbar: torch.Tensor, scale: float = 1e-6, gain: float = 14.0) -> torch.Tensor:
    """T = 1e-6 exp(14 T_bar) (Roy): in [1e-6, 1e-6 e^14 ~ 1.2]."""
    return scale * torch.exp(gain * tbar)


def feasible_weights(tbar: np.ndarray, threshold: float) -> np.ndarray:
    """Loss weights (b, H, W) float32 from T_bar (b, H, W): 1 off the feasible set; on it, inverse area of the
    connected region (8-connectivity within a sample), scaled by F / R (F feasible pixels, R regions)."""
    feas = np.asarray(tbar) >= threshold
    structure = np.zeros((3, 3, 3), dtype=bool)
    structure[1] = True  # connect within a sample only
    labels, n = ndimage.label(feas, structure)
    out = np.ones(feas.shape, dtype=np.float32)
    if n == 0:
        return out
    area = np.bincount(labels.ravel(), minlength=n + 1).astype(np.float64)
    sample_of = np.zeros(n + 1, dtype=np.int64)
    sample_of[labels[feas]] = np.nonzero(feas)[0]
    regions = np.bincount(sample_of[1:], minlength=feas.shape[0]).astype(np.float64)  # R per sample
    n_feas = feas.reshape(feas.shape[0], -1).sum(1).astype(np.float64)  # F per sample
    lab = labels[feas]
    s = sample_of[lab]
    out[feas] = (n_feas[s] / (regions[s] * area[lab])).astype(np.float32)
    return out


class Collate:
    """Samples -> batch dict: ``map`` (b, 1, H, W) free mask, ``odo`` (b, n, 2) pixels, ``target`` T (b, H, W),
    ``tbar`` (b, H, W), ``weight`` (b, H, W), ``end`` (b, 2) int64 (row, col) of the window end in the crop."""

    def __init__(self, feasible_tbar: float = 0.93, scale: float = 1e-6, gain: float = 14.0):
        self.feasible_tbar, self.scale, self.gain = float(feasible_tbar), float(scale), float(gain)

    def __call__(self, rows) -> dict[str, torch.Tensor]:
        crop = torch.from_numpy(np.stack([r[0] for r in rows]))
        odo = torch.from_numpy(np.stack([r[1] for r in rows]))
        offs = torch.from_numpy(np.stack([r[2] for r in rows]))
        end = torch.from_numpy(np.stack([r[3] for r in rows]))
        offs, w = unique_weights(offs)
        tbar = target_tbar(crop, offs, w)
        return {"map": crop[:, None], "odo": odo, "tbar": tbar, "target": target_from_tbar(tbar, self.scale, self.gain),
                "weight": torch.from_numpy(feasible_weights(tbar.numpy(), self.feasible_tbar)), "end": end}


# --- windows over sessions -------------------------------------------------------------------------------

@dataclass
class Track:
    """One session's ground truth: ``t`` (T,) s, ``xy`` (T, 2) world m, the floor key, and the window end times
    ``ends`` (E,) s usable for a split."""

    session: str
    floor: tuple[str, str]
    t: np.ndarray
    xy: np.ndarray
    ends: np.ndarray

    def at(self, times: np.ndarray) -> np.ndarray:
        """Positions (N, 2) world m at ``times`` (N,) s: the ground truth interpolated linearly between its rows
        (for waypoint ground truth, straight lines between consecutive surveyed waypoints, at training time
        only; exactly the waypoints at their own times)."""
        return np.stack([np.interp(times, self.t, self.xy[:, j]) for j in (0, 1)], axis=-1)


def window_ends(t: np.ndarray, window_s: float, hz: float, max_gap_s: float, lo: float = -np.inf,
                hi: float = np.inf) -> np.ndarray:
    """End times (E,) on a 1 / hz grid such that [end - window_s, end] lies within the ground truth, within
    [lo, hi], and spans no gap longer than ``max_gap_s``."""
    if len(t) < 2:
        return np.zeros(0)
    first = max(t[0] + window_s, lo + window_s)
    last = min(t[-1], hi)
    if last < first:
        return np.zeros(0)
    ends = first + np.arange(int(np.floor((last - first) * hz + 1e-9)) + 1) / hz
    gap = np.flatnonzero(np.diff(t) > max_gap_s)
    if len(gap):
        g0, g1 = t[gap], t[gap + 1]  # sorted, disjoint
        n = np.searchsorted(g0, ends, side="left") - np.searchsorted(g1, ends - window_s, side="right")
        ends = ends[n <= 0]
    return ends


class WindowSet(TorchDataset):
    """Map-style dataset of (crop (H, W) float32, odo (n, 2) float32 px, kernel offsets (P, 2) int64, end (2,)
    int64) samples; item ``i`` is drawn with ``default_rng([seed, split, i])`` (any i >= 0 is valid;
    ``len`` is the nominal epoch size)."""

    def __init__(self, tracks: list[Track], maps: dict, cfg: MapPriorDataConfig, split: str, length: int,
                 augment: bool = True):
        if not tracks:
            raise ValueError(f"no ground-truth window for split {split}")
        self.tracks, self.maps, self.cfg, self.split = tracks, maps, cfg, split
        self.length, self.augment = int(length), augment
        counts = np.array([len(tr.ends) for tr in tracks])
        self.cum = np.concatenate([[0], np.cumsum(counts)])
        if self.cum[-1] == 0:
            raise ValueError(f"no window of {cfg.window_s:g} s fits in the ground truth of split {split}")

    def __len__(self) -> int:
        return self.length

    @property
    def n_windows(self) -> int:
        return int(self.cum[-1])

    def draw(self, index: int):
        """(floor key, O (n, 2) float32 px augmented, end pixel (row, col) int64 on the floor's net grid,
        kernel offsets (P, 2) int64 relative to the end pixel, the item's generator) of item ``index``."""
        c = self.cfg
        rng = np.random.default_rng([int(c.seed), SPLITS[self.split], int(index)])
        k = int(rng.integers(self.cum[-1]))
        i = int(np.searchsorted(self.cum, k, side="right") - 1)
        tr = self.tracks[i]
        t_end = tr.ends[k - self.cum[i]]
        grid = self.maps[tr.floor][0]
        t_pts = t_end - c.window_s + np.arange(c.n_points) / c.step_hz
        t_ker = t_end - c.window_s + np.arange(c.n_kernel) / c.kernel_hz
        pts, ker = tr.at(t_pts), tr.at(t_ker)
        # O: relative to the window start, world axes, pixels; augmented (Roy)
        odo = (pts - pts[0]) / grid.resolution
        if self.augment:
            a = c.augment
            v = np.diff(odo, axis=0) * max(a.bias_min, 1.0 + a.bias_std * rng.standard_normal())
            if a.rot_std_deg:
                th = np.radians(a.rot_std_deg) * rng.standard_normal()
                rot = np.array([[np.cos(th), -np.sin(th)], [np.sin(th), np.cos(th)]])
                v = v @ rot.T
            odo = np.concatenate([np.zeros((1, 2)), np.cumsum(v, axis=0)])
            odo = odo + a.noise_px * rng.standard_normal(odo.shape)
            odo = odo - odo[0]
        # kernel: pixels of the densified ground truth relative to the end pixel
        kr, kc = grid.world_to_pixel(ker)
        er, ec = grid.world_to_pixel(pts[-1])
        offs = np.stack([kr - er, kc - ec], axis=-1).astype(np.int64)
        return tr.floor, odo.astype(np.float32), np.array([er, ec], dtype=np.int64), offs, rng

    def __getitem__(self, index: int):
        key, odo, (er, ec), offs, rng = self.draw(index)
        grid, padded = self.maps[key]
        # crop around the end pixel (padded map: crop_px of obstacle on every side)
        n = self.cfg.crop_px
        j = int(self.cfg.crop_jitter * n)
        top = int(np.clip(er - (n // 2 + int(rng.integers(-j, j + 1))), -n, grid.shape[0]))
        left = int(np.clip(ec - (n // 2 + int(rng.integers(-j, j + 1))), -n, grid.shape[1]))
        crop = padded[top + n: top + 2 * n, left + n: left + 2 * n]
        end = np.clip(np.array([er - top, ec - left], dtype=np.int64), 0, n - 1)
        return crop, odo, offs, end


class EpochSampler(Sampler):
    """Indices epoch * n .. epoch * n + n - 1: every epoch new samples, fixed by the epoch (Lightning calls
    :meth:`set_epoch`, also when a run resumes)."""

    def __init__(self, n: int):
        self.n, self.epoch = int(n), 0

    def set_epoch(self, epoch: int) -> None:
        self.epoch = int(epoch)

    def __iter__(self):
        return iter(range(self.epoch * self.n, (self.epoch + 1) * self.n))

    def __len__(self) -> int:
        return self.n


# --- data module -----------------------------------------------------------------------------------------

def split_sessions(building_of: dict[str, str], fraction: float, rng: np.random.Generator) -> dict[str, list[str]]:
    """Session id -> splits it feeds: about ``fraction`` of the sessions go to ``val_seen`` whole, drawn at random
    but only where their building keeps another session for training; when that leaves no validation session
    (e.g. one walk per building) every session is split in time instead (``["train", "val_seen"]``)."""
    ids = sorted(building_of)
    if fraction <= 0 or not ids:
        return {s: ["train"] for s in ids}
    n_val = max(1, int(round(fraction * len(ids))))
    left: dict[str, int] = {}
    for s in ids:
        left[building_of[s]] = left.get(building_of[s], 0) + 1
    val = []
    for i in rng.permutation(len(ids)):
        b = building_of[ids[i]]
        if len(val) < n_val and left[b] > 1:
            val.append(ids[i])
            left[b] -= 1
    if not val:
        return {s: ["train", "val_seen"] for s in ids}
    return {s: ["val_seen"] if s in val else ["train"] for s in ids}


class MapPriorDataModule(L.LightningDataModule):
    """Windows of a dataset's labelled sessions at ``resolution_m``: loaders ``train`` and the validation splits
    present (:attr:`val_names`, ``val_seen`` first)."""

    def __init__(self, cfg: MapPriorDataConfig, resolution_m: float):
        super().__init__()
        self.cfg, self.resolution_m = cfg, float(resolution_m)
        self.sets: dict[str, WindowSet] = {}
        self.maps: dict = {}
        self.train_buildings: list[str] = []
        self.val_buildings: list[str] = []
        self.groups: dict[str, list[str]] = {}
        self.train_floors: list[str] = []  # "building/floor" of the training windows
        self.waypoint_sessions = 0  # sessions whose ground truth is waypoints (interpolated linearly)

    @property
    def val_names(self) -> list[str]:
        return [k for k in ("val_seen", "val_unseen") if k in self.sets]

    def _floor(self, session) -> tuple[str, str]:
        key = (session.building.id, str(session.meta.get("floor")))
        if key not in self.maps:
            grid, free = net_grid(session.floor, self.resolution_m)
            n = self.cfg.crop_px
            padded = np.pad(free.astype(np.float32), n)  # obstacle beyond the map
            self.maps[key] = (grid, padded)
        return key

    def _sessions(self) -> list:
        """The labelled sessions with at least two ground-truth rows of ``path`` and ``extra_paths`` (only the ids of
        ``sessions`` when given), checked for clashes between the datasets (:func:`labelled_sessions`)."""
        return labelled_sessions(self.cfg.paths, self.cfg.sessions, unique_floors=True)

    def setup(self, stage: str | None = None) -> None:
        if self.sets:
            return
        c = self.cfg
        where = ", ".join(c.paths)
        held = [str(b) for b in (c.val_buildings or [])]
        by_building: dict[str, list] = {}
        for s in self._sessions():
            by_building.setdefault(s.building.id, []).append(s)
        if not by_building:
            raise ValueError(f"{where} has no labelled session with ground truth"
                             f"{' among data.sessions' if c.sessions is not None else ''}; "
                             "the map prior trains on groundtruth.csv trajectories")
        missing = [b for b in held if b not in by_building]
        if missing:
            raise ValueError(f"data.val_buildings {missing} are not buildings with a labelled session of {where} "
                             f"({sorted(by_building)})")
        rng = np.random.default_rng([int(c.seed), 7])
        tracks: dict[str, list[Track]] = {k: [] for k in SPLITS}
        groups: dict[str, list[str]] = {k: [] for k in SPLITS}
        assign = split_sessions({s.id: b for b in by_building if b not in held for s in by_building[b]},
                                c.val_fraction, rng)
        assign |= {s.id: ["val_unseen"] for b in held for s in by_building[b]}
        self.waypoint_sessions = 0
        for b in sorted(by_building):
            for s in sorted(by_building[b], key=lambda s: s.id):
                gt = s.groundtruth
                t = gt["t"].to_numpy(float)
                xy = gt[["x", "y"]].to_numpy(float)
                key = self._floor(s)
                # waypoint ground truth: the windows may span the gaps between waypoints (linear interpolation)
                gap = c.waypoint_max_gap_s if s.groundtruth_sparse else c.max_gap_s
                self.waypoint_sessions += int(s.groundtruth_sparse)
                for split in assign[s.id]:
                    lo, hi = -np.inf, np.inf
                    if len(assign[s.id]) == 2:  # split in time: the last val_fraction validates
                        cut = t[0] + (1.0 - c.val_fraction) * (t[-1] - t[0])
                        hi, lo = (cut, -np.inf) if split == "train" else (np.inf, cut)
                    ends = window_ends(t, c.window_s, c.kernel_hz, gap, lo=lo, hi=hi)
                    if len(ends):
                        tracks[split].append(Track(s.id, key, t, xy, ends))
                        groups[split].append(s.id)
        if not tracks["train"]:
            raise ValueError(f"no training window of {c.window_s:g} s in {where} (buildings {sorted(by_building)}, "
                             f"held out {held}); record longer walks, shorten data.window_s or allow longer "
                             "ground-truth gaps (data.max_gap_s, data.waypoint_max_gap_s)")
        self.groups = groups
        self.train_buildings = sorted({tr.floor[0] for tr in tracks["train"]})
        self.train_floors = sorted({f"{tr.floor[0]}/{tr.floor[1]}" for tr in tracks["train"]})
        self.val_buildings = held
        self.sets["train"] = WindowSet(tracks["train"], self.maps, c, "train", c.samples_per_epoch)
        for split in ("val_seen", "val_unseen"):
            if tracks[split]:
                self.sets[split] = WindowSet(tracks[split], self.maps, c, split, c.val_samples)

    def collate(self) -> Collate:
        c = self.cfg
        return Collate(c.feasible_tbar, c.target_scale, c.target_gain)

    def train_dataloader(self) -> DataLoader:
        c = self.cfg
        return DataLoader(self.sets["train"], batch_size=c.batch_size, sampler=EpochSampler(c.samples_per_epoch),
                          collate_fn=self.collate(), num_workers=c.num_workers, drop_last=False)

    def val_dataloader(self):
        c = self.cfg
        return [DataLoader(self.sets[k], batch_size=c.batch_size, shuffle=False, collate_fn=self.collate(),
                           num_workers=c.num_workers) for k in self.val_names]

    def grids(self) -> dict[tuple[str, str], NetGrid]:
        return {k: v[0] for k, v in self.maps.items()}
