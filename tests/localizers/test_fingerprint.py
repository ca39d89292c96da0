"""Fingerprinting on real-walk datasets (blenav.localizers.fingerprint, blenav.features.fingerprints) and the floor
classifier (blenav.eval.floors): synthetic ILC path files with position-coded access points (exact neighbours),
the harness with a train/test split, and a few real walks of ../shared (marker ``realdata``)."""

from __future__ import annotations

import re
import tarfile

import numpy as np
import pandas as pd
import pytest

from blenav.configs import compose
from blenav.data import Dataset
from blenav.errors import MissingStream
from blenav.eval.floors import classify_floors
from blenav.eval.harness import evaluate
from blenav.features import fingerprints as FP
from blenav.importers import run_import
from blenav.localizers.fingerprint import FingerprintLocalizer
from helpers import training_node
from ilc20_helpers import START, coded_walk, write_floor, write_walk

def test_step_vectors_average_a_scan_and_a_ble_window():
    rd = pd.DataFrame({"t": [1.0, 1.0, 2.0, 0.5, 1.8, 2.9], "feature": ["wifi:a", "wifi:b", "wifi:a", "ble:x", "ble:x", "ble:x"],
                       "rssi": [-40.0, -70.0, -60.0, -80.0, -60.0, -101.0], "kind": ["wifi"] * 3 + ["ble"] * 3})
    cfg = FP.FingerprintConfig(features="both", ble_window_s=1.0)
    tau = FP.step_times(rd, cfg)
    np.testing.assert_allclose(tau, [1.0, 2.0])
    V = FP.step_vectors(rd, {"ble:x": 0, "wifi:a": 1, "wifi:b": 2}, tau, cfg)
    # step 1: the scan at 1.0 s, BLE of [0, 1] s (20); step 2: the scan at 2.0 s, BLE of [1, 2] s (40)
    np.testing.assert_allclose(V, [[20.0, 60.0, 30.0], [40.0, 40.0, 0.0]])
    ble = FP.FingerprintConfig(features="ble", ble_window_s=2.0, ble_step_s=1.0)
    tb = FP.step_times(rd[rd["kind"] == "ble"], ble)
    np.testing.assert_allclose(tb, [0.5, 1.5, 2.5])
    Vb = FP.step_vectors(rd[rd["kind"] == "ble"], {"ble:x": 0}, tb, ble)
    # [-1.5, 0.5]: 20; [-0.5, 1.5]: 20; [0.5, 2.5]: (20 + 40) / 2; -101 dBm is heard, barely (floor_u)
    np.testing.assert_allclose(Vb[:, 0], [20.0, 20.0, 30.0])
    np.testing.assert_allclose(FP.step_vectors(rd[rd["kind"] == "ble"], {"ble:x": 0}, np.array([3.0]), ble), [[20.25]])
    assert FP.vocabulary([rd], min_count=2) == ["ble:x", "wifi:a"]
    assert FP.vocabulary([rd], max_features=1) == ["ble:x"]


def test_knn_finds_the_exact_neighbours(coded):
    train = [coded.session("mall_F1_walkA"), coded.session("mall_F1_walkB")]
    test = coded.session("mall_F1_walkC")
    one = FingerprintLocalizer("KNN-1", k=1)
    rep = one.fit(train[:1])
    fl = rep["floors"]["mall/F1"]
    # scans at 0.5 .. 5.5 s; the one at 5.5 s lies after the last waypoint (5.01 s): dropped from training
    assert fl["windows"] == 5 and fl["dropped_outside_waypoints"] == 1 and fl["n_features"] == 7
    est = one.run(test, 3, seed=0)
    np.testing.assert_allclose(est.t[:5], [0.5, 1.5, 2.5, 3.5, 4.5])
    assert est.position.shape == (3, 6, 2) and np.array_equal(est.position[0], est.position[2])
    want = np.stack([5.0 + 4.0 * (est.t[:5] - 0.01), np.full(5, 5.0)], -1)  # the train walk's labels
    np.testing.assert_allclose(est.position[0, :5], want, atol=1e-9)
    # k = 2 over two walks: the mean of the two identical fingerprints' positions (y = 5 and 7), their spread
    two = FingerprintLocalizer("KNN-2", k=2, cov_floor_m=0.5)
    two.fit(train)
    est = two.run(test, 1, seed=0)
    inner = (est.t > 0.4) & (est.t < 4.6)
    np.testing.assert_allclose(est.position[0, inner, 1], 6.0, atol=1e-9)
    np.testing.assert_allclose(est.cov[0, inner], np.broadcast_to([[0.25, 0.0], [0.0, 1.25]], (5, 2, 2)), atol=1e-9)
    assert est.t[0] == 0.5 and est.t[-1] == 5.5  # the first and last scans: nothing padded to the session's ends
    with pytest.raises(MissingStream, match="no model for floor"):
        two.floors = {"other/F9": two.floors["mall/F1"]}
        two.run(test, 1, seed=0)


def test_fit_and_run_through_the_harness_with_a_split(tmp_path):
    d = write_floor(tmp_path / "raw")
    for k in range(3):  # three walks of one geometry: whichever two train, the third is found exactly
        write_walk(d, f"walk{k}", coded_walk(START + k * 100_000, 5.0))
    run_import("ilc20", d, tmp_path / "ds")
    cfg = compose("eval", "experiment=mapfusion_002", f"data={tmp_path / 'ds'}", "runs=2", f"out={tmp_path / 'out'}",
                  "plots=false", "progress=false", "calibration=none", "methods.pf_pl=null", "methods.pf_pl_map=null",
                  "methods.pf_ps=null", "methods.pf_ps_map=null", "methods.pf_pl_offset=null",
                  "methods.pf_ps_map_offset=null", "+split.train_fraction=0.6", "+split.seed=0",
                  "+localizer@methods.knn=fingerprint", "methods.knn.k=1", "methods.knn.label=KNN-WiFi",
                  "scoring.hold_ends=true")
    res = evaluate(cfg)
    m = res["methods"]["KNN-WiFi"]
    assert len(res["split"]["train"]) == 2 and len(res["sessions"]) == 1
    tr = m["training"]
    assert "interpolated linearly between the surveyed waypoints" in tr["labels"]
    assert tr["floors"]["mall/F1"]["train_walks"] == 2
    # waypoints at 0.01 / 2.51 / 5.01 s (x = 5, 15, 25 m): the first held from the scan at 0.5 s (x = 6.96) at scoring,
    # the second exact, the third between the scans at 4.5 and 5.5 s, both found at x = 22.96 m (the last scan
    # repeats the code of the one before)
    assert m["error_m"]["mean"] == pytest.approx((1.96 + 0.0 + 2.04) / 3, abs=1e-6)


def _two_floors(tmp_path):
    raw = tmp_path / "raw"
    for f, prefix in (("F1", "aa:01"), ("F2", "bb:02")):
        d = write_floor(raw, floor=f)
        for k in range(3):
            write_walk(d, f"w{f}{k}", coded_walk(START + (10 * (f == "F2") + k) * 100_000, 5.0 + k, prefix))
    run_import("ilc20", raw / "mall", tmp_path / "ds")
    return Dataset.open(tmp_path / "ds")


def test_floor_classifier_on_two_floors(tmp_path):
    ds = _two_floors(tmp_path)
    ss = list(ds.sessions())
    train = [s for s in ss if s.id.endswith(("0", "1"))]
    test = [s for s in ss if s.id.endswith("2")]
    res = classify_floors(train, test, features="wifi", k=1)
    # the two shared access points are on both floors; the coded ones decide
    assert res["accuracy"] == 1.0 and res["walks"] == 2 and res["scan_accuracy"] == 1.0
    assert res["confusion"] == {"mall/F1": {"mall/F1": 1}, "mall/F2": {"mall/F2": 1}}
    with pytest.raises(ValueError, match="two or more"):
        classify_floors(train[:1], test)
    cfg = compose("eval", "experiment=mapfusion_002", f"data={ds.root}", "runs=1", f"out={tmp_path / 'out'}",
                  "plots=false", "progress=false", "calibration=none", "methods.pf_pl=null", "methods.pf_pl_map=null",
                  "methods.pf_ps=null", "methods.pf_ps_map=null", "methods.pf_pl_offset=null",
                  "methods.pf_ps_map_offset=null", "split={train_fraction: 0.6, seed: 0}",
                  "floor_classifier={features: wifi, k: 1}", "+localizer@methods.knn=fingerprint")
    fa = evaluate(cfg)["floor_accuracy"]
    assert fa["accuracy"] == 1.0 and fa["walks"] == 2 and set(fa["per_floor"]) == {"mall/F1", "mall/F2"}


@pytest.mark.realdata
def test_real_walks_knn_wifi(raw_dir, tmp_path):
    """Twelve walks of site1/F1 unpacked into a temporary folder: KNN on WiFi trained on 8, run on 4."""
    tgz = raw_dir / "ilc20" / "site1_F1.tar.gz"
    if not tgz.is_file():
        pytest.skip(f"{tgz} is absent")
    root, n = tmp_path / "raw", 0
    with tarfile.open(tgz, "r|gz") as tf:
        for m in tf:
            take = m.name.endswith(("floor_info.json", "geojson_map.json")) or (m.name.endswith(".txt") and n < 12)
            if m.isfile() and take:
                p = root / m.name
                p.parent.mkdir(parents=True, exist_ok=True)
                p.write_bytes(tf.extractfile(m).read())
                n += m.name.endswith(".txt")
    from blenav.eval.metrics import waypoint_metrics

    run_import("ilc20", root / "site1" / "F1", tmp_path / "ds")
    ss = list(Dataset.open(tmp_path / "ds").sessions(labelled=True))
    loc = FingerprintLocalizer("KNN-WiFi", features="wifi", k=3)
    rep = loc.fit(ss[:8])
    fl = rep["floors"]["site1/F1"]
    assert fl["windows"] > 50 and fl["n_features"] > 100
    for s in ss[8:]:
        est = loc.run(s, 1, seed=0)
        gt = s.groundtruth
        # every waypoint scored when the experiment holds the ends at scoring (the estimates themselves are the scans')
        m = waypoint_metrics(est.t, est.position, gt["t"].to_numpy(), gt[["x", "y"]].to_numpy(), hold_ends=True)
        assert m["waypoints"] == len(gt) and np.isfinite(m["error_m"]["mean"])
        # positions stay within the span of the train walks' waypoints (a mean of labels)
        lab = np.concatenate([t.groundtruth[["x", "y"]].to_numpy() for t in ss[:8]])
        assert (est.position[0] >= lab.min(axis=0) - 1e-9).all() and (est.position[0] <= lab.max(axis=0) + 1e-9).all()


def test_fingerprint_fixes_are_the_scans_only(coded, tmp_path):
    """FixProvider's fixes of a fingerprint localizer: one per scan with the KNN's own std, none invented at the
    session's start or end (the estimates are not padded); roles sharing the localizer share one run."""
    from blenav.eval.fixes import FixProvider

    knn = FingerprintLocalizer("KNN-2", k=2, cov_floor_m=0.5)
    knn.fit([coded.session("mall_F1_walkA"), coded.session("mall_F1_walkB")])
    test = coded.session("mall_F1_walkC")
    prov = FixProvider({"wifi": None, "again": None}, {"wifi": knn, "again": knn}, 4, tmp_path)
    t, xy, sd, src, _ = prov._fixes("wifi", test)
    est = knn.run(test, 1, 0)
    np.testing.assert_array_equal(t, est.t)
    assert t[0] == 0.5 and t[-1] == 5.5 and src == "fix-wifi"
    np.testing.assert_allclose(sd, est.std[0])
    assert prov._fixes("again", test)[0] is t and len(prov.methods) == 1


def test_fingerprint_fixes_through_the_fix_provider(tmp_path):
    """``fixes.compute`` = a fingerprint localizer: trained on the train walks by the harness (provider.methods),
    its estimates at the scan times are the dense fixes, scored as a track equal to the method itself."""
    d = write_floor(tmp_path / "raw")
    for k in range(3):
        write_walk(d, f"walk{k}", coded_walk(START + k * 100_000, 5.0))
    run_import("ilc20", d, tmp_path / "ds")
    cfg = compose("eval", "experiment=mapfusion_002", f"data={tmp_path / 'ds'}", "runs=1", f"out={tmp_path / 'out'}",
                  "plots=false", "progress=false", "calibration=none", "methods.pf_pl=null", "methods.pf_pl_map=null",
                  "methods.pf_ps=null", "methods.pf_ps_map=null", "methods.pf_pl_offset=null",
                  "methods.pf_ps_map_offset=null", "split={train_fraction: 0.6, seed: 0}",
                  "+localizer@methods.knn=fingerprint", "methods.knn.k=1",
                  "+localizer@methods.track=fix_track", "+fixes={dense: null, again: null}",
                  "+fixes.compute={_target_: blenav.localizers.fingerprint.FingerprintLocalizer, k: 1}",
                  "scoring.hold_ends=true")
    res = evaluate(cfg)
    assert res["fixes"]["training"]["fix-dense"]["floors"]["mall/F1"]["train_walks"] == 2
    # a second role sharing the localizer reports the same training under its own source (it was left out)
    assert res["fixes"]["training"]["fix-again"] == res["fixes"]["training"]["fix-dense"]
    track, knn = res["methods"]["track"]["error_m"], res["methods"]["KNN-WiFi"]["error_m"]
    assert track["mean"] == pytest.approx(knn["mean"], abs=1e-9) and track["mean"] == pytest.approx(4.0 / 3, abs=1e-6)


def test_locnet_trains_with_the_project_trainer(coded, tmp_path):
    """LocNet on WiFi windows through blenav.learn.train (step budget, report); a short budget, numbers finite."""
    from blenav.localizers import RunInputs

    loc = FingerprintLocalizer("LocNet-WiFi", model="locnet", val_fraction=0.5, seed=3, training=training_node(),
                               trainer={"budget": {"max_steps": 20, "val_every_steps": 5, "warmup_steps": 2}})
    rep = loc.fit([coded.session("mall_F1_walkA"), coded.session("mall_F1_walkB")], RunInputs(out=tmp_path))
    tr = rep["floors"]["mall/F1"]["training"]
    assert tr["steps"] == 20 and tr["train_windows"] == 5 and tr["val_windows"] == 5 and tr["val_walks"] == 1
    assert (tmp_path / "fingerprint" / "LocNet-WiFi" / "mall_F1" / "training.json").is_file()
    est = loc.run(coded.session("mall_F1_walkC"), 2, seed=0)
    # net_cov: none (the default, pre-issue 29): no covariance, so a fused filter falls back on its own sigma
    assert est.cov is None and np.isfinite(est.position).all() and np.array_equal(est.position[0], est.position[1])
    assert loc.net_cov == "none" and "fix_std_m" not in rep["floors"]["mall/F1"]


def test_locnet_fix_std_is_its_validation_rms_error_when_asked(coded, tmp_path):
    """net_cov: validation (issue 29, opt-in): each fix's std is the network's RMS error per axis on its validation
    walk (+ cov_floor_m 1 m), the same for all fixes."""
    from blenav.learn.fingerprint.train import split_walks
    from blenav.localizers import RunInputs

    loc = FingerprintLocalizer("LocNet-WiFi", model="locnet", val_fraction=0.5, seed=3, training=training_node(),
                               trainer={"budget": {"max_steps": 20, "val_every_steps": 5, "warmup_steps": 2}},
                               net_cov="validation")
    walks = [coded.session("mall_F1_walkA"), coded.session("mall_F1_walkB")]
    rep = loc.fit(walks, RunInputs(out=tmp_path))
    est = loc.run(coded.session("mall_F1_walkC"), 2, seed=0)
    val = walks[int(np.flatnonzero(split_walks(np.array([0, 1]), 0.5, 3))[0])]
    ev = loc.run(val, 1, seed=0)
    inside = ev.t <= val.groundtruth["t"].iloc[-1]  # the windows it was scored on: inside the waypoints' span
    var = np.mean(np.sum((ev.position[0, inside] - val.positions_at(ev.t[inside])) ** 2, axis=1)) / 2.0
    assert var > 0.01
    np.testing.assert_allclose(est.cov, np.broadcast_to((var + 1.0) * np.eye(2), est.cov.shape), rtol=1e-5)
    assert rep["floors"]["mall/F1"]["fix_std_m"] == pytest.approx(np.sqrt(var + 1.0), rel=1e-5)
    with pytest.raises(ValueError, match="net_cov"):
        FingerprintLocalizer("x", net_cov="rms")


def test_locnet_fix_std_is_its_own_calibrated_sigma_when_asked(coded, tmp_path):
    """net_cov: predicted (issue 29): each fix's std is LocNet's std head, scaled on the validation walk, plus
    cov_floor_m; the positions are those of the network without the head; the scale is in the training report."""
    from blenav.localizers import RunInputs

    kw = dict(model="locnet", val_fraction=0.5, seed=3, training=training_node(),
              trainer={"budget": {"max_steps": 20, "val_every_steps": 5, "warmup_steps": 2}})
    walks = [coded.session("mall_F1_walkA"), coded.session("mall_F1_walkB")]
    loc = FingerprintLocalizer("LocNet-WiFi", **kw, net={"locnet": {"std_head": True}}, net_cov="predicted")
    rep = loc.fit(walks, RunInputs(out=tmp_path / "a"))["floors"]["mall/F1"]
    plain = FingerprintLocalizer("LocNet-WiFi", **kw)
    plain.fit(walks, RunInputs(out=tmp_path / "b"))
    est, ref = loc.run(coded.session("mall_F1_walkC"), 1, seed=0), plain.run(coded.session("mall_F1_walkC"), 1, seed=0)
    np.testing.assert_array_equal(est.position, ref.position)
    std = np.sqrt(est.cov[0, :, 0, 0] - 1.0)  # the head's calibrated sigma (cov_floor_m = 1 m added in quadrature)
    np.testing.assert_allclose(est.cov[0], (std ** 2 + 1.0)[:, None, None] * np.eye(2), rtol=1e-6)
    assert np.all(std > 0) and np.ptp(std) > 0  # one sigma per fix
    assert rep["fix_std"]["scale"] > 0 and rep["fix_std"]["windows"] > 0
    with pytest.raises(ValueError, match="std head"):
        FingerprintLocalizer("x", **kw, net_cov="predicted")
    with pytest.raises(ValueError, match="std head"):
        FingerprintLocalizer("x", net_cov="predicted")  # a KNN has none


def test_locnet_fix_std_calibrated_on_the_head_and_the_distance_to_the_survey(coded, tmp_path, monkeypatch):
    """net_cov: calibrated (issue 29): log std = c0 + c1 log(1 + sigma) + c2 d1 of the std head's sigma and the
    window's cosine signal distance to the windows the network trained on, fitted on the validation walk; the
    positions stay the network's."""
    from blenav.localizers import RunInputs
    from blenav.localizers import fingerprint_net as FPN
    from blenav.localizers import knn as KNN

    monkeypatch.setattr(FPN, "MIN_STD_FIT", 3)  # the coded walks' validation walk has 5 windows
    kw = dict(model="locnet", val_fraction=0.5, seed=3, training=training_node(), net={"locnet": {"std_head": True}},
              trainer={"budget": {"max_steps": 20, "val_every_steps": 5, "warmup_steps": 2}})
    walks = [coded.session("mall_F1_walkA"), coded.session("mall_F1_walkB")]
    loc = FingerprintLocalizer("LocNet-WiFi", **kw, net_cov="calibrated")
    rep = loc.fit(walks, RunInputs(out=tmp_path / "a"))["floors"]["mall/F1"]
    ref = FingerprintLocalizer("LocNet-WiFi", **kw, net_cov="predicted")
    ref.fit(walks, RunInputs(out=tmp_path / "b"))
    s = coded.session("mall_F1_walkC")
    est, plain = loc.run(s, 1, seed=0), ref.run(s, 1, seed=0)
    np.testing.assert_array_equal(est.position, plain.position)
    fs = rep["fix_std"]
    assert len(fs["c"]) == 3 and fs["windows"] > 0 and 0 <= fs["coverage_1sigma"] <= fs["coverage_2sigma"] <= 1
    # the std by hand: the head's sigma (the predicted row's, less its floor) and d1 to the training walk's windows
    fm = loc.floors["mall/F1"]
    from blenav.learn.fingerprint.train import split_walks

    train = walks[int(np.flatnonzero(~split_walks(np.array([0, 1]), 0.5, 3))[0])]
    tw, _ = FP.label_windows(train, FP.session_windows(train, fm.columns, loc.cfg))
    keep = ~np.isnan(tw.xy).any(axis=1) & tw.heard  # the windows it trained on: labelled, something heard
    X = KNN.represent(tw.S[keep], "cosine", np.zeros(len(fm.columns), bool), 1.0, loc.cfg.fill_dbm)
    w = FP.session_windows(s, fm.columns, loc.cfg)
    Q = KNN.represent(w.S[w.heard], "cosine", np.zeros(len(fm.columns), bool), 1.0, loc.cfg.fill_dbm)
    d1 = np.sqrt(KNN.neighbours(Q, X, 1)[1][:, 0])
    sigma = np.sqrt(plain.cov[0, :, 0, 0] - 1.0)
    sd = KNN.StdModel(tuple(fs["c"])).std(sigma, d1)
    np.testing.assert_allclose(est.cov[0, :, 0, 0], sd ** 2 + 1.0, rtol=1e-6)
    # the model is the one fitted on the validation walk's errors, its coverage that of the std the fixes state
    vwalk = walks[1] if train is walks[0] else walks[0]
    vw, _ = FP.label_windows(vwalk, FP.session_windows(vwalk, fm.columns, loc.cfg))
    vk = ~np.isnan(vw.xy).any(axis=1) & vw.heard
    vxy, vcov = ref.floors["mall/F1"].predict(vw.S[vk])
    verr = np.hypot(*(vxy - vw.xy[vk]).T)
    vsig = np.sqrt(vcov[:, 0, 0] - 1.0)
    vd1 = np.sqrt(KNN.neighbours(KNN.represent(vw.S[vk], "cosine", np.zeros(len(fm.columns), bool), 1.0,
                                                 loc.cfg.fill_dbm), X, 1)[1][:, 0])
    model = KNN.fit_std_model(verr, vsig, vd1)
    np.testing.assert_allclose(fs["c"], model.c, rtol=1e-6, atol=1e-9)
    stated = np.sqrt(model.std(vsig, vd1) ** 2 + 1.0)
    assert fs["windows"] == vk.sum() and fs["coverage_1sigma"] == pytest.approx(np.mean(verr <= stated))
    # too few validation windows (2 walks at val_fraction 0.2: none held out): the head's own sigma, said so
    few = FingerprintLocalizer("LocNet-WiFi", **{**kw, "val_fraction": 0.2}, net_cov="calibrated")
    frep = few.fit(walks, RunInputs(out=tmp_path / "c"))["floors"]["mall/F1"]
    assert "not fitted" in frep["fix_std_calibrated"] and np.isfinite(few.run(s, 1, seed=0).cov).all()
    with pytest.raises(ValueError, match="std head"):
        FingerprintLocalizer("x", model="locnet", training=training_node(), net_cov="calibrated")


def test_named_train_walks_through_the_harness(tmp_path):
    """split: {train: [ids]}: those walks train the fingerprint rows and are not scored; the others are."""
    d = write_floor(tmp_path / "raw")
    for k in range(3):
        write_walk(d, f"walk{k}", coded_walk(START + k * 100_000, 5.0))
    run_import("ilc20", d, tmp_path / "ds")
    ids = Dataset.open(tmp_path / "ds").session_ids
    over = ["runs=1", "plots=false", "progress=false", "calibration=none", "methods.pf_pl=null", "methods.pf_pl_map=null",
            "methods.pf_ps=null", "methods.pf_ps_map=null", "methods.pf_pl_offset=null", "methods.pf_ps_map_offset=null",
            "+localizer@methods.knn=fingerprint", "methods.knn.k=1", "methods.knn.label=KNN-WiFi"]
    cfg = compose("eval", "experiment=mapfusion_002", f"data={tmp_path / 'ds'}", f"out={tmp_path / 'out'}", *over,
                  f"split={{train: [{ids[0]}, {ids[2]}]}}")
    res = evaluate(cfg)
    assert res["split"]["train"] == [ids[0], ids[2]] and res["sessions"] == [ids[1]]
    assert res["methods"]["KNN-WiFi"]["training"]["floors"]["mall/F1"]["train_walks"] == 2
    # a fingerprint's own fixes and their stated std (the neighbours' spread + 1 m): scored as fix_coverage own
    cov = res["methods"]["KNN-WiFi"]["fix_coverage"]["own"]
    n = len(Dataset.open(tmp_path / "ds").session(ids[1]).groundtruth)
    assert cov["waypoints"] == n and 0 <= cov["1sigma"] <= cov["2sigma"] <= 1
    assert round(cov["1sigma"] * n) == pytest.approx(cov["1sigma"] * n)  # shares of whole waypoints
    with pytest.raises(Exception, match="nothing left to score"):
        evaluate(compose("eval", "experiment=mapfusion_002", f"data={tmp_path / 'ds'}", f"out={tmp_path / 'o2'}", *over,
                         f"sessions=[{ids[1]}]", f"split={{train: [{ids[1]}]}}"))


def test_cosine_knn_is_not_drawn_to_short_scan_lists():
    """A scan heard strongly everywhere at the test point (A) against one that lists a single access point (B):
    Euclidean KNN on u picks B (|t - B| = 43.6 < |t - A| = 52.0), cosine picks A (same direction as t)."""
    from blenav.localizers.fingerprint import knn_model

    S = np.array([[60.0, 60.0, 60.0], [20.0, 0.0, 0.0]])[:, :, None]  # (N=2, F=3, H=1)
    xy = np.array([[0.0, 0.0], [100.0, 0.0]])
    t = np.array([[[30.0], [30.0], [30.0]]])
    np.testing.assert_allclose(knn_model(S, xy, 1, "uniform", 1.0, "euclidean")(t)[0], [[100.0, 0.0]])
    est, cov = knn_model(S, xy, 1, "uniform", 1.0, "cosine")(t)
    np.testing.assert_allclose(est, [[0.0, 0.0]])
    np.testing.assert_allclose(cov, [np.eye(2)])  # one neighbour: no spread, the floor only
    np.testing.assert_allclose(FP.unit_windows(np.zeros((1, 3, 2))), 0.0)


@pytest.mark.parametrize("features, named", [("wifi", "WiFi scans (wifi.csv)"),
                                             ("both", "both WiFi scans (wifi.csv) and BLE readings (rssi.csv)")])
def test_a_source_no_train_walk_has_is_named_with_its_file(coded, tmp_path, features, named):
    """Train walks without WiFi: the fingerprint rows that need it say which readings and which file are missing."""
    for sid in coded.session_ids:
        (coded.root / "sessions" / sid / "wifi.csv").unlink()
    ds = Dataset.open(coded.root)
    loc = FingerprintLocalizer("KNN-X", features=features)
    with pytest.raises(MissingStream, match=rf"KNN-X: no train walk has {re.escape(named)} inside its waypoints "
                                            rf"\(features: {features}\)"):
        loc.fit([ds.session("mall_F1_walkA"), ds.session("mall_F1_walkB")])
