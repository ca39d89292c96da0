"""A bundle's ONNX graphs in one variant, as onnxruntime sessions: the cross-phone localizer and the map prior's
encoders (file names: :func:`blenav.runtime.bundle.format.variant_name`)."""

from __future__ import annotations

from pathlib import Path

from blenav.limits import read_json
from blenav.onnx_io import session

from ..map_prior import OnnxBackend
from ..onnx_localizer import LocalizerSession
from .format import MAP_GRAPHS, variant_name


class LocalizerGraph(LocalizerSession):
    """The cross-phone localizer of a bundle in one variant: (K, B, H) windows on the thesis scale -> (K, 2) m,
    each from a zero LSTM state (the export's ``lstm_state`` contract); NaN rows where nothing was heard. ``meta``:
    the float graph's metadata (the ORT variants may not keep it); ``sess``: an open session of ``path``."""

    def __init__(self, path: Path, meta: dict, threads: int = 1, sess=None):
        super().__init__(path, meta, sess if sess is not None else session(Path(path), threads))

    #: unchecked (the live path builds the windows itself)
    predict = LocalizerSession.predict_windows


class MapBackend(OnnxBackend):
    """A bundle's map prior graphs (one variant) as a :class:`blenav.runtime.map_prior.MapPrior` backend: an
    :class:`~blenav.runtime.map_prior.OnnxBackend` (its encoders) over the bundle's file names and manifest."""

    def __init__(self, root: Path, variant: str, threads: int, digest: str):
        self.meta = read_json(root / "meta.json")
        self.map_sess = session(root / variant_name(MAP_GRAPHS[0], variant), threads)
        self.traj_sess = session(root / variant_name(MAP_GRAPHS[1], variant), threads)
        self.weights_hash = f"bundle-{variant}:{digest[:16]}"
        self.resolution_m = float(self.meta["resolution_m"])
