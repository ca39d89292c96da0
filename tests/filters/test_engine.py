"""Particle-filter engine: resampling, Kalman agreement, motion-model moments, measurement models."""

from __future__ import annotations

import numpy as np
import pytest

from blenav.filters.engine import FilterConfig, Initializer, ParticleFilter
from blenav.filters.measurement import AnchorTable, MeasurementModel, PathLossRange, RssiDomain
from blenav.filters.motion import DeadReckoning, ImuProposal, OdometryIncrement, Pdr, RandomWalk
from blenav.filters.resampling import SCHEMES, ess, get_scheme, log_normalise


@pytest.mark.parametrize("name", sorted(SCHEMES))
def test_resampling_is_unbiased(name):
    """E[copies of particle i] = N w_i: a chi-square test on the pooled counts of many draws."""
    rng = np.random.default_rng(1)
    R, N, draws = 4, 8, 4000
    w = rng.dirichlet(np.ones(N), size=R)
    counts = np.zeros((R, N))
    fn = get_scheme(name)
    for _ in range(draws):
        idx = fn(w, rng)
        assert idx.shape == (R, N) and idx.min() >= 0 and idx.max() < N
        np.add.at(counts, (np.repeat(np.arange(R), N), idx.ravel()), 1)
    expected = draws * N * w
    # deterministic schemes have far less than multinomial variance: a multinomial-variance z test is
    # conservative for them and exact for multinomial
    z = (counts - expected) / np.sqrt(draws * N * w * (1 - w))
    assert np.abs(z).max() < 4.5


def test_unknown_scheme_is_named():
    with pytest.raises(ValueError, match="systematic"):
        get_scheme("nope")


def test_log_normalise_and_ess():
    logw = np.log(np.array([[0.5, 0.5, 1e-300, 1e-300], [0.25] * 4])) + 1000.0
    w, _ = log_normalise(logw)
    np.testing.assert_allclose(w.sum(axis=1), 1.0)
    np.testing.assert_allclose(ess(w), [2.0, 4.0])
    w, _ = log_normalise(np.array([[-np.inf, 0.0, -np.inf]]))
    np.testing.assert_allclose(w, [[0.0, 1.0, 0.0]])


class _GaussianPosition(MeasurementModel):
    """Test measurement: z = p + N(0, sigma^2 I)."""

    def __init__(self, sigma):
        self.sigma = sigma

    def n_obs(self, obs):
        return 1 if obs.get("z") is not None else 0

    def log_likelihood(self, xy, obs):
        d = (xy - obs["z"]) / self.sigma
        return -0.5 * np.sum(d * d, axis=-1)


class _GaussianInit(Initializer):
    def __init__(self, m, s):
        self.m, self.s = np.asarray(m, float), s

    def sample(self, rng, R, N):
        return self.m + self.s * rng.standard_normal((R, N, 2))


def test_particle_filter_matches_kalman_filter_on_linear_gaussian_toy():
    """RW motion + direct position measurements is linear-Gaussian: the PF mean must track the KF mean."""
    rng = np.random.default_rng(3)
    dt, T, sp, sv, sz = 0.5, 30, 0.1, 0.3, 0.7
    motion = RandomWalk(sigma_p=sp, sigma_v=sv, max_speed=1e9)
    # truth and measurements
    p, v = np.zeros(2), np.array([0.4, -0.2])
    zs = []
    for _ in range(T):
        v = v + sv * rng.standard_normal(2)
        p = p + dt * v + sp * rng.standard_normal(2)
        zs.append(p + sz * rng.standard_normal(2))
    # Kalman filter on (px, py, vx, vy): v' = v + nu; p' = p + dt v' + eps
    F = np.block([[np.eye(2), dt * np.eye(2)], [np.zeros((2, 2)), np.eye(2)]])
    G = np.block([[dt * np.eye(2)], [np.eye(2)]])
    Q = G @ (sv**2 * np.eye(2)) @ G.T + np.diag([sp**2, sp**2, 0, 0])
    H = np.hstack([np.eye(2), np.zeros((2, 2))])
    m = np.zeros(4)
    P = np.diag([1.0, 1.0, 1e-12, 1e-12])
    kf = []
    for z in zs:
        m, P = F @ m, F @ P @ F.T + Q
        S = H @ P @ H.T + sz**2 * np.eye(2)
        K = P @ H.T @ np.linalg.inv(S)
        m, P = m + K @ (z - H @ m), (np.eye(4) - K @ H) @ P
        kf.append((m[:2].copy(), P[:2, :2].copy()))
    cfg = FilterConfig(n_particles=4000, ess_threshold=0.5, divergence_sigma=1e9)
    pf = ParticleFilter(cfg, motion, [_GaussianPosition(sz)], _GaussianInit([0, 0], 1.0), np.random.default_rng(0),
                        n_runs=8)
    pf.initialize(0.0)
    for k, z in enumerate(zs):
        res = pf.step((k + 1) * dt, {}, {"z": z})
        m_kf, P_kf = kf[k]
        err = np.abs(res.position.mean(axis=0) - m_kf)
        tol = 0.1 * np.sqrt(np.diag(P_kf))  # a tenth of the posterior std (the MC error is about 1/50 of it)
        assert (err < tol).all(), (k, err, tol)
        np.testing.assert_allclose(res.cov.mean(axis=0), P_kf, rtol=0.25, atol=0.025, err_msg=f"step {k}")


def _moments(model, ctrl, dt, x0, n=200000, seed=0):
    x = np.broadcast_to(x0, (1, n, len(x0))).copy()
    out = model.propagate(x, ctrl, dt, np.random.default_rng(seed))[0]
    return out.mean(axis=0), np.cov(out.T)


def test_imu_proposal_moments_follow_eqs_4_to_7():
    m = ImuProposal(sigma_a=1.5, sigma_v=0.005, max_speed=1e9)
    dt = 0.1
    a = np.array([3.0, 4.0])  # direction (0.6, 0.8)
    x0 = np.array([1.0, 2.0, 0.5, -0.3])
    mean, cov = _moments(m, {"acc_w": a}, dt, x0)
    ah = a / 5.0
    np.testing.assert_allclose(mean[:2], x0[:2] + dt * x0[2:], atol=2e-4)
    np.testing.assert_allclose(mean[2:], x0[2:], atol=2e-3)
    # position: (dt^2/2)^2 sigma_a^2 a a^T + dt^2 sigma_v^2 I ; velocity: dt^2 sigma_a^2 a a^T + sigma_v^2 I
    Pp = (0.5 * dt * dt) ** 2 * 1.5**2 * np.outer(ah, ah) + dt * dt * 0.005**2 * np.eye(2)
    Pv = dt * dt * 1.5**2 * np.outer(ah, ah) + 0.005**2 * np.eye(2)
    Ppv = 0.5 * dt**3 * 1.5**2 * np.outer(ah, ah) + dt * 0.005**2 * np.eye(2)
    np.testing.assert_allclose(cov[:2, :2], Pp, rtol=0.03, atol=1e-9)
    np.testing.assert_allclose(cov[2:, 2:], Pv, rtol=0.03, atol=1e-8)
    np.testing.assert_allclose(cov[:2, 2:], Ppv, rtol=0.03, atol=1e-9)


def test_imu_proposal_without_acceleration_only_diffuses():
    m = ImuProposal()
    mean, cov = _moments(m, {"acc_w": np.zeros(2)}, 0.1, np.array([0, 0, 1.0, 0]))
    np.testing.assert_allclose(cov[2:, 2:], 0.005**2 * np.eye(2), rtol=0.03, atol=2e-7)


def test_random_walk_moments():
    m = RandomWalk(sigma_p=0.1, sigma_v=0.05, max_speed=1e9)
    dt = 0.2
    mean, cov = _moments(m, {}, dt, np.array([0, 0, 1.0, 0.5]))
    np.testing.assert_allclose(mean, [0.2, 0.1, 1.0, 0.5], atol=2e-3)
    np.testing.assert_allclose(np.diag(cov)[:2], dt * dt * 0.05**2 + 0.1**2, rtol=0.03)
    np.testing.assert_allclose(np.diag(cov)[2:], 0.05**2, rtol=0.03)


def test_dead_reckoning_moves_along_heading():
    m = DeadReckoning(increment_m=0.075, sigma_v=0.03)
    mean, cov = _moments(m, {"heading": np.pi / 2}, 0.1, np.zeros(5))
    np.testing.assert_allclose(mean[:2], [0.0, 0.075], atol=1e-4)
    np.testing.assert_allclose(np.diag(cov)[:2], (0.1 * 0.03) ** 2, rtol=0.03)


def test_odometry_increment_rotates_by_particle_frame():
    m = OdometryIncrement(sigma2_per_s=0.1, sigma_theta=0.0, theta0=np.pi / 2)
    x0 = m.init_state(np.zeros((1, 1, 2)), np.random.default_rng(0))[0, 0]
    mean, cov = _moments(m, {"odo": np.array([1.0, 0.0])}, 1.0, x0)
    np.testing.assert_allclose(mean[:2], [0.0, 1.0], atol=3e-3)
    np.testing.assert_allclose(np.diag(cov)[:2], 0.1, rtol=0.03)


def test_odometry_increment_takes_the_odometrys_own_variance():
    """Issue 31: with odo_var_scale the step's noise is scale x the track's variance growth (per axis); a step whose
    track states none (0) keeps Roy's 0.1 dt; without odo_var_scale the stated variance is ignored."""
    x0 = OdometryIncrement(theta0=0.0).init_state(np.zeros((1, 1, 2)), np.random.default_rng(0))[0, 0]
    for scale, g, want in ((2.0, 0.04, 0.08), (2.0, 0.0, 0.05), (None, 0.04, 0.05)):
        m = OdometryIncrement(sigma2_per_s=0.1, sigma_theta=0.0, theta0=0.0, odo_var_scale=scale)
        mean, cov = _moments(m, {"odo": np.array([1.0, 0.0]), "odo_var": g}, 0.5, x0)
        np.testing.assert_allclose(mean[:2], [1.0, 0.0], atol=3e-3)
        np.testing.assert_allclose(np.diag(cov)[:2], want, rtol=0.03)
    with pytest.raises(ValueError, match="odo_var_scale"):
        OdometryIncrement(odo_var_scale=0.0)


def test_batch_steps_carry_the_tracks_variance_growth():
    """The batch path's control odo_var is the growth of the odometry's column var between the step times."""
    import pandas as pd

    from blenav.filters.steps import _var_growth

    t = np.array([0.0, 0.5, 1.0, 1.5, 2.0])
    var = np.array([0.0, 0.01, 0.03, 0.06, 0.10])
    assert _var_growth(t, var, 0.0, 1.0) == pytest.approx(0.03)
    assert _var_growth(t, var, 1.0, 1.9) == pytest.approx(0.03)  # last sample at or before 1.9: t = 1.5
    assert _var_growth(t, None, 0.0, 1.0) == 0.0
    assert pd.api.types.is_float(_var_growth(t, var, -1.0, 0.0))


def test_pdr_moves_one_step_length_per_step():
    m = Pdr(step_length=0.7, sigma_length=0.0, sigma_heading=0.0, sigma_p=0.0, heading_offset_rw=0.0)
    x = np.zeros((1, 3, 5))
    out = m.propagate(x, {"steps": 2, "heading": 0.0}, 0.5, np.random.default_rng(0))
    np.testing.assert_allclose(out[0, :, :2], [[1.4, 0.0]] * 3)


def _table():
    return AnchorTable(np.array(["a", "b"]), np.array([[0.0, 0.0, 1.2], [10.0, 0.0, 1.2]]), np.array([-60.0, np.nan]))


def test_rssi_domain_likelihood_peaks_at_consistent_distance():
    m = RssiDomain(a_x=-60.0, gamma=2.0, d0=1.0, sigma_s=5.0, device_z=1.2)
    m.bind(_table())
    xs = np.linspace(0.5, 9.5, 181)
    xy = np.stack([xs, np.zeros_like(xs)], -1)[None]
    rssi = -60 - 20 * np.log10(4.0)  # 4 m from anchor a, whose tx power is known (-60)
    ll = m.log_likelihood(xy, {"rssi_idx": np.array([0]), "rssi": np.array([rssi])})
    assert abs(xs[np.argmax(ll[0])] - 4.0) < 0.06


def test_path_loss_range_drops_far_ranges_and_uses_reference_distance():
    m = PathLossRange(a_x=-64.53, gamma=1.72, d0=1.78, sigma_n=5.0, max_range_m=10.0, use_anchor_tx_power=False)
    m.bind(_table())
    near = -64.53 - 17.2 * np.log10(3.0 / 1.78)  # range 3 m
    far = -64.53 - 17.2 * np.log10(30.0 / 1.78)  # range 30 m: discarded
    obs = {"rssi_idx": np.array([0, 1]), "rssi": np.array([near, far])}
    idx, r = m.ranges(obs)
    assert list(idx) == [0] and abs(r[0] - 3.0) < 1e-9
    assert m.n_obs(obs) == 1
    xy = np.array([[[3.0, 0.0], [7.0, 0.0]]])
    ll = m.log_likelihood(xy, obs)
    assert ll[0, 0] > ll[0, 1]


def test_anchor_table_index_of_unknown_is_minus_one():
    assert list(_table().index_of(np.array(["b", "zz", "a"]))) == [1, -1, 0]


def test_recovery_reinitialises_a_diverged_run():
    """A cloud far from what the measurements say is re-initialised and the event recorded."""
    cfg = FilterConfig(n_particles=200, patience_s=1.0, divergence_sigma=3.0, ess_threshold=0.5)
    init = _GaussianInit([50.0, 50.0], 0.5)  # everything starts 50 m away from the truth

    class Global(_GaussianInit):
        def sample(self, rng, R, N):
            return rng.uniform(-5, 5, (R, N, 2))

    pf = ParticleFilter(cfg, RandomWalk(), [_GaussianPosition(0.5)], init, np.random.default_rng(0), n_runs=2)
    pf.initialize()
    pf.initializer = Global([0, 0], 1)
    for k in range(60):
        res = pf.step(0.1 * (k + 1), {}, {"z": np.zeros(2)})
    assert pf.events and all(np.isfinite(res.position).ravel())
    assert np.linalg.norm(res.position, axis=1).max() < 1.0
