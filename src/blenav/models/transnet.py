"""TransNet: the BLE signal translation network of Roy, section 3.1.3.

g(S) = ReLU(r(S) + S), with S in R_{>=0}^{B x H} (beacons x time steps, thesis scale, 0 = not heard) and
r a 6-layer 1-D convolutional autoencoder over time (3 encoder, 3 decoder layers). Beacons are the
convolution's channels, so every layer mixes all beacons and the kernel slides along the H steps; the
hidden layers use ReLU, the last decoder layer is linear because the correction r(S) must be able to
lower a reading as well as raise it. Kernel 3 with padding 1 keeps the length H. Shapes: input
(batch, B, H), output (batch, B, H), non-negative.
"""

from __future__ import annotations

import torch
from torch import nn


class TransNet(nn.Module):
    def __init__(self, n_beacons: int, channels: tuple[int, int, int] = (64, 32, 16), kernel: int = 3):
        super().__init__()
        if kernel % 2 != 1:
            raise ValueError(f"TransNet kernel must be odd to keep the window length, got {kernel}")
        pad = kernel // 2
        c1, c2, c3 = channels
        enc = [n_beacons, c1, c2, c3]
        dec = [c3, c2, c1, n_beacons]
        layers: list[nn.Module] = []
        for a, b in zip(enc[:-1], enc[1:]):
            layers += [nn.Conv1d(a, b, kernel, padding=pad), nn.ReLU()]
        for i, (a, b) in enumerate(zip(dec[:-1], dec[1:])):
            layers.append(nn.Conv1d(a, b, kernel, padding=pad))
            if i < 2:
                layers.append(nn.ReLU())
        self.r = nn.Sequential(*layers)
        self.n_beacons = n_beacons

    def forward(self, S: torch.Tensor) -> torch.Tensor:
        if S.dim() != 3 or S.shape[1] != self.n_beacons:
            raise ValueError(f"TransNet expects (batch, {self.n_beacons}, H), got {tuple(S.shape)}")
        return torch.relu(self.r(S) + S)
