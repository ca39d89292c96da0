"""LocNet: the localization network of Roy, section 3.1.3: a 2-layer LSTM over the H steps of an RSSI
window followed by two fully connected layers, giving the position at the window's last step.

Input S (batch, B, H) on the thesis scale (beacons x steps, as TransNet); the LSTM reads the H columns
in time order. Output (batch, 2): world x, y in metres. Positions are learnt normalised: the network
stores ``xy_mean`` and ``xy_scale`` (set from the training labels) as buffers and returns metres, so an
exported model is self-contained. :meth:`forward_state` takes and returns the LSTM state explicitly
(h, c of shape (layers, batch, hidden)) for on-device streaming and ONNX export.

``std_head`` (issue 29): a second head from the LSTM's last output to a per-window std sigma (batch,) m, the
isotropic 1-sigma of each axis of the position's error (a 2-D Gaussian N(xy, sigma^2 I)), trained with the Gaussian
negative log-likelihood (:func:`blenav.learn.crossphone.losses.gaussian_nll`). It reads the LSTM output *detached*
and is built after every other layer with the global torch RNG restored after it, so the positions, their gradients
and their initialisation (and those of a TransNet built next) are those of the network without it: the head only adds an answer to "how far off is this fix". sigma = exp(clip(z, -7, 7)) times
the mean of ``xy_scale`` (labels' spread), so the head starts near the labels' own scale, times ``std_scale`` (a
buffer, 1 until the training's end sets it by maximum likelihood on the validation windows:
:meth:`blenav.learn.crossphone.module.CrossPhoneModule.calibrate`), so that an exported model states calibrated stds.
"""

from __future__ import annotations

import torch
from torch import nn


class LocNet(nn.Module):
    def __init__(self, n_beacons: int, hidden: int = 128, fc_hidden: int = 64, layers: int = 2, dropout: float = 0.0,
                 std_head: bool = False):
        super().__init__()
        self.n_beacons, self.hidden, self.layers = n_beacons, hidden, layers
        self.lstm = nn.LSTM(n_beacons, hidden, num_layers=layers, batch_first=True,
                            dropout=dropout if layers > 1 else 0.0)
        self.head = nn.Sequential(nn.Linear(hidden, fc_hidden), nn.ReLU(), nn.Linear(fc_hidden, 2))
        self.register_buffer("xy_mean", torch.zeros(2))
        self.register_buffer("xy_scale", torch.ones(2))
        self.std_head = bool(std_head)
        self.head_std = None
        if self.std_head:  # built last, and the global torch RNG restored after it: this network's other layers and
            with torch.random.fork_rng(devices=[]):  # any built after it (TransNet) draw the same weights with or without it
                self.head_std = nn.Sequential(nn.Linear(hidden, fc_hidden), nn.ReLU(), nn.Linear(fc_hidden, 1))
        if self.std_head:
            self.register_buffer("std_scale", torch.ones(()))

    def set_normalisation(self, xy: torch.Tensor) -> None:
        """Centre and scale of the training labels (N, 2) m."""
        self.xy_mean.copy_(xy.mean(dim=0))
        self.xy_scale.copy_(xy.std(dim=0).clamp_min(1e-3))

    def _last(self, S: torch.Tensor, h0: torch.Tensor, c0: torch.Tensor):
        """The LSTM's output at the window's last step (batch, hidden) and its new state."""
        if S.dim() != 3 or S.shape[1] != self.n_beacons:
            raise ValueError(f"LocNet expects (batch, {self.n_beacons}, H), got {tuple(S.shape)}")
        out, (h, c) = self.lstm(S.transpose(1, 2), (h0, c0))
        return out[:, -1], h, c

    def forward_state(self, S: torch.Tensor, h0: torch.Tensor, c0: torch.Tensor):
        """(batch, B, H), state -> (batch, 2) metres, new state."""
        last, h, c = self._last(S, h0, c0)
        return self.head(last) * self.xy_scale + self.xy_mean, h, c

    def forward_state_std(self, S: torch.Tensor, h0: torch.Tensor, c0: torch.Tensor):
        """(batch, B, H), state -> (batch, 2) metres, sigma (batch,) metres, new state (``std_head`` only)."""
        if self.head_std is None:
            raise ValueError("this LocNet has no std head (std_head: false)")
        last, h, c = self._last(S, h0, c0)
        z = self.head_std(last.detach())[:, 0].clamp(-7.0, 7.0)
        return self.head(last) * self.xy_scale + self.xy_mean, torch.exp(z) * self.xy_scale.mean() * self.std_scale, h, c

    def forward_std(self, S: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """(batch, B, H) from a zero state -> positions (batch, 2) m, sigma (batch,) m (``std_head`` only)."""
        h0, c0 = self.initial_state(S.shape[0], S.device, S.dtype)
        return self.forward_state_std(S, h0, c0)[:2]

    def initial_state(self, batch: int, device=None, dtype=None) -> tuple[torch.Tensor, torch.Tensor]:
        """Zero LSTM state (layers, batch, hidden), in ``dtype`` (default: the network's own)."""
        dtype = dtype if dtype is not None else next(self.parameters()).dtype
        z = torch.zeros(self.layers, batch, self.hidden, device=device, dtype=dtype)
        return z, z.clone()

    def forward(self, S: torch.Tensor) -> torch.Tensor:
        h0, c0 = self.initial_state(S.shape[0], S.device, S.dtype)
        return self.forward_state(S, h0, c0)[0]
