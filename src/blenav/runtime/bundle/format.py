"""What a runtime bundle folder holds: the format's name, its file names and variants, and the files' sha256.

Layout (``python export.py bundle=true ckpt=RUN/last.ckpt out=BUNDLE [mapprior=RUN2/last.ckpt]``)::

    BUNDLE/manifest.json          format, versions, sha256 and size of every file, variants with their size,
                                  latency and accuracy change against the float models
    BUNDLE/settings.json          the filter, motion, fix and map-prior settings of the pipeline
    BUNDLE/building.json          the building's signature: beacon order and positions, floor-plan hashes
    BUNDLE/localizer.onnx         the cross-phone localizer (TransNet + LocNet, metadata as blenav.learn.crossphone.export)
    BUNDLE/localizer.ort          ... in ONNX Runtime's ORT format (mobile builds)
    BUNDLE/localizer.int8.onnx    ... dynamically quantised to int8 weights (onnxruntime.quantization)
    BUNDLE/localizer.int8.ort     ... both
    BUNDLE/map_prior/             optional: map_encoder.*, trajectory_encoder.* (same four variants), meta.json
    BUNDLE/inertial/              optional (``io_model=IO_DIR``): the learned inertial odometry, inertial.onnx and its
                                  meta.json as ``export.py`` wrote them (issue 31): the bundle's odometry
"""

from __future__ import annotations

import hashlib
from pathlib import Path

FORMAT = "blenav-bundle/1"
MANIFEST = "manifest.json"
SETTINGS = "settings.json"
BUILDING = "building.json"
LOCALIZER = "localizer"
MAP_DIR = "map_prior"
MAP_GRAPHS = ("map_encoder", "trajectory_encoder")
INERTIAL_DIR = "inertial"
VARIANTS = ("float", "ort", "int8", "int8_ort")
#: the source name of the fixes the bundle's localizer makes (the filter's fix likelihood weighs these)
FIX_SOURCE = "bundle"
#: the files every bundle has, so every manifest lists them
REQUIRED_FILES = (SETTINGS, BUILDING, LOCALIZER + ".onnx")


def variant_name(base: str, variant: str) -> str:
    """File name of graph ``base`` in ``variant`` (float: BASE.onnx, ort: BASE.ort, int8: BASE.int8.onnx, ...)."""
    if variant not in VARIANTS:
        raise ValueError(f"bundle variant must be one of {VARIANTS}, got {variant!r}")
    return base + {"float": ".onnx", "ort": ".ort", "int8": ".int8.onnx", "int8_ort": ".int8.ort"}[variant]


def graph_paths(has_prior: bool) -> list[str]:
    """The graphs of a bundle, as paths without the variant's suffix: the localizer, and the map prior's two
    encoders when it has one."""
    return [LOCALIZER] + ([f"{MAP_DIR}/{g}" for g in MAP_GRAPHS] if has_prior else [])


def sha256_file(path: Path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for chunk in iter(lambda: f.read(1 << 20), b""):
            h.update(chunk)
    return h.hexdigest()
