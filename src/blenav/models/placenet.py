"""PlaceNet (issue 29): a fingerprint network that scores *places* of the survey instead of regressing a position.

The survey's labelled positions are clustered into P places (k-means anchors a_m (P, 2) m, set from the training
labels by :meth:`PlaceNet.set_normalisation`, seeded). A scan is scored by an MLP over its powed, unit-norm vector;
the position is the softmax-weighted mean of the anchors and the fix's std the weighted spread of the anchors about
it::

    x = unit( mean_H clamp(S, 0, 1)^power )                     S (b, B, H) on u / 100, the trainer's scale
    p = softmax(MLP(x))                                          (b, P)
    xy = p @ a                                                   (b, 2) m
    sigma = sqrt(sum_m p_m |a_m - xy|^2 / 2 + std_floor_m^2) * std_scale     (b,) m, per axis

Trained by cross-entropy to soft targets q_m proportional to exp(-|a_m - y|^2 / (2 kernel_m^2)) (:meth:`place_loss`),
a Gaussian kernel around the label y, so neighbouring places share the credit and the answer can fall between
anchors; a regression head (LocNet's) answers an ambiguous scan with the mean of the places it fits, which may lie
between them (on the real mall floors PlaceNet is 2.3-3.0 m better than the LocNet row it replaced, whose scans were
read at their delivery: docs/results-ilc20.md). The powed input (weak
readings shrunk against strong ones, Torres-Sospedra et al. 2015) and the unit norm are the KNN's ``powed``
representation (:mod:`blenav.localizers.knn`), with the power 2.

It has the interface the cross-phone pipeline drives a LocNet by (``forward``, ``forward_std``, ``forward_state``,
``forward_state_std``, ``initial_state``, ``set_normalisation``, ``std_head``, ``std_scale``), so the trainer, the
checkpoint, the ONNX export and :class:`blenav.runtime.OnnxLocalizer` take it unchanged. It has no recurrent state:
``h0`` / ``c0`` (1, batch, 1) pass through unchanged (``layers`` = ``hidden`` = 1 size them for the export). The
std is always there (``std_head`` True): the softmax's own spread, scaled by ``std_scale`` (1 until the training's
end fits it on the validation windows: :meth:`blenav.learn.crossphone.module.CrossPhoneModule.calibrate`).
"""

from __future__ import annotations

import torch
from torch import nn


def kmeans_anchors(xy: torch.Tensor, places: int, seed: int, iters: int = 25) -> torch.Tensor:
    """(min(places, distinct labels), 2) k-means centres of labels ``xy`` (N, 2) m: k-means++ seeding from a
    ``torch.Generator`` seeded with ``seed``, then ``iters`` Lloyd steps (an empty cluster keeps its centre)."""
    pts = torch.unique(xy.double(), dim=0)
    k = max(1, min(int(places), len(pts)))
    g = torch.Generator().manual_seed(int(seed))
    chosen = [int(torch.randint(len(pts), (1,), generator=g))]
    d2 = torch.cdist(pts, pts[chosen]).min(dim=1).values ** 2  # squared distance to the nearest centre, kept running
    while len(chosen) < k:  # k-means++: the next centre drawn with probability ~ squared distance to the nearest
        if not float(d2.sum()) > 0:
            break
        j = int(torch.multinomial(d2 / d2.sum(), 1, generator=g))
        chosen.append(j)
        d2 = torch.minimum(d2, torch.cdist(pts, pts[j:j + 1])[:, 0] ** 2)
    centres = pts[chosen]
    for _ in range(int(iters)):
        lab = torch.cdist(pts, centres).argmin(dim=1)
        sums = torch.zeros_like(centres).index_add_(0, lab, pts)
        counts = torch.bincount(lab, minlength=len(centres)).to(pts.dtype)[:, None]
        centres = torch.where(counts > 0, sums / counts.clamp_min(1.0), centres)
    return centres.to(xy.dtype)


class PlaceNet(nn.Module):
    def __init__(self, n_beacons: int, width: int = 256, places: int = 300, kernel_m: float = 3.0,
                 power: float = 2.0, input_dropout: float = 0.2, dropout: float = 0.3, std_floor_m: float = 0.5,
                 seed: int = 0):
        super().__init__()
        if int(places) < 2 or not float(kernel_m) > 0 or not float(power) > 0:
            raise ValueError(f"PlaceNet: places >= 2, kernel_m > 0 and power > 0 needed, got {places}, {kernel_m}, "
                             f"{power}")
        self.n_beacons, self.places, self.seed = int(n_beacons), int(places), int(seed)
        self.kernel_m, self.power, self.std_floor_m = float(kernel_m), float(power), float(std_floor_m)
        self.layers, self.hidden = 1, 1  # the (absent) recurrent state's size: h0, c0 pass through
        self.std_head = True
        self.mlp = nn.Sequential(nn.Dropout(float(input_dropout)), nn.Linear(self.n_beacons, int(width)), nn.ReLU(),
                                 nn.Dropout(float(dropout)), nn.Linear(int(width), self.places))
        self.register_buffer("anchors", torch.zeros(self.places, 2))
        self.register_buffer("std_scale", torch.ones(()))

    def set_normalisation(self, xy: torch.Tensor) -> None:
        """The anchors: k-means centres of the training labels (N, 2) m (:func:`kmeans_anchors`). With fewer distinct
        labels than ``places`` the spare anchors repeat the last centre (they split its probability, no harm)."""
        a = kmeans_anchors(xy.detach().cpu(), self.places, self.seed)
        self.anchors.copy_(torch.cat([a, a[-1:].expand(self.places - len(a), 2)]).to(self.anchors))

    def logits(self, S: torch.Tensor) -> torch.Tensor:
        """(batch, B, H) on u / 100 -> place scores (batch, P)."""
        if S.dim() != 3 or S.shape[1] != self.n_beacons:
            raise ValueError(f"PlaceNet expects (batch, {self.n_beacons}, H), got {tuple(S.shape)}")
        x = S.clamp(0.0, 1.0).pow(self.power).mean(dim=2)
        x = x / x.norm(dim=1, keepdim=True).clamp_min(1e-6)
        return self.mlp(x)

    def position_std(self, logits: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Place scores (batch, P) -> positions (batch, 2) m, sigma (batch,) m (module doc)."""
        p = torch.softmax(logits, dim=1)
        xy = p @ self.anchors
        spread = (p * ((self.anchors[None] - xy[:, None]) ** 2).sum(dim=2)).sum(dim=1)
        return xy, torch.sqrt(0.5 * spread + self.std_floor_m ** 2) * self.std_scale

    def place_loss(self, logits: torch.Tensor, xy: torch.Tensor) -> torch.Tensor:
        """Cross-entropy of the place scores (b, P) against the soft targets of labels xy (b, 2) m, mean over the
        batch."""
        d2 = ((xy[:, None] - self.anchors[None]) ** 2).sum(dim=2)
        q = torch.softmax(-d2 / (2.0 * self.kernel_m ** 2), dim=1)
        return -(q * torch.log_softmax(logits, dim=1)).sum(dim=1).mean()

    def forward_std(self, S: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """(batch, B, H) -> positions (batch, 2) m, sigma (batch,) m."""
        return self.position_std(self.logits(S))

    def forward(self, S: torch.Tensor) -> torch.Tensor:
        return self.forward_std(S)[0]

    def initial_state(self, batch: int, device=None, dtype=None) -> tuple[torch.Tensor, torch.Tensor]:
        """The pass-through state (1, batch, 1) of zeros (LocNet's interface)."""
        dtype = dtype if dtype is not None else self.anchors.dtype
        z = torch.zeros(1, batch, 1, device=device, dtype=dtype)
        return z, z.clone()

    def forward_state(self, S: torch.Tensor, h0: torch.Tensor, c0: torch.Tensor):
        """(batch, B, H), state -> (batch, 2) m, the state unchanged."""
        return self.forward(S), h0, c0

    def forward_state_std(self, S: torch.Tensor, h0: torch.Tensor, c0: torch.Tensor):
        """(batch, B, H), state -> (batch, 2) m, sigma (batch,) m, the state unchanged."""
        xy, sigma = self.forward_std(S)
        return xy, sigma, h0, c0
