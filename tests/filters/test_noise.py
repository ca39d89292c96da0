"""The motion noise drawn a step ahead (blenav.filters.noise): same numbers whatever the thread timing."""

from __future__ import annotations

import multiprocessing as mp
import sys
import time

import numpy as np
import pytest

from blenav.filters.noise import PrefetchedNormals, motion_stream


class _SlowRng:
    """A Generator whose draws take a while: the filter's thread reaches the next request first."""

    def __init__(self, seed, delay):
        self.rng, self.delay = np.random.default_rng(seed), delay

    def standard_normal(self, *a, **k):
        time.sleep(self.delay)
        return self.rng.standard_normal(*a, **k)

    def uniform(self, *a, **k):
        time.sleep(self.delay)
        return self.rng.uniform(*a, **k)


def _requests(g):
    """Interleaved shapes and another method, as the inertial models request them."""
    out = []
    for _ in range(5):
        out.append(g.standard_normal((3, 4, 2)))
        out.append(g.standard_normal((3, 4)))
        out.append(g.uniform(-1.0, 1.0, 2))
    out.append(g.standard_normal(7))
    return out


class _Always(PrefetchedNormals):
    MIN_PREFETCH = 0  # threaded whatever the block size


def test_stream_does_not_depend_on_thread_timing():
    fast = _requests(_Always(_SlowRng(3, 0.0)))
    slow = _requests(_Always(_SlowRng(3, 0.02)))
    assert len(fast) == len(slow)
    for a, b in zip(fast, slow):
        np.testing.assert_array_equal(a, b)


def test_one_shape_gives_the_generator_own_sequence():
    """RandomWalk requests one shape per step: the blocks are the generator's plain sequence."""
    g = _Always(np.random.default_rng(5))
    got = np.stack([g.standard_normal((10, 4)) for _ in range(4)])
    ref = np.random.default_rng(5)
    want = np.stack([ref.standard_normal((10, 4)) for _ in range(4)])
    np.testing.assert_array_equal(got, want)
    off = PrefetchedNormals(np.random.default_rng(5), prefetch=False)
    np.testing.assert_array_equal(np.stack([off.standard_normal((10, 4)) for _ in range(4)]), want)


def test_small_blocks_stay_in_the_callers_thread(monkeypatch):
    """A streaming step's few thousand numbers are drawn directly: no worker, the plain Generator's numbers."""
    import blenav.filters.noise as N

    monkeypatch.setattr(N, "_executor", lambda: (_ for _ in ()).throw(AssertionError("worker used")))
    g = PrefetchedNormals(np.random.default_rng(8))
    got = [g.standard_normal((1000, 4)), g.uniform(0, 1, 3), g.standard_normal(5)]
    ref = np.random.default_rng(8)
    want = [ref.standard_normal((1000, 4)), ref.uniform(0, 1, 3), ref.standard_normal(5)]
    for a, b in zip(got, want):
        np.testing.assert_array_equal(a, b)


def test_motion_stream_is_a_child_and_leaves_the_parent_alone():
    a, b = np.random.default_rng(9), np.random.default_rng(9)
    s = motion_stream(a)
    x = s.standard_normal((4, 2))
    np.testing.assert_array_equal(a.random(5), b.random(5))  # the parent's stream is not advanced
    assert not np.allclose(x, np.random.default_rng(9).standard_normal((4, 2)))
    np.testing.assert_array_equal(x, motion_stream(np.random.default_rng(9)).standard_normal((4, 2)))


def _child_draw(q):
    q.put(motion_stream(np.random.default_rng(1)).standard_normal(3).tolist())


@pytest.mark.skipif(sys.platform == "win32", reason="fork start method is POSIX only")
def test_draws_work_in_a_forked_child():
    motion_stream(np.random.default_rng(0)).standard_normal(2)  # the parent's worker thread exists
    ctx = mp.get_context("fork")
    q = ctx.Queue()
    p = ctx.Process(target=_child_draw, args=(q,))
    p.start()
    got = q.get(timeout=30)
    p.join(timeout=30)
    np.testing.assert_array_equal(got, motion_stream(np.random.default_rng(1)).standard_normal(3))
