"""Networks as plain ``torch.nn.Module``s (Roy, chapter 3). Training wrappers live elsewhere."""

from .dlrnn import DLRNN
from .locnet import LocNet
from .placenet import PlaceNet
from .transnet import TransNet

__all__ = ["DLRNN", "LocNet", "PlaceNet", "TransNet"]
