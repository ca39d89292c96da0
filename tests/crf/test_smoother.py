"""The walk smoother (blenav.crf.smoother): exact against enumeration on a toy grid, robust to biased fixes."""

from __future__ import annotations

import math

import numpy as np
import pytest

from blenav.crf.grid import grid_from_occupancy
from blenav.crf.smoother import Layers, brute_force, edge_log_kernel, forward_backward, viterbi
from blenav.data import FREE, OCCUPIED


def _toy():
    """An L-shaped toy floor of 1 m cells: 5 walkable cells, a wall cell in the corner block."""
    occ = np.full((2, 3), FREE, np.uint8)  # rows from the top
    occ[0, 0] = OCCUPIED
    return grid_from_occupancy(occ, 1.0, (0.0, 0.0), 1.0, 1.5)


def _unaries(g, rng, K):
    return [None if k == 1 else rng.normal(0, 1.5, g.n_cells) for k in range(K)]


def _toy_walk(seed: int, K: int):
    """(grid, disp (K-1, 2), unaries) of a random walk model on the toy floor."""
    g = _toy()
    rng = np.random.default_rng(seed)
    return g, rng.normal(0, 0.8, (K - 1, 2)), _unaries(g, rng, K)


@pytest.mark.parametrize("layers", [None, Layers((0.0, 0.5), (1.0, 1.3))])
def test_forward_backward_and_viterbi_equal_enumeration(layers):
    g = _toy()
    assert g.n_cells == 5
    rng = np.random.default_rng(3)
    K = 4
    disp = rng.normal(0, 0.8, (K - 1, 2))
    unary = _unaries(g, rng, K)
    log_prior = rng.normal(0, 0.3, g.n_cells)
    log_init = np.log(rng.dirichlet(np.ones(g.n_cells)))
    M, best, best_l = brute_force(g, disp, 0.7, unary, log_init, log_prior, layers)
    r = forward_backward(g, disp, 0.7, unary, log_init, log_prior, layers, prune=0.0)
    np.testing.assert_allclose(r.smoothed_mean, M @ g.xy, atol=1e-9)
    np.testing.assert_array_equal(r.smoothed_mode, M.argmax(1))
    path, layer = viterbi(g, disp, 0.7, unary, log_init, log_prior, layers, prune=0.0)
    np.testing.assert_array_equal(path, best)
    assert layer == best_l


def _corridor_case(case: str):
    """(grid, disp, sigma, unary, log_prior) on a 1 x 10 corridor of 1 m cells (steps of at most 1 m) where the walk
    is forced through states whose transition weights lie 700-1000 nats below the others' (module doc of
    blenav.crf.smoother: the linear-domain passes' fallback)."""
    g = grid_from_occupancy(np.full((1, 10), FREE, np.uint8), 1.0, (0.0, 0.0), 1.0, 1.0)
    cell = np.arange(g.n_cells)
    K = 4
    disp, sigma = np.zeros((K - 1, 2)), 0.6
    unary = [None] * K
    log_prior = np.zeros(g.n_cells)
    if case == "prior":  # the walk starts at cell 8, whose every neighbour is 900 nats down in the prior
        log_prior[6:] = -900.0
        unary[0] = np.where(cell == 8, 0.0, -1e4)
    elif case == "odometry":  # at node 1 on cell 4, at node 2 on cell 3: against an odometry step of +30 m
        disp[1], sigma = (30.0, 0.0), 0.25
        unary[1] = np.where(cell == 4, 0.0, -1e4)
        unary[2] = np.where(cell == 3, 0.0, -1e5)
    else:  # node 1 on cell 0, node 2's fixes 800 nats down everywhere but on cell 9, out of reach
        unary[1] = np.where(cell == 0, 0.0, -1e4)
        unary[2] = np.where(cell == 9, 0.0, -800.0)
    return g, disp, sigma, unary, log_prior


@pytest.mark.parametrize("case", ["prior", "odometry", "unary"])
def test_weights_beyond_the_linear_domain_still_equal_enumeration(case):
    """The sum-product passes run in the linear domain and take a source in the log domain where its sums underflow:
    a start whose neighbours are all far down in the prior (forward), an odometry step that makes the only way on
    ~1000 nats unlikely and fixes that leave only ways 800 nats down (backward). Each equals enumeration."""
    g, disp, sigma, unary, log_prior = _corridor_case(case)
    M, _, _ = brute_force(g, disp, sigma, unary, None, log_prior, None)
    r = forward_backward(g, disp, sigma, unary, None, log_prior, None, prune=0.0)
    np.testing.assert_allclose(r.smoothed_mean, M @ g.xy, atol=1e-9)
    np.testing.assert_array_equal(r.smoothed_mode, M.argmax(1))
    assert np.isfinite(r.log_evidence)


def test_filtered_marginal_of_the_last_node_is_the_smoothed_one_and_the_first_uses_only_its_own_fix():
    g, disp, unary = _toy_walk(5, 3)
    r = forward_backward(g, disp, 0.6, unary, prune=0.0)
    np.testing.assert_allclose(r.filtered_mean[-1], r.smoothed_mean[-1], atol=1e-12)
    p0 = np.exp(unary[0] - unary[0].max())
    np.testing.assert_allclose(r.filtered_mean[0], (p0 / p0.sum()) @ g.xy, atol=1e-12)


def test_each_source_row_of_the_kernel_is_a_distribution():
    g = _toy()
    w = edge_log_kernel(g, np.array([1.0, 0.0]), 0.5)
    src = np.repeat(np.arange(g.n_cells), np.diff(g.src_ptr))
    np.testing.assert_allclose(np.bincount(src, np.exp(w)), 1.0, atol=1e-12)


def _corridor(length_m=60.0):
    occ = np.full((4, int(length_m)), OCCUPIED, np.uint8)
    occ[1:3, :] = FREE
    return grid_from_occupancy(occ, 1.0, (0.0, 0.0), 1.0, 3.0)


def _fix_unary(g, xy, std, eps=0.05):
    d2 = ((g.xy - xy) ** 2).sum(1)
    gauss = -d2 / (2 * std**2) - math.log(2 * math.pi * std**2)
    return np.logaddexp(math.log(1 - eps) + gauss, math.log(eps / (g.n_cells * 1.0)))


def test_a_fix_20_m_off_for_10_s_does_not_drag_the_track():
    """A walk along a corridor at 1 m/s with good odometry and 4 m fixes every second, ten of which are 20 m off:
    the smoothed track stays within 2 m of the truth there, and the filter within 3 m."""
    g = _corridor()
    rng = np.random.default_rng(0)
    K = 50
    truth = np.column_stack([5.0 + np.arange(K), np.full(K, 2.0)])
    disp = np.diff(truth, axis=0) + rng.normal(0, 0.05, (K - 1, 2))
    fixes = truth + rng.normal(0, 2.0, (K, 2))
    fixes[20:30, 0] += 20.0
    unary = [_fix_unary(g, f, 4.0) for f in fixes]
    r = forward_backward(g, disp, 0.5, unary)
    err_s = np.linalg.norm(r.smoothed_mean - truth, axis=1)
    err_f = np.linalg.norm(r.filtered_mean - truth, axis=1)
    assert err_s[20:30].max() < 2.0, err_s[20:30]
    assert err_f[20:30].max() < 3.0, err_f[20:30]
    naive = np.linalg.norm(fixes - truth, axis=1)[20:30].mean()
    assert naive > 15.0


def test_a_uniform_start_converges_and_the_layers_find_the_heading_offset():
    """No start given (uniform), odometry rotated by 0.3 rad: the layer with that offset wins."""
    g = _corridor()
    rng = np.random.default_rng(1)
    K = 40
    truth = np.column_stack([5.0 + 1.2 * np.arange(K), np.full(K, 2.0)])
    d = np.diff(truth, axis=0)
    c, s = math.cos(-0.3), math.sin(-0.3)  # the odometry's heading is 0.3 rad off
    disp = d @ np.array([[c, s], [-s, c]])
    unary = [_fix_unary(g, f, 3.0) if k % 3 == 0 else None
             for k, f in enumerate(truth + rng.normal(0, 2.0, (K, 2)))]
    layers = Layers((-0.3, 0.0, 0.3), (1.0,))
    r = forward_backward(g, disp, 0.4, unary, layers=layers)
    assert int(np.argmax(r.layer_post)) == 2
    assert np.linalg.norm(r.smoothed_mean - truth, axis=1)[5:].mean() < 1.0


def test_pruning_that_cuts_every_path_still_gives_a_finite_track():
    """With a pruning threshold no cell reaches (0.9 on a spread-out posterior), the backward pass finds no path to the
    future: those nodes keep their filtered marginal, and every estimate stays finite."""
    g = _corridor(20.0)
    rng = np.random.default_rng(2)
    K = 12
    disp = np.tile([1.0, 0.0], (K - 1, 1))
    unary = [_fix_unary(g, np.array([3.0 + k, 2.0]) + rng.normal(0, 3, 2), 6.0) for k in range(K)]
    r = forward_backward(g, disp, 0.5, unary, prune=0.9)
    assert np.isfinite(r.smoothed_mean).all() and np.isfinite(r.filtered_mean).all()
    assert np.isfinite(r.smoothed_cov).all()


def test_fixed_lag_equals_enumeration_of_the_truncated_walk():
    """The lag-1 marginal of node k is the smoothed marginal of the walk cut after node k + 1 (enumerated exactly);
    lag 0 is the filter, a lag of the whole walk the smoother."""
    K = 4
    g, disp, unary = _toy_walk(7, K)
    r1 = forward_backward(g, disp, 0.7, unary, prune=0.0, lag=1)
    for k in range(K):
        end = min(k + 1, K - 1)
        M, _, _ = brute_force(g, disp[:end], 0.7, unary[:end + 1])
        np.testing.assert_allclose(r1.filtered_mean[k], M[k] @ g.xy, atol=1e-9)
    r0 = forward_backward(g, disp, 0.7, unary, prune=0.0)
    rK = forward_backward(g, disp, 0.7, unary, prune=0.0, lag=K)
    np.testing.assert_allclose(rK.filtered_mean, r0.smoothed_mean, atol=1e-9)
    with pytest.raises(ValueError, match="lag"):
        forward_backward(g, disp, 0.7, unary, lag=-1)


def test_bad_shapes_and_a_prior_that_rules_out_every_target_are_refused_or_survived():
    g, disp, unary = _toy_walk(4, 3)
    with pytest.raises(ValueError, match="log_init"):
        forward_backward(g, disp, 0.7, unary, log_init=np.zeros(3))
    with pytest.raises(ValueError, match=r"unary\[0\]"):
        forward_backward(g, disp, 0.7, [np.zeros(2)] + unary[1:])
    with pytest.raises(ValueError, match="prune"):
        forward_backward(g, disp, 0.7, unary, prune=1.5)
    lp = np.zeros(g.n_cells)
    lp[[0, 1]] = -np.inf  # cells no walker goes to: no source may normalise over nothing
    r = forward_backward(g, disp, 0.7, unary, log_prior=lp, prune=0.0)
    assert np.isfinite(r.smoothed_mean).all() and np.isfinite(r.log_evidence)


def test_viterbi_after_a_restart_returns_cells_only():
    """A unary that rules out every cell reachable from the previous node forces a restart: the path has no -1."""
    occ = np.full((1, 12), FREE, np.uint8)
    g = grid_from_occupancy(occ, 1.0, (0.0, 0.0), 1.0, 1.0)
    K = 4
    U = [np.where(np.arange(g.n_cells) == 0, 0.0, -np.inf), None,
         np.where(np.arange(g.n_cells) == 11, 0.0, -np.inf), None]
    path, _ = viterbi(g, np.zeros((K - 1, 2)), 0.5, U, prune=0.0)
    assert (path >= 0).all() and path[0] == 0 and path[2] == 11
