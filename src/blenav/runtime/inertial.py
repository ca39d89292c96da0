"""The learned inertial odometry in onnxruntime, no torch (issue 31): :class:`InertialModel` of an export directory
(``python export.py ckpt=RUN/last.ckpt out=IO_DIR`` on a checkpoint of ``train.py experiment=inertial``).

The directory holds ``inertial.onnx`` and ``meta.json``. The graph: input ``imu`` (batch, n_window, 15) float32, the
IMU in the attitude's gravity-aligned frame resampled to ``grid.rate_hz`` (:mod:`blenav.features.inertial`: world-frame
acceleration without gravity m/s^2, rate rad/s; the normalisation is inside the graph); outputs ``velocity`` (batch, 2)
m/s over the window's last ``grid.stride_s`` and ``log_var`` (batch, 2) its log variance; with ``input_frame: heading``
each window is first turned into its heading frame and the velocity turned back
(:func:`blenav.features.inertial.heading_frame`). meta.json records the grid,
channels, frame, units, the normalisation, the parity measured at export and the files' sha256; the same entries are
in the graph's ``metadata_props``. Everything read is bounded before use (a stranger's files): the JSON's size
(:func:`blenav.limits.read_json`), the model file's (:func:`blenav.onnx_io.session`), the grid's numbers; the graph's
weights and file must match the hashes recorded at export (:func:`blenav.onnx_io.check_export_files`).

``model.odometry(session)`` is :func:`blenav.filters.inertial_odometry.lio_odometry`: the track every odometry consumer
reads.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from blenav.features.inertial import CHANNELS, FRAMES, InertialGrid
from blenav.limits import read_json
from blenav.onnx_io import check_export_files, read_metadata, session

__all__ = ["InertialModel", "INERTIAL_ONNX", "META_JSON", "KIND"]

INERTIAL_ONNX = "inertial.onnx"
META_JSON = "meta.json"
KIND = "inertial"


class InertialModel:
    """An inertial odometry export directory in onnxruntime: ``grid``, ``predict(windows)``, ``odometry(session)``."""

    def __init__(self, root: str | Path, threads: int = 1):
        root = Path(root)
        if root.is_file():
            raise ValueError(f"io_model={root} is a file; give the directory `python export.py ckpt=RUN/last.ckpt "
                             "out=IO_DIR` wrote (inertial.onnx and meta.json)")
        paths = [root / INERTIAL_ONNX, root / META_JSON]
        missing = [p.name for p in paths if not p.is_file()]
        if missing:
            raise FileNotFoundError(f"{root} lacks {missing}: not an inertial odometry export (write it with `python "
                                    "export.py ckpt=RUN/last.ckpt out=IO_DIR` on a run of train.py experiment=inertial)")
        meta = read_json(paths[1])
        where = str(paths[1])
        if not isinstance(meta, dict) or meta.get("kind") != KIND:
            got = meta.get("kind") if isinstance(meta, dict) else type(meta).__name__
            raise ValueError(f"{where}: kind {got!r}, not an inertial odometry export ({KIND!r})")
        self.grid = InertialGrid.from_meta(meta.get("grid"), where)
        if list(meta.get("channels") or []) != list(CHANNELS):
            raise ValueError(f"{where}: channels {meta.get('channels')!r}, this blenav feeds {list(CHANNELS)}")
        self.frame = meta.get("input_frame", "world")
        if self.frame not in FRAMES:
            raise ValueError(f"{where}: input_frame {self.frame!r}, not one of {FRAMES}")
        check_export_files(root, meta, (INERTIAL_ONNX,), META_JSON)
        self.meta, self.root = meta, root
        self.key = "onnx:" + str((meta.get("sha256") or {}).get(INERTIAL_ONNX) or root.resolve())  # cache key part
        #: the attitude source the network was trained in (the default of :meth:`odometry`): one a deployed phone has
        #: (never ``groundtruth``, the simulated walks' training-only source), checked here, before any session
        from blenav.filters.pdr_odometry import HEADING_SOURCES  # what odometry() will read
        from blenav.filters.yaw_hold import check_yaw

        att = meta.get("attitude") or {}
        self.attitude = str((att.get("attitude") if isinstance(att, dict) else None) or "auto")
        if self.attitude not in HEADING_SOURCES:
            raise ValueError(f"{where}: attitude {self.attitude!r}, not one a phone has at run time "
                             f"({', '.join(HEADING_SOURCES)})")
        #: the attitude's yaw the network was trained with (blenav.filters.yaw_hold); an export without it: its own
        self.yaw = check_yaw((att.get("yaw") if isinstance(att, dict) else None) or "attitude",
                             f"{where}: attitude.yaw")
        self.key += f":yaw={self.yaw}"  # the same weights fed another yaw make another track
        self.sess = session(paths[0], threads)
        props = read_metadata(self.sess)  # the contract the graph was exported with: meta.json must say the same
        for key in ("grid", "channels", "input_frame", "attitude", "yaw_ensemble"):  # attitude: exports since data.yaw
            if key in props and props[key] != meta.get(key):
                raise ValueError(f"{where}: {key} = {meta.get(key)!r}, but {paths[0].name} was exported with "
                                 f"{props[key]!r}: meta.json was changed after export; export IO_DIR again")
        shape = self.sess.get_inputs()[0].shape
        if len(shape) != 3 or shape[1] != self.grid.n_window or shape[2] != len(CHANNELS):
            raise ValueError(f"{paths[0]}: input shape {shape}, meta.json says (batch, {self.grid.n_window}, "
                             f"{len(CHANNELS)})")

    def predict(self, windows: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(K, n_window, 15) float32 windows -> (velocity (K, 2) m/s, log variance (K, 2))."""
        W = np.ascontiguousarray(windows, dtype=np.float32)
        if W.ndim != 3 or W.shape[1:] != (self.grid.n_window, len(CHANNELS)):
            raise ValueError(f"inertial model: windows of shape (K, {self.grid.n_window}, {len(CHANNELS)}) expected, "
                             f"got {W.shape}")
        if not len(W):
            return np.zeros((0, 2), np.float32), np.zeros((0, 2), np.float32)
        v, lv = self.sess.run(["velocity", "log_var"], {"imu": W})
        return v, lv

    def odometry(self, session, attitude: str | None = None, cache: dict | None = None):
        """The session's learned odometry track (:func:`blenav.filters.inertial_odometry.lio_odometry`) in the frame of
        ``attitude`` (None: the source the network was trained in, :attr:`attitude`)."""
        from blenav.filters.inertial_odometry import lio_odometry

        return lio_odometry(session, self, attitude or self.attitude, cache=cache)
