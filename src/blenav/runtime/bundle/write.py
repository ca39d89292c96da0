"""Writing a bundle (the export side; onnxruntime's tools, no torch): the ORT and int8 variants of every graph, the
settings, the building's signature and the manifest around the ONNX files the export traced
(:func:`finish_bundle`, called by :mod:`blenav.learn.bundle`)."""

from __future__ import annotations

import json
import platform
import shutil
import time
from pathlib import Path
from typing import Iterable

import numpy as np

from blenav.onnx_io import blenav_version

from ..signature import building_signature
from .format import (BUILDING, FORMAT, LOCALIZER, MANIFEST, MAP_DIR, SETTINGS, VARIANTS, graph_paths, sha256_file,
                     variant_name)
from .measure import measure_variants
from .settings import DEFAULT_SETTINGS


def make_variants(root: Path, base: str) -> dict:
    """BASE.onnx -> BASE.ort, BASE.int8.onnx (onnxruntime.quantization.quantize_dynamic, int8 weights) and
    BASE.int8.ort (onnxruntime.tools.convert_onnx_models_to_ort); returns {variant: reason} for those that failed."""
    import logging

    logging.disable(logging.WARNING)  # the tools log progress lines and a pre-processing hint (restored below)
    try:
        return _make_variants(root, base)
    finally:
        logging.disable(logging.NOTSET)


def _make_variants(root: Path, base: str) -> dict:
    import contextlib
    import io
    import tempfile

    from onnxruntime.quantization import QuantType, quantize_dynamic
    from onnxruntime.tools.convert_onnx_models_to_ort import OptimizationStyle, convert_onnx_models_to_ort

    failed = {}
    try:
        with contextlib.redirect_stdout(io.StringIO()):
            quantize_dynamic(str(root / variant_name(base, "float")), str(root / variant_name(base, "int8")),
                             weight_type=QuantType.QInt8)
    except Exception as exc:  # an op the quantiser cannot handle: keep the float model, say why
        failed["int8"] = " ".join(str(exc).split())[:200]
    for v, f in (("ort", "float"), ("int8_ort", "int8")):
        if f in failed:
            failed[v] = f"no {f} model"
            continue
        with tempfile.TemporaryDirectory() as tmp:
            tin = Path(tmp) / "in"
            tin.mkdir()
            shutil.copy(root / variant_name(base, f), tin / "m.onnx")
            try:
                with contextlib.redirect_stdout(io.StringIO()):
                    convert_onnx_models_to_ort(tin / "m.onnx", output_dir=Path(tmp) / "out",
                                               optimization_styles=[OptimizationStyle.Fixed])
                shutil.move(str(Path(tmp) / "out" / "m.ort"), str(root / variant_name(base, v)))
            except Exception as exc:
                failed[v] = " ".join(str(exc).split())[:200]
    return failed


def _versions() -> dict:
    import onnxruntime

    try:
        import onnx

        onnx_v = onnx.__version__
    except ImportError:
        onnx_v = None
    return {"blenav": blenav_version(), "onnxruntime": onnxruntime.__version__, "onnx": onnx_v,
            "numpy": np.__version__, "python": platform.python_version()}


def finish_bundle(root: str | Path, building, settings: dict | None = None, variants: bool = True,
                  sessions: Iterable | None = None, extra: dict | None = None, reps: int = 200) -> Path:
    """Complete a bundle folder that holds ``localizer.onnx`` (and ``map_prior/`` when it has a prior): the
    building's signature (``building``: a :class:`blenav.data.Building` or a signature dict), the settings (default
    :data:`DEFAULT_SETTINGS`), the ORT and int8 variants (``variants``), their measurements (on ``sessions``,
    labelled sessions of the building, when given) and the manifest. Returns the folder."""
    root = Path(root)
    has_prior = (root / MAP_DIR / "meta.json").is_file()
    if not (root / variant_name(LOCALIZER, "float")).is_file():
        raise FileNotFoundError(f"{root} has no {variant_name(LOCALIZER, 'float')}")
    sig = building if isinstance(building, dict) else building_signature(building)
    settings = json.loads(json.dumps(settings if settings is not None else DEFAULT_SETTINGS))
    (root / SETTINGS).write_text(json.dumps(settings, indent=2, sort_keys=True) + "\n", encoding="utf-8")
    (root / BUILDING).write_text(json.dumps(sig, indent=2, sort_keys=True) + "\n", encoding="utf-8")
    failed: dict = {}
    available = list(VARIANTS[:1])
    if variants:
        for base in graph_paths(has_prior):
            for v, why in make_variants(root, base).items():
                failed[f"{base}:{v}"] = why
        available = [v for v in VARIANTS if not any(k.endswith(f":{v}") for k in failed)]
    files = {}
    for p in sorted(root.rglob("*")):
        if p.is_file() and p.name != MANIFEST and not p.name.startswith("dmt_"):
            files[p.relative_to(root).as_posix()] = {"sha256": sha256_file(p), "bytes": p.stat().st_size}
    manifest = {"format": FORMAT, "created_utc": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()),
                "versions": _versions(), "building": {k: sig[k] for k in ("building", "plan_sha256")},
                "beacons": sig["beacons"], "has_map_prior": has_prior, "variants_available": available,
                "variants_failed": failed, "files": files, **(extra or {})}
    (root / MANIFEST).write_text(json.dumps(manifest, indent=2, sort_keys=True) + "\n", encoding="utf-8")
    if variants:
        sessions = list(sessions or [])
        manifest["measured"] = measure_variants(root, has_prior, sessions, reps=reps)
        manifest["measured"]["note"] = ("latency: one call on one intra-op thread of this machine (the localizer: one "
                                        "window; the trajectory encoder: 36 heading windows; the map encoder: once per "
                                        "floor); pipeline: the whole bundle on pipeline_sessions, seed 0")
        (root / MANIFEST).write_text(json.dumps(manifest, indent=2, sort_keys=True) + "\n", encoding="utf-8")
    return root
