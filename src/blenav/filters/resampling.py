"""Resampling schemes, vectorised over independent runs.

Every scheme maps normalised weights ``w`` of shape (R, N) (rows sum to 1) to ancestor indices of shape
(R, N) (Douc, Cappé and Moulines 2005 for the comparison of schemes). All use an explicit
``numpy.random.Generator``. Rows are handled at once by offsetting row r's cumulative weights by r,
so one ``searchsorted`` serves all runs.

- ``multinomial``: N i.i.d. draws from w.
- ``stratified``: one uniform draw in each stratum [(i + U_i) / N].
- ``systematic``: one uniform draw shared by all strata [(i + U) / N] (000 and 002 use it).
- ``low_variance``: Thrun et al.'s low-variance sampler, which is systematic resampling written with
  a single offset r ~ U(0, 1/N); kept as its own name because Roy's thesis names it.
- ``residual``: floor(N w) deterministic copies, the rest multinomial on the residual weights.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from .kernels import ess_rows, inverse_cdf, normalise_rows, shift_by_row_max

Scheme = Callable[[np.ndarray, np.random.Generator], np.ndarray]
SCHEMES: dict[str, Scheme] = {}


def resampling_scheme(name: str):
    def register(fn: Scheme) -> Scheme:
        SCHEMES[name] = fn
        return fn

    return register


def get_scheme(name: str) -> Scheme:
    if name not in SCHEMES:
        raise ValueError(f"unknown resampling scheme {name!r}; choose one of {sorted(SCHEMES)}")
    return SCHEMES[name]


def _inverse_cdf(w: np.ndarray, u: np.ndarray) -> np.ndarray:
    """Indices i with cumsum(w)[i-1] <= u < cumsum(w)[i], row by row; u (R, M) sorted or not, in [0, 1).

    Compiled (:func:`blenav.filters.kernels.inverse_cdf`): the indices of :func:`_inverse_cdf_numpy`, the
    same float sums and numpy's own binary search, without the (R N) temporaries."""
    if w.ndim == 2 and u.ndim == 2 and w.size and u.size:
        return inverse_cdf(np.ascontiguousarray(w, dtype=float), np.ascontiguousarray(u, dtype=float))
    return _inverse_cdf_numpy(w, u)


def _inverse_cdf_numpy(w: np.ndarray, u: np.ndarray) -> np.ndarray:
    """:func:`_inverse_cdf` in numpy (the reference)."""
    R, N = w.shape
    c = np.cumsum(w, axis=1)
    c[:, -1] = 1.0  # guard against round-off leaving the last cumulative weight below 1
    offset = np.arange(R, dtype=float)[:, None]
    idx = np.searchsorted((c + offset).ravel(), (u + offset).ravel(), side="right")
    return (idx.reshape(u.shape) - (np.arange(R) * N)[:, None]).clip(0, N - 1)


@resampling_scheme("multinomial")
def multinomial(w: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    return _inverse_cdf(w, rng.random(w.shape))


@resampling_scheme("stratified")
def stratified(w: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    R, N = w.shape
    return _inverse_cdf(w, (np.arange(N)[None, :] + rng.random((R, N))) / N)


@resampling_scheme("systematic")
def systematic(w: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    R, N = w.shape
    return _inverse_cdf(w, (np.arange(N)[None, :] + rng.random((R, 1))) / N)


@resampling_scheme("low_variance")
def low_variance(w: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    R, N = w.shape
    r = rng.uniform(0.0, 1.0 / N, (R, 1))
    return _inverse_cdf(w, r + np.arange(N)[None, :] / N)


@resampling_scheme("residual")
def residual(w: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    R, N = w.shape
    copies = np.floor(N * w).astype(np.int64)
    k = copies.sum(axis=1)  # deterministic copies per run
    rest = N * w - copies
    rsum = rest.sum(axis=1, keepdims=True)
    rest = np.where(rsum > 0, rest / np.where(rsum > 0, rsum, 1), 1.0 / N)
    det = np.repeat(np.tile(np.arange(N), R), copies.ravel())  # ancestors by copy count, run-major
    run_of = np.repeat(np.repeat(np.arange(R), N), copies.ravel())
    out = _inverse_cdf(rest, rng.random((R, N)))  # random fill for every slot, overwritten below
    slot = np.arange(len(det)) - np.repeat(np.concatenate([[0], np.cumsum(k)[:-1]]), k)
    out[run_of, slot] = det
    return out


def log_normalise(logw: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Normalised weights (R, N) and log-normaliser (R,) of log-weights; rows of all -inf give NaN weights."""
    if logw.ndim == 2 and logw.shape[1] and logw.dtype == np.float64:
        # compiled max, shift, pairwise row sums and division (numpy's numbers); exp and log stay numpy's
        d, m = shift_by_row_max(np.ascontiguousarray(logw))
        with np.errstate(invalid="ignore"):
            np.exp(d, out=d)
            s = normalise_rows(d)
            return d, m + np.log(s)
    m = np.max(logw, axis=1, keepdims=True)
    with np.errstate(invalid="ignore"):
        e = np.exp(logw - m)
    s = e.sum(axis=1, keepdims=True)
    return e / s, (m + np.log(s))[:, 0]


def ess(w: np.ndarray) -> np.ndarray:
    """Effective sample size 1 / sum w^2 per run (R,)."""
    if w.ndim == 2 and w.shape[1] and w.dtype == np.float64:
        return ess_rows(np.ascontiguousarray(w))  # compiled: the same pairwise sums
    return 1.0 / np.sum(w * w, axis=1)
