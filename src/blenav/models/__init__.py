"""Networks as plain ``torch.nn.Module``s (Roy, chapter 3). Training wrappers live elsewhere."""

from .locnet import LocNet
from .transnet import TransNet

__all__ = ["LocNet", "TransNet"]
