"""What a cross-phone checkpoint carries besides weights, and how to rebuild its networks.

``train(cfg)`` stores a ``"blenav"`` entry in every Lightning checkpoint (via
:meth:`CrossPhoneModule.on_save_checkpoint`) with:

- ``model``: the resolved ``cfg.model`` node (``_target_`` of ``locnet`` / ``transnet``, sizes, lr, weights);
- ``beacons``: the fixed beacon order of S's rows (sorted BLE anchor ids of the building);
- ``window``: the :class:`blenav.features.windows.WindowConfig` fields (history H, step_hz, offset_db, floor_u)
  and ``u_scale`` (networks read u / u_scale);
- ``building``: building id; ``data_hash``: sha256 of the training windows and labels (first 16 hex);
- ``train_devices`` / ``known_devices`` / ``unlabelled_devices``: device models used.

:func:`load_module` rebuilds the :class:`CrossPhoneModule` from that entry and the state dict, with no
config file beside the checkpoint. The file is read by :func:`blenav.learn.common.checkpoint.read_checkpoint`
(weights only, every ``_target_`` of the meta checked); :func:`build_networks` checks the node it builds again.
"""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path

import torch
from hydra.utils import instantiate

from blenav.limits import check_range
from blenav.trust import check_targets

from ..common.checkpoint import KEY, check_weight_shapes, read_checkpoint
from .module import CrossPhoneModule


def build_networks(model_cfg: dict, n_beacons: int, where: str = "model config"):
    """(locnet, transnet or None) from a ``model`` node (``_target_`` entries) for B beacons. Every ``_target_`` of
    the node must be one of blenav's (:func:`blenav.trust.check_targets`; ``where`` names the node's source in the
    refusal): the node may come from a checkpoint file."""
    if not isinstance(model_cfg, Mapping) or not model_cfg.get("locnet"):
        raise ValueError(f"{where}: the model node has no locnet (a {type(model_cfg).__name__}); was it written by "
                         "train.py?")
    check_targets(model_cfg, where, prefix="model")
    locnet = instantiate(model_cfg["locnet"], n_beacons=n_beacons)
    tn = model_cfg.get("transnet")
    transnet = instantiate(tn, n_beacons=n_beacons) if tn else None
    return locnet, transnet


def load_module(path: str | Path) -> tuple[CrossPhoneModule, dict]:
    """(module in eval mode, meta) from a checkpoint written by ``train(cfg)``."""
    ck = read_checkpoint(path, "blenav cross-phone")
    meta = ck[KEY]
    if meta.get("kind") == "mapprior":
        raise ValueError(f"{path} is a map prior checkpoint, not a cross-phone localizer: load it with "
                         "blenav.learn.mapprior.checkpoint.load_mapprior or load_map_prior")
    where = f"checkpoint {path}"
    window = meta.get("window") if isinstance(meta.get("window"), dict) else {}
    for key in ("history", "step_hz"):  # sizes of the export's sample inputs and of every window built
        if key in window:
            check_range(window[key], key, where, field=f"blenav.window.{key}")
    n_beacons = len(meta["beacons"]) if isinstance(meta.get("beacons"), list) else -1
    # sizes from the file, checked against its weights before any memory is claimed
    check_weight_shapes(lambda: dict(zip(("locnet", "transnet"), build_networks(meta["model"], n_beacons, where))),
                        ck["state_dict"], where, "blenav.model / blenav.beacons")
    locnet, transnet = build_networks(meta["model"], n_beacons, where=where)
    n_m = ck["state_dict"].get("M", torch.zeros(0, 0))
    module = CrossPhoneModule(locnet, transnet, M=torch.zeros_like(n_m), meta=meta)
    module.load_state_dict(ck["state_dict"])
    return module.eval(), meta

