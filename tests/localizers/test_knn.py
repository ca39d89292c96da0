"""Issue 29: WiFi scans read the way they were heard (blenav.features.fingerprints.heard_scans) and the KNN whose
settings are chosen by leave-walks-out cross-validation on the train walks only (blenav.localizers.knn)."""

from __future__ import annotations

import numpy as np
import pytest

from blenav.configs import compose
from blenav.data import Dataset
from blenav.eval.harness import evaluate
from blenav.features import fingerprints as FP
from blenav.importers import run_import
from blenav.localizers import knn as KNN
from blenav.localizers.fingerprint import CV_GRID, FingerprintLocalizer
from ilc20_helpers import START, coded_walk, walk_lines, write_floor, write_walk

HEARD = {"wifi_age_ref": "scan", "wifi_time": "heard"}  # issue 29's reading (opt-in)


def test_defaults_fingerprint_yaml_and_realwalks():
    """conf/localizer/fingerprint.yaml: scans read at their delivery (5 s age from it), no cross-validation (k = 5
    uniform cosine), the neighbours' std, no covariance for the networks' fixes; experiment=realwalks turns issue 29's
    reading and cross-validation on for its WiFi KNN rows, the calibrated std on for every KNN row and LocNet's std
    head on for its LocNets; Net-WiFi+BLE is PlaceNet on scans read as heard, refitted on every train walk; cv: {} is
    CV_GRID."""
    m = compose("eval", "experiment=realwalks").methods
    for name in ("locnet_wifi", "transnet_wifi", "net_both"):
        assert m[name].cv is None and m[name].net_cov == "calibrated", name
    for name in ("locnet_wifi", "transnet_wifi"):
        assert m[name].net.locnet.std_head and not m[name].refit, name
    nb = m.net_both
    assert (nb.model, nb.refit, nb.wifi_age_ref, nb.wifi_time, nb.min_count) == ("placenet", True, "scan", "heard", 2)
    assert nb.training.models.placenet.locnet._target_ == "blenav.models.PlaceNet"
    assert nb.training.models.placenet.locnet.places == 300
    assert compose("eval", "experiment=mapfusion_002", "+localizer@methods.n=fingerprint").methods.n.net_cov == "none"
    for name in ("locnet_wifi", "transnet_wifi"):
        assert (m[name].wifi_max_age_s, m[name].wifi_age_ref, m[name].wifi_time) == (5.0, "delivery", "delivery")
    for name in ("knn_wifi", "knn_both"):
        assert m[name].cv == {} and (m[name].wifi_age_ref, m[name].wifi_time, m[name].fix_std) == \
            ("scan", "heard", "calibrated"), name
    assert m.knn_ble.cv is None and m.knn_ble.fix_std == "calibrated"
    plain = compose("eval", "experiment=mapfusion_002", "+localizer@methods.knn=fingerprint").methods.knn
    assert plain.cv is None and (plain.wifi_age_ref, plain.wifi_time, plain.fix_std) == ("delivery", "delivery",
                                                                                          "neighbours")
    loc = FingerprintLocalizer("KNN", cv=None)
    assert loc.cv is None and (loc.k, loc.weights, loc.metric) == (5, "uniform", "cosine")
    assert FingerprintLocalizer("KNN", cv={}).cv == CV_GRID
    assert FingerprintLocalizer("KNN", cv={"k": 3}).cv == {**CV_GRID, "k": [3]}
    with pytest.raises(ValueError, match="unknown keys"):
        FingerprintLocalizer("KNN", cv={"kk": [3]})


def test_knn_fixes_at_the_heard_times_when_asked(coded):
    """The coded walks' scans are delivered at 0.5 .. 5.5 s and heard at 0.2 .. 5.2 s (median t_seen of their
    rows): the default KNN's fixes are at the deliveries, issue 29's at the heard times."""
    train, test = [coded.session("mall_F1_walkA")], coded.session("mall_F1_walkC")
    old = FingerprintLocalizer("KNN-1", k=1)
    settings = old.fit(train)["settings"]  # the report of before issue 29: no reading keys
    assert "wifi_age_ref" not in settings and "wifi_time" not in settings and settings["wifi_max_age_s"] == 5.0
    np.testing.assert_allclose(old.run(test, 1, seed=0).t, np.arange(6) + 0.5)
    new = FingerprintLocalizer("KNN-1", k=1, **HEARD)
    rep = new.fit(train)
    assert (rep["settings"]["wifi_age_ref"], rep["settings"]["wifi_time"]) == ("scan", "heard")
    est = new.run(test, 1, seed=0)
    np.testing.assert_allclose(est.t, np.arange(6) + 0.2)
    # labels take the heard times too: the train walk's position at 0.2 .. 4.2 s (x = 5 + 4 (t - 0.01) m)
    assert rep["floors"]["mall/F1"]["windows"] == 5
    np.testing.assert_allclose(est.position[0, :5, 0], 5.0 + 4.0 * (est.t[:5] - 0.01), atol=1e-9)


def test_stale_readings_dropped_and_the_scan_placed_when_heard():
    # one delivery at t = 10 s: access points heard 0.5, 1.0, 1.5 s before it (this scan), one 4 s before the newest
    # reading (kept at 5 s), one 9.5 s before it (stale: cached from an earlier scan), one of unknown time (kept);
    # a second delivery at 12 s whose rows have no t_seen at all keeps its delivery time
    t = np.array([10.0, 10.0, 10.0, 10.0, 10.0, 10.0, 12.0])
    seen = np.array([9.5, 9.0, 8.5, 5.5, 0.0, np.nan, np.nan])
    cfg = FP.FingerprintConfig(wifi_max_age_s=5.0, **HEARD)
    out = FP.heard_scans(t, seen, cfg)
    # kept: 9.5, 9.0, 8.5, 5.5 (4.0 s before the newest, 9.5), and the unknown one: at their median t_seen, 8.75 s
    np.testing.assert_allclose(out, [8.75, 8.75, 8.75, 8.75, np.nan, 8.75, 12.0])
    # a 3 s threshold also drops the 4 s old reading: median of 9.5, 9.0, 8.5
    np.testing.assert_allclose(FP.heard_scans(t, seen, FP.FingerprintConfig(wifi_max_age_s=3.0, **HEARD)),
                               [9.0, 9.0, 9.0, np.nan, np.nan, 9.0, 12.0])
    # the pre-issue-29 rule: age from the delivery time (the 5.5 s reading 4.5 s old: kept), fix at the delivery time
    # the pre-issue-29 rule, still the default: age from the delivery time (the 5.5 s reading 4.5 s old: kept), fix
    # at the delivery time
    old = FP.FingerprintConfig()
    assert (old.wifi_max_age_s, old.wifi_age_ref, old.wifi_time) == (5.0, "delivery", "delivery")
    np.testing.assert_allclose(FP.heard_scans(t, seen, old), [10.0, 10.0, 10.0, 10.0, np.nan, 10.0, 12.0])
    older = FP.FingerprintConfig(wifi_max_age_s=4.0, wifi_age_ref="delivery", wifi_time="delivery")
    np.testing.assert_allclose(FP.heard_scans(t, seen, older), [10.0, 10.0, 10.0, np.nan, np.nan, 10.0, 12.0])
    # no threshold: everything kept, at the median of all known t_seen
    np.testing.assert_allclose(FP.heard_scans(t, seen, FP.FingerprintConfig(wifi_max_age_s=None, **HEARD))[:6], 8.5)
    with pytest.raises(ValueError, match="wifi_age_ref"):
        FP.FingerprintConfig(wifi_age_ref="now")


def test_readings_use_the_heard_time(tmp_path):
    """Through the importer (wifi.csv t_seen): each delivery (every second from 0.5 s) holds two access points heard
    0.3 and 2.0 s before it: one step at their median, 1.15 s before the delivery; a third reading, 6.8 s older than
    the first scan's newest, is stale and dropped."""
    d = write_floor(tmp_path / "raw")
    t = START + 500
    stale = (t, f"{t}\tTYPE_WIFI\told\tcc:00:00:00:00:09\t-40\t2412\t{t - 7100}")
    write_walk(d, "w", walk_lines(start=START, extra=[stale]))
    run_import("ilc20", d, tmp_path / "ds")
    s = Dataset.open(tmp_path / "ds").session("mall_F1_w")
    heard = FP.FingerprintConfig(**HEARD)
    rd = FP.readings(s, heard)
    assert "wifi:cc:00:00:00:00:09" not in set(rd["feature"]) and len(rd) == 12
    np.testing.assert_allclose(FP.step_times(rd, heard), np.arange(6) + 0.5 - 1.15, atol=1e-9)
    # the default (pre-issue 29): the stale row is 7.1 s older than its delivery (dropped too), steps at delivery
    rd = FP.readings(s, FP.FingerprintConfig())
    assert "wifi:cc:00:00:00:00:09" not in set(rd["feature"]) and len(rd) == 12
    np.testing.assert_allclose(FP.step_times(rd, FP.FingerprintConfig()), np.arange(6) + 0.5, atol=1e-9)
    late = FP.readings(s, FP.FingerprintConfig(wifi_max_age_s=None, wifi_time="delivery"))
    assert len(late) == 13 and np.isclose(late["t"].min(), 0.5)


def _walks(n_walks=6, n_steps=20, seed=0):
    """Windows of walks along x on lines y = 2 * walk, position-coded fingerprints plus noise: (S, xy, t, walk_of,
    waypoints)."""
    rng = np.random.default_rng(seed)
    S, xy, t, wo, wps = [], [], [], [], []
    centres = np.linspace(0, 40, 12)
    for w in range(n_walks):
        x = np.linspace(0, 38, n_steps)
        y = np.full(n_steps, 2.0 * (w % 3))
        u = 60.0 * np.exp(-((x[:, None] - centres[None]) ** 2) / 20.0) + rng.normal(0, 2, (n_steps, 12))
        S.append(np.clip(u, 0, None)[:, :, None])
        xy.append(np.c_[x, y])
        t.append(np.arange(n_steps, dtype=float))
        wo.append(np.full(n_steps, w))
        wps.append((np.arange(n_steps, dtype=float)[::4], np.c_[x, y][::4]))
    return np.concatenate(S), np.concatenate(xy), np.concatenate(t), np.concatenate(wo), wps


def test_cross_validation_picks_the_better_k_and_scores_only_what_it_is_given():
    S, xy, t, wo, wps = _walks()
    grid = KNN.grid(["cosine"], [1, 40], ["uniform"], [1.0])
    best, table = KNN.cross_validate(S, xy, t, wo, wps, grid, np.zeros(12, bool), -100.0, folds=3)
    assert best.k == 1 and table[0]["cv_error_m"] < table[1]["cv_error_m"]
    # the score is a function of the arrays handed over only: relabelling rows outside them changes nothing, and
    # changing one fitted walk's waypoints changes its score
    again = KNN.cross_validate(S.copy(), xy.copy(), t, wo, wps, grid, np.zeros(12, bool), -100.0, folds=3)[1]
    assert again == table
    moved = [(a, b + 5.0) if i == 0 else (a, b) for i, (a, b) in enumerate(wps)]
    assert KNN.cross_validate(S, xy, t, wo, moved, grid, np.zeros(12, bool), -100.0, folds=3)[1] != table


def test_cross_validation_scores_are_the_per_walk_definition():
    """The scores are those of the module doc computed the plain way (per held-out walk: a KNN of the other folds'
    windows, fixes interpolated at the walk's waypoints), bit for bit, for every metric, k and weighting."""
    S, xy, t, wo, wps = _walks()
    is_ble = np.arange(12) >= 8
    grid = KNN.grid(["cosine", "powed", "euclidean"], [1, 3, 40], ["uniform", "distance", 0.05], [0.5, 1.0])
    _, table = KNN.cross_validate(S, xy, t, wo, wps, grid, is_ble, -100.0, folds=3, seed=4)
    fold = np.random.default_rng(4).permutation(np.arange(len(wps)) % 3)
    for s, row in zip(grid, table):
        X = KNN.represent(S, s.metric, is_ble, s.ble_weight, -100.0)
        err = []
        for f in range(3):
            tr = fold[wo] != f
            for w in np.flatnonzero(fold == f):
                o = np.flatnonzero(wo == w)
                o = o[np.argsort(t[o], kind="stable")]
                idx, d2 = KNN.neighbours(X[o], X[tr], 40)
                err.append(KNN.waypoint_errors(t[o], KNN.combine(idx, d2, xy[tr], s.k, s.weights)[0], *wps[w]))
        assert row["cv_error_m"] == np.concatenate(err).mean(), s


def test_knn_cv_sees_only_the_train_walks(tmp_path, monkeypatch):
    """Through the harness with a split: the cross-validation gets the train walks' windows and waypoints only (the
    test walk lies on its own line, y = 9 m: none of its labels or waypoints reaches the choice); the chosen setting
    is in the training report."""
    d = write_floor(tmp_path / "raw")
    for k, y in enumerate((5.0, 5.0, 7.0, 9.0)):
        write_walk(d, f"walk{k}", coded_walk(START + k * 100_000, y))
    run_import("ilc20", d, tmp_path / "ds")
    seen = []
    real = KNN.cross_validate

    def spy(S, xy, t, walk_of, waypoints, *a, **kw):
        seen.append((xy.copy(), [w[1].copy() for w in waypoints]))
        return real(S, xy, t, walk_of, waypoints, *a, **kw)

    monkeypatch.setattr(KNN, "cross_validate", spy)
    cfg = compose("eval", "experiment=mapfusion_002", f"data={tmp_path / 'ds'}", "runs=1", f"out={tmp_path / 'out'}",
                  "plots=false", "progress=false", "calibration=none", "methods.pf_pl=null", "methods.pf_pl_map=null",
                  "methods.pf_ps=null", "methods.pf_ps_map=null", "methods.pf_pl_offset=null",
                  "methods.pf_ps_map_offset=null", "+split={train: [mall_F1_walk0, mall_F1_walk1, mall_F1_walk2]}",
                  "+localizer@methods.knn=fingerprint", "methods.knn.label=KNN-WiFi", "methods.knn.cv={}",
                  "scoring.hold_ends=true")
    res = evaluate(cfg)
    assert list(res["sessions"]) == ["mall_F1_walk3"]
    assert len(seen) == 1
    xy, wps = seen[0]
    assert len(wps) == 3 and not np.isclose(xy[:, 1], 9.0).any()
    assert all(not np.isclose(w[:, 1], 9.0).any() for w in wps)
    cv = res["methods"]["KNN-WiFi"]["training"]["floors"]["mall/F1"]["cv"]
    assert cv["chosen"]["k"] in (1, 3, 5, 7, 10, 15, 20) and len(cv["table"]) == 2 * 7 * 5


def test_knn_fit_cov_is_the_neighbours_spread():
    S = np.array([[[1.0], [0.0]], [[1.0], [0.0]], [[0.0], [1.0]]])  # (3, F=2, H=1)
    xy = np.array([[0.0, 0.0], [2.0, 0.0], [50.0, 50.0]])
    predict = KNN.fit(S, xy, KNN.KnnSetting("cosine", 2, "uniform"), np.zeros(2, bool), -100.0, cov_floor_m=0.5)
    est, cov = predict(np.array([[[3.0], [0.0]]]))
    np.testing.assert_allclose(est, [[1.0, 0.0]])
    np.testing.assert_allclose(cov[0], [[1.0 + 0.25, 0.0], [0.0, 0.25]])
    with pytest.raises(ValueError, match="weights"):
        KNN.KnnSetting(weights="nearest")


def test_std_model_recovers_the_noise_law_and_covers_as_stated():
    """Errors drawn with std = exp(0.5 + 0.8 d1) (2-D isotropic): the fitted model finds those coefficients, and its
    1-sigma / 2-sigma regions hold 39.3 % / 86.5 % of fresh errors of the same law."""
    rng = np.random.default_rng(0)
    n = 20_000
    spread, d1 = rng.uniform(0, 5, n), rng.uniform(0, 2, n)
    sd = np.exp(0.5 + 0.8 * d1)
    err = np.hypot(*(rng.normal(0, 1, (2, n)) * sd))
    model = KNN.fit_std_model(err, spread, d1)
    np.testing.assert_allclose(model.c, [0.5, 0.0, 0.8], atol=0.05)
    fresh = np.hypot(*(rng.normal(0, 1, (2, n)) * sd))
    r = fresh / model.std(spread, d1)
    assert abs(np.mean(r <= 1) - (1 - np.exp(-0.5))) < 0.015 and abs(np.mean(r <= 2) - (1 - np.exp(-2))) < 0.015


def test_out_of_fold_errors_use_the_other_folds_only():
    """Each walk's windows are predicted by a model of the other folds: with k = 1 on walks that repeat one line, the
    out-of-fold error of a window is its distance to the nearest label of another walk, never 0 (its own)."""
    S, xy, t, wo, _ = _walks(n_walks=6)
    err, spread, d1 = KNN.out_of_fold(S, xy, wo, KNN.KnnSetting("cosine", 1, "uniform"), np.zeros(12, bool), -100.0,
                                      cov_floor_m=0.5, folds=3)
    assert len(err) == len(S) and (spread == 0).all() and (d1 > 0).all()
    fold = np.random.default_rng(0).permutation(np.arange(6) % 3)
    X = KNN.represent(S, "cosine", np.zeros(12, bool), 1.0, -100.0)
    for i in (0, 25, 77):
        other = fold[wo] != fold[wo[i]]
        j = np.flatnonzero(other)[np.argmin(((X[other] - X[i]) ** 2).sum(1))]
        assert np.isclose(err[i], np.hypot(*(xy[j] - xy[i])))


def test_calibrated_fix_std_is_reported_and_is_the_cov(coded):
    """fix_std: calibrated: the training report has the model and its out-of-fold coverage; each fix's covariance is
    std^2 I of that model."""
    train, test = [coded.session("mall_F1_walkA"), coded.session("mall_F1_walkB")], coded.session("mall_F1_walkC")
    loc = FingerprintLocalizer("KNN", k=1, fix_std="calibrated")
    rep = loc.fit(train)
    fs = next(iter(rep["floors"].values()))["fix_std"]
    assert isinstance(fs, dict) and len(fs["c"]) == 3 and 0 <= fs["coverage_1sigma"] <= fs["coverage_2sigma"] <= 1
    est = loc.run(test, 1, 0)
    c = est.cov[0]
    np.testing.assert_allclose(c[:, 0, 1], 0.0)
    np.testing.assert_allclose(c[:, 0, 0], c[:, 1, 1])
    with pytest.raises(ValueError, match="fix_std"):
        FingerprintLocalizer("KNN", fix_std="wild")


def test_std_model_fit_survives_outliers_and_degenerate_inputs():
    """One signal distance 100x the others, errors that grow fast with it, constant features, all-zero errors, too
    few fixes: a finite model every time (no singular Hessian, no overflow)."""
    rng = np.random.default_rng(1)
    n = 500
    d1 = rng.uniform(0, 1, n)
    d1[0] = 100.0
    err = np.abs(rng.normal(0, 1, n)) * np.exp(3.0 * np.minimum(d1, 5.0))
    for e, sp, d in ((err, rng.uniform(0, 3, n), d1), (np.abs(rng.normal(0, 2, n)), np.zeros(n), np.ones(n)),
                     (np.zeros(n), rng.uniform(0, 3, n), d1), (np.array([3.0, 4.0]), np.zeros(2), np.zeros(2))):
        m = KNN.fit_std_model(e, sp, d)
        assert np.isfinite(m.c).all() and np.isfinite(m.std(sp, d)).all(), m.c
    m = KNN.fit_std_model(np.array([3.0, 4.0]), np.zeros(2), np.zeros(2))
    assert np.isclose(m.std(np.zeros(1), np.zeros(1))[0], np.sqrt((9 + 16) / 2 / 2), rtol=1e-3)


def test_novelty_model_recovers_a_logistic_law_and_its_log_ratio_is_bayes():
    """P(off | d1) = sigmoid(-3 + 4 d1) drawn on 20,000 windows: the fit finds (a, b) and the base rate; its log ratio
    is log p(d1 | off) - log p(d1 | on), i.e. logit P(off | d1) - logit P(off); too few windows on a side: None."""
    rng = np.random.default_rng(2)
    d1 = rng.uniform(0, 1.5, 20_000)
    off = rng.uniform(size=d1.size) < 1 / (1 + np.exp(-(-3 + 4 * d1)))
    survey = np.where(off, rng.uniform(6, 20, d1.size), rng.uniform(0, 4, d1.size))
    m = KNN.fit_novelty_model(d1, survey, off_m=5.0)
    np.testing.assert_allclose([m.a, m.b], [-3, 4], atol=0.15)
    assert abs(m.base - off.mean()) < 1e-12
    d = np.array([0.2, 1.0])
    p = 1 / (1 + np.exp(-(m.a + m.b * d)))  # P(off | d1)
    np.testing.assert_allclose(m.log_ratio(d), np.log(p / (1 - p)) - np.log(m.base / (1 - m.base)))
    assert KNN.fit_novelty_model(d1[:50], np.zeros(50)) is None  # nobody off the survey: nothing to learn
    assert KNN.fit_novelty_model(np.r_[d1[:50], 9.0], np.r_[np.zeros(50), 9.0]) is None  # one off: too few


def test_out_of_fold_survey_measures_against_the_other_folds_walks_only():
    """Each window's survey distance is its label's distance to the nearest path point of another fold's walk (the
    lines y = 0, 2, 4 of _walks: a walk's own line never counts), and its d1 the signal distance to the nearest window
    of those walks, brute force."""
    S, xy, t, wo, _ = _walks(n_walks=6)
    X = KNN.represent(S, "cosine", np.zeros(12, bool), 1.0, -100.0)
    paths = [np.c_[np.linspace(0, 38, 77), np.full(77, 2.0 * (w % 3))] for w in range(6)]
    d1, sm = KNN.out_of_fold_survey(X, xy, wo, paths, folds=3, seed=0)
    assert len(d1) == len(X)
    fold = np.random.default_rng(0).permutation(np.arange(6) % 3)
    for i in (0, 33, 101):
        other = fold[wo] != fold[wo[i]]
        pts = np.concatenate([paths[w] for w in range(6) if fold[w] != fold[wo[i]]])
        assert np.isclose(sm[i], np.hypot(*(pts - xy[i]).T).min())
        assert np.isclose(d1[i], np.sqrt(((X[other] - X[i]) ** 2).sum(1).min()))


def test_the_calibrated_knn_states_each_fix_off_survey_evidence(coded):
    """fix_std: calibrated: a fitted novelty model's log ratio is an output of every fix (what the fused rows read),
    from the fix's own signal distance to the survey; without the model the output is absent."""
    train, test = [coded.session("mall_F1_walkA"), coded.session("mall_F1_walkB")], coded.session("mall_F1_walkC")
    loc = FingerprintLocalizer("KNN", k=1, fix_std="calibrated")
    loc.fit(train)
    model = next(iter(loc.floors.values())).predict
    model.novelty_model = None
    assert "off_survey_log_ratio" not in loc.run(test, 1, 0).outputs
    model.novelty_model = KNN.NoveltyModel(-2.0, 3.0, 0.2)
    est = loc.run(test, 1, 0)
    S, _ = loc.heard_windows(test, next(iter(loc.floors.values())).columns)
    lr = est.outputs["off_survey_log_ratio"]
    assert lr.shape == est.t.shape and np.isfinite(lr).all()
    d1 = KNN.nearest_distance(model.represent(S), model.X)  # the fix's own signal distance to the survey
    np.testing.assert_allclose(lr, model.novelty_model.log_ratio(d1))
    xy, cov = model(S)  # the estimates are the plain KNN's, whether or not it states the evidence
    np.testing.assert_allclose(est.position[0], xy)


def test_the_fix_provider_hands_the_off_survey_evidence_to_every_role_of_the_knn(coded, tmp_path):
    """blenav.eval.fixes: fixes computed by a KNN that states its off-survey evidence carry it (the same array for two
    roles sharing the localizer); a KNN without the model (the neighbours' std) carries none."""
    from blenav.eval.fixes import FixProvider

    train, test = [coded.session("mall_F1_walkA"), coded.session("mall_F1_walkB")], coded.session("mall_F1_walkC")
    loc = FingerprintLocalizer("KNN", k=1, fix_std="calibrated")
    loc.fit(train)
    next(iter(loc.floors.values())).predict.novelty_model = KNN.NoveltyModel(-2.0, 3.0, 0.2)
    est = loc.run(test, 1, 0)
    fp = FixProvider({"both": None, "again": None}, {"both": loc, "again": loc}, None, tmp_path)
    got = fp.resolve(["both", "again"], test)
    for role in ("both", "again"):
        np.testing.assert_allclose(got[role].off_log_ratio, est.outputs["off_survey_log_ratio"])
        np.testing.assert_allclose(got[role].xy, est.position[0])
    plain = FingerprintLocalizer("KNN", k=1)  # the neighbours' std: no novelty model
    plain.fit(train)
    assert FixProvider({"x": None}, {"x": plain}, None, tmp_path).resolve(["x"], test)["x"].off_log_ratio is None
