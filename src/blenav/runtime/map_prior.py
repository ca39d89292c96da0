"""The learned map prior (Roy, section 3.2.2) at run time, for a particle filter: DMT once per floor, DTV per
step, scores gathered at particle positions.

Notation as in :mod:`blenav.models.mapprior`: M free mask at the network's resolution, O odometry window,
DMT f(M) (c, H, W), DTV g(O) (c,), score S(x | M, O) = f(M)_x . g(O) (eq. 3.8, Roy).

Use::

    prior = MapPrior("DIR2")                   # an export: map_encoder.onnx, trajectory_encoder.onnx, meta.json
    prior.bind(session.floor)                  # DMT once per floor (cached in memory and on disk)
    dtv = prior.dtv(odo)                       # odo (K, n_points, 2) m: one window per heading hypothesis
    logw = prior.log_score_at(xy[None], dtv[:, None, :])   # xy (N, 2) world m -> (K, N)

The LSTM runs once per filter step per heading hypothesis (K windows, rotated by the filter before the
call), the U-Net never runs in the loop; scores are gathered at the particles' pixels only (K x N x c
multiply-adds, no full-map product). Log scores are log(max(S, 1e-12)); a position outside the map or in
a pixel of the floor that is not FREE (at the floor's own resolution) gets :data:`LOG_FLOOR` = log(1e-12).

Resolution. The network works at one metric resolution (``resolution_m``, from the checkpoint / meta.json).
A floor at another resolution is resampled to it on a grid with the same lower-left origin
(:mod:`blenav.features.mapgrid`, shared with training); scores are mapped back by looking up the net pixel
that contains each world point (:meth:`MapPrior.log_score_map` gives them at every pixel of the floor's own
grid).

DMT cache. :meth:`MapPrior.bind` keys a DMT by sha256 of (the floor's FREE mask, its shape and resolution,
the network resolution, the weights' hash); it is kept in memory and, with a ``cache_dir``, as
``dmt_<key>.npy`` there, so a second bind of the same floor -- in this process or a later one -- does not run
the U-Net (:attr:`MapPrior.encode_calls` counts the runs).

Backends. An export directory runs in onnxruntime (:class:`OnnxBackend`), after :func:`check_export` found
each graph's weights equal to the hash recorded at export and each file equal to meta.json's sha256. A checkpoint (``RUN/last.ckpt``)
needs PyTorch, which this layer does not import: the caller hands MapPrior the loader,
``MapPrior(path, loader=blenav.learn.mapprior.checkpoint.TorchBackend)`` (or calls
``blenav.learn.mapprior.checkpoint.load_map_prior(path)``). A backend has ``meta`` (the checkpoint's or
meta.json's), ``weights_hash`` (str, part of the DMT cache key), ``encode_map(mask (H, W) float32) -> (c, H, W)``
and ``encode_trajectory(odo_px (K, n_points, 2) float32) -> (K, c)``.

This module needs numpy (and onnxruntime for an ONNX directory).
"""

from __future__ import annotations

import hashlib
import os
from pathlib import Path
from typing import Callable

import numpy as np

from blenav.features.mapgrid import NetGrid, floor_key, net_grid, pad_to_multiple
from blenav.limits import check_memory, check_range, read_json
from blenav.onnx_io import check_export_files, session

SCORE_FLOOR = 1e-12
LOG_FLOOR = float(np.log(SCORE_FLOOR))
MAP_ENCODER_ONNX = "map_encoder.onnx"
TRAJECTORY_ENCODER_ONNX = "trajectory_encoder.onnx"
META_JSON = "meta.json"


# --- backends --------------------------------------------------------------------------------------------

class OnnxBackend:
    """An export directory (map_encoder.onnx, trajectory_encoder.onnx, meta.json) in onnxruntime."""

    def __init__(self, root: Path, threads: int = 1):
        paths = [root / n for n in (MAP_ENCODER_ONNX, TRAJECTORY_ENCODER_ONNX, META_JSON)]
        missing = [p.name for p in paths if not p.is_file()]
        if missing:
            raise FileNotFoundError(f"{root} lacks {missing}; write it with `python export.py ckpt=RUN/last.ckpt "
                                    "out=DIR`")
        self.meta = read_json(paths[2])
        if not isinstance(self.meta, dict) or self.meta.get("kind") != "mapprior":
            raise ValueError(f"{paths[2]} is not a map prior export (kind {self.meta.get('kind') if isinstance(self.meta, dict) else None!r})")
        self.map_sess = session(paths[0], threads)
        self.traj_sess = session(paths[1], threads)
        check_export(root, self.meta)
        h = hashlib.sha256(paths[0].read_bytes())
        self.weights_hash = "onnx:" + h.hexdigest()[:16]
        self.resolution_m = check_range(self.meta.get("resolution_m"), "cell_m", str(paths[2]), field="resolution_m")

    def encode_map(self, mask: np.ndarray) -> np.ndarray:
        h, w = mask.shape
        padded = pad_to_multiple(mask, int(self.meta["size_multiple"]))
        return self.map_sess.run(["dmt"], {"mask": padded[None, None]})[0][0, :, :h, :w]

    def encode_trajectory(self, odo_px: np.ndarray) -> np.ndarray:
        odo_m = (odo_px * self.resolution_m).astype(np.float32)  # the graph takes metres
        return self.traj_sess.run(["dtv"], {"odometry": odo_m})[0]


def check_export(root: Path, meta: dict) -> None:
    """Refuse an export directory whose graphs are not the ones written with its meta.json
    (:func:`blenav.onnx_io.check_export_files`)."""
    check_export_files(root, meta, (MAP_ENCODER_ONNX, TRAJECTORY_ENCODER_ONNX), META_JSON)


# --- the prior -------------------------------------------------------------------------------------------

class MapPrior:
    """Learned map prior from an export directory (onnxruntime) or, with ``loader``, a checkpoint file.

    ``loader``: a callable that turns a file into a backend (see the module docstring), e.g.
    ``blenav.learn.mapprior.checkpoint.TorchBackend`` for a ``.ckpt``; not used for a directory.
    ``cache_dir``: where DMTs are stored as ``dmt_<key>.npy`` (None: memory only). ``threads``: onnxruntime
    intra-op threads (PyTorch keeps its own setting).
    """

    def __init__(self, source: str | Path, cache_dir: str | Path | None = None, threads: int = 1,
                 loader: Callable[[Path], object] | None = None):
        source = Path(source)
        if source.is_dir():
            self._backend = OnnxBackend(source, threads)
        elif source.is_file():
            if loader is None:
                raise ValueError(f"map prior {source} is a file (a checkpoint?): MapPrior runs an export directory "
                                 "in onnxruntime; for a checkpoint pass the PyTorch loader, MapPrior(path, "
                                 "loader=blenav.learn.mapprior.checkpoint.TorchBackend) or blenav.learn."
                                 "mapprior.checkpoint.load_map_prior(path), or export it first with `python "
                                 "export.py ckpt=RUN/last.ckpt out=DIR`")
            self._backend = loader(source)
        else:
            raise FileNotFoundError(f"map prior {source} does not exist (a last.ckpt or an export directory)")
        meta = self._backend.meta
        self.source = source
        self.meta: dict = meta
        where = f"map prior {source / META_JSON if source.is_dir() else source}"
        self.where = where
        # sizes from a file: bounded before a floor is resampled at them (resolution_m = 1e-4 asked 28 GiB)
        self.resolution_m = check_range(meta.get("resolution_m"), "cell_m", where, field="resolution_m")
        w = meta.get("window") if isinstance(meta.get("window"), dict) else {}
        self.window_s = check_range(w.get("window_s"), "window_s", where, field="window.window_s")
        self.step_hz = check_range(w.get("step_hz"), "step_hz", where, field="window.step_hz")
        self.n_points = check_range(w.get("n_points"), "history", where, field="window.n_points")
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
            h, w = (int(round(n * float(floor.resolution) / self.resolution_m)) for n in np.shape(floor.free_mask))
            check_memory(h * w * (4.0 * self.channels + 2), f"a {h:,} x {w:,} grid at resolution_m = "
                         f"{self.resolution_m:g} m with {self.channels} channels", self.where)
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
