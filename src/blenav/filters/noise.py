"""Motion noise drawn one step ahead, on the second core.

The motion models draw (R, N, k) standard normals every filter step; with 100 runs x 300 particles that is
a third of a PF-PS+MAP run (numpy's ziggurat on PCG64, about 14 ns per number on this machine). The draws
do not depend on the filter state, only on their shape, so :class:`PrefetchedNormals` draws the next block of
each shape in a worker thread while the filter computes likelihoods and resamples (numpy releases the GIL
while it fills an array).

Determinism: the proxy owns its own Generator (a child of the filter's, see :func:`motion_stream`), and every
draw from it -- the prefetched blocks, and any other method a model calls -- runs in one worker thread in the
order the filter requested it. The stream a model sees is therefore a function of the seed and of the
sequence of requests only, never of thread timing (tests/filters/test_noise.py delays the worker to check it).
"""

from __future__ import annotations

import atexit
import os
import threading
import weakref
from concurrent.futures import Future, ThreadPoolExecutor

import numpy as np

_EXECUTOR: ThreadPoolExecutor | None = None
_LOCK = threading.Lock()


def _executor() -> ThreadPoolExecutor:
    """One worker thread shared by every stream of the process (requests stay in submission order)."""
    global _EXECUTOR
    with _LOCK:
        if _EXECUTOR is None:
            _EXECUTOR = ThreadPoolExecutor(max_workers=1, thread_name_prefix="blenav-noise")
            atexit.register(_EXECUTOR.shutdown, wait=False, cancel_futures=True)
        return _EXECUTOR


def _forget_executor() -> None:
    """In a forked child the worker thread does not exist: start a new one on first use."""
    global _EXECUTOR, _LOCK
    _EXECUTOR, _LOCK = None, threading.Lock()


if hasattr(os, "register_at_fork"):
    os.register_at_fork(after_in_child=_forget_executor)


class PrefetchedNormals:
    """A Generator proxy for motion models: ``standard_normal(shape)`` served from a block drawn ahead.

    After a request of shape S the next block of shape S is submitted at once; the following request of
    shape S waits for it (usually already done). Any other Generator method (``uniform``, ``random``, ...)
    is forwarded through the same worker, after everything submitted before it. A stream whose first request
    is smaller than :attr:`MIN_PREFETCH` numbers (or that starts with another method) never uses the worker:
    it is then the plain child Generator (the mode is a function of the requests, so still deterministic).
    ``prefetch=False`` draws
    on request only: the same numbers when a model requests one shape and nothing else (RandomWalk), a
    different (equally valid, equally deterministic) stream when requests of several shapes interleave.
    """

    #: blocks smaller than this many numbers are not worth a thread hand-off (a streaming step of 1000 particles
    #: draws 4000; 100 runs x 300 particles 120,000)
    MIN_PREFETCH = 16384

    def __init__(self, rng: np.random.Generator, prefetch: bool = True):
        self._rng = rng
        self._prefetch = bool(prefetch)
        self._threaded: bool | None = None  # decided by the first request (its size), then fixed
        self._ahead: dict[tuple[int, ...], Future] = {}
        weakref.finalize(self, _drop, self._ahead)

    def _submit(self, fn, *args, **kwargs) -> Future:
        return _executor().submit(fn, *args, **kwargs)

    def standard_normal(self, size=None, dtype=np.float64, out=None):
        if self._threaded is None:  # small blocks: every draw in the caller's thread, as a plain Generator
            n = 1 if size is None else int(np.prod(size))
            self._threaded = self._prefetch and n >= self.MIN_PREFETCH
        if not self._threaded:
            return self._rng.standard_normal(size, dtype=dtype, out=out)
        if size is None or out is not None or np.dtype(dtype) != np.float64:
            return self._submit(self._rng.standard_normal, size, dtype=dtype, out=out).result()
        shape = (int(size),) if np.isscalar(size) else tuple(int(s) for s in size)
        fut = self._ahead.pop(shape, None)
        if fut is None:
            fut = self._submit(self._rng.standard_normal, shape)
        if self._prefetch:
            self._ahead[shape] = self._submit(self._rng.standard_normal, shape)
        return fut.result()

    def __getattr__(self, name):
        attr = getattr(self._rng, name)
        if not callable(attr):
            return attr

        if not self._threaded:  # nothing in flight: straight to the generator (and fixes the mode)
            self._threaded = False
            return attr

        def call(*args, **kwargs):
            return self._submit(attr, *args, **kwargs).result()
        return call


def _drop(ahead: dict) -> None:
    for fut in ahead.values():
        fut.cancel()
    ahead.clear()


def motion_stream(rng: np.random.Generator, prefetch: bool = True) -> PrefetchedNormals:
    """The motion models' own stream: a child Generator of ``rng`` (``Generator.spawn``: does not advance
    ``rng``), behind a :class:`PrefetchedNormals`."""
    return PrefetchedNormals(rng.spawn(1)[0], prefetch=prefetch)
