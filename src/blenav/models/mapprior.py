"""The Map Prior Network (MPN) of Roy, section 3.2.2, as plain ``torch.nn.Module``s.

Notation (used throughout :mod:`blenav.learn.mapprior.module` and :mod:`blenav.runtime.map_prior`):

- ``M``: occupancy map of one floor resampled to the network's resolution ``resolution_m`` (m/px),
  a free-space mask on [0, 1] (1 = free, 0 = obstacle or unknown), image row order (row 0 on top).
  Outside the map counts as obstacle: the convolutions zero-pad.
- ``O``: odometry window, the ``n_points`` positions at ``step_hz`` covering the last ``window_s`` seconds
  (n_points = window_s * step_hz + 1; 5 s at 1 Hz -> 6 points), relative to the window's first point
  (so ``O[0] = 0``), world-aligned axes (x east, y north), in *pixels* (metres / resolution_m).
- DMT ``f(M)`` (c, H, W): the Deep Map Tensor, same H, W as the map, c channels (c = 32 in the thesis).
- DTV ``g(O)`` (c,): the Deep Trajectory Vector, the last hidden state of a 2-layer LSTM over ``O``.
- score ``S(x | M, O) = f(M)_x . g(O)`` (eq. 3.8, Roy): the likelihood score that the window *ends* at
  pixel x. Trained to regress T = 1e-6 exp(14 T_bar) (see :mod:`blenav.learn.mapprior.data`), so scores lie
  roughly in [0, 1.2]; they are not normalised and may be slightly negative.

:class:`MapEncoder` is f (a small U-Net, Ronneberger et al. via Roy [42, 43]), :class:`TrajectoryEncoder`
is g, :class:`MapPriorNet` holds both and the product of eq. 3.8, either over the whole map
(:meth:`MapPriorNet.score`) or gathered at given pixels only (:meth:`MapPriorNet.score_at`, what a
particle filter needs: one DMT per floor, one DTV per step and heading hypothesis, K x N dot products).
"""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import nn


def _block(cin: int, cout: int) -> nn.Sequential:
    """Two 3x3 conv + BatchNorm + ReLU. BatchNorm (not GroupNorm): in eval mode it uses running statistics,
    so a 64 px training crop and a whole building map are normalised alike."""
    return nn.Sequential(
        nn.Conv2d(cin, cout, 3, padding=1, bias=False), nn.BatchNorm2d(cout), nn.ReLU(inplace=True),
        nn.Conv2d(cout, cout, 3, padding=1, bias=False), nn.BatchNorm2d(cout), nn.ReLU(inplace=True))


class MapEncoder(nn.Module):
    """f(M): small U-Net, free mask (b, 1, H, W) on [0, 1] -> DMT (b, c, H, W), any H, W.

    ``channels`` are the encoder widths per level (``len(channels) - 1`` poolings by 2, e.g. (16, 32, 64):
    full, 1/2 and 1/4 resolution); the decoder mirrors them with transposed convolutions and skip
    connections; a final 1x1 conv gives ``out_channels`` = c. :meth:`forward` zero-pads H, W up to a multiple
    of :attr:`size_multiple` (zero = obstacle, as outside the map) and crops back; :meth:`forward_padded`
    is the core for inputs already of such a size (what the ONNX graph holds).
    """

    def __init__(self, channels: tuple[int, ...] | list[int] = (8, 16, 32, 64), out_channels: int = 32):
        super().__init__()
        channels = [int(c) for c in channels]
        if len(channels) < 1:
            raise ValueError("MapEncoder needs at least one level of channels")
        self.channels, self.out_channels = channels, int(out_channels)
        self.down = nn.ModuleList()
        cin = 1
        for c in channels:
            self.down.append(_block(cin, c))
            cin = c
        self.up = nn.ModuleList()
        self.dec = nn.ModuleList()
        for c_skip in reversed(channels[:-1]):
            self.up.append(nn.ConvTranspose2d(cin, c_skip, 2, stride=2))
            self.dec.append(_block(2 * c_skip, c_skip))
            cin = c_skip
        self.head = nn.Conv2d(cin, self.out_channels, 1)

    @property
    def size_multiple(self) -> int:
        """H and W of :meth:`forward_padded` inputs must be multiples of this (2 ** poolings)."""
        return 2 ** (len(self.channels) - 1)

    def forward_padded(self, m: torch.Tensor) -> torch.Tensor:
        """(b, 1, H, W) with H, W multiples of :attr:`size_multiple` -> (b, c, H, W)."""
        skips = []
        x = m
        for i, blk in enumerate(self.down):
            if i:
                x = F.max_pool2d(x, 2)
            x = blk(x)
            skips.append(x)
        for up, dec, skip in zip(self.up, self.dec, reversed(skips[:-1])):
            x = dec(torch.cat([up(x), skip], dim=1))
        return self.head(x)

    def forward(self, m: torch.Tensor) -> torch.Tensor:
        """Free mask (b, 1, H, W) on [0, 1] -> DMT (b, c, H, W) for any H, W >= 1."""
        if m.dim() != 4 or m.shape[1] != 1:
            raise ValueError(f"MapEncoder expects a (b, 1, H, W) mask, got shape {tuple(m.shape)}")
        h, w = int(m.shape[-2]), int(m.shape[-1])
        k = self.size_multiple
        ph, pw = (-h) % k, (-w) % k
        if ph or pw:
            m = F.pad(m, (0, pw, 0, ph))  # zeros = obstacle, like outside the map
        return self.forward_padded(m)[..., :h, :w]


class TrajectoryEncoder(nn.Module):
    """g(O): 2-layer LSTM (hidden c) over the window; the last layer's last hidden state is the DTV.

    Input (b, n, 2): positions relative to the window start in pixels, world axes (x east, y north).
    Per step the LSTM reads 4 features divided by ``px_scale``: the position relative to the window's *end*
    (the score is for where the window ends) and the step displacement (zero at the first point).
    Output (b, c) on (-1, 1) (an LSTM hidden state).
    """

    def __init__(self, hidden: int = 32, layers: int = 2, px_scale: float = 8.0):
        super().__init__()
        self.hidden, self.layers, self.px_scale = int(hidden), int(layers), float(px_scale)
        self.lstm = nn.LSTM(4, self.hidden, num_layers=self.layers, batch_first=True)

    def features(self, odo: torch.Tensor) -> torch.Tensor:
        """(b, n, 2) pixels -> (b, n, 4) LSTM inputs."""
        rel_end = odo - odo[:, -1:, :]
        step = torch.cat([torch.zeros_like(odo[:, :1]), odo[:, 1:] - odo[:, :-1]], dim=1)
        return torch.cat([rel_end, step], dim=-1) / self.px_scale

    def forward(self, odo: torch.Tensor) -> torch.Tensor:
        if odo.dim() != 3 or odo.shape[-1] != 2:
            raise ValueError(f"TrajectoryEncoder expects (b, n, 2) odometry, got shape {tuple(odo.shape)}")
        _, (h, _) = self.lstm(self.features(odo))
        return h[-1]


class MapPriorNet(nn.Module):
    """f and g of Roy's MPN and the score of eq. 3.8: S(x | M, O) = f(M)_x . g(O).

    ``n_points`` is the window length the LSTM was trained on; :meth:`encode_trajectory` refuses shorter
    windows (ValueError naming the seconds needed when ``step_hz`` is known).
    """

    def __init__(self, channels: int = 32, unet_channels: tuple[int, ...] | list[int] = (8, 16, 32, 64),
                 lstm_layers: int = 2, px_scale: float = 8.0, n_points: int = 6, step_hz: float = 1.0):
        super().__init__()
        self.c, self.n_points, self.step_hz = int(channels), int(n_points), float(step_hz)
        self.map_encoder = MapEncoder(unet_channels, self.c)
        self.trajectory_encoder = TrajectoryEncoder(self.c, lstm_layers, px_scale)

    def encode_map(self, m: torch.Tensor) -> torch.Tensor:
        """Free mask (b, 1, H, W) on [0, 1] -> DMT (b, c, H, W)."""
        return self.map_encoder(m)

    def encode_trajectory(self, odo: torch.Tensor) -> torch.Tensor:
        """Odometry (b, n_points, 2) pixels relative to the window start -> DTV (b, c).

        A longer window is cut to its last ``n_points`` (re-based to start at zero); a shorter one is an error.
        """
        n = int(odo.shape[-2]) if odo.dim() >= 2 else 0
        if n < self.n_points:
            need = (self.n_points - 1) / self.step_hz
            raise ValueError(f"odometry window has {n} points but the map prior needs {self.n_points} "
                             f"({need:g} s at {self.step_hz:g} Hz, window start included)")
        if n > self.n_points:
            odo = odo[..., -self.n_points:, :]
            odo = odo - odo[..., :1, :]
        return self.trajectory_encoder(odo)

    @staticmethod
    def score(dmt: torch.Tensor, dtv: torch.Tensor) -> torch.Tensor:
        """eq. 3.8, Roy, at every pixel: DMT (b, c, H, W), DTV (b, c) -> S (b, H, W)."""
        return torch.einsum("bchw,bc->bhw", dmt, dtv)

    @staticmethod
    def score_at(dmt: torch.Tensor, dtv: torch.Tensor, ij: torch.Tensor) -> torch.Tensor:
        """eq. 3.8 at given pixels only: DMT (c, H, W), DTV (K, c), ij (K, N, 2) int64 (row, col) -> S (K, N).

        Indices must be inside the map (the caller masks the others, see :class:`blenav.runtime.map_prior.MapPrior`);
        cost K x N x c, no full-map product.
        """
        feats = dmt[:, ij[..., 0], ij[..., 1]]  # (c, K, N)
        return torch.einsum("ckn,kc->kn", feats, dtv)

    def forward(self, m: torch.Tensor, odo: torch.Tensor) -> torch.Tensor:
        """(b, 1, H, W) mask, (b, n, 2) odometry pixels -> S (b, H, W)."""
        return self.score(self.encode_map(m), self.encode_trajectory(odo))
