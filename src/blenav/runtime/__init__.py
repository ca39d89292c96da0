"""Running exported models outside training (onnxruntime, no PyTorch), as a phone app would."""

from .onnx_localizer import OnnxLocalizer

__all__ = ["OnnxLocalizer"]
