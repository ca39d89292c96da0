"""Losses of the cross-phone localizer (Roy, section 3.1.3, eqs. 3.1-3.6).

Notation: S (batch, B, H) RSSI windows, g = TransNet(S) the translated windows, f the predicted
positions (batch, 2) m, x the labels. The statistic similarity loss weighs deviations by
w_it = exp((S_it - M_ii) / tau) with tau = 0.1: on the raw thesis scale (readings near 30) that weight
overflows, so every loss here takes windows on the *normalised* scale u / ``U_SCALE`` (u = rssi + 100,
so values lie in [0, about 0.7]; :mod:`blenav.features.scale`); the networks are trained on that scale too.

Reductions: sums over beacons and steps as in the equations, means over the batch.
"""

from __future__ import annotations

import numpy as np
import torch


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

    d_ijt = |M_ij - g_jt| where M_ij - g_jt < 0 (the translation reads too high), else (M_ij - g_jt)^2,
    i.e. d = phi(M_ij - g_jt) with phi(x) = x^2 (x >= 0), -x (x < 0).

    Computed exactly but without the (batch, B, B, H) tensor. A beacon i not heard at step t (S_it = 0)
    has the weight w0_i = exp(-M_ii / tau) whatever the window, so
    sum_i w_it phi(M_ij - g) = F_j(g) + sum_{i heard} (w_it - w0_i) phi(M_ij - g), where
    F_j(g) = sum_i w0_i phi(M_ij - g) is piecewise quadratic in the scalar g: with column j of M sorted and
    prefix sums of w0, w0 M, w0 M^2 it is evaluated by one binary search per (window, j, t). The heard
    beacons (a fraction of B) are summed directly. :func:`ssl_loss_dense` is the direct form. When more than
    :data:`DENSE_ABOVE` of the entries are heard (the heard-beacon term then dominates), the dense form is
    evaluated instead, fused with its gradient (:class:`_SSLDense`, chunks of windows): same value.
    """
    b, B, H = g.shape
    heard = S > 0
    if int(heard.sum()) > DENSE_ABOVE * heard.numel():  # most beacons heard: the fused dense form is cheaper
        return _ssl_fused(g, S, M, tau)
    w0 = torch.exp(-torch.diagonal(M) / tau)  # (B_i,)
    # F_j(g) for every (window, j, t): sorted columns of M and prefix sums over them
    Ms, order = torch.sort(M.T.contiguous(), dim=1)  # (B_j, B_i) ascending in i
    v = w0[order]  # (B_j, B_i) weights in that order
    zero = torch.zeros(B, 1, dtype=M.dtype, device=M.device)
    P0, P1, P2 = (torch.cat([zero, torch.cumsum(x, dim=1)], dim=1) for x in (v, v * Ms, v * Ms * Ms))
    G = g.permute(1, 0, 2).reshape(B, b * H)  # (B_j, windows x steps)
    n = torch.searchsorted(Ms, G.detach().contiguous())  # how many M_ij < g in column j
    lo0, lo1 = P0.gather(1, n), P1.gather(1, n)
    hi0, hi1, hi2 = P0[:, -1:] - lo0, P1[:, -1:] - lo1, P2[:, -1:] - P2.gather(1, n)
    F = G * lo0 - lo1 + hi2 - 2 * G * hi1 + G * G * hi0  # (B_j, b*H)
    total = F.sum()
    # heard beacons: their weight differs from w0
    bi, ii, ti = torch.nonzero(heard, as_tuple=True)
    if len(bi):
        c = torch.exp((S[bi, ii, ti] - M[ii, ii]) / tau) - w0[ii]  # (K,)
        x = M[ii] - g[bi, :, ti]  # (K, B_j)
        total = total + (c[:, None] * torch.where(x < 0, -x, x * x)).sum()
    return total / b


#: share of heard entries of S above which :func:`ssl_loss` takes the fused dense form (:class:`_SSLDense`): with
#: most beacons heard the sparse form's heard-beacon term is as large as the dense tensor and slower (2.4x at 80 %)
DENSE_ABOVE = 0.3


class _SSLDense(torch.autograd.Function):
    """sum_{b,i,j,t} w_bit phi(M_ij - g_bjt) / b with its gradient in g computed in the same pass (eq. 3.2-3.4):
    d phi / d g = -phi'(x), phi'(x) = 2x (x >= 0), -1 (x < 0). The (c, B_i, B_j, H) tensor is built for chunks of
    ``chunk`` windows only (memory). w (b, B_i, H) and M carry no gradient (the input windows and the known
    brand's statistics)."""

    @staticmethod
    def forward(ctx, g, w, M, chunk: int):
        b = g.shape[0]
        need = ctx.needs_input_grad[0]
        grad = torch.empty_like(g) if need else None
        total = g.new_zeros(())
        Mx = M[None, :, :, None]
        for s in range(0, b, chunk):
            gc, wc = g[s:s + chunk], w[s:s + chunk]
            x = Mx - gc[:, None]  # (c, B_i, B_j, H)
            y = torch.where(x < 0, -1.0, x)  # phi(x) = x * y
            total = total + torch.einsum("bit,bijt->", wc, x * y)
            if need:  # phi'(x) = y + max(x, 0)
                grad[s:s + chunk] = -torch.einsum("bit,bijt->bjt", wc, y.add_(x.clamp_(min=0)))
        ctx.save_for_backward(grad if need else g.new_zeros(0))
        return total / b

    @staticmethod
    def backward(ctx, grad_out):
        (grad,) = ctx.saved_tensors
        return grad_out * grad / grad.shape[0], None, None, None


def _ssl_fused(g: torch.Tensor, S: torch.Tensor, M: torch.Tensor, tau: float) -> torch.Tensor:
    b, B, H = g.shape
    w = torch.exp((S - torch.diagonal(M)[None, :, None]) / tau).detach()  # (b, B_i, H)
    chunk = max(1, (1 << 22) // max(1, B * B * H))  # about 4M elements (16 MB) per chunk
    return _SSLDense.apply(g, w, M.detach(), chunk)


def ssl_loss_dense(g: torch.Tensor, S: torch.Tensor, M: torch.Tensor, tau: float = 0.1) -> torch.Tensor:
    """:func:`ssl_loss` written as the equations read, over the (batch, B, B, H) tensor (reference)."""
    w = torch.exp((S - torch.diagonal(M)[None, :, None]) / tau)  # (b, B_i, H)
    diff = M[None, :, :, None] - g[:, None, :, :]  # (b, B_i, B_j, H)
    d = torch.relu(-diff) + torch.relu(diff).square()
    return torch.einsum("bit,bijt->b", w, d).mean()


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
