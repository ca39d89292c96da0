"""DL-RNN: the "double RNN" localizer of Bai et al. 2020 (ref. [20] of Roy; a baseline of Roy, Table 3.5).

Input S (batch, B, H) RSSI windows on the *normalised* scale u / 100 (:data:`blenav.features.scale.U_SCALE`;
0 = not heard), B beacons by H steps in time order (oldest first), as LocNet. Two stacked recurrent stages:

1. a first LSTM reads the H step vectors s_t (B,) and gives hidden states h_t (hidden,); a linear head maps
   each h_t to a coarse position p_t (2,) -- the per-step estimate of the first RNN;
2. a second LSTM reads [h_t, p_t] (hidden + 2,) per step; a linear head on its last output gives the final
   position (batch, 2).

Positions are learnt normalised: ``xy_mean`` / ``xy_scale`` buffers (set by :meth:`set_normalisation` from
the training labels, as :class:`blenav.models.LocNet`) turn both coarse and final outputs into metres.
``forward`` returns the final position only (the ``locnet`` slot of the cross-phone module);
:meth:`forward_all` also returns the coarse track (batch, H, 2) m for an optional per-step loss.
"""

from __future__ import annotations

import torch
from torch import nn


class DLRNN(nn.Module):
    def __init__(self, n_beacons: int, hidden: int = 64, hidden2: int | None = None, layers: int = 1,
                 dropout: float = 0.0):
        super().__init__()
        hidden2 = hidden if hidden2 is None else hidden2
        self.n_beacons, self.hidden, self.hidden2, self.layers = n_beacons, hidden, hidden2, layers
        drop = dropout if layers > 1 else 0.0
        self.rnn1 = nn.LSTM(n_beacons, hidden, num_layers=layers, batch_first=True, dropout=drop)
        self.coarse = nn.Linear(hidden, 2)
        self.rnn2 = nn.LSTM(hidden + 2, hidden2, num_layers=layers, batch_first=True, dropout=drop)
        self.head = nn.Linear(hidden2, 2)
        self.register_buffer("xy_mean", torch.zeros(2))
        self.register_buffer("xy_scale", torch.ones(2))

    def set_normalisation(self, xy: torch.Tensor) -> None:
        """Centre and scale of the training labels (N, 2) m."""
        self.xy_mean.copy_(xy.mean(dim=0))
        self.xy_scale.copy_(xy.std(dim=0).clamp_min(1e-3))

    def forward_all(self, S: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """(batch, B, H) -> final (batch, 2) m, coarse per-step positions (batch, H, 2) m."""
        if S.dim() != 3 or S.shape[1] != self.n_beacons:
            raise ValueError(f"DLRNN expects (batch, {self.n_beacons}, H), got {tuple(S.shape)}")
        h1, _ = self.rnn1(S.transpose(1, 2))  # (batch, H, hidden)
        p = self.coarse(h1)  # (batch, H, 2) normalised
        h2, _ = self.rnn2(torch.cat([h1, p], dim=2))
        final = self.head(h2[:, -1])
        return final * self.xy_scale + self.xy_mean, p * self.xy_scale + self.xy_mean

    def forward(self, S: torch.Tensor) -> torch.Tensor:
        return self.forward_all(S)[0]
