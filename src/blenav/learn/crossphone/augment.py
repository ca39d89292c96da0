"""Receiver augmentation for cross-phone training: a random phone per training window.

Phones differ in the level they report (an offset of up to about 15 dB between the brands of Roy's
Table 3.2), in the slope of reported vs. true level (automatic gain control) and in how many packets
they miss. A window S (B, H) on the normalised scale u / 100 (u = rssi + 100, 0 = not heard, see
:mod:`blenav.learn.crossphone.losses`) is re-received by a random phone:

    u' = u_ref + a (u - u_ref) + delta,   a ~ N(1, gain_std^2),  delta ~ N(0, offset_db_std^2) dB,

on heard entries only, with u_ref = 30 (-70 dBm). A reading pushed to u' <= 0 (below -100 dBm) is lost
(not heard, 0), as it would be below a receiver's sensitivity; one left in (0, floor_u) counts floor_u
like the window transform's weak packets. Each heard reading is also dropped with a probability
q ~ U(0, dropout_max) drawn per window. One draw of (a, delta, q) per sample serves all windows of that
sample (S and the previous window S_prev come from the same phone).

This is not part of Roy's method: it is our addition against the brand gap TransNet alone does not
close in our simulation (see docs/results/crossphone_003.md); with every parameter 0 it is off.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch

from blenav.features.scale import U_SCALE


@dataclass
class ReceiverAugment:
    offset_db_std: float = 0.0  # std of the level offset delta, dB
    gain_std: float = 0.0  # std of the slope a around 1
    dropout_max: float = 0.0  # per-window extra dropout probability drawn from U(0, dropout_max)
    u_ref: float = 30.0  # pivot of the slope on the u scale (-70 dBm)
    floor_u: float = 0.5  # smallest heard reading on the u scale (the window transform's weak packets)

    @property
    def active(self) -> bool:
        return bool(self.offset_db_std or self.gain_std or self.dropout_max)

    def __call__(self, windows: list[torch.Tensor], generator: torch.Generator) -> list[torch.Tensor]:
        """Windows of one batch, each (b, B, H) on the scale u / 100, all re-received by the same b phones."""
        b = windows[0].shape[0]
        dev, dt = windows[0].device, windows[0].dtype
        draw = lambda: torch.randn(b, 1, 1, generator=generator).to(dev, dt)  # noqa: E731
        a, delta = 1.0 + self.gain_std * draw(), self.offset_db_std * draw()
        q = self.dropout_max * torch.rand(b, 1, 1, generator=generator).to(dev, dt)
        out = []
        for S in windows:
            u = S * U_SCALE
            u2 = self.u_ref + a * (u - self.u_ref) + delta
            kept = (u > 0) & (u2 > 0) & (torch.rand(S.shape, generator=generator).to(dev, dt) >= q)
            out.append(torch.where(kept, u2.clamp(min=self.floor_u), torch.zeros_like(u)) / U_SCALE)
        return out
