"""FusedWalk (issue 30): fixes + PDR odometry + plan + train-walk prior on the walkable grid, no known start."""

from __future__ import annotations

import numpy as np
import pytest

from helpers import as_waypoint_walks, simulate_small

from blenav.crf.grid import build_grid
from blenav.data import Dataset
from blenav.data.session import Session
from blenav.localizers.fingerprint import FingerprintLocalizer
from blenav.localizers.fusedwalk import FusedWalk, fix_log_likelihood, path_prior, survey_distance
from blenav.localizers.inputs import Fixes, RoleFixes, RunInputs


@pytest.fixture(scope="module")
def walks(tmp_path_factory):
    root = as_waypoint_walks(simulate_small(tmp_path_factory.mktemp("fw") / "d", 5, 40, 3))
    ds = Dataset.open(root)
    return [ds.session(i) for i in ds.session_ids]


def _fixes(loc, session):
    est = loc.run(session, 1, 0)
    return Fixes(roles={"both": RoleFixes(est.t, est.position[0], np.sqrt(np.trace(est.cov[0], axis1=1, axis2=2) / 2),
                                           "fix-both", computed=True)})


def test_no_ground_truth_of_the_walk_is_read_and_both_modes_share_one_pass(walks, monkeypatch):
    """The walk's estimates come from its sensors, the plan and the train walks only: reading the scored walk's
    ground truth fails the run; the online row starts at the first fix, the offline row covers the whole walk, and
    the second mode reuses the first's pass."""
    train, test = walks[:2], walks[2]
    knn = FingerprintLocalizer("KNN", features="ble", fix_std="calibrated")
    knn.fit(train)
    inputs = RunInputs(cache={})
    online, offline = FusedWalk("on", mode="online"), FusedWalk("off", mode="offline")
    for m in (online, offline):
        m.fit(train, inputs)
    fx = _fixes(knn, test)
    real = Session.groundtruth

    def guarded(self):
        if self.id == test.id:
            raise AssertionError("the scored walk's ground truth was read")
        return real.fget(self)

    monkeypatch.setattr(Session, "groundtruth", property(guarded))
    e_on = online.run(test, 2, 0, inputs.with_fixes(fx))
    n_cached = len(inputs.cache)
    e_off = offline.run(test, 2, 0, inputs.with_fixes(fx))
    assert len(inputs.cache) == n_cached  # the offline row: the same forward-backward pass
    monkeypatch.setattr(Session, "groundtruth", real)
    assert e_on.t[0] >= fx["both"].t[0] - 0.5 and e_off.t[0] <= e_on.t[0]
    assert np.isfinite(e_on.position).all() and np.isfinite(e_off.position).all()
    assert e_off.position.shape[0] == 2 and np.array_equal(e_off.position[0], e_off.position[1])
    gt = test.positions_at(e_off.t)[:, :2]
    ok = np.isfinite(gt).all(axis=1)
    err_off = np.linalg.norm(e_off.position[0][ok] - gt[ok], axis=1).mean()
    fix_gt = test.positions_at(fx["both"].t)[:, :2]
    err_fix = np.nanmean(np.linalg.norm(fx["both"].xy - fix_gt, axis=1))
    assert err_off < err_fix, (err_off, err_fix)


def test_a_session_without_the_role_is_skipped_with_the_reason(walks):
    from blenav.errors import MissingStream

    m = FusedWalk("off", fix_roles=["wifi", "both"])
    with pytest.raises(MissingStream, match="no fixes of roles"):
        m.run(walks[0], 1, 0, RunInputs(fixes=Fixes(missing={"wifi": "no wifi.csv", "both": "no scans"})))
    with pytest.raises(MissingStream, match="no fixes block"):
        m.run(walks[0], 1, 0, RunInputs())


def test_path_prior_is_a_density_where_the_walks_went(walks):
    g = build_grid(walks[0].floor, cell_m=1.0, max_step_m=3.0)
    p = path_prior(g, walks[:2], blur_m=1.0)
    assert np.isclose(p.sum(), 1.0) and (p >= 0).all()
    on = g.cell_of(walks[0].positions_at(walks[0].groundtruth["t"].to_numpy(float))[:, :2])
    assert p[on].mean() > 5 * p.mean()


def test_survey_distance_is_the_distance_to_the_nearest_surveyed_cell(walks):
    """Every cell's distance to the cells the train walk passed (its positions every 0.5 s) equals brute force, and the
    cell it names is one of them at that distance; without a walk every cell is its own (distance 0)."""
    g = build_grid(walks[0].floor, cell_m=1.0, max_step_m=3.0)
    gt = walks[0].groundtruth
    t = np.arange(float(gt["t"].iloc[0]), float(gt["t"].iloc[-1]) + 1e-9, 0.5)
    on = np.unique(g.cell_of(walks[0].positions_at(t)[:, :2]))
    d, near = survey_distance(g, walks[:1])
    brute = np.sqrt(((g.xy[:, None, :] - g.xy[on][None]) ** 2).sum(-1)).min(axis=1)
    np.testing.assert_allclose(d, brute, atol=1e-9)
    assert np.isin(near, on).all() and (d[on] == 0).all() and d.max() > 3.0
    np.testing.assert_allclose(np.linalg.norm(g.xy - g.xy[near], axis=1), d, atol=1e-9)
    d0, near0 = survey_distance(g, [])
    assert (d0 == 0).all() and np.array_equal(near0, np.arange(g.n_cells))


def test_the_fix_likelihood_is_the_heavy_tailed_gaussian_at_the_expected_cell():
    """log((1 - eps) N(fix; expected_i, (std^2 + extra_i) I) + eps / N) against scipy's density, cell by cell."""
    from scipy.stats import multivariate_normal

    rng = np.random.default_rng(3)
    expected, extra = rng.normal(0.0, 6.0, (40, 2)), rng.uniform(0.0, 25.0, 40)
    fix, sd, eps = np.array([1.5, -2.0]), 2.5, 0.01
    ref = [np.log((1 - eps) * multivariate_normal(e, (sd * sd + v) * np.eye(2)).pdf(fix) + eps / 40)
           for e, v in zip(expected, extra)]
    np.testing.assert_allclose(fix_log_likelihood(expected, extra, fix, sd, eps, 40), ref, rtol=1e-10)


def test_off_the_survey_moves_the_track_only_where_the_walker_can_be_off_it(walks):
    """off_survey (the default) against the plain likelihood (std_per_m 0, project false): with the train walks the
    tracks differ; fitted on no train walk (every cell its own surveyed cell, distance 0) they are identical; bad
    settings are refused."""
    plain = {"off_survey": {"std_per_m": 0.0, "project": False}}
    out = _offline_rows(walks, {"default": {}, "plain": plain})
    assert np.isfinite(out["default"].position).all()
    assert np.abs(out["default"].position - out["plain"].position).max() > 0.05
    test = walks[2]
    knn = FingerprintLocalizer("KNN", features="ble", fix_std="calibrated")
    knn.fit(walks[:2])
    fx = _fixes(knn, test)
    pos = []
    for kw in ({}, plain):
        m = FusedWalk("x", odometry={"step_length": 0.7}, **kw)
        m.fit([], RunInputs(cache={}))
        pos.append(m.run(test, 1, 0, RunInputs(cache={}).with_fixes(fx)).position)
    np.testing.assert_array_equal(pos[0], pos[1])
    for bad, match in (({"std_per_m": -1.0}, "std_per_m"), ({"per_m": 1.0}, "off_survey: unknown key")):
        with pytest.raises(ValueError, match=match):
            FusedWalk("x", off_survey=bad)


def test_a_walk_without_imu_is_smoothed_under_a_random_walk(walks, tmp_path):
    """No imu.csv: the walk is not skipped; its fixes are smoothed under the random walk, and the notes say so."""
    import shutil

    from blenav.data import Dataset as DS

    root = tmp_path / "noimu"
    shutil.copytree(walks[2].root.parent.parent, root)
    (root / "sessions" / walks[2].id / "imu.csv").unlink()
    test = DS.open(root).session(walks[2].id)
    knn = FingerprintLocalizer("KNN", features="ble", fix_std="calibrated")
    knn.fit(walks[:2])
    m = FusedWalk("off")
    m.fit(walks[:2], RunInputs(cache={}))
    est = m.run(test, 1, 0, RunInputs(cache={}).with_fixes(_fixes(knn, test)))
    assert np.isfinite(est.position).all() and "random walk" in est.notes[0]


@pytest.mark.parametrize("bad, match", [({"mode": "both"}, "mode"), ({"fix_roles": []}, "fix_roles"),
                                        ({"motion": {"sigma": 1.0}}, "motion: unknown key"),
                                        ({"layers": {"scale": [1.0]}}, "layers: unknown key"),
                                        ({"fix_outlier": 0.0}, "fix_outlier"), ({"grid": {"max_step_m": 0.5}}, "max_step_m"),
                                        ({"odometry": {"heading": "compass"}}, "heading"),
                                        ({"odometry": {"yaw": "magnetometer"}}, "odometry.yaw")])
def test_settings_are_checked(bad, match):
    with pytest.raises(ValueError, match=match):
        FusedWalk("x", **bad)


def _offline_rows(walks, rows: dict) -> dict:
    """Each of ``rows`` (label -> FusedWalk settings) fitted on the first two walks and run on the third with the KNN's
    fixes: label -> Estimate."""
    train, test = walks[:2], walks[2]
    knn = FingerprintLocalizer("KNN", features="ble", fix_std="calibrated")
    knn.fit(train)
    fx = _fixes(knn, test)
    inputs = RunInputs(cache={})
    out = {}
    for label, kw in rows.items():
        m = FusedWalk(label, **kw)
        m.fit(train, inputs)
        out[label] = m.run(test, 1, 0, inputs.with_fixes(fx))
    return out


def test_offline_estimates_mode_and_viterbi_are_cells_of_the_grid(walks):
    test = walks[2]
    out = _offline_rows(walks, {est: {"estimate": est} for est in ("mean", "mode", "viterbi")})
    for est in out:
        assert np.isfinite(out[est].position).all() and np.isfinite(out[est].cov).all()
    g = build_grid(test.floor, cell_m=1.0, max_step_m=3.0)
    for est in ("mode", "viterbi"):
        d = np.linalg.norm(out[est].position[0][:, None] - g.xy[None], axis=2).min(axis=1)
        assert d.max() < 1e-9, est
    with pytest.raises(ValueError, match="estimate"):
        FusedWalk("x", mode="online", estimate="viterbi")


def test_the_radio_map_option_scores_the_scans_too(walks):
    """radio_map on (a BLE-only floor: the map of BLE fingerprints): the walk's scans join the fixes as observations,
    the track stays finite and the notes say how many scans were scored."""
    train, test = walks[:2], walks[2]
    knn = FingerprintLocalizer("KNN", features="ble", fix_std="calibrated")
    knn.fit(train)
    m = FusedWalk("off", fix_weight=0.5, radio_map={"bandwidth_m": 3.0, "min_count": 1})
    inputs = RunInputs(cache={})
    m.fit(train, inputs)
    est = m.run(test, 1, 0, inputs.with_fixes(_fixes(knn, test)))
    assert np.isfinite(est.position).all()
    n = int(est.notes[0].split(" scans on the radio map")[0].rsplit(" ", 1)[1])
    assert n > 10
    with pytest.raises(ValueError, match="radio_map: unknown key"):
        FusedWalk("x", radio_map={"bandwith_m": 3.0})


@pytest.mark.parametrize("bad, match", [({"prune": 1.5}, "prune"), ({"path_prior": {"floor": 0.0}}, "path_prior"),
                                        ({"motion": {"sigma_per_m": -0.1}}, "sigma_per_m"),
                                        ({"layers": {"heading_offsets_deg": []}}, "layers"),
                                        ({"layers": {"scales": [0.0]}}, "layers"),
                                        ({"fix_weight": 0.0}, "nothing to observe")])
def test_more_settings_are_checked(bad, match):
    with pytest.raises(ValueError, match=match):
        FusedWalk("x", **bad)


def test_the_graph_estimate_refines_the_marginal_means(walks):
    """estimate: graph: a finite track with SPD covariances on the same nodes as the marginal mean; with a prior a
    million times tighter than the marginals it is those means (to 1 cm), and its settings are checked."""
    out = _offline_rows(walks, {"mean": {}, "graph": {"estimate": "graph"},
                                "tight": {"estimate": "graph", "graph": {"prior_scale": 1e-6}}})
    g = out["graph"]
    assert np.isfinite(g.position).all() and np.allclose(g.t, out["mean"].t)
    assert (np.linalg.eigvalsh(g.cov[0]) > 0).all() and "estimate graph" in g.notes[0]
    assert np.abs(g.position - out["mean"].position).max() > 0.05  # the refinement moves the track
    np.testing.assert_allclose(out["tight"].position, out["mean"].position, atol=0.01)
    for bad in ({"kernel": "tukey"}, {"kernel_k": 0.0}, {"odo_sigma_scale": -1.0}, {"prior": 1.0},
                {"prior_scale": float("nan")}, {"prior_scale": -1.0}, {"window_s": 0.0}):
        with pytest.raises(ValueError, match="graph"):
            FusedWalk("x", estimate="graph", graph=bad)
    with pytest.raises(ValueError, match="online: > 0"):
        FusedWalk("x", mode="online", estimate="graph", graph={"prior_scale": 0.0})
    with pytest.raises(ValueError, match="fix_weight 1"):
        FusedWalk("x", estimate="graph", fix_weight=0.5, radio_map={"bandwidth_m": 3.0})


def test_the_online_graph_is_causal_and_bounded_by_its_window(walks):
    """fused-online with estimate: graph: changing every fix after a time leaves every estimate before it unchanged
    (to 1e-9 m: nothing later is read), and a window shorter than the walk changes the estimates (it bounds the
    graph); a lag with it is refused."""
    train, test = walks[:2], walks[2]
    knn = FingerprintLocalizer("KNN", features="ble", fix_std="calibrated")
    knn.fit(train)
    fx = _fixes(knn, test)
    rf = fx.roles["both"]
    t_cut = float(rf.t[len(rf.t) // 2])
    moved = np.where((rf.t > t_cut + 1.0)[:, None], rf.xy + [7.0, -4.0], rf.xy)
    fx2 = Fixes(roles={"both": RoleFixes(rf.t, moved, rf.std, "fix-both", computed=True)})
    out = {}
    for label, kw, f in (("a", {}, fx), ("b", {}, fx2), ("short", {"graph": {"window_s": 5.0}}, fx)):
        m = FusedWalk(label, mode="online", estimate="graph", **kw)
        inputs = RunInputs(cache={})
        m.fit(train, inputs)
        out[label] = m.run(test, 1, 0, inputs.with_fixes(f))
    a, b = out["a"], out["b"]
    before = a.t < t_cut
    assert before.sum() > 5 and np.isfinite(a.position).all()
    np.testing.assert_allclose(a.position[0][before], b.position[0][before], atol=1e-9)
    assert np.abs(a.position[0][~before] - b.position[0][~before]).max() > 0.5  # the later fixes do move it
    assert np.abs(out["short"].position - a.position).max() > 1e-3
    with pytest.raises(ValueError, match="lag_s 0"):
        FusedWalk("x", mode="online", estimate="graph", lag_s=1.0)


def test_the_known_start_bound_pins_the_first_waypoint_and_says_so(walks):
    """start.source first_waypoint (a bound that reads the walk's ground truth, benchmarks/fused_start.py): the
    offline track at the first waypoint's time is within a few std of it, closer than the uniform start's; the notes
    say the start is ground truth; a walk without waypoints is skipped with the reason; settings are checked."""
    from blenav.errors import MissingStream

    test = walks[2]
    out = _offline_rows(walks, {"uniform": {}, "start": {"start": {"source": "first_waypoint", "std_m": 0.5}}})
    gt = test.groundtruth
    t0, xy0 = float(gt["t"].iloc[0]), gt[["x", "y"]].to_numpy(float)[0]
    d = {k: float(np.linalg.norm(e.position[0][np.argmin(np.abs(e.t - t0))] - xy0)) for k, e in out.items()}
    assert d["start"] < 1.5 and d["start"] <= d["uniform"], d
    assert "first waypoint, 0.5 m: ground truth" in out["start"].notes[0] and "uniform start" in out["uniform"].notes[0]

    class NoTruth:
        groundtruth = gt.iloc[:0]
        id = "x"

    m = FusedWalk("s", start={"source": "first_waypoint"})
    with pytest.raises(MissingStream, match="needs the walk's ground truth"):
        m._start_log_likelihood(NoTruth(), build_grid(test.floor, cell_m=1.0, max_step_m=3.0), np.arange(3.0))
    for bad, match in (({"source": "entrance"}, "start.source"), ({"std_m": 0.0}, "start.std_m"),
                       ({"sd": 1.0}, "start: unknown key")):
        with pytest.raises(ValueError, match=match):
            FusedWalk("x", start=bad)


def test_off_survey_evidence_moves_the_walk_off_the_survey_by_its_weight(walks):
    """novelty: fixes whose scans say "off the survey" (a log Bayes factor of +4 each) pull the track onto cells
    farther from the train walks than the same fixes without it; weight 0 and fixes without the ratios leave the
    track as it was; the notes count the fixes read; a ratio array of the wrong length is refused."""
    train, test = walks[:2], walks[2]
    knn = FingerprintLocalizer("KNN", features="ble", fix_std="calibrated")
    knn.fit(train)
    base = _fixes(knn, test)["both"]
    said = RoleFixes(base.t, base.xy, base.std, base.source, computed=True, off_log_ratio=np.full(len(base.t), 4.0))
    g = build_grid(test.floor, cell_m=1.0, max_step_m=3.0)
    sdist, _ = survey_distance(g, train)
    out = {}
    for label, weight, fx in (("plain", 0.0, base), ("zero", 0.0, said), ("novel", 1.0, said), ("unsaid", 1.0, base)):
        m = FusedWalk(label, novelty={"weight": weight, "off_m": 2.0})
        inputs = RunInputs(cache={})
        m.fit(train, inputs)
        out[label] = m.run(test, 1, 0, inputs.with_fixes(Fixes(roles={"both": fx})))
    off = {k: float(sdist[g.cell_of(e.position[0])].mean()) for k, e in out.items()}
    np.testing.assert_allclose(out["zero"].position, out["plain"].position)
    np.testing.assert_allclose(out["unsaid"].position, out["plain"].position)
    assert off["novel"] > off["plain"] + 0.5, off
    assert "off-survey evidence of %d fixes" % len(base.t) in out["novel"].notes[0]
    assert "off-survey evidence of 0 fixes" in out["unsaid"].notes[0]
    with pytest.raises(ValueError, match="off_log_ratio"):
        RoleFixes(base.t, base.xy, base.std, base.source, off_log_ratio=np.zeros(len(base.t) + 1))
    with pytest.raises(ValueError, match="novelty"):
        FusedWalk("x", novelty={"weight": -1.0})


def test_fix_std_scale_is_each_fix_stated_wider(walks):
    """fix_std_scale s (measured with benchmarks/fused_tuning.py; the realwalks rows keep 1: docs/results-ilc20.md)
    weighs every fix as if its std were s times the stated one, in the grid and in the factor graph, offline and
    online: the same estimates as scale 1 on the same fixes with their std multiplied by s; and a fix moved 6 m then
    drags the track less than at scale 1."""
    train, test = walks[:2], walks[2]
    knn = FingerprintLocalizer("KNN", features="ble", fix_std="calibrated")
    knn.fit(train)
    base = _fixes(knn, test)["both"]
    wide = RoleFixes(base.t, base.xy, 2.0 * base.std, base.source, computed=True)
    moved_xy = base.xy.copy()
    j = len(base.t) // 2
    moved_xy[j] += (6.0, 0.0)
    moved = RoleFixes(base.t, moved_xy, base.std, base.source, computed=True)

    def run(fx, scale, mode="offline"):
        m = FusedWalk("x", mode=mode, estimate="graph", fix_std_scale=scale)
        inputs = RunInputs(cache={})
        m.fit(train, inputs)
        return m.run(test, 1, 0, inputs.with_fixes(Fixes(roles={"both": fx})))

    for mode in ("offline", "online"):
        a, b = run(base, 2.0, mode), run(wide, 1.0, mode)
        np.testing.assert_allclose(a.position, b.position, atol=1e-9)
        np.testing.assert_allclose(a.t, b.t)
    pull = {}
    for scale in (1.0, 2.0):
        e0, e1 = run(base, scale), run(moved, scale)
        k = int(np.argmin(np.abs(e0.t - base.t[j])))
        pull[scale] = float(np.hypot(*(e1.position[0, k] - e0.position[0, k])))
    assert pull[2.0] < pull[1.0], pull
