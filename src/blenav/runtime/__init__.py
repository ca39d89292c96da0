"""Running exported models outside training (onnxruntime, no PyTorch), as a phone app would.

:class:`OnnxLocalizer` runs an exported cross-phone localizer; :class:`MapPrior` the map prior network (an
export directory; a checkpoint only with a loader handed in from :mod:`blenav.learn`). Below
:mod:`blenav.learn`: imports none of torch, lightning or hydra (``tests/test_layers.py``).
"""

from .map_prior import MapPrior
from .onnx_localizer import OnnxLocalizer

__all__ = ["MapPrior", "OnnxLocalizer"]
