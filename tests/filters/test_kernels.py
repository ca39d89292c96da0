"""The compiled particle-filter kernels (blenav.filters.kernels, .motion_kernels, .measurement_kernels,
.map.kernels) give the numbers of the numpy code they replaced, bit for bit: the numpy expressions are kept
here as the references."""

from __future__ import annotations

import numpy as np
import pytest

from blenav.filters import kernels as K
from blenav.filters import measurement_kernels as MK
from blenav.filters.map import kernels as MAPK
from blenav.filters.measurement import AnchorTable, PathLossRange, RssiDomain
from blenav.filters.motion import ImuProposal, RandomWalk


def _clip_speed2(vx, vy, vmax):
    s2 = vx * vx + vy * vy
    if not (s2 > vmax * vmax).any():
        return vx, vy
    f = np.minimum(1.0, vmax / np.sqrt(np.maximum(s2, 1e-24)))
    return vx * f, vy * f


def rw_numpy(m, x, dt, rng):
    out = x.copy()
    e = rng.standard_normal(x.shape[:-1] + (4,))
    vx, vy = _clip_speed2(x[..., 2] + m.sigma_v * e[..., 0], x[..., 3] + m.sigma_v * e[..., 1], m.max_speed)
    out[..., 2], out[..., 3] = vx, vy
    out[..., 0] = x[..., 0] + dt * vx + m.sigma_p * e[..., 2]
    out[..., 1] = x[..., 1] + dt * vy + m.sigma_p * e[..., 3]
    return out


def imu_numpy(m, x, ctrl, dt, rng):
    a = np.asarray(ctrl["acc_w"], dtype=float)[:2]
    na = np.hypot(a[0], a[1])
    a_hat = a / na if na >= m.min_acc else np.zeros(2)
    shape = x.shape[:-1]
    zeta = m.sigma_a * rng.standard_normal(shape + (1,))
    nu = m.sigma_v * rng.standard_normal(shape + (2,))
    out = x.copy()
    h = 0.5 * dt * dt
    for k in range(2):
        u = zeta[..., 0] * a_hat[k]
        out[..., k] = x[..., k] + dt * x[..., 2 + k] + h * u + dt * nu[..., k]
        out[..., 2 + k] = x[..., 2 + k] + dt * u + nu[..., k]
    out[..., 2], out[..., 3] = _clip_speed2(out[..., 2], out[..., 3], m.max_speed)
    return out


def distances_numpy(model, xy, idx):
    l = model.anchors.xyz[idx].astype(np.float32)
    d = xy[..., 0].astype(np.float32).reshape(1, -1) - l[:, 0:1]
    d *= d
    dy = xy[..., 1].astype(np.float32).reshape(1, -1) - l[:, 1:2]
    dy *= dy
    d += dy
    d += ((np.float32(model.device_z) - l[:, 2]) ** 2)[:, None]
    return np.sqrt(d, out=d)


def sum_squares_numpy(res, lead):
    r = np.ascontiguousarray(res.T).reshape(*lead, res.shape[0])
    return -0.5 * np.einsum("rnm,rnm->rn", r, r).astype(np.float64)


def rssi_numpy(model, xy, obs):
    idx, rssi = obs["rssi_idx"], obs["rssi"]
    d = distances_numpy(model, xy, idx)
    np.maximum(d, np.float32(model.d_min), out=d)
    base = (rssi - model._ax()[idx] - 10.0 * model.gamma * np.log10(model.d0)).astype(np.float32)
    res = np.log10(d, out=d)
    res *= np.float32(10.0 * model.gamma)
    res += base[:, None]
    res *= np.float32(1.0 / model.sigma_s)
    return sum_squares_numpy(res, xy.shape[:-1])


def range_numpy(model, xy, obs):
    idx, r = model.ranges(obs)
    if len(idx) == 0:
        return np.zeros(xy.shape[:-1])
    res = distances_numpy(model, xy, idx)
    res -= r.astype(np.float32)[:, None]
    res *= np.float32(1.0 / model.sigma_n)
    return sum_squares_numpy(res, xy.shape[:-1])


def estimate_numpy(w, x):
    xy = x[..., :2]
    mean = np.einsum("rn,rnk->rk", w, xy)
    d = xy - mean[:, None, :]
    return mean, np.einsum("rn,rni,rnj->rij", w, d, d)


@pytest.fixture
def anchors():
    rng = np.random.default_rng(5)
    A = 40
    tx = rng.uniform(-70, -55, A)
    tx[::7] = np.nan
    return AnchorTable(np.array([f"b{i}" for i in range(A)]),
                       np.column_stack([rng.uniform(0, 45, A), rng.uniform(0, 55, A), rng.uniform(2, 3, A)]), tx)


@pytest.mark.parametrize("D", [4, 5])
def test_random_walk(D):
    rng = np.random.default_rng(0)
    m = RandomWalk(max_speed=0.3)  # low cap: some particles are clipped, most not
    x = rng.standard_normal((7, 50, D)) * [3, 3, 0.2, 0.2, 1][:D]
    for dt in (0.1, 0.25):
        a = m.propagate(x, {}, dt, np.random.default_rng(1))
        b = rw_numpy(m, x, dt, np.random.default_rng(1))
        assert a.dtype == b.dtype and a.shape == b.shape
        assert np.array_equal(a, b)
    m = RandomWalk()  # no particle clipped
    assert np.array_equal(m.propagate(x, {}, 0.1, np.random.default_rng(2)), rw_numpy(m, x, 0.1, np.random.default_rng(2)))


@pytest.mark.parametrize("acc", [(0.3, -0.2), (0.01, 0.0), (2.0, 1.0)])
def test_imu_proposal(acc):
    rng = np.random.default_rng(0)
    x = rng.standard_normal((5, 60, 4)) * [3, 3, 1.5, 1.5]  # some above max_speed
    m = ImuProposal()
    ctrl = {"acc_w": np.array([*acc, 0.1])}
    a = m.propagate(x, ctrl, 0.1, np.random.default_rng(3))
    b = imu_numpy(m, x, ctrl, 0.1, np.random.default_rng(3))
    assert np.array_equal(a, b)


@pytest.mark.parametrize("M", [1, 3, 4, 5, 15, 16, 17, 18, 33, 64, 70])
def test_path_loss_likelihoods(anchors, M):
    rng = np.random.default_rng(M)
    x = np.concatenate([rng.uniform(0, 45, (4, 30, 1)), rng.uniform(0, 55, (4, 30, 1)), rng.standard_normal((4, 30, 2))],
                       axis=-1)
    x[0, 0, :2] = anchors.xyz[3, :2]  # a particle under a beacon: distance floored at d_min
    xy = x[..., :2]
    obs = {"rssi_idx": rng.integers(0, len(anchors.ids), M), "rssi": rng.uniform(-95, -50, M)}
    ps = RssiDomain()
    ps.bind(anchors)
    assert np.array_equal(ps.log_likelihood(xy, obs), rssi_numpy(ps, xy, obs))
    pl = PathLossRange()
    pl.bind(anchors)
    assert np.array_equal(pl.log_likelihood(xy, obs), range_numpy(pl, xy, obs))
    assert np.array_equal(ps._distances(xy, obs["rssi_idx"]), distances_numpy(ps, xy, obs["rssi_idx"]))


def test_sum_squares_order():
    rng = np.random.default_rng(7)
    for M in range(1, 130):
        r = (rng.standard_normal((2, 20, M)) * 3).astype(np.float32)
        ref = np.einsum("rnm,rnm->rn", r, r)
        got = np.array([[MK._sum_squares_sse(r[i, j], M) for j in range(20)] for i in range(2)], dtype=np.float32)
        assert np.array_equal(ref, got), M


@pytest.mark.parametrize("shape", [(100, 300, 4), (3, 7, 5), (1, 1000, 4)])
def test_mean_cov(shape):
    rng = np.random.default_rng(11)
    x = rng.standard_normal(shape) * 10
    w = rng.random(shape[:2])
    w /= w.sum(axis=1, keepdims=True)
    m1, c1 = K.mean_cov(w, x)
    m2, c2 = estimate_numpy(w, x)
    assert np.array_equal(m1, m2) and np.array_equal(c1, c2)


def test_duplicates():
    rng = np.random.default_rng(3)
    for _ in range(20):
        idx = rng.integers(0, 30, (4, 30))
        order = np.argsort(idx, axis=1, kind="stable")
        srt = np.take_along_axis(idx, order, axis=1)
        dup_sorted = np.zeros_like(srt, dtype=bool)
        dup_sorted[:, 1:] = srt[:, 1:] == srt[:, :-1]
        ref = np.empty_like(dup_sorted)
        np.put_along_axis(ref, order, dup_sorted, axis=1)
        assert np.array_equal(K.duplicates(idx), ref)


@pytest.mark.parametrize("rooms_routes", [True, False])  # given map, and rooms/routes derived from the plan
def test_grid_nearest_edge(tmp_path, rooms_routes):
    from blenav.cli.sim import run as sim_run
    from blenav.configs import compose
    from blenav.data.building import Building
    from blenav.filters.map import MapGeometry

    out = tmp_path / "small"
    sim_run(compose("sim", "sim=small", "seed=0", f"out={out}", "duration_s=2", "sessions=1", "progress=false"))
    b = out / "buildings" / "small"
    if not rooms_routes:
        (b / "rooms.geojson").unlink()
        (b / "navgraph.geojson").unlink()
    ix = MapGeometry.from_building(Building.load(b), 0).get_index("grid", 3.0, 1.0)
    x0, y0, x1, y1 = ix.x0, ix.y0, ix.x0 + ix.nx * ix.cell, ix.y0 + ix.ny * ix.cell
    rng = np.random.default_rng(0)
    xy = np.column_stack([rng.uniform(x0 - 3, x1 + 3, 20000), rng.uniform(y0 - 3, y1 + 3, 20000)])
    xy[:5] = ix.segs[:5, 0]  # on segment end points
    xy[5] = np.nan
    with np.errstate(invalid="ignore"):  # the NaN point's cell index
        ref = ix.nearest_edge_numpy(xy)
    for a, b in zip(ix.nearest_edge(xy), ref):
        assert np.array_equal(a, b, equal_nan=True)


@pytest.mark.parametrize("scheme", ["systematic", "stratified", "multinomial", "residual", "low_variance"])
def test_inverse_cdf(scheme):
    from blenav.filters import resampling as RS

    rng = np.random.default_rng(4)
    for R, N in ((100, 300), (3, 7), (1, 1)):
        for _ in range(10):
            w = rng.random((R, N)) ** 8  # uneven weights
            w /= w.sum(axis=1, keepdims=True)
            w[0, : N // 2] = 0.0  # zero weights: ties in the cumulative sums
            w[0] /= w[0].sum()
            a = RS.get_scheme(scheme)(w, np.random.default_rng(9))
            orig, RS._inverse_cdf = RS._inverse_cdf, RS._inverse_cdf_numpy
            try:
                b = RS.get_scheme(scheme)(w, np.random.default_rng(9))
            finally:
                RS._inverse_cdf = orig
            assert np.array_equal(a, b)
    u = np.sort(rng.random((50, 300)), axis=1)
    u[:, -1] = np.nextafter(1.0, 0.0)  # keys whose offset sum rounds up to the row's end
    w = rng.random((50, 300))
    w /= w.sum(axis=1, keepdims=True)
    assert np.array_equal(K.inverse_cdf(w, u), RS._inverse_cdf_numpy(w, u))


def test_gather_rows():
    rng = np.random.default_rng(8)
    x = rng.standard_normal((6, 40, 5))
    runs = np.array([0, 2, 5])
    idx = rng.integers(0, 40, (3, 40))
    ref = x.copy()
    ref[runs] = np.take_along_axis(ref[runs], idx[..., None], axis=1)
    K.gather_rows(x, runs, idx)
    assert np.array_equal(x, ref)


@pytest.fixture(scope="module")
def small_geometry(tmp_path_factory):
    from blenav.cli.sim import run as sim_run
    from blenav.configs import compose
    from blenav.data.building import Building
    from blenav.filters.map import MapGeometry

    out = tmp_path_factory.mktemp("kernels") / "small"
    sim_run(compose("sim", "sim=small", "seed=0", f"out={out}", "duration_s=2", "sessions=1", "progress=false"))
    return MapGeometry.from_building(Building.load(out / "buildings" / "small"), 0)


def _points(ix, n, seed):
    rng = np.random.default_rng(seed)
    x0, y0, x1, y1 = ix.x0, ix.y0, ix.x0 + ix.nx * ix.cell, ix.y0 + ix.ny * ix.cell
    xy = np.column_stack([rng.uniform(x0 - 3, x1 + 3, n), rng.uniform(y0 - 3, y1 + 3, n)])
    xy[0] = np.nan
    xy[1, 1] = np.nan
    xy[2] = (1e30, -1e30)
    return xy


def test_grid_cells_and_project_shrunk(small_geometry):
    ix = small_geometry.get_index("grid", 3.0, 1.0)
    xy = _points(ix, 20000, 1)
    with np.errstate(invalid="ignore"):
        assert np.array_equal(ix._cells(xy), ix._cells_numpy(xy))
    assert np.array_equal(ix.room_of(xy), ix.room_of_numpy(xy))
    assert (ix.room_of(xy) >= 0).sum() > 1000
    k = np.random.default_rng(2).integers(0, len(ix.rooms), len(xy))
    assert np.array_equal(ix.project_shrunk(xy, k), ix.project_shrunk_numpy(xy, k), equal_nan=True)


def test_obstacle_snap(small_geometry):
    from blenav.data.floor import FREE, OCCUPIED

    m = small_geometry
    fl = m.floor
    xy = _points(m.get_index("grid", 3.0, 1.0), 20000, 3)
    c = np.random.default_rng(4).integers(0, 4, len(xy)).astype(np.int8)
    with np.errstate(invalid="ignore"):
        occupied = fl.lookup(xy, outside=FREE) == OCCUPIED
        ref = m.snap_free(xy, only=(c > 0) | occupied)
    ox, oy, res = float(fl.origin[0]), float(fl.origin[1]), float(fl.resolution)
    got = xy.copy()
    bad = MAPK.obstacle_candidates(got, c, fl.occupancy, ox, oy, res, FREE, OCCUPIED)
    MAPK.snap_to_free(got, bad, ox, oy, res, fl.shape[0], fl.shape[1], m.nearest_free_pixels())
    assert bad.sum() > 100
    assert np.array_equal(got, ref, equal_nan=True)


def test_inverse_cdf_unsorted_rows():
    """Cumulative sums that overshoot 1 before the last weight (set to 1.0): numpy's own search path."""
    from blenav.filters import resampling as RS

    rng = np.random.default_rng(12)
    w = np.full((3, 10), 0.1)
    w[1, -1] = 0.0
    w[1, -2] += 1e-15  # cumsum passes 1.0 before the end
    for u in (np.sort(rng.random((3, 10)), axis=1), rng.random((3, 10)), np.full((3, 10), 1 - 1e-16)):
        assert np.array_equal(K.inverse_cdf(w, u), RS._inverse_cdf_numpy(w, u))


def test_window_controls():
    """steps._window_controls (Python floats) == the numpy expressions it replaced, bit for bit."""
    from blenav.filters.steps import _window_controls, _window_controls_numpy

    rng = np.random.default_rng(13)
    for i in range(3000):
        k = int(rng.integers(1, 25))
        acc = rng.standard_normal((k, 3)) * 3 + [0, 0, 9.8]
        q = rng.standard_normal((k, 4)) * rng.uniform(0.2, 3)
        if i % 100 == 0:
            acc[-1, 1] = np.nan
        for mw in (1, 4, 5):
            a, h = _window_controls(acc, q, mw)
            b, g = _window_controls_numpy(acc, q, mw)
            assert np.array_equal(a, b, equal_nan=True) and (h == g or (h != h and g != g))


def test_log_normalise_and_ess():
    from blenav.filters.resampling import ess, log_normalise

    rng = np.random.default_rng(14)
    for R, N in ((100, 300), (1, 1000), (3, 7), (2, 1), (4, 129)):
        logw = rng.standard_normal((R, N)) * 30
        logw[0, : N // 2] = -np.inf
        if R > 2:
            logw[1] = -np.inf  # all weights vanished: NaN row
            logw[2, 0] = np.nan
        m = np.max(logw, axis=1, keepdims=True)
        with np.errstate(invalid="ignore"):
            e = np.exp(logw - m)
            s = e.sum(axis=1, keepdims=True)
            w_ref, l_ref = e / s, (m + np.log(s))[:, 0]
        w, lz = log_normalise(logw)
        assert np.array_equal(w, w_ref, equal_nan=True) and np.array_equal(lz, l_ref, equal_nan=True)
        assert np.array_equal(ess(w), 1.0 / np.sum(w_ref * w_ref, axis=1), equal_nan=True)


def _crossed_numpy(wc, p0, p1):
    """The numpy wall test the kernel replaced (one pass per sample along all steps)."""
    d = p1 - p0
    n = int(np.clip(np.ceil(np.max(np.hypot(d[..., 0], d[..., 1]), initial=0.0) / (0.5 * wc.resolution)), 1,
                    wc.max_samples))
    h, w = wc._blocked.shape
    out = np.zeros(p0.shape[:-1], dtype=bool)
    for tk in np.arange(1, n + 1, dtype=float) / n:
        col = np.fmin(np.fmax(np.floor(((p0[..., 0] + tk * d[..., 0]) - wc.origin[0]) / wc.resolution), -1), w)
        rb = np.fmin(np.fmax(np.floor(((p0[..., 1] + tk * d[..., 1]) - wc.origin[1]) / wc.resolution), -1), h)
        out |= wc._blocked_pad[(h - rb.astype(np.int64)) * (w + 2) + (col.astype(np.int64) + 1)]
    return out


@pytest.mark.parametrize("unknown_blocks", [False, True])
def test_walls_crossed(unknown_blocks):
    from blenav.filters.map.walls import WallCrossing

    rng = np.random.default_rng(5)
    for _ in range(10):
        H, W = rng.integers(5, 120, 2)
        occ = rng.choice(np.array([-1, 0, 1], np.int8), size=(H, W), p=[0.1, 0.7, 0.2])
        res, origin = rng.uniform(0.05, 0.5), rng.uniform(-5, 5, 2)
        wc = WallCrossing(occ, res, origin, unknown_blocks=unknown_blocks)
        shape = (int(rng.integers(1, 4)), int(rng.integers(1, 400)), 2)
        p0 = np.stack([rng.uniform(-3, W * res + 3, shape[:2]), rng.uniform(-3, H * res + 3, shape[:2])], -1) + origin
        p1 = p0 + rng.normal(0, rng.uniform(0.01, 4), shape)  # some steps longer than max_samples half-pixels
        np.testing.assert_array_equal(wc.crossed(p0, p1), _crossed_numpy(wc, p0, p1))
        np.testing.assert_array_equal(wc.crossed(p0[0], p0[0]), _crossed_numpy(wc, p0[0], p0[0]))  # zero-length
