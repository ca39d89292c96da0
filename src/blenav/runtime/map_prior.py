"""The learned map prior (Roy, section 3.2.2) at run time, for a particle filter: DMT once per floor, DTV per
step, scores gathered at particle positions.

Notation as in :mod:`blenav.models.mapprior`: M free mask at the network's resolution, O odometry window,
DMT f(M) (c, H, W), DTV g(O) (c,), score S(x | M, O) = f(M)_x . g(O) (eq. 3.8, Roy).

Use::

    prior = MapPrior("RUN/last.ckpt")          # or MapPrior("DIR2") with map_encoder.onnx, meta.json, ...
    prior.bind(session.floor)                  # DMT once per floor (cached in memory and on disk)
    dtv = prior.dtv(odo)                       # odo (K, n_points, 2) m: one window per heading hypothesis
    logw = prior.log_score_at(xy[None], dtv[:, None, :])   # xy (N, 2) world m -> (K, N)

The LSTM runs once per filter step per heading hypothesis (K windows, rotated by the filter before the
call), the U-Net never runs in the loop; scores are gathered at the particles' pixels only (K x N x c
multiply-adds, no full-map product). Log scores are log(max(S, 1e-12)); a position outside the map or in
a pixel of the floor that is not FREE (at the floor's own resolution) gets :data:`LOG_FLOOR` = log(1e-12).

Resolution. The network works at one metric resolution (``resolution_m``, from the checkpoint / meta.json).
A floor at another resolution is resampled to it (:func:`resample_free`) on a grid with the same lower-left
origin (:class:`NetGrid`); scores are mapped back by looking up the net pixel that contains each world point
(:meth:`MapPrior.log_score_map` gives them at every pixel of the floor's own grid).

DMT cache. :meth:`MapPrior.bind` keys a DMT by sha256 of (the floor's FREE mask, its shape and resolution,
the network resolution, the weights' hash); it is kept in memory and, with a ``cache_dir``, as
``dmt_<key>.npy`` there, so a second bind of the same floor -- in this process or a later one -- does not run
the U-Net (:attr:`MapPrior.encode_calls` counts the runs).

This module needs numpy (and onnxruntime for an ONNX directory); torch only for a checkpoint.
"""

from __future__ import annotations

import hashlib
import json
import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

SCORE_FLOOR = 1e-12
LOG_FLOOR = float(np.log(SCORE_FLOOR))
MAP_ENCODER_ONNX = "map_encoder.onnx"
TRAJECTORY_ENCODER_ONNX = "trajectory_encoder.onnx"
META_JSON = "meta.json"


# --- grids and resampling (numpy only; training uses the same functions) ---------------------------------

def _free_ranges(n_out: int, res_in: float, res_out: float, n_in: int):
    """For each output cell i (counted from the lower-left origin) the input index range [lo, hi) it covers."""
    i = np.arange(n_out)
    lo = np.floor(i * res_out / res_in + 1e-9).astype(np.int64)
    hi = np.ceil((i + 1) * res_out / res_in - 1e-9).astype(np.int64)
    return np.clip(lo, 0, n_in), np.clip(np.maximum(hi, lo + 1), 0, n_in + 1)


def resample_free(free: np.ndarray, res_in: float, res_out: float) -> np.ndarray:
    """Free mask (H, W) bool at ``res_in`` m/px -> (H2, W2) bool at ``res_out`` m/px, same lower-left origin.

    H2 = max(1, round(H * res_in / res_out)) (W2 alike). Coarser output (res_out > res_in): a cell is free
    only if *every* input pixel it touches is free (any obstacle wins, so 0.2 m walls survive at 0.25 or
    0.5 m/px; doors narrow by at most one output pixel per side); finer or equal output: nearest input pixel
    (pixel centre). Input beyond the image counts as obstacle. Image row 0 is the top row (largest y).
    """
    free = np.asarray(free, dtype=bool)
    if free.ndim != 2:
        raise ValueError(f"free mask must be (H, W), got shape {free.shape}")
    res_in, res_out = float(res_in), float(res_out)
    H, W = free.shape
    H2 = max(1, int(round(H * res_in / res_out)))
    W2 = max(1, int(round(W * res_in / res_out)))
    if H2 == H and W2 == W and abs(res_in - res_out) <= 1e-9 * res_out:
        return free.copy()
    up = free[::-1]  # row 0 = bottom row, so output cells align with the lower-left origin
    if res_out <= res_in:  # finer: nearest by centre
        r = np.floor((np.arange(H2) + 0.5) * res_out / res_in).astype(np.int64)
        c = np.floor((np.arange(W2) + 0.5) * res_out / res_in).astype(np.int64)
        ok_r, ok_c = r < H, c < W
        out = up[np.minimum(r, H - 1)][:, np.minimum(c, W - 1)] & ok_r[:, None] & ok_c[None, :]
        return np.ascontiguousarray(out[::-1])
    occ = np.zeros((H + 2, W + 2), dtype=np.int64)  # summed-area table of obstacles, one row/col beyond as obstacle
    occ[1:H + 1, 1:W + 1] = ~up
    occ[H + 1, :] = 1
    occ[:, W + 1] = 1
    sat = np.zeros((H + 3, W + 3), dtype=np.int64)
    sat[1:, 1:] = occ.cumsum(0).cumsum(1)
    r0, r1 = _free_ranges(H2, res_in, res_out, H)
    c0, c1 = _free_ranges(W2, res_in, res_out, W)
    r0, r1 = r0 + 1, r1 + 1  # into the padded table
    c0, c1 = c0 + 1, c1 + 1
    n_occ = sat[r1][:, c1] - sat[r0][:, c1] - sat[r1][:, c0] + sat[r0][:, c0]
    return np.ascontiguousarray((n_occ == 0)[::-1])


@dataclass(frozen=True)
class NetGrid:
    """A floor's grid at the network's resolution: ``shape`` (H, W), ``resolution`` m/px, ``origin`` (x, y) m of
    the lower-left corner (the floor's), row 0 on top (ROS map_server convention, as :class:`blenav.data.Floor`)."""

    shape: tuple[int, int]
    resolution: float
    origin: tuple[float, float]

    def world_to_pixel(self, xy: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """World (..., 2) m -> int64 (row, col) of the containing pixel (may be out of range)."""
        xy = np.asarray(xy, dtype=float)
        h = self.shape[0]
        col = np.floor((xy[..., 0] - self.origin[0]) / self.resolution).astype(np.int64)
        row = (h - 1) - np.floor((xy[..., 1] - self.origin[1]) / self.resolution).astype(np.int64)
        return row, col

    def inside(self, row: np.ndarray, col: np.ndarray) -> np.ndarray:
        return (row >= 0) & (row < self.shape[0]) & (col >= 0) & (col < self.shape[1])


def net_grid(floor, resolution_m: float) -> tuple[NetGrid, np.ndarray]:
    """(grid, free mask (H, W) bool) of a :class:`blenav.data.Floor` resampled to ``resolution_m``.

    Raises ValueError naming the building and floor when the floor (or its resampled mask) has no free pixel.
    """
    free = np.asarray(floor.free_mask, dtype=bool)
    where = _floor_name(floor)
    if not free.any():
        raise ValueError(f"{where} has no free space (no FREE pixel in {floor.image_path}); the map prior needs "
                         "a floor plan with walkable pixels")
    m = resample_free(free, float(floor.resolution), float(resolution_m))
    if not m.any():
        raise ValueError(f"{where} has no free space at the map prior's resolution {resolution_m:g} m/px "
                         f"(floor resolution {floor.resolution:g} m/px; every free area is narrower than a pixel)")
    grid = NetGrid((int(m.shape[0]), int(m.shape[1])), float(resolution_m),
                   (float(floor.origin[0]), float(floor.origin[1])))
    return grid, m


def _floor_name(floor) -> str:
    path = Path(floor.image_path)  # a Floor has no back reference: its building is the folder with building.yaml
    b = next((p.name for p in path.parents if (p / "building.yaml").is_file()), path.parent.name)
    return f"building '{b}' floor {floor.id!r}"


def floor_key(floor, resolution_m: float, weights_hash: str) -> str:
    """sha256 hex of (FREE mask bits, shape, floor resolution, network resolution, weights hash)."""
    free = np.asarray(floor.free_mask, dtype=bool)
    h = hashlib.sha256()
    h.update(str(free.shape).encode())
    h.update(np.packbits(free).tobytes())
    h.update(f"{float(floor.resolution):.9g}|{float(resolution_m):.9g}|{weights_hash}".encode())
    return h.hexdigest()


def pad_to_multiple(mask: np.ndarray, k: int) -> np.ndarray:
    """(H, W) float32 -> (H', W') zero-padded at the bottom/right to multiples of ``k`` (zero = obstacle)."""
    h, w = mask.shape
    return np.pad(mask, ((0, (-h) % k), (0, (-w) % k)))


# --- backends --------------------------------------------------------------------------------------------

class _TorchBackend:
    """A checkpoint of ``train.py experiment=mapprior`` in PyTorch (eval mode, no grad)."""

    def __init__(self, path: Path):
        from blenav.learn.mapprior import load_mapprior, weights_hash

        self.net, self.meta = load_mapprior(path)
        self.weights_hash = weights_hash(self.net)

    def encode_map(self, mask: np.ndarray) -> np.ndarray:
        import torch

        with torch.no_grad():
            return self.net.encode_map(torch.from_numpy(mask)[None, None]).numpy()[0]

    def encode_trajectory(self, odo_px: np.ndarray) -> np.ndarray:
        import torch

        with torch.no_grad():
            return self.net.encode_trajectory(torch.from_numpy(odo_px)).numpy()


class _OnnxBackend:
    """An export directory (map_encoder.onnx, trajectory_encoder.onnx, meta.json) in onnxruntime."""

    def __init__(self, root: Path, threads: int = 1):
        import onnxruntime as ort

        paths = [root / n for n in (MAP_ENCODER_ONNX, TRAJECTORY_ENCODER_ONNX, META_JSON)]
        missing = [p.name for p in paths if not p.is_file()]
        if missing:
            raise FileNotFoundError(f"{root} lacks {missing}; write it with `python export.py ckpt=RUN/last.ckpt "
                                    "out=DIR`")
        self.meta = json.loads(paths[2].read_text(encoding="utf-8"))
        if self.meta.get("kind") != "mapprior":
            raise ValueError(f"{paths[2]} is not a map prior export (kind {self.meta.get('kind')!r})")
        so = ort.SessionOptions()
        so.intra_op_num_threads = int(threads)
        so.inter_op_num_threads = 1
        so.execution_mode = ort.ExecutionMode.ORT_SEQUENTIAL
        self.map_sess = ort.InferenceSession(str(paths[0]), so, providers=["CPUExecutionProvider"])
        self.traj_sess = ort.InferenceSession(str(paths[1]), so, providers=["CPUExecutionProvider"])
        h = hashlib.sha256(paths[0].read_bytes())
        self.weights_hash = "onnx:" + h.hexdigest()[:16]
        self.resolution_m = float(self.meta["resolution_m"])

    def encode_map(self, mask: np.ndarray) -> np.ndarray:
        h, w = mask.shape
        padded = pad_to_multiple(mask, int(self.meta["size_multiple"]))
        return self.map_sess.run(["dmt"], {"mask": padded[None, None]})[0][0, :, :h, :w]

    def encode_trajectory(self, odo_px: np.ndarray) -> np.ndarray:
        odo_m = (odo_px * self.resolution_m).astype(np.float32)  # the graph takes metres
        return self.traj_sess.run(["dtv"], {"odometry": odo_m})[0]


# --- the prior -------------------------------------------------------------------------------------------

class MapPrior:
    """Learned map prior from a checkpoint (``.ckpt`` file, PyTorch) or an export directory (onnxruntime).

    ``cache_dir``: where DMTs are stored as ``dmt_<key>.npy`` (None: memory only). ``threads``: onnxruntime
    intra-op threads (PyTorch keeps its own setting).
    """

    def __init__(self, source: str | Path, cache_dir: str | Path | None = None, threads: int = 1):
        source = Path(source)
        if source.is_dir():
            self._backend = _OnnxBackend(source, threads)
        elif source.is_file():
            self._backend = _TorchBackend(source)
        else:
            raise FileNotFoundError(f"map prior {source} does not exist (a last.ckpt or an export directory)")
        meta = self._backend.meta
        self.source = source
        self.meta: dict = meta
        self.resolution_m = float(meta["resolution_m"])
        w = meta["window"]
        self.window_s, self.step_hz, self.n_points = float(w["window_s"]), float(w["step_hz"]), int(w["n_points"])
        self.channels = int(meta["channels"])
        self.cache_dir = Path(cache_dir) if cache_dir is not None else None
        self.encode_calls = 0  # U-Net runs (cache misses)
        self._memory: dict[str, tuple[NetGrid, np.ndarray]] = {}
        self._floor = None
        self._grid: NetGrid | None = None
        self._dmt: np.ndarray | None = None

    @property
    def weights_hash(self) -> str:
        return self._backend.weights_hash

    @property
    def grid(self) -> NetGrid:
        self._check_bound()
        return self._grid

    @property
    def dmt(self) -> np.ndarray:
        """The bound floor's DMT (c, H, W) float32 at the network's resolution."""
        self._check_bound()
        return self._dmt

    def _check_bound(self) -> None:
        if self._dmt is None:
            raise RuntimeError("no floor bound: call MapPrior.bind(floor) first")

    def bind(self, floor) -> None:
        """Make ``floor`` (a :class:`blenav.data.Floor`) current: DMT from memory, disk cache, or one U-Net run."""
        key = floor_key(floor, self.resolution_m, self.weights_hash)
        if key not in self._memory:
            grid, mask = net_grid(floor, self.resolution_m)
            path = self.cache_dir / f"dmt_{key[:32]}.npy" if self.cache_dir is not None else None
            dmt = None
            if path is not None and path.is_file():
                dmt = np.load(path)
                if dmt.shape != (self.channels, *grid.shape):
                    dmt = None  # stale or foreign file: recompute
            if dmt is None:
                dmt = np.ascontiguousarray(self._backend.encode_map(mask.astype(np.float32)), dtype=np.float32)
                self.encode_calls += 1
                if path is not None:
                    path.parent.mkdir(parents=True, exist_ok=True)
                    tmp = path.with_suffix(f".{os.getpid()}.tmp.npy")
                    np.save(tmp, dmt)
                    os.replace(tmp, path)
            self._memory[key] = (grid, dmt)
        self._floor = floor
        self._grid, self._dmt = self._memory[key]

    def dtv(self, odo_windows: np.ndarray) -> np.ndarray:
        """Odometry windows (K, n, 2) metres, relative to each window's start, world-aligned axes (x east,
        y north), ``n >= n_points`` samples at ``step_hz`` (longer windows: the last n_points are used)
        -> DTV (K, c) float32. Raises ValueError for shorter windows, saying how many seconds are needed."""
        odo = np.asarray(odo_windows, dtype=np.float64)
        if odo.ndim != 3 or odo.shape[-1] != 2:
            raise ValueError(f"odometry windows must be (K, n, 2) metres, got shape {odo.shape}")
        if odo.shape[1] < self.n_points:
            raise ValueError(f"odometry window has {odo.shape[1]} samples ({(odo.shape[1] - 1) / self.step_hz:g} s) "
                             f"but the map prior needs {self.n_points} samples at {self.step_hz:g} Hz "
                             f"({self.window_s:g} s of odometry)")
        odo = odo[:, -self.n_points:]
        odo = odo - odo[:, :1]
        return np.asarray(self._backend.encode_trajectory((odo / self.resolution_m).astype(np.float32)),
                          dtype=np.float32)

    def score_at(self, xy: np.ndarray, dtv: np.ndarray) -> np.ndarray:
        """Raw scores S (eq. 3.8, Roy) at world points ``xy`` (..., 2) m for DTVs ``dtv`` (..., c) broadcastable
        against xy's leading dims (e.g. xy (1, N, 2) and dtv (K, 1, c) -> (K, N)). NaN outside the net grid."""
        self._check_bound()
        xy = np.asarray(xy, dtype=float)
        dtv = np.asarray(dtv, dtype=np.float32)
        r, c = self._grid.world_to_pixel(xy)
        ok = self._grid.inside(r, c)
        if dtv.shape[-1] != self.channels:
            raise ValueError(f"dtv must end in c = {self.channels} channels, got shape {dtv.shape}")
        feats = np.moveaxis(self._dmt[:, np.where(ok, r, 0), np.where(ok, c, 0)], 0, -1)  # (..., c)
        s = np.einsum("...c,...c->...", feats, dtv)
        return np.where(ok, s, np.nan)

    def log_score_at(self, xy: np.ndarray, dtv: np.ndarray) -> np.ndarray:
        """log(max(S, 1e-12)) at world points ``xy`` (..., 2) m for ``dtv`` (..., c) (broadcast as in
        :meth:`score_at`); :data:`LOG_FLOOR` outside the map or where the floor is not FREE. float64."""
        s = self.score_at(xy, dtv)
        free = self._floor.is_free(np.asarray(xy, dtype=float))
        s = np.where(np.isfinite(s) & free, s, SCORE_FLOOR)
        return np.log(np.maximum(s, SCORE_FLOOR))

    def log_score_map(self, dtv: np.ndarray) -> np.ndarray:
        """Log scores of one DTV (c,) at every pixel centre of the bound floor's *own* grid -> (H, W), i.e. the
        network-resolution scores mapped back to the floor's resolution."""
        self._check_bound()
        h, w = self._floor.shape
        rr, cc = np.meshgrid(np.arange(h), np.arange(w), indexing="ij")
        return self.log_score_at(self._floor.pixel_to_world(rr, cc), np.asarray(dtv)[None, None, :])
