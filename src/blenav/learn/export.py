"""``export(cfg)``: ``python export.py ckpt=RUN/last.ckpt out=...`` for a checkpoint of either task, dispatched on its
meta's ``kind``: a cross-phone localizer (no kind) gives one .onnx file (:mod:`blenav.learn.crossphone.export`); a
map prior (``kind: mapprior``) a directory with two graphs and meta.json (:mod:`blenav.learn.mapprior.export`); an inertial
odometry (``kind: inertial``) a directory with inertial.onnx and meta.json (:mod:`blenav.learn.inertial.export`).
"""

from __future__ import annotations

from pathlib import Path

from .common.checkpoint import read_meta
from .common.onnx_export import DEFAULT_OPSET
from .common.trainer import check_run_folder
from .crossphone.checkpoint import load_module
from .crossphone.export import export_module


def export(cfg) -> Path:
    """``cfg.ckpt`` (a ``last.ckpt`` of ``train(cfg)``) -> ``cfg.out``, opset ``cfg.opset`` (default 17).
    Returns the output path."""
    opset = cfg.get("opset", DEFAULT_OPSET) if hasattr(cfg, "get") else getattr(cfg, "opset", DEFAULT_OPSET)
    opset = int(opset if opset is not None else DEFAULT_OPSET)
    if not Path(cfg.ckpt).is_file():
        raise FileNotFoundError(f"checkpoint {cfg.ckpt} does not exist")
    if Path(cfg.out).resolve() == Path(cfg.ckpt).resolve():  # the export would replace the checkpoint it reads
        raise ValueError(f"out={cfg.out} is the checkpoint itself; write the export elsewhere")
    check_run_folder(Path(cfg.out), "an export")
    kind = read_meta(cfg.ckpt).get("kind")
    if kind == "mapprior":
        from .mapprior.export import export_checkpoint

        return export_checkpoint(cfg.ckpt, cfg.out, opset=opset)
    if kind == "inertial":
        from .inertial.export import export_checkpoint as export_inertial

        data = (cfg.get("data") or {}).get("path") if hasattr(cfg, "get") else None
        k = cfg.get("yaw_ensemble") if hasattr(cfg, "get") else None
        return export_inertial(cfg.ckpt, cfg.out, opset=opset, data=data, yaw_ensemble=k)
    module, meta = load_module(cfg.ckpt)
    return export_module(module, meta, cfg.out, opset=opset)
