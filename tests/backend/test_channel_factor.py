"""Issue 32: the receiver offset and the path-loss exponent as variables of the graph (blenav.backend.factors.
channel_range_error): the M-estimators against GTSAM's own, the grouped factor against RangeFactor3D and against
central differences, and a toy graph whose channel (exponent 2.6, receiver 6 dB hot, against the model's 1.72) the
variables recover while the track stays."""

from __future__ import annotations

import numpy as np
import pytest

gtsam = pytest.importorskip("gtsam")
from gtsam.symbol_shorthand import E, L, O, X  # noqa: E402

from blenav.backend import Keyframes, RangeObs, load_backend_config, smooth  # noqa: E402
from blenav.backend.config import RobustKernel  # noqa: E402
from blenav.backend.factors import channel_range_factor, kernel_loss  # noqa: E402

from .test_graph import _scene  # noqa: E402

KERNELS = [RobustKernel.none, RobustKernel.huber, RobustKernel.cauchy, RobustKernel.geman_mcclure, RobustKernel.dcs]


def _gtsam_kernel(kind, k):
    est = gtsam.noiseModel.mEstimator
    return {RobustKernel.huber: lambda: est.Huber.Create(k), RobustKernel.cauchy: lambda: est.Cauchy.Create(k),
            RobustKernel.geman_mcclure: lambda: est.GemanMcClure.Create(k),
            RobustKernel.dcs: lambda: est.DCS.Create(k * k)}[kind]()


@pytest.mark.parametrize("kind", KERNELS[1:])
def test_kernel_loss_is_gtsams(kind):
    u = np.array([-7.3, -2.0, -0.4, 0.0, 0.3, 1.2, 1.345, 2.5, 9.0])
    rho, w = kernel_loss(kind, 1.345, u)
    ref = _gtsam_kernel(kind, 1.345)
    np.testing.assert_allclose(rho, [ref.loss(x) for x in u], rtol=1e-12, atol=1e-15)
    np.testing.assert_allclose(w, [ref.weight(x) for x in u], rtol=1e-12)


def _values(rng, n_pose=2, n_beacon=3, delta=0.0, b=None):
    vals = gtsam.Values()
    for i in range(n_pose):
        vals.insert(X(i), gtsam.Pose3(gtsam.Rot3.Ypr(*rng.uniform(-np.pi, np.pi, 3)), rng.uniform(-5, 5, 3)))
    for j in range(n_beacon):
        vals.insertPoint3(L(j), rng.uniform(-5, 5, 3))
    vals.insert(O(0), np.array([delta]))
    if b is not None:
        vals.insert(E(0), np.array([b]))
    return vals


@pytest.mark.parametrize("kind", KERNELS)
def test_channel_factor_at_zero_offset_is_gtsams_robust_range_factors(kind):
    """delta = 0, no exponent: the grouped factor's error is the sum of robust RangeFactor3D's (one per range, the
    same kernel inside the same sigma), and its linearization (right-hand side and the pose and beacon Jacobian rows)
    is theirs: GTSAM's reweighted system, residuals inside and outside the kernel's width."""
    from blenav.backend.factors import robust_noise

    rng = np.random.default_rng(4)
    sigma = 0.7
    vals = _values(rng)
    pk, bk = [X(0), X(1), X(0), X(1), X(1)], [L(0), L(0), L(2), L(1), L(2)]
    d = np.array([np.linalg.norm(vals.atPose3(p).translation() - vals.atPoint3(b)) for p, b in zip(pk, bk)])
    r = d + sigma * np.array([0.2, -3.0, 0.5, 4.0, -0.1])  # whitened residuals inside and outside the width
    mine = channel_range_factor(pk, bk, O(0), None, r, 2.0, 1.78, sigma, kind, 1.345)
    refs = [gtsam.RangeFactor3D(p, b, float(x), robust_noise(kind, 1.345, sigma)) for p, b, x in zip(pk, bk, r)]
    assert mine.error(vals) == pytest.approx(sum(f.error(vals) for f in refs), rel=1e-12)
    A, rhs = mine.linearize(vals).jacobian()  # columns: X0 (6), X1 (6), L0, L1, L2 (3 each), O
    col = {X(0): 0, X(1): 6, L(0): 12, L(1): 15, L(2): 18}
    for i, f in enumerate(refs):
        Ar, br = f.linearize(vals).jacobian()
        assert rhs[i] == pytest.approx(br[0], rel=1e-10, abs=1e-12)
        np.testing.assert_allclose(A[i, col[pk[i]]:col[pk[i]] + 6], Ar[0, :6], atol=1e-10)
        np.testing.assert_allclose(A[i, col[bk[i]]:col[bk[i]] + 3], Ar[0, 6:], atol=1e-10)
        others = [c for key, c in col.items() if key not in (pk[i], bk[i])]
        assert all(not A[i, c:c + (6 if c < 12 else 3)].any() for c in others)


def test_channel_factor_jacobian_is_its_errors_derivative():
    """No kernel: the linearized (whitened) Jacobian of every key against central differences of the whitened error
    (offset, exponent, each beacon axis, each pose's rotation and translation in its tangent space)."""
    rng = np.random.default_rng(7)
    vals = _values(rng, delta=-3.0, b=1.3)
    pk, bk = [X(0), X(1), X(0), X(1)], [L(0), L(1), L(2), L(2)]
    r = rng.uniform(0.5, 12, len(pk))
    f = channel_range_factor(pk, bk, O(0), E(0), r, 1.72, 1.78, 0.5, RobustKernel.none, 1.345)
    A = f.linearize(vals).jacobian()[0]  # columns: X0, X1 (6 each), L0, L1, L2 (3 each), O, E
    h = 1e-6

    def central(perturb):
        vp, vm = gtsam.Values(vals), gtsam.Values(vals)
        perturb(vp, h)
        perturb(vm, -h)
        return (f.whitenedError(vp) - f.whitenedError(vm)) / (2 * h)

    def vector(key):
        return lambda v, e: v.update(key, vals.atVector(key) + e)

    def point(key, axis):
        def go(v, e):
            p0 = np.asarray(vals.atPoint3(key), float)
            v.erase(key)
            v.insertPoint3(key, p0 + np.eye(3)[axis] * e)
        return go

    def pose(key, axis):
        return lambda v, e: v.update(key, vals.atPose3(key).retract(np.eye(6)[axis] * e))

    cols = [(vector(O(0)), 21), (vector(E(0)), 22)]
    cols += [(point(L(j), a), 12 + 3 * j + a) for j in range(3) for a in range(3)]
    cols += [(pose(X(i), a), 6 * i + a) for i in range(2) for a in range(6)]
    for perturb, c in cols:
        np.testing.assert_allclose(A[:, c], central(perturb), rtol=1e-5, atol=1e-7)
    assert not A[:, [0, 1, 2, 6, 7, 8]].any()  # a range does not see the pose's rotation


@pytest.mark.parametrize("method", ["lm", "isam2"])
def test_the_graph_recovers_offset_and_exponent_as_variables(method):
    """Exact trajectory (keyframes at the truth, their cloud 0.3 m), beacons known to 5 cm, every range read through a
    channel of exponent 2.6 and a receiver 6 dB hot against the model's 1.72: with ``range.estimate_offset`` and
    ``range.estimate_exponent`` the smoother's variables recover both and the track stays on the truth (range noise
    0.3 m: with the default 5 m the exact ranges say less than the exponent's prior, 0.3 around 1)."""
    true = np.array([[6.0, 4.0, 2.5], [14.0, 4.0, 2.5], [10.0, 13.0, 2.5], [10.0, 3.0, 2.5]])
    kf, imu, ranges, bp = _scene(true, true, 0.05, range_sigma=0.0)
    gamma_c, offset, d0 = 2.6, 6.0, 1.78  # r = d0 (d / d0)^(gamma_c / gamma) 10^(-offset / (10 gamma))
    r = d0 * 10 ** ((gamma_c / 1.72) * np.log10(ranges.range_m / d0) - offset / (10 * 1.72))
    kf = Keyframes(kf.t, kf.position, kf.velocity, kf.q, cov=np.tile(np.eye(2) * 0.3 ** 2, (len(kf.t), 1, 1)))
    cfg = load_backend_config(overrides=[f"solver.method={method}", "range.gate_m=null", f"range.d0={d0}",
                                         "range.max_range_m=100", "range.estimate_offset=true",
                                         "range.estimate_exponent=true", "range.channel_group=4", "range.sigma_n=0.3"])
    res = smooth(cfg, kf, imu, RangeObs(ranges.t, ranges.anchor, r, 1.72), bp)
    assert res.ok, [str(f) for f in res.failures]
    print(f"{method}: exponent {res.channel_exponent:.3f} +- {res.channel_exponent_std:.3f}, offset "
          f"{res.offset_db:.2f} +- {res.offset_std_db:.2f} dB")
    assert res.channel_exponent == pytest.approx(gamma_c, abs=0.1)
    assert res.offset_db == pytest.approx(offset, abs=1.0)
    assert np.isfinite(res.channel_exponent_std) and np.isfinite(res.offset_std_db)
    assert np.linalg.norm(res.position[:, :2] - kf.position[:, :2], axis=-1).max() < 0.3


def test_the_exponent_needs_the_offset():
    with pytest.raises(ValueError, match="estimate_exponent needs range.estimate_offset"):
        load_backend_config(overrides=["range.estimate_exponent=true"])
    with pytest.raises(ValueError, match="channel_group"):
        load_backend_config(overrides=["range.estimate_offset=true", "range.channel_group=0"])
