"""What an inertial odometry checkpoint carries besides weights, and how its network is rebuilt from it alone.

Checkpoint meta (``checkpoint["blenav"]``, written by :func:`blenav.learn.inertial.train.build_meta`): ``kind:
"inertial"``, ``model`` (the resolved model node, its ``net._target_`` one of :mod:`blenav.models.inertial`),
``grid`` {rate_hz, window_s, stride_s} (:class:`blenav.features.inertial.InertialGrid`), ``channels``, ``frame``,
``attitude``, the datasets, sessions and their counts, ``data_hash``. :func:`load_inertial` checks every size against
the weights before building anything (:func:`blenav.learn.common.checkpoint.check_weight_shapes`) and every
``_target_`` against blenav's classes (:func:`blenav.trust.check_targets`): the file may come from a stranger.
"""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path

from hydra.utils import instantiate

from blenav.features.inertial import CHANNELS, InertialGrid
from blenav.models.inertial import InertialNet
from blenav.trust import check_targets

from ..common.checkpoint import KEY, check_weight_shapes, read_checkpoint

KIND = "inertial"


def build_net(model: dict, grid: InertialGrid, where: str = "model config") -> InertialNet:
    """The :class:`InertialNet` of a model node's ``net`` for windows of ``grid``; every ``_target_`` of the node must
    be one of blenav's (refusals name ``where``)."""
    if not isinstance(model, Mapping) or not model.get("net"):
        raise ValueError(f"{where}: the model node has no net (a {type(model).__name__}); was it written by "
                         "train.py experiment=inertial?")
    check_targets(model, where, prefix="model")
    net = instantiate(model["net"], n_window=grid.n_window, n_stride=grid.n_stride, in_channels=len(CHANNELS))
    if not isinstance(net, InertialNet):
        raise ValueError(f"{where}: model.net must build an inertial network (blenav.models.inertial), got "
                         f"{type(net).__name__}")
    return net


def load_inertial(path: str | Path) -> tuple[InertialNet, dict]:
    """(network in eval mode, meta) of a ``last.ckpt`` of ``train.py experiment=inertial``."""
    ck = read_checkpoint(path, "inertial odometry")
    meta = ck[KEY]
    if meta.get("kind") != KIND:
        raise ValueError(f"{path}: a {meta.get('kind', 'crossphone')} checkpoint, not an inertial odometry model")
    where = f"checkpoint {path}"
    grid = InertialGrid.from_meta(meta.get("grid"), where, field="blenav.grid")
    check_weight_shapes(lambda: {"net": build_net(meta["model"], grid, where)}, ck["state_dict"], where,
                        "blenav.model and blenav.grid")
    net = build_net(meta["model"], grid, where)
    net.load_state_dict({k[len("net."):]: v for k, v in ck["state_dict"].items() if k.startswith("net.")})
    return net.eval(), meta
