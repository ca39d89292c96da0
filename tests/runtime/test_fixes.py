"""Position fixes (fixes.csv) as a particle-filter measurement (Roy eq. 3.9) and the fixes.csv writer."""

from __future__ import annotations

import re
import shutil

import numpy as np
import pandas as pd
import pytest
from blenav.configs import compose
from omegaconf import open_dict
from scipy.stats import norm

from blenav.data import Dataset, validate
from blenav.data.writer import write_fixes
from blenav.errors import MissingStream
from blenav.eval.harness import build_methods, evaluate
from blenav.filters.measurement import FixLikelihood
from blenav.filters.online import OnlineLocalizer, replay
from blenav.filters.runner import run_session
from helpers import simulate_small, streamed

SOURCE = "gt+noise"
#: a fixes-only method composed like the experiments compose theirs (package defaults)
FIX_METHOD = ["+localizer@methods.fix=particle_filter", "+filter/motion@methods.fix.motion=rw",
              "+filter/measurement@methods.fix.measurements.fix=fix_003",
              "+filter/map@methods.fix.map=uniform", "+methods.fix.label=FIX",
              # a livelier random walk than Table I's: with fixes only, the velocity must follow turns
              "methods.fix.motion.sigma_v=0.2"]


def eval_cfg(*overrides):
    return compose("eval", *["data=unused", "progress=false", *overrides])


def fix_method(*overrides, **filter_over):
    cfg = eval_cfg("experiment=mapfusion_002", *FIX_METHOD, *overrides,
                   *[f"filter.{k}={v}" for k, v in filter_over.items()])
    return build_methods(cfg)["FIX"].method


def noisy_fixes(s, rate_hz=1.0, sigma=1.0, seed=0):
    """Ground truth + N(0, sigma^2) per axis, at rate_hz from 0.5 s (t (F,), xy (F, 2))."""
    t = np.arange(0.5, s.duration_s, 1.0 / rate_hz)
    return t, s.positions_at(t) + np.random.default_rng(seed).normal(0.0, sigma, (len(t), 2))


@pytest.fixture(scope="module")
def small(tmp_path_factory):
    """Two 40 s pedestrian sessions of `small`; the first has fixes of source SOURCE, the second none."""
    out = tmp_path_factory.mktemp("fix") / "small"
    simulate_small(out, 3, 40, 2)
    ds = Dataset.open(out)
    s = ds.session(ds.session_ids[0])
    write_fixes(s.root, *noisy_fixes(s, seed=3), source=SOURCE)
    return out


def _session(root, i=0):
    ds = Dataset.open(root)
    return ds.session(ds.session_ids[i])


# ------------------------------------------------------------------ likelihood


def test_fix_likelihood_is_the_gaussian_log_density_up_to_a_constant():
    """eq. 3.9, Roy: log N(||x - z||; 0, sigma) for every particle, fixes of one step add."""
    xy = np.array([[[0.0, 0.0], [3.0, 4.0], [-1.0, 2.5]], [[10.0, -2.0], [1.0, 1.0], [0.3, 0.4]]])  # (R=2, N=3, 2)
    z = np.array([[0.0, 0.0], [1.0, -1.0]])
    obs = {"fix_xy": z, "fix_std": np.array([np.nan, 0.5]), "fix_source": np.array(["a", "b"])}
    d = np.linalg.norm(xy[..., None, :] - z, axis=-1)  # (R, N, F)

    m = FixLikelihood()  # sigma_m = 3 m, every source
    ll = m.log_likelihood(xy, obs)
    assert ll.shape == (2, 3) and m.n_obs(obs) == 2
    ref = norm.logpdf(d, 0.0, 3.0).sum(axis=-1)
    np.testing.assert_allclose(ll - ll[0, 0], ref - ref[0, 0], rtol=0, atol=1e-12)
    np.testing.assert_allclose(ll, -0.5 * (d**2).sum(-1) / 9.0, rtol=1e-14)

    only_b = FixLikelihood(sigma_m=2.0, source=" b ")  # spaces stripped, like the reader does
    assert only_b.n_obs(obs) == 1
    np.testing.assert_allclose(only_b.log_likelihood(xy, obs), -0.5 * (d[..., 1] / 2.0) ** 2, rtol=1e-14)

    with_std = FixLikelihood(sigma_m=3.0, use_std=True)  # row a: no std -> sigma_m; row b: its std 0.5 m
    np.testing.assert_allclose(with_std.log_likelihood(xy, obs),
                               norm.logpdf(d[..., 0], 0, 3.0) + norm.logpdf(d[..., 1], 0, 0.5)
                               - norm.logpdf(0, 0, 3.0) - norm.logpdf(0, 0, 0.5), rtol=1e-12)

    none = FixLikelihood(source="nope")
    assert none.n_obs(obs) == 0 and not none.log_likelihood(xy, obs).any()
    empty = {"fix_xy": np.zeros((0, 2)), "fix_std": np.zeros(0), "fix_source": np.zeros(0, str)}
    assert m.n_obs(empty) == 0 and m.log_likelihood(xy, empty).shape == (2, 3)
    assert m.n_obs({"rssi_idx": np.zeros(0, int), "rssi": np.zeros(0)}) == 0
    with pytest.raises(ValueError, match="sigma_m"):
        FixLikelihood(sigma_m=0.0)


def test_fix_003_config_builds():
    m = fix_method("methods.fix.measurements.fix.source=ble-4")
    (f,) = m.measurements
    assert isinstance(f, FixLikelihood) and f.sigma_m == 3.0 and f.source == "ble-4" and not f.use_std
    assert not m.needs_imu


# ------------------------------------------------------------------ filtering


def test_fixes_only_filter_tracks_ground_truth(small):
    """Random walk + 1 Hz fixes (ground truth + N(0, 1 m) per axis), global start over the floor."""
    s = _session(small)
    res = run_session(fix_method(), s, n_runs=5, seed=1)
    gt = s.positions_at(res.t)
    err = np.linalg.norm(res.position - gt[None], axis=-1)
    after_first_fix = res.t >= 1.0
    rmse = np.sqrt(np.mean(err[:, after_first_fix] ** 2, axis=1))
    # measured (seed 1): 1.45..1.60 m per run; the fixes themselves are 1.4 m RMS off
    assert rmse.max() < 2.0, rmse
    assert not res.events


def test_missing_fixes_are_skipped_with_the_reason(small, tmp_path):
    s0, s1 = _session(small, 0), _session(small, 1)
    with pytest.raises(MissingStream, match=rf"session {s1.id} has no position fixes.*available sources: none"):
        run_session(fix_method(), s1, n_runs=1, seed=0)
    wrong = rf"session {s0.id} has no fixes of source 'other'.*'{re.escape(SOURCE)}' \(40 rows\)"
    with pytest.raises(MissingStream, match=wrong):
        run_session(fix_method("methods.fix.measurements.fix.source=other"), s0, n_runs=1, seed=0)

    cfg = eval_cfg("experiment=mapfusion_002", f"data={small}", *FIX_METHOD, "runs=2", f"out={tmp_path / 'o'}",
                   "plots=false", "calibration=none", "init_s=5", "filter.n_particles=100")
    with open_dict(cfg):  # the fixes-only method alone
        for k in [k for k in cfg.methods if k != "fix"]:
            del cfg.methods[k]
    res = evaluate(cfg)["methods"]["FIX"]
    assert set(res["per_session"]) == {s0.id}
    assert s1.id in res["skipped"] and s1.id in res["skipped"][s1.id] and "fixes.csv" in res["skipped"][s1.id]


def test_streaming_equals_batch_with_fixes(small, tmp_path):
    """Two fix sources (one on step boundaries, one between, with stds) and BLE: bit-identical paths."""
    root = tmp_path / "two"
    shutil.copytree(small, root)
    s = _session(root)
    t = np.arange(0.37, s.duration_s, 0.7)
    std = np.where(np.arange(len(t)) % 3 == 0, np.nan, 0.8)
    write_fixes(s.root, t, s.positions_at(t) + 0.5, std=std, source="other")
    s = _session(root)

    def method():
        m = fix_method("+filter/measurement@methods.fix.measurements.ps=ps_002",
                       "+methods.fix.measurements.other={_target_: blenav.filters.measurement.FixLikelihood, "
                       "source: other, use_std: true}", n_particles=100)
        assert len(m.measurements) == 3
        return m

    batch = run_session(method(), s, n_runs=3, seed=5)
    online = OnlineLocalizer(method(), s, n_runs=3, seed=5, t_start=0.0)
    events = replay(s)
    assert sum(e[0] == "fix" for e in events) == len(s.fixes) > 0
    pos = streamed(online, events, batch.t[-1])
    assert pos.shape == batch.position.shape
    np.testing.assert_array_equal(pos, batch.position)


# ------------------------------------------------------------------ writer


def test_write_fixes_merges_sources_and_validates(small, tmp_path):
    root = tmp_path / "w"
    shutil.copytree(small, root)
    sdir = _session(root).root
    n_gt = len(_session(root).fixes)
    write_fixes(sdir, [2.25, 0.1, 7.0], [[1, 2], [3, 4], [5, 6]], std=0.5, source="b")
    path = write_fixes(sdir, [1.0, 2.0], np.array([[1.5, 2.5], [3.5, 4.5]]), source="a")
    assert path == sdir / "fixes.csv"
    write_fixes(sdir, [3.0], [[0.0, 0.0]], source="a")  # replaces the two rows of 'a'
    assert not [i for i in validate(root) if i.is_error]
    f = _session(root).fixes
    assert f["source"].value_counts().to_dict() == {SOURCE: n_gt, "b": 3, "a": 1}
    assert (np.diff(f["t"].to_numpy()) >= 0).all()
    a = f[f.source == "a"]
    assert a["t"].tolist() == [3.0] and a["std"].isna().all()  # std None: empty cells
    assert sorted(f[f.source == "b"]["t"]) == [0.1, 2.25, 7.0] and (f[f.source == "b"]["std"] == 0.5).all()
    raw = pd.read_csv(path, keep_default_na=False, dtype=str)
    assert (raw.loc[raw.source == "a", "std"] == "").all() and "nan" not in path.read_text().lower()

    before = path.read_bytes()
    with pytest.raises(ValueError, match="2 of 3 fixes have a NaN"):
        write_fixes(sdir, [1, 2, 3], [[np.nan, 0], [1, 1], [2, np.nan]], source="a")
    with pytest.raises(ValueError, match="non-empty"):
        write_fixes(sdir, [1], [[0, 0]], source=" ")
    with pytest.raises(ValueError, match="shape"):
        write_fixes(sdir, [1, 2], [[0, 0]], source="a")
    assert path.read_bytes() == before  # nothing written


def test_fix_error_stats_recovers_sigma_and_correlation_time():
    from blenav.runtime.fixes import fix_error_stats

    rng = np.random.default_rng(0)
    iid = [rng.normal(0.0, 2.0, (4000, 2)) for _ in range(3)]
    st = fix_error_stats(iid)
    assert st["sigma_m"] == pytest.approx(2.0, rel=0.03) and st["tau_fixes"] == pytest.approx(1.0, abs=0.1)
    # AR(1) errors, phi = 0.9: rho(k) = phi^k; summed while rho >= 0.05 (k <= 28): 1 + 2 sum phi^k
    phi, n, sessions = 0.9, 20000, 8
    e = np.zeros((n, sessions, 2))
    w = rng.normal(0.0, np.sqrt(1 - phi**2), (n, sessions, 2))
    for t in range(1, n):  # the AR recursion is sequential in time (vectorised over sessions)
        e[t] = phi * e[t - 1] + w[t]
    k = np.arange(1, 29)
    want = 1 + 2 * np.sum(phi**k)
    st = fix_error_stats([e[:, i] for i in range(sessions)])
    assert st["tau_fixes"] == pytest.approx(want, rel=0.1) and st["last_lag"] in range(24, 34)
    assert st["sigma_eff_m"] == pytest.approx(st["sigma_m"] * np.sqrt(st["tau_fixes"]))
    with pytest.raises(ValueError, match="NaN"):
        fix_error_stats([np.array([[0.0, np.nan]])])
    with pytest.raises(ValueError, match="no fixes"):
        fix_error_stats([np.zeros((0, 2))])


# ------------------------------------------------------------------ the fix provider


def test_sparse_fixes_leave_a_shared_ble_filter_on_all_beacons(small, tmp_path):
    """The sparse role limits its BLE filter to the subset only while computing: the filter may be shared with
    other roles or be a scored row (a node of fixes.compute equal to a methods row is that row's localizer)."""
    from blenav.eval.fixes import FixProvider

    loc = build_methods(eval_cfg("experiment=mapfusion_002", "filter.n_particles=100"))["PF-PL"]
    assert loc.method.beacons is None
    provider = FixProvider({"sparse": None, "dense": None}, {"sparse": loc, "dense": loc}, 3, tmp_path / "eval")
    s = _session(small)
    t, xy, src = provider.fixes_for("sparse", s)
    assert src == "ps-sparse3" and len(t) > 10 and np.isfinite(xy).all()
    assert loc.method.beacons is None  # restored
    assert len(provider.beacon_ids[str(s.building.id)]) == 3
    _, xy_dense, src_dense = provider.fixes_for("dense", s)
    assert src_dense == "ps-dense" and not np.allclose(xy_dense[: len(xy)], xy[: len(xy_dense)])


def test_a_misspelt_fixes_option_is_an_error_not_a_role(small, tmp_path):
    from blenav.errors import EvalError
    from blenav.eval.harness import build_fix_provider

    cfg = eval_cfg("experiment=leaderboard", f"out={tmp_path}", "+fixes.rate=2")
    with pytest.raises(EvalError, match=r"fixes.rate=2: not a role.*'rate_hz'"):
        build_fix_provider(cfg, build_methods(cfg), tmp_path)
