"""What a map prior checkpoint carries besides weights, how to rebuild its network, and the PyTorch loader the
runtime's :class:`blenav.runtime.map_prior.MapPrior` is handed for a checkpoint.

Checkpoint meta (``checkpoint["blenav"]``, written by :func:`blenav.learn.mapprior.train.build_meta`):
``kind: "mapprior"``, ``model`` (the resolved model node), ``resolution_m``, ``window`` {window_s, step_hz,
n_points}, ``channels`` c, ``size_multiple`` (the U-Net's), ``target`` {scale, gain, feasible_tbar},
``augment``, ``crop_px``, ``buildings`` / ``val_buildings``, ``data_hash``. :func:`load_mapprior` rebuilds the
network from it with no config file (reading through :func:`blenav.learn.common.checkpoint.read_checkpoint`, as the
cross-phone side does).

The runtime does not import this module (it is below ``learn/`` and torch-free): a caller that wants to run a
checkpoint hands it the loader, ``MapPrior(path, loader=TorchBackend)``, or calls :func:`load_map_prior`.
"""

from __future__ import annotations

import hashlib
from collections.abc import Mapping
from pathlib import Path

import numpy as np
import torch
from hydra.utils import instantiate

from blenav.limits import check_range
from blenav.models.mapprior import MapPriorNet
from blenav.runtime.map_prior import MapPrior
from blenav.trust import check_targets

from ..common.checkpoint import KEY, check_weight_shapes, read_checkpoint

KIND = "mapprior"


def build_net(model: dict, n_points: int, step_hz: float, where: str = "model config") -> MapPriorNet:
    """:class:`MapPriorNet` from a model node's ``net`` (``_target_`` and sizes) for windows of n_points. Every
    ``_target_`` of the node must be one of blenav's (:func:`blenav.trust.check_targets`, refusals name ``where``):
    the node may come from a checkpoint file."""
    if not isinstance(model, Mapping) or not model.get("net"):
        raise ValueError(f"{where}: the model node has no net (a {type(model).__name__}); was it written by "
                         "train.py experiment=mapprior?")
    check_targets(model, where, prefix="model")
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


def load_mapprior(path: str | Path) -> tuple[MapPriorNet, dict]:
    """(network in eval mode, meta) from a ``last.ckpt`` of ``train.py experiment=mapprior``."""
    ck = read_checkpoint(path)
    meta = ck[KEY]
    if meta.get("kind") != KIND:
        raise ValueError(f"{path}: a {meta.get('kind', 'crossphone')} checkpoint, not a map prior")
    where = f"checkpoint {path}"
    # sizes from the file (the export's sample inputs are n_points long, its graph divides by resolution_m), bounded
    # as the runtime bounds an export's meta.json (blenav.runtime.map_prior.MapPrior), then the network they
    # describe checked against the weights before any memory is claimed
    w = meta.get("window") if isinstance(meta.get("window"), dict) else {}
    n_points = check_range(w.get("n_points"), "history", where, field="blenav.window.n_points")
    step_hz = check_range(w.get("step_hz"), "step_hz", where, field="blenav.window.step_hz")
    check_range(w.get("window_s"), "window_s", where, field="blenav.window.window_s")
    check_range(meta.get("resolution_m"), "cell_m", where, field="blenav.resolution_m")
    check_weight_shapes(lambda: {"net": build_net(meta["model"], n_points, step_hz, where)}, ck["state_dict"], where,
                        "blenav.model")
    net = build_net(meta["model"], n_points, step_hz, where=where)
    state = {k[len("net."):]: v for k, v in ck["state_dict"].items() if k.startswith("net.")}
    net.load_state_dict(state)
    return net.eval(), meta


class TorchBackend:
    """A checkpoint of ``train.py experiment=mapprior`` in PyTorch (eval mode, no grad), as the backend of a
    :class:`~blenav.runtime.map_prior.MapPrior` (``MapPrior(path, loader=TorchBackend)``)."""

    def __init__(self, path: str | Path):
        self.net, self.meta = load_mapprior(path)
        self.weights_hash = weights_hash(self.net)

    def encode_map(self, mask: np.ndarray) -> np.ndarray:
        with torch.no_grad():
            return self.net.encode_map(torch.from_numpy(mask)[None, None]).numpy()[0]

    def encode_trajectory(self, odo_px: np.ndarray) -> np.ndarray:
        with torch.no_grad():
            return self.net.encode_trajectory(torch.from_numpy(odo_px)).numpy()


def load_map_prior(source: str | Path, **kw) -> MapPrior:
    """A :class:`~blenav.runtime.map_prior.MapPrior` of a checkpoint (PyTorch) or an export directory
    (onnxruntime); ``kw`` as MapPrior's (``cache_dir``, ``threads``)."""
    return MapPrior(source, loader=TorchBackend, **kw)
