"""Losses of the cross-phone localizer (Roy, section 3.1.3, eqs. 3.1-3.6).

Notation: S (batch, B, H) RSSI windows, g = TransNet(S) the translated windows, f the predicted
positions (batch, 2) m, x the labels. The statistic similarity loss weighs deviations by
w_it = exp((S_it - M_ii) / tau) with tau = 0.1: on the raw thesis scale (readings near 30) that weight
overflows, so every loss here takes windows on the *normalised* scale u / ``U_SCALE`` (u = rssi + 100,
so values lie in [0, about 0.7]); the networks are trained on that scale too.

Reductions: sums over beacons and steps as in the equations, means over the batch.
"""

from __future__ import annotations

import numpy as np
import torch

U_SCALE = 100.0


def brand_statistics(S: np.ndarray) -> np.ndarray:
    """Eq. 3.1: M_ij = E[s_j | s_i > 0] over the step vectors s (columns) of windows S (N, B, H) of a known brand.

    Rows of beacons never heard are 0. Returns (B, B) float32.
    """
    s = np.moveaxis(np.asarray(S, float), 2, 1).reshape(-1, S.shape[1])  # (N*H, B) step vectors
    heard = (s > 0).astype(float)
    n_i = heard.sum(axis=0)  # (B,)
    sums = heard.T @ s  # (B, B): sum over vectors with s_i > 0 of s_j
    return np.divide(sums, n_i[:, None], out=np.zeros_like(sums), where=n_i[:, None] > 0).astype(np.float32)


def ssl_loss(g: torch.Tensor, S: torch.Tensor, M: torch.Tensor, tau: float = 0.1) -> torch.Tensor:
    """Eqs. 3.2-3.4: sum_t sum_i sum_j w_it d_ijt, mean over the batch.

    d_ijt = |M_ij - g_jt| where M_ij - g_jt < 0 (the translation reads too high), else (M_ij - g_jt)^2.
    """
    w = torch.exp((S - torch.diagonal(M)[None, :, None]) / tau)  # (b, B_i, H)
    diff = M[None, :, :, None] - g[:, None, :, :]  # (b, B_i, B_j, H)
    d = torch.relu(-diff) + torch.relu(diff).square()  # eq. 3.4 without a branch: one of the two is 0
    return torch.einsum("bit,bijt->b", w, d).mean()  # 3x faster than materialising w * d


def temporal_smoothness_loss(g: torch.Tensor) -> torch.Tensor:
    """Eq. 3.5: sum_t sum_i |g_{i,t} - g_{i,t+1}|, mean over the batch."""
    return (g[..., 1:] - g[..., :-1]).abs().sum(dim=(1, 2)).mean()


def localization_loss(f: torch.Tensor, x: torch.Tensor) -> torch.Tensor:
    """L_loc = ||f - x||^2, mean over the batch."""
    return ((f - x) ** 2).sum(dim=1).mean()


def position_smoothness_loss(f_t: torch.Tensor, f_prev: torch.Tensor) -> torch.Tensor:
    """L_ps = ||f(S_t) - f(S_{t-1})||^2 for predictions of consecutive windows, mean over the batch."""
    return ((f_t - f_prev) ** 2).sum(dim=1).mean()


def total_loss(terms: dict[str, torch.Tensor], weights: dict[str, float]) -> torch.Tensor:
    """Eq. 3.6: sum_k w_k L_k over the terms present (keys loc, ps, ssl, ts)."""
    unknown = set(terms) - {"loc", "ps", "ssl", "ts"}
    if unknown:
        raise KeyError(f"unknown loss terms {sorted(unknown)}")
    return sum(weights.get(k, 0.0) * v for k, v in terms.items())
