"""Running exported models outside training (onnxruntime, no PyTorch), as a phone app would.

:class:`OnnxLocalizer` runs an exported cross-phone localizer; :class:`MapPrior` the map prior network (an
export directory; a checkpoint only with a loader handed in from :mod:`blenav.learn`); :class:`Bundle` a runtime
bundle folder (``python export.py bundle=true ...``: localizer, map prior, filter settings, building signature) with
its push API (``Bundle.open(dir).localizer(building)``, :mod:`blenav.runtime.bundle`). Below
:mod:`blenav.learn`: imports none of torch, lightning or hydra (``tests/test_layers.py``).
"""

from .bundle import Bundle, BundleLocalizer, TrackPoint
from .map_prior import MapPrior
from .onnx_localizer import OnnxLocalizer
from .signature import BuildingMismatch

__all__ = ["Bundle", "BundleLocalizer", "BuildingMismatch", "MapPrior", "OnnxLocalizer", "TrackPoint"]
