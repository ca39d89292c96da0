"""A runtime bundle: one folder an app embeds, run without PyTorch (onnxruntime + numpy).

``python export.py bundle=true ckpt=RUN/last.ckpt out=BUNDLE [mapprior=RUN2/last.ckpt] [io_model=IO_DIR]`` writes one;
``Bundle.open(BUNDLE).localizer(building)`` runs it live. The package, one idea a module:

- :mod:`.format`: the file layout, the format's name, the graphs' variants (float, ORT, int8, both), sha256;
- :mod:`.verify`: the folder checked whole against its manifest;
- :mod:`.settings`: settings.json: defaults, range and target checks, the filter method it builds;
- :mod:`.graphs`: the localizer and map prior graphs as onnxruntime sessions;
- :mod:`.windows`: RSSI packets -> the localizer's fixes, live;
- :mod:`.live`: the push API (:class:`BundleLocalizer`, :class:`TrackPoint`);
- :mod:`.read`: :class:`Bundle`, an opened folder;
- :mod:`.measure` and :mod:`.write`: the export side (variants, their measurements, the manifest).

This module is the interface: the bundle, its push API and the format's names. Imports numpy, pandas (through
blenav.data) and onnxruntime; never torch, lightning or hydra.
"""

from .format import (BUILDING, FIX_SOURCE, FORMAT, INERTIAL_DIR, LOCALIZER, MANIFEST, MAP_DIR, MAP_GRAPHS, SETTINGS,
                     VARIANTS, variant_name)
from .live import BundleLocalizer, TrackPoint
from .read import Bundle
from .settings import DEFAULT_SETTINGS

__all__ = ["BUILDING", "DEFAULT_SETTINGS", "FIX_SOURCE", "FORMAT", "INERTIAL_DIR", "LOCALIZER", "MANIFEST", "MAP_DIR", "MAP_GRAPHS",
           "SETTINGS", "VARIANTS", "Bundle", "BundleLocalizer", "TrackPoint", "variant_name"]
