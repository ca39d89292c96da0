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
config file beside the checkpoint.

:func:`read_checkpoint` is the one place a blenav checkpoint of either task is read (the map prior's loader,
:mod:`blenav.learn.mapprior_checkpoint`, and the evaluation use it too); :func:`data_hash` the one hash of
training data stored in them.
"""

from __future__ import annotations

import hashlib
from pathlib import Path

import numpy as np
import torch
from hydra.utils import instantiate

from .module import CrossPhoneModule

KEY = "blenav"


def data_hash(*arrays: np.ndarray) -> str:
    h = hashlib.sha256()
    for a in arrays:
        a = np.ascontiguousarray(a)
        h.update(str(a.shape).encode())
        h.update(a.tobytes())
    return h.hexdigest()[:16]


def build_networks(model_cfg: dict, n_beacons: int):
    """(locnet, transnet or None) from a ``model`` node (``_target_`` entries) for B beacons."""
    locnet = instantiate(model_cfg["locnet"], n_beacons=n_beacons)
    tn = model_cfg.get("transnet")
    transnet = instantiate(tn, n_beacons=n_beacons) if tn else None
    return locnet, transnet


def read_checkpoint(path: str | Path, what: str = "blenav", require_meta: bool = True) -> dict:
    """The whole checkpoint dict of ``path`` (state dict, optimizer states, counters, the ``"blenav"`` meta),
    on the CPU. FileNotFoundError without the file; ValueError when ``require_meta`` and it has no
    ``"blenav"`` entry (``what`` names the expected kind in the message)."""
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"checkpoint {path} does not exist")
    ck = torch.load(path, map_location="cpu", weights_only=False)
    if require_meta and KEY not in ck:
        raise ValueError(f"{path}: not a {what} checkpoint (no '{KEY}' entry); was it written by train.py?")
    return ck


def read_meta(path: str | Path) -> dict:
    return read_checkpoint(path, "blenav cross-phone")[KEY]


def load_module(path: str | Path) -> tuple[CrossPhoneModule, dict]:
    """(module in eval mode, meta) from a checkpoint written by ``train(cfg)``."""
    ck = read_checkpoint(path, "blenav cross-phone")
    meta = ck[KEY]
    if meta.get("kind") == "mapprior":
        raise ValueError(f"{path} is a map prior checkpoint, not a cross-phone localizer: load it with "
                         "blenav.learn.mapprior_checkpoint.load_mapprior or load_map_prior")
    locnet, transnet = build_networks(meta["model"], len(meta["beacons"]))
    n_m = ck["state_dict"].get("M", torch.zeros(0, 0))
    module = CrossPhoneModule(locnet, transnet, M=torch.zeros_like(n_m), meta=meta)
    module.load_state_dict(ck["state_dict"])
    return module.eval(), meta
