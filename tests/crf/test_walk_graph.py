"""The walk's factor graph (issue 30, ``estimate: graph``): exact against dense least squares, equal to GTSAM's own
factors under Levenberg-Marquardt, robust to a burst of fixes 20 m off."""

from __future__ import annotations

import numpy as np
import pytest

from blenav.crf.walk_graph import refine_walk


def _walk(K=40, seed=0):
    rng = np.random.default_rng(seed)
    truth = np.cumsum(np.r_[[[3.0, 4.0]], rng.normal(0, 0.8, (K - 1, 2))], axis=0)
    disp = np.diff(truth, axis=0) + rng.normal(0, 0.1, (K - 1, 2))
    sigma = 0.2 + 0.1 * np.hypot(*disp.T)
    init = truth + rng.normal(0, 1.5, (K, 2))
    A = rng.normal(0, 1, (K, 2, 2))
    prior_cov = np.einsum("kij,klj->kil", A, A) + 0.3 * np.eye(2)  # SPD, anisotropic
    node = rng.integers(0, K, 25)
    fxy = truth[node] + rng.normal(0, 2.0, (25, 2))
    fsd = rng.uniform(1.5, 4.0, 25)
    return truth, init, prior_cov, disp, sigma, node, fxy, fsd


def test_without_a_kernel_it_is_the_weighted_least_squares_solution_and_its_covariance():
    """kernel none: one pass gives the dense normal equations' solution and the diagonal blocks of their inverse."""
    _, init, P, disp, sigma, node, fxy, fsd = _walk()
    K, s, c = len(init), 9.0, 1.0
    x, cov, it = refine_walk(init, P, disp, sigma, node, fxy, fsd, prior_scale=s, cell_m=c, kernel="none")
    H, g = np.zeros((2 * K, 2 * K)), np.zeros(2 * K)

    def add(J, r0, W):  # factor J x - r0 with information W: H += J'WJ, g += J'W r0
        nonlocal H, g
        H += J.T @ W @ J
        g += J.T @ W @ r0

    for k in range(K):
        J = np.zeros((2, 2 * K))
        J[:, 2 * k:2 * k + 2] = np.eye(2)
        add(J, init[k], np.linalg.inv(s * (P[k] + c * c / 12 * np.eye(2))))
    for k in range(K - 1):
        J = np.zeros((2, 2 * K))
        J[:, 2 * k:2 * k + 2], J[:, 2 * k + 2:2 * k + 4] = -np.eye(2), np.eye(2)
        add(J, disp[k], np.eye(2) / sigma[k] ** 2)
    for n, f, sd in zip(node, fxy, fsd):
        J = np.zeros((2, 2 * K))
        J[:, 2 * n:2 * n + 2] = np.eye(2)
        add(J, f, np.eye(2) / sd ** 2)
    ref = np.linalg.solve(H, g).reshape(K, 2)
    Hinv = np.linalg.inv(H)
    ref_cov = np.array([Hinv[2 * k:2 * k + 2, 2 * k:2 * k + 2] for k in range(K)])
    assert it == 1
    np.testing.assert_allclose(x, ref, atol=1e-9)
    np.testing.assert_allclose(cov, ref_cov, atol=1e-10)


@pytest.mark.parametrize("kernel", ["cauchy", "huber"])
def test_equals_gtsam_levenberg_marquardt_on_its_own_factors(kernel):
    """The same graph in GTSAM (PriorFactorPoint2, BetweenFactorPoint2, a robust fix noise model) from the same start:
    the same optimum and marginal covariances."""
    gtsam = pytest.importorskip("gtsam")
    _, init, P, disp, sigma, node, fxy, fsd = _walk(seed=1)
    fxy[:4] += 15.0  # outliers, so the kernel matters
    K, s, c, kk = len(init), 16.0, 1.0, 1.0
    x, cov, _ = refine_walk(init, P, disp, sigma, node, fxy, fsd, prior_scale=s, cell_m=c, kernel=kernel, kernel_k=kk)
    graph, values = gtsam.NonlinearFactorGraph(), gtsam.Values()
    for k in range(K):
        values.insert(k, init[k])
        graph.add(gtsam.PriorFactorPoint2(k, init[k], gtsam.noiseModel.Gaussian.Covariance(
            s * (P[k] + c * c / 12 * np.eye(2)))))
    for k in range(K - 1):
        graph.add(gtsam.BetweenFactorPoint2(k, k + 1, disp[k], gtsam.noiseModel.Isotropic.Sigma(2, sigma[k])))
    est = (gtsam.noiseModel.mEstimator.Cauchy if kernel == "cauchy" else gtsam.noiseModel.mEstimator.Huber).Create(kk)
    for n, f, sd in zip(node, fxy, fsd):
        graph.add(gtsam.PriorFactorPoint2(int(n), f, gtsam.noiseModel.Robust.Create(
            est, gtsam.noiseModel.Isotropic.Sigma(2, sd))))
    params = gtsam.LevenbergMarquardtParams()
    params.setRelativeErrorTol(1e-14)
    params.setAbsoluteErrorTol(1e-14)
    params.setMaxIterations(500)
    res = gtsam.LevenbergMarquardtOptimizer(graph, values, params).optimize()
    ref = np.array([res.atPoint2(k) for k in range(K)])
    np.testing.assert_allclose(x, ref, atol=1e-5)
    marg = gtsam.Marginals(graph, res)
    ref_cov = np.array([marg.marginalCovariance(k) for k in range(K)])
    np.testing.assert_allclose(cov, ref_cov, rtol=1e-4, atol=1e-6)


def test_a_burst_of_fixes_20_m_off_does_not_drag_the_track():
    """Good odometry, 2 m fixes every node, ten of them 20 m off; the start (the grid's means) 1.5 m off with a loose
    prior: the refined track stays within 2 m of the truth in the burst, the plain least squares does not."""
    rng = np.random.default_rng(3)
    K = 50
    truth = 0.7 * np.arange(K)[:, None] * np.ones(2)  # a diagonal at 1 m/s
    noisy = lambda a, sd: a + rng.normal(0, sd, a.shape)  # noqa: E731
    fxy = noisy(truth, 2.0)
    fxy[20:30] += [20.0, -5.0]
    args = (noisy(truth, 1.5), np.tile(np.eye(2), (K, 1, 1)), noisy(np.diff(truth, axis=0), 0.05), np.full(K - 1, 0.35),
            np.arange(K), fxy, np.full(K, 3.0))
    robust, _, _ = refine_walk(*args)
    plain, _, _ = refine_walk(*args, kernel="none")
    err = np.hypot(*(robust - truth).T)
    assert err[20:30].max() < 2.0, err[20:30]
    assert np.hypot(*(plain - truth).T)[20:30].mean() > 2.5


def test_bad_inputs_are_refused():
    _, init, P, disp, sigma, node, fxy, fsd = _walk(K=5)
    with pytest.raises(ValueError, match="kernel"):
        refine_walk(init, P, disp, sigma, node, fxy, fsd, kernel="tukey")
    with pytest.raises(ValueError, match="disp"):
        refine_walk(init, P, disp[:-1], sigma, node, fxy, fsd)
    with pytest.raises(ValueError, match="nodes in"):
        refine_walk(init, P, disp, sigma, np.full(len(fxy), 9), fxy, fsd)
    with pytest.raises(ValueError, match="no anchor"):
        refine_walk(init, P, disp, sigma, node[:0], fxy[:0], fsd[:0], prior_scale=0)
    with pytest.raises(ValueError, match="finite"):
        refine_walk(init, P, disp, np.r_[sigma[:-1], np.inf], node, fxy, fsd, prior_scale=0)
    with pytest.raises(ValueError, match="finite"):
        refine_walk(init, P, disp, sigma, node, np.where(np.arange(len(fxy))[:, None] == 0, np.nan, fxy), fsd)
