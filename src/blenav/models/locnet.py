"""LocNet: the localization network of Roy, section 3.1.3: a 2-layer LSTM over the H steps of an RSSI
window followed by two fully connected layers, giving the position at the window's last step.

Input S (batch, B, H) on the thesis scale (beacons x steps, as TransNet); the LSTM reads the H columns
in time order. Output (batch, 2): world x, y in metres. Positions are learnt normalised: the network
stores ``xy_mean`` and ``xy_scale`` (set from the training labels) as buffers and returns metres, so an
exported model is self-contained. :meth:`forward_state` takes and returns the LSTM state explicitly
(h, c of shape (layers, batch, hidden)) for on-device streaming and ONNX export.
"""

from __future__ import annotations

import torch
from torch import nn


class LocNet(nn.Module):
    def __init__(self, n_beacons: int, hidden: int = 128, fc_hidden: int = 64, layers: int = 2, dropout: float = 0.0):
        super().__init__()
        self.n_beacons, self.hidden, self.layers = n_beacons, hidden, layers
        self.lstm = nn.LSTM(n_beacons, hidden, num_layers=layers, batch_first=True,
                            dropout=dropout if layers > 1 else 0.0)
        self.head = nn.Sequential(nn.Linear(hidden, fc_hidden), nn.ReLU(), nn.Linear(fc_hidden, 2))
        self.register_buffer("xy_mean", torch.zeros(2))
        self.register_buffer("xy_scale", torch.ones(2))

    def set_normalisation(self, xy: torch.Tensor) -> None:
        """Centre and scale of the training labels (N, 2) m."""
        self.xy_mean.copy_(xy.mean(dim=0))
        self.xy_scale.copy_(xy.std(dim=0).clamp_min(1e-3))

    def forward_state(self, S: torch.Tensor, h0: torch.Tensor, c0: torch.Tensor):
        """(batch, B, H), state -> (batch, 2) metres, new state."""
        if S.dim() != 3 or S.shape[1] != self.n_beacons:
            raise ValueError(f"LocNet expects (batch, {self.n_beacons}, H), got {tuple(S.shape)}")
        out, (h, c) = self.lstm(S.transpose(1, 2), (h0, c0))
        return self.head(out[:, -1]) * self.xy_scale + self.xy_mean, h, c

    def initial_state(self, batch: int, device=None, dtype=None) -> tuple[torch.Tensor, torch.Tensor]:
        """Zero LSTM state (layers, batch, hidden), in ``dtype`` (default: the network's own)."""
        dtype = dtype if dtype is not None else next(self.parameters()).dtype
        z = torch.zeros(self.layers, batch, self.hidden, device=device, dtype=dtype)
        return z, z.clone()

    def forward(self, S: torch.Tensor) -> torch.Tensor:
        h0, c0 = self.initial_state(S.shape[0], S.device, S.dtype)
        return self.forward_state(S, h0, c0)[0]
