"""Inertial odometry networks (issue 31): a window of gravity-aligned IMU -> the 2-D velocity over its last stride and
its log variance (TLIO's covariance head), in the window's own frame (:mod:`blenav.features.inertial`).

Two architectures, both plain ``nn.Module`` with the same contract:

* :class:`ResNet1D`: RoNIN's ResNet-1D (Herath et al., ICRA 2020), shrunk for a phone and a 2-core CPU: a stem and
  three residual stages that halve the time axis, the final feature map flattened into a small MLP;
* :class:`TCN`: a causal temporal convolution network (dilated residual convolutions, receptive field
  ``1 + 2 (kernel - 1) (2^levels - 1)`` samples), averaged over the output stride's samples.

Input ``imu`` (B, n_window, 15) float32 in :data:`blenav.features.inertial.CHANNELS` order (world-frame acceleration
without gravity m/s^2, rate rad/s); output (B, 4): velocity (vx, vy) m/s and log variance (log vx^2, log vy^2) of
its error, ``log_var`` clipped to [``LOG_VAR_MIN``, ``LOG_VAR_MAX``]. The per-channel input normalisation (mean,
std of the training windows) is part of the network (buffers), so an exported graph takes raw units.
"""

from __future__ import annotations

import torch
from torch import nn

from blenav.features.inertial import YAW_PAIRS

__all__ = ["InertialNet", "ResNet1D", "TCN", "YawEnsemble", "to_attitude_frame", "LOG_VAR_MIN", "LOG_VAR_MAX"]

LOG_VAR_MIN, LOG_VAR_MAX = -9.0, 4.0  # (m/s)^2: std 0.011 .. 7.4 m/s


def to_attitude_frame(out: torch.Tensor, psi: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Velocities (N, 2) and per-axis variances (N, 2) of outputs ``out`` (N, 4) in frames turned by psi (N,) rad,
    turned back by psi (:func:`blenav.features.inertial.rotate_velocity`, in torch): the heading frame's windows in
    training, the members of :class:`YawEnsemble`."""
    c, s = torch.cos(psi), torch.sin(psi)
    v, var = out[:, :2], torch.exp(out[:, 2:])
    vw = torch.stack([c * v[:, 0] - s * v[:, 1], s * v[:, 0] + c * v[:, 1]], dim=1)
    varw = torch.stack([c * c * var[:, 0] + s * s * var[:, 1], s * s * var[:, 0] + c * c * var[:, 1]], dim=1)
    return vw, varw


class InertialNet(nn.Module):
    """Base: input normalisation buffers, the (B, T, C) -> (B, C, T) transpose and the output head split."""

    def __init__(self, n_window: int, n_stride: int, in_channels: int = 15):
        super().__init__()
        if not (0 < int(n_stride) <= int(n_window)):
            raise ValueError(f"inertial network: need 0 < n_stride ({n_stride}) <= n_window ({n_window})")
        self.n_window, self.n_stride, self.in_channels = int(n_window), int(n_stride), int(in_channels)
        self.register_buffer("input_mean", torch.zeros(self.in_channels))
        self.register_buffer("input_std", torch.ones(self.in_channels))

    def set_normalisation(self, mean: torch.Tensor, std: torch.Tensor) -> None:
        self.input_mean.copy_(torch.as_tensor(mean, dtype=torch.float32))
        self.input_std.copy_(torch.as_tensor(std, dtype=torch.float32).clamp(min=1e-3))

    def features(self, x: torch.Tensor) -> torch.Tensor:  # (B, C, T) normalised -> (B, 4)
        raise NotImplementedError

    def forward(self, imu: torch.Tensor) -> torch.Tensor:
        x = ((imu - self.input_mean) / self.input_std).transpose(1, 2)
        out = self.features(x)
        return torch.cat([out[:, :2], out[:, 2:].clamp(LOG_VAR_MIN, LOG_VAR_MAX)], dim=1)


class _Block(nn.Module):
    """Basic residual block (two k=3 convolutions, batch norm), ``stride`` on the first."""

    def __init__(self, c_in: int, c_out: int, stride: int):
        super().__init__()
        self.body = nn.Sequential(
            nn.Conv1d(c_in, c_out, 3, stride=stride, padding=1, bias=False), nn.BatchNorm1d(c_out), nn.ReLU(),
            nn.Conv1d(c_out, c_out, 3, padding=1, bias=False), nn.BatchNorm1d(c_out))
        self.skip = (nn.Identity() if stride == 1 and c_in == c_out else
                     nn.Sequential(nn.Conv1d(c_in, c_out, 1, stride=stride, bias=False), nn.BatchNorm1d(c_out)))

    def forward(self, x):
        return torch.relu(self.body(x) + self.skip(x))


class ResNet1D(InertialNet):
    """RoNIN-style ResNet-1D: stem (k=7), stages of ``channels`` * (1, 2, 4) each halving time, flatten, MLP."""

    def __init__(self, n_window: int, n_stride: int, in_channels: int = 15, channels: int = 32, hidden: int = 64,
                 dropout: float = 0.1):
        super().__init__(n_window, n_stride, in_channels)
        c = int(channels)
        self.stem = nn.Sequential(nn.Conv1d(self.in_channels, c, 7, padding=3, bias=False), nn.BatchNorm1d(c),
                                  nn.ReLU())
        self.stages = nn.Sequential(_Block(c, c, 2), _Block(c, 2 * c, 2), _Block(2 * c, 4 * c, 2))
        t = self.n_window
        for _ in range(3):
            t = (t - 1) // 2 + 1
        self.head = nn.Sequential(nn.Flatten(), nn.Dropout(float(dropout)), nn.Linear(4 * c * t, int(hidden)),
                                  nn.ReLU(), nn.Linear(int(hidden), 4))

    def features(self, x):
        return self.head(self.stages(self.stem(x)))


class _CausalBlock(nn.Module):
    """Two dilated causal convolutions (left padding only) with a residual connection."""

    def __init__(self, c: int, kernel: int, dilation: int):
        super().__init__()
        self.pad = (kernel - 1) * dilation
        self.c1 = nn.Conv1d(c, c, kernel, dilation=dilation)
        self.c2 = nn.Conv1d(c, c, kernel, dilation=dilation)

    def forward(self, x):
        h = torch.relu(self.c1(nn.functional.pad(x, (self.pad, 0))))
        h = self.c2(nn.functional.pad(h, (self.pad, 0)))
        return torch.relu(x + h)


class TCN(InertialNet):
    """Causal TCN: 1x1 input projection, ``levels`` blocks with dilations 1, 2, 4, ..., the features of the last
    ``n_stride`` samples averaged (the output interval), linear head."""

    def __init__(self, n_window: int, n_stride: int, in_channels: int = 15, channels: int = 32, levels: int = 5,
                 kernel: int = 3):
        super().__init__(n_window, n_stride, in_channels)
        c = int(channels)
        self.proj = nn.Conv1d(self.in_channels, c, 1)
        self.blocks = nn.Sequential(*[_CausalBlock(c, int(kernel), 2 ** i) for i in range(int(levels))])
        self.head = nn.Linear(c, 4)

    def features(self, x):
        h = self.blocks(self.proj(x))
        return self.head(h[:, :, -self.n_stride:].mean(dim=2))


class YawEnsemble(nn.Module):
    """A network of the attitude's frame (``input_frame: world``, trained with random yaws) averaged over ``k`` turns of
    that frame: window x turned by a_j = 2 pi j / k (every horizontal pair of :data:`YAW_PAIRS`), the member's
    velocity turned back by -a_j, the k velocities averaged; the variance the mean of the members' per-axis
    variances turned back (the diagonal of R D R^T) plus the members' spread about the mean, as for any ensemble.
    The frame's heading is arbitrary to a network trained with random yaws, so the k answers are draws of one
    estimate: their mean removes the part of its error that depends on the heading (test-time augmentation). Exactly
    equivariant to turns by multiples of 2 pi / k (they permute the members); ``k = 1`` is the network itself.

    (B, n_window, 15) -> (B, 4) as :class:`InertialNet`; k members cost k forward passes (one batch of B k)."""

    def __init__(self, net: InertialNet, k: int):
        super().__init__()
        if not 1 <= int(k) <= 64:
            raise ValueError(f"yaw ensemble: k must be 1 .. 64 turns, got {k!r}")
        self.net, self.k = net, int(k)
        self.n_window, self.n_stride, self.in_channels = net.n_window, net.n_stride, net.in_channels
        a = 2 * torch.pi * torch.arange(self.k, dtype=torch.float64) / self.k
        self.register_buffer("angle", a.to(torch.float32), persistent=False)  # member j's turn a_j, rad

    def forward(self, imu: torch.Tensor) -> torch.Tensor:
        if self.k == 1:
            return self.net(imu)
        B, T, C = imu.shape
        c, s = torch.cos(self.angle)[:, None, None], torch.sin(self.angle)[:, None, None]  # (k, 1, 1)
        x = imu[None].expand(self.k, B, T, C)
        cols = list(x.unbind(dim=-1))  # every horizontal pair turned by its member's angle, the rest as it is
        for i, j in YAW_PAIRS:
            cols[i], cols[j] = c * x[..., i] - s * x[..., j], s * x[..., i] + c * x[..., j]
        out = self.net(torch.stack(cols, dim=-1).reshape(self.k * B, T, C))
        v, var = to_attitude_frame(out, -self.angle.repeat_interleave(B))  # member-major, as the batch was stacked
        v, var = v.reshape(self.k, B, 2), var.reshape(self.k, B, 2)
        mean = v.mean(dim=0)
        var = var.mean(dim=0) + ((v - mean) ** 2).mean(dim=0)  # the members' variance and their spread
        return torch.cat([mean, torch.log(var).clamp(LOG_VAR_MIN, LOG_VAR_MAX)], dim=1)
