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
from numba import njit


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
    i.e. d = phi(M_ij - g_jt) with phi(x) = x^2 (x >= 0), -x (x < 0), and w_it = exp((S_it - M_ii) / tau).

    Evaluated with its gradient in g in one pass (:class:`_SSLDense`; w and M carry no gradient: the input
    windows and the known brand's statistics), never building the (batch, B, B, H) tensor of
    :func:`ssl_loss_dense`, the direct form: on CPU tensors by a compiled loop (:func:`_ssl_kernel`, one
    pass over the B x B x H terms of each window: forward 1.8 ms against 13.7 ms for the chunked tensor form,
    with the backward 3.3 against 19.1 ms, on a batch of 256 windows of 50 beacons: benchmarks/crossphone_step.py),
    on other devices in chunks of windows."""
    w = torch.exp((S - torch.diagonal(M)[None, :, None]) / tau).detach()  # (b, B_i, H)
    return _SSLDense.apply(g, w, M.detach())


@njit(cache=True, fastmath=True)
def _ssl_kernel(g: np.ndarray, w: np.ndarray, MT: np.ndarray, need_grad: bool):
    """sum_{n,t,i,j} w[n,t,i] phi(M[i,j] - g[n,t,j]) and its gradient in g (zeros (0,0,0) when not needed).

    g, w (b, H, B) and MT = M.T (B_j, B_i), C-contiguous: the inner loop runs over i along memory, summing the
    value and the gradient of g[n,t,j] in registers (fastmath: reassociated, vectorised sums, accumulated in
    float64). phi(x) = x * y with y = x (x >= 0), -1 (x < 0); d phi / d g = -(y + max(x, 0))."""
    b, H, B = g.shape
    grad = np.zeros(g.shape if need_grad else (0, 0, 0), g.dtype)
    total = 0.0
    for n in range(b):
        for t in range(H):
            wt = w[n, t]
            for j in range(B):
                gj = g[n, t, j]
                acc = 0.0
                gacc = 0.0
                for i in range(B):
                    x = MT[j, i] - gj
                    y = x if x >= 0 else -1.0
                    acc += wt[i] * (x * y)
                    gacc += wt[i] * (y + (x if x > 0 else 0.0))
                total += acc
                if need_grad:
                    grad[n, t, j] = -gacc
    return total, grad


class _SSLDense(torch.autograd.Function):
    """sum_{b,i,j,t} w_bit phi(M_ij - g_bjt) / b with its gradient in g computed in the same pass (eq. 3.2-3.4):
    d phi / d g = -phi'(x), phi'(x) = 2x (x >= 0), -1 (x < 0). CPU tensors: :func:`_ssl_kernel`; other devices:
    the (c, B_i, B_j, H) tensor for chunks of ``chunk`` windows (about 4M elements) at a time."""

    @staticmethod
    def forward(ctx, g, w, M, chunk: int | None = None):
        b, B, H = g.shape
        need = ctx.needs_input_grad[0]
        if g.device.type == "cpu" and chunk is None:
            gt, wt = (x.detach().permute(0, 2, 1).contiguous().numpy() for x in (g, w))
            value, grad = _ssl_kernel(gt, wt, M.detach().T.contiguous().numpy(), need)
            total = torch.tensor(value, dtype=g.dtype)
            grad = torch.from_numpy(grad).permute(0, 2, 1) if need else None
        else:
            chunk = chunk or max(1, (1 << 22) // max(1, B * B * H))
            total, grad = _ssl_chunked(g, w, M, chunk, need)
        ctx.save_for_backward(grad if need else g.new_zeros(0))
        return total / b

    @staticmethod
    def backward(ctx, grad_out):
        (grad,) = ctx.saved_tensors
        return grad_out * grad / grad.shape[0], None, None, None


def _ssl_chunked(g, w, M, chunk: int, need: bool):
    """:class:`_SSLDense`'s value and gradient with tensors, ``chunk`` windows at a time."""
    grad = torch.empty_like(g) if need else None
    total = g.new_zeros(())
    Mx = M[None, :, :, None]
    for s in range(0, g.shape[0], chunk):
        gc, wc = g[s:s + chunk], w[s:s + chunk]
        x = Mx - gc[:, None]  # (c, B_i, B_j, H)
        y = torch.where(x < 0, -1.0, x)  # phi(x) = x * y
        total = total + torch.einsum("bit,bijt->", wc, x * y)
        if need:  # phi'(x) = y + max(x, 0)
            grad[s:s + chunk] = -torch.einsum("bit,bijt->bjt", wc, y.add_(x.clamp_(min=0)))
    return total, grad


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


def gaussian_nll(f: torch.Tensor, x: torch.Tensor, sigma: torch.Tensor) -> torch.Tensor:
    """Negative log-likelihood of labels x (b, 2) m under N(f, sigma^2 I) per window (f (b, 2) m, sigma (b,) m, the
    isotropic std of each axis), without the constant log(2 pi): |f - x|^2 / (2 sigma^2) + 2 log sigma, mean over
    the batch. LocNet's std head is trained with it (:class:`blenav.models.LocNet`, ``std_head``)."""
    return ((f - x) ** 2).sum(dim=1).div(2.0 * sigma ** 2).add(2.0 * torch.log(sigma)).mean()


def position_smoothness_loss(f_t: torch.Tensor, f_prev: torch.Tensor) -> torch.Tensor:
    """L_ps = ||f(S_t) - f(S_{t-1})||^2 for predictions of consecutive windows, mean over the batch."""
    return ((f_t - f_prev) ** 2).sum(dim=1).mean()


def total_loss(terms: dict[str, torch.Tensor], weights: dict[str, float]) -> torch.Tensor:
    """Eq. 3.6: sum_k w_k L_k over the terms present (keys loc, ps, ssl, ts; nll: the std head's, issue 29)."""
    unknown = set(terms) - {"loc", "ps", "ssl", "ts", "nll"}
    if unknown:
        raise KeyError(f"unknown loss terms {sorted(unknown)}")
    return sum(weights.get(k, 0.0) * v for k, v in terms.items())
