"""experiment=realwalks (issue 17 section 2): PDR odometry, the fused rows, the contract keys on real walks."""

from __future__ import annotations

import math
import tarfile

import numpy as np
import pandas as pd
import pytest

from helpers import as_waypoint_walks, simulate_small

from blenav.configs import compose
from blenav.eval.harness import evaluate
from blenav.filters.motion_pdr import pdr_track
from blenav.filters.steps import StepDetectorConfig

CONTRACT = ("KNN-WiFi", "LocNet-WiFi", "PDR", "PDR+map", "PDR+learned-map", "WiFi+PDR+map", "WiFi+PDR+learned-map",
            "BLE+PDR+learned-map", "fused-online", "fused-offline", "Net-WiFi+BLE")


def _cfg(*overrides):
    return compose("eval", "progress=false", "plots=false", *overrides)


def test_pdr_track_walks_steps_along_the_heading():
    """Steps (acceleration bursts every 0.5 s) along a heading of 30 deg: the track is n steps of L metres at 30 deg."""
    t = np.arange(0.0, 10.0, 0.01)
    acc = np.zeros((len(t), 3))
    acc[:, 2] = 9.80665 + 3.0 * (np.sin(2 * np.pi * 2.0 * t) > 0.7)  # 2 steps per second, about 0.1 s above 1.2
    yaw = np.radians(30.0)  # device +y at 30 deg CCW from world +x: rotate about z by yaw - 90 deg
    half = (yaw - np.pi / 2) / 2
    q = np.tile([np.cos(half), 0.0, 0.0, np.sin(half)], (len(t), 1))
    tt, xy = pdr_track(t, acc, t, q, step_length=0.5, cfg=StepDetectorConfig(min_interval_s=0.3))
    n = round(np.hypot(*xy[-1]) / 0.5)
    assert n == 20  # 2 Hz for 10 s
    assert math.isclose(np.degrees(np.arctan2(xy[-1, 1], xy[-1, 0])), 30.0, abs_tol=1e-6)
    assert np.all(np.diff(tt) > 0) and xy[0].tolist() == [0.0, 0.0]
    from blenav.filters.steps import detect_steps

    flags = detect_steps(t, acc, StepDetectorConfig(min_interval_s=0.3))  # flags detected once, given: same track
    t2, xy2 = pdr_track(t, np.zeros_like(acc), t, q, step_length=0.5, flags=flags)
    assert np.array_equal(t2, tt) and np.array_equal(xy2, xy)
    with pytest.raises(ValueError, match="step flags"):
        pdr_track(t, acc, t, q, flags=flags[1:])


def test_realwalks_on_simulated_waypoint_walks(tmp_path):
    """The experiment on 4 simulated walks turned into waypoint walks: the inertial, BLE-fingerprint and fused rows
    run and give finite errors at the waypoints; WiFi rows are skipped with the reason (no wifi.csv)."""
    data = as_waypoint_walks(simulate_small(tmp_path / "d", 3, 40, 4))
    res = evaluate(_cfg("experiment=realwalks", f"data={data}", "runs=1", f"out={tmp_path / 'o'}",
                        "methods.locnet_wifi=null", "methods.transnet_wifi=null", "methods.net_both=null", "methods.crf=null",
                        "methods.imu=null", "methods.pf_pl=null", "methods.pf_ps=null", "filter.n_particles=200"))
    assert res["split"]["train_fraction"] == 0.5 and len(res["split"]["train"]) == 2 and len(res["sessions"]) == 2
    m = res["methods"]
    for row in ("PDR", "PDR (rotation vector)", "PDR+map", "KNN-BLE", "BLE+PDR", "BLE+PDR+map", "PF-PS+MAP"):
        e = m[row]["error_m"]
        assert all(np.isfinite(e[k]) for k in ("mean", "median", "p90")), row
        assert set(m[row]["walks_within_m"]) == {"2", "5"}
    assert 0.3 < m["PDR (rotation vector)"]["training"]["step_length"]["step_length_m"] < 1.5
    assert "wifi" in str(m["KNN-WiFi"]["skipped"]).lower() and "error_m" not in m["WiFi+PDR"]
    assert "model_path" in str(m["PDR+learned-map"]["skipped"])  # no map prior given: skipped with the reason
    for row in ("fused-online", "fused-offline"):  # issue 30: no known start, the fixes' coverage reported
        assert all(np.isfinite(m[row]["error_m"][k]) for k in ("mean", "median", "p90")), row
        cov = m[row]["fix_coverage"]["ble"]  # no WiFi in the simulator: the BLE role
        assert 0 <= cov["1sigma"] <= cov["2sigma"] <= 1 and cov["waypoints"] > 0
        assert 0 <= m[row]["convergence"]["settled"] <= 1


def _unpack_walks(raw_dir, tmp_path, floor="F1", n=6):
    tgz = raw_dir / "ilc20" / f"site1_{floor}.tar.gz"
    if not tgz.is_file():
        pytest.skip(f"{tgz} is absent")
    root = tmp_path / "raw"
    walks = 0
    with tarfile.open(tgz, "r|gz") as tf:
        for mem in tf:
            take = mem.name.endswith(("floor_info.json", "geojson_map.json")) or (mem.name.endswith(".txt") and walks < n)
            if mem.isfile() and take:
                p = root / mem.name
                p.parent.mkdir(parents=True, exist_ok=True)
                p.write_bytes(tf.extractfile(mem).read())
                walks += mem.name.endswith(".txt")
    return root / "site1" / floor


@pytest.mark.realdata
@pytest.mark.slow
def test_realwalks_contract_on_real_walks(raw_dir, tmp_path):
    """Six F1 walks unpacked into a temporary folder, imported, the experiment with a stand-in map prior (the
    feasibility prior, no network): every contract key has finite error_m mean/median/p90 over the test walks."""
    from blenav.importers import run_import

    floor = _unpack_walks(raw_dir, tmp_path)
    data = tmp_path / "ds"
    run_import("ilc20", floor, data)
    from blenav.filters import map_prior
    from blenav.localizers import particle

    orig = particle.load_prior
    particle.load_prior = lambda path: map_prior.FeasibilityPrior()
    try:
        res = evaluate(_cfg("experiment=realwalks", f"data={data}", "runs=1", f"out={tmp_path / 'o'}",
                            "model_path=feasibility", "methods.transnet_wifi.trainer={budget: {max_steps: 20}}",
                            "methods.locnet_wifi.trainer={budget: {max_steps: 20}}",
                            "methods.net_both.trainer={budget: {max_steps: 20}}", "filter.n_particles=200"))
    finally:
        particle.load_prior = orig
    assert len(res["sessions"]) == 3
    for row in CONTRACT:
        e = res["methods"][row].get("error_m")
        assert e is not None, (row, res["methods"][row].get("skipped"))
        assert all(np.isfinite(e[k]) for k in ("mean", "median", "p90")), row
    # no beacon map in a fresh import: the range-based rows are skipped with the reason
    assert "blenav-map" in str(res["methods"]["PF-PS+MAP"]["skipped"])


def test_odometry_argument_equals_an_odometry_csv(tiny_dataset):
    """run_session(odometry=DF) gives exactly the numbers of the same session with DF as its odometry.csv (what the
    removed session overlay did), and leaves the session untouched; RealWalkPF hands its PDR odometry over this way
    and adds no estimate before the filter's first step or after its last (no padding)."""
    import shutil

    from blenav.data import Dataset
    from blenav.localizers.realwalk import RealWalkPF
    from blenav.localizers import RunInputs
    from blenav.filters.runner import run_session

    odo = pd.DataFrame({"t": [0.0, 10.0, 19.0], "x": [0.0, 5.0, 9.0], "y": [0.0, 0.0, 1.0]})
    copy = tiny_dataset.parent / "with_odo"
    shutil.copytree(tiny_dataset, copy)
    odo.to_csv(copy / "sessions" / "walk0" / "odometry.csv", index=False)
    s = Dataset.open(tiny_dataset).session("walk0")
    s2 = Dataset.open(copy).session("walk0")
    pf = RealWalkPF("IO", None, motion={"_target_": "blenav.filters.motion.OdometryIncrement", "theta0": 0.0},
                    map={"init": "groundtruth"}, filter={"n_particles": 50, "rate_hz": 1.0})
    a = run_session(pf.method, s, 2, 0, odometry=odo)
    b = run_session(pf.method, s2, 2, 0)
    np.testing.assert_array_equal(a.t, b.t)
    np.testing.assert_array_equal(a.position, b.position)
    assert len(s.odometry) == 0  # the session keeps its own (none)
    pdr = RealWalkPF("PDR-AHRS", None, motion={"_target_": "blenav.filters.motion.OdometryIncrement", "theta0": 0.0},
                     map={"init": "groundtruth"}, filter={"n_particles": 50, "rate_hz": 1.0},
                     odometry={"heading": "ahrs", "step_length": 0.7})
    est = pdr.run(s, 2, 0, RunInputs(cache={}))
    t0 = min(float(s.imu["t"].min()), float(s.rssi["t"].min()) if len(s.rssi) else np.inf)
    assert est.t[0] == pytest.approx(t0 + 1.0)  # the first filter step, not the session's first sample
    assert np.isfinite(est.position).all() and any("PDR odometry" in n for n in est.notes)
    with pytest.raises(ValueError, match="unknown key"):
        RealWalkPF("x", None, motion={"_target_": "blenav.filters.motion.OdometryIncrement"},
                   odometry={"heading": "ahrs", "rate_hz": 10})
    with pytest.raises(ValueError, match="odometry.yaw must be one of"):
        RealWalkPF("x", None, motion={"_target_": "blenav.filters.motion.OdometryIncrement"},
                   odometry={"heading": "ahrs", "yaw": "compass"})
    held = RealWalkPF("PDR-AHRS-held", None, motion={"_target_": "blenav.filters.motion.OdometryIncrement",
                                                     "theta0": 0.0},
                      map={"init": "groundtruth"}, filter={"n_particles": 50, "rate_hz": 1.0},
                      odometry={"heading": "ahrs", "step_length": 0.7, "yaw": "gyro"})
    inputs = RunInputs(cache={})
    odo_held, odo = held.odometry_for(s, inputs), pdr.odometry_for(s, inputs)
    assert len(odo_held) == len(odo)  # the held yaw's track is its own cache entry, not the attitude's
    assert {k[3] for k in inputs.cache if isinstance(k, tuple) and k[0] == "rw-pdr"} == {"attitude", "gyro"}


def test_ahrs_odometry_reads_the_pdr_rows_ahrs(tmp_path):
    """The AHRS heading of the PDR odometry is the PDR motion model's: the same ("imu", ...) cache entry, computed
    with the magnetometer's hard-iron offset (a sentinel in that entry is what pdr_odometry reads)."""
    from blenav.data import Dataset
    from blenav.filters.pdr_odometry import pdr_odometry
    from blenav.filters.attitude import AttitudeConfig, estimate_attitude
    from blenav.filters.runner import hard_iron_offset
    from blenav.filters.steps import SessionArrays
    from blenav.filters.pdr_odometry import _NO_ANCHORS

    ds = Dataset.open(simulate_small(tmp_path / "d", 3, 20, 1))
    s = ds.session(ds.session_ids[0])
    att, steps = AttitudeConfig(), StepDetectorConfig()
    cache: dict = {}
    pdr_odometry(s, "ahrs", 0.7, att, steps, cache)
    key = ("imu", s.id, repr(att), repr(steps))
    assert key in cache
    a = SessionArrays.from_session(s, _NO_ANCHORS)
    off = hard_iron_offset(a, att)
    want = estimate_attitude(a.imu_t, a.acc, a.gyr, a.mag_t, a.mag, att, mag_offset=off)
    np.testing.assert_allclose(cache[key][0], want)
    q = np.tile([np.cos(-np.pi / 4), 0.0, 0.0, np.sin(-np.pi / 4)], (len(a.imu_t), 1))  # heading +x
    cache2 = {key: (q, cache[key][1])}
    df = pdr_odometry(s, "ahrs", 0.7, att, steps, cache2)
    assert len(df) > 10 and df["x"].iloc[-1] > 5.0  # steps were detected, all east
    np.testing.assert_allclose(df["y"], 0.0, atol=1e-9)  # the sentinel's heading (east), not a recomputed one


def _level_walk_with_calibrated_magnetometer():
    """A phone held level (screen up) turning 0 -> 90 -> 0 -> 90 -> 0 deg about z in 60 s at 100 Hz, its magnetometer
    already calibrated (no hard-iron offset, as Android's TYPE_MAGNETIC_FIELD of the ILC walks): the field
    (0, 22, -42) uT plus a 6 uT indoor disturbance, 0.5 uT noise. Returns (arrays, true heading of the device's
    +y axis (T,) rad CCW from +x)."""
    from types import SimpleNamespace

    rng = np.random.default_rng(0)
    t = np.arange(0.0, 60.0, 0.01)
    phi = np.radians(45.0) * (1 - np.cos(2 * np.pi * t / 30.0))
    dphi = np.radians(45.0) * 2 * np.pi / 30.0 * np.sin(2 * np.pi * t / 30.0)
    c, s = np.cos(phi), np.sin(phi)
    m_w = np.array([0.0, 22.0, -42.0]) + 6.0 * np.column_stack([np.sin(0.7 * t), np.cos(0.4 * t), np.sin(0.3 * t)])
    m_d = np.column_stack([c * m_w[:, 0] + s * m_w[:, 1], -s * m_w[:, 0] + c * m_w[:, 1], m_w[:, 2]])  # R^T m_w
    a = SimpleNamespace(imu_t=t, acc=np.tile([0.0, 0.0, 9.81], (len(t), 1)) + 0.05 * rng.standard_normal((len(t), 3)),
                        gyr=np.column_stack([np.zeros_like(t), np.zeros_like(t), dphi]), mag_t=t,
                        mag=m_d + 0.5 * rng.standard_normal(m_d.shape))
    return a, np.pi / 2 + phi


def test_realwalks_ahrs_fits_no_hard_iron_on_a_calibrated_magnetometer(tmp_path):
    """The realwalks AHRS rows (PDR, PDR (AHRS odometry): one ("imu", ...) cache entry) do not fit a hard-iron offset
    on the ILC walks' already calibrated magnetometer: on a level walk that turns through 90 deg their heading stays
    within 6 deg (mean) of the truth; the sphere fit (AttitudeConfig's default, for raw magnetometers) is
    ill-determined there (offset ~ the field itself) and puts the heading > 30 deg off. ff8617b gave the AHRS
    odometry the fitted offset: mean waypoint error 3.81 -> 5.09 m on F1."""
    from blenav.eval.harness import build_methods
    from blenav.filters.attitude import AttitudeConfig, yaw_of_device_forward
    from blenav.filters.runner import hard_iron_offset, session_imu

    a, heading = _level_walk_with_calibrated_magnetometer()
    later = a.imu_t > 5.0

    def mean_err_deg(att):
        q, _ = session_imu("walk", a, att, StepDetectorConfig())
        return np.degrees(np.abs(np.angle(np.exp(1j * (yaw_of_device_forward(q) - heading)))))[later].mean()

    assert np.linalg.norm(hard_iron_offset(a, AttitudeConfig())) > 20.0  # uT, true offset 0
    assert mean_err_deg(AttitudeConfig()) > 30.0
    for exp in ("realwalks", "realwalks_inertial"):
        methods = build_methods(_cfg(f"experiment={exp}", f"data={tmp_path}"))
        atts = {name: m.method.attitude for name, m in methods.items()
                if name in ("PDR", "PDR (AHRS odometry)")}
        assert len(atts) == 2, exp
        for name, att in atts.items():
            assert att.hard_iron is False and hard_iron_offset(a, att) is None, (exp, name)
            assert mean_err_deg(att) < 6.0, (exp, name)


def test_waypoint_scoring_holds_the_ends_only_when_asked():
    """waypoint_metrics(hold_ends): waypoints before the first / after the last estimate are scored against it;
    without it they are not scored. The estimates themselves are not changed."""
    from blenav.eval.metrics import waypoint_metrics

    t = np.array([2.0, 4.0])
    pos = np.array([[[0.0, 0.0], [2.0, 0.0]]])
    gt_t = np.array([0.0, 3.0, 6.0])
    gt = np.array([[0.0, 1.0], [1.0, 0.0], [2.0, 2.0]])
    m = waypoint_metrics(t, pos, gt_t, gt)
    assert m["waypoints"] == 1 and m["error_m"]["mean"] == pytest.approx(0.0)
    h = waypoint_metrics(t, pos, gt_t, gt, hold_ends=True)
    assert h["waypoints"] == 3 and h["error_m"]["mean"] == pytest.approx((1.0 + 0.0 + 2.0) / 3)
    assert pos.shape == (1, 2, 2)


def test_one_fix_localizer_per_node_shared_with_its_row(tmp_path):
    """fixes.compute per role: roles with equal nodes share one localizer, and a node equal to a methods row is that
    row's own localizer (trained once by the harness, not a second copy)."""
    from blenav.eval.config import parse_eval_config
    from blenav.eval.harness import build_fix_provider, build_methods

    cfg = _cfg("experiment=realwalks", f"data={tmp_path}", "+fixes.again=null",
               '+fixes.compute.again="${methods.knn_wifi}"')
    methods = build_methods(cfg)
    prov = build_fix_provider(parse_eval_config(cfg), methods, tmp_path)
    loc = prov.localizers
    assert loc["wifi"] is methods["KNN-WiFi"] and loc["again"] is loc["wifi"]
    assert loc["ble"] is methods["KNN-BLE"] and loc["both"] is methods["KNN-WiFi+BLE"]
    assert loc["both_crowd"] is methods["KNN-WiFi+BLE+crowd"]  # the crowds' own rows (issue 30)
    assert loc["ble_crowd"] is methods["KNN-BLE+crowd"]
    assert len(prov.methods) == 5  # each localizer once


def test_train_ids_and_table_rows_come_from_the_experiment(tmp_path):
    """train-ids is the harness's split of the composed experiment; the tables' rows are the YAML's labels (the entry
    point blenav.cli.realwalks composes the experiment, blenav.eval.realwalks / blenav.reporting.realwalks read the nodes
    they are handed)."""
    from blenav.cli.realwalks import table_rows_of, train_ids_of
    from blenav.eval.config import parse_eval_config
    from blenav.eval.sessions import open_dataset, scored_sessions, train_test
    from blenav.eval.realwalks import train_ids
    from blenav.reporting.realwalks import OUTCOMES

    data = as_waypoint_walks(simulate_small(tmp_path / "d", 3, 20, 4))
    cfg = _cfg("experiment=realwalks", f"data={data}")
    ecfg = parse_eval_config(cfg)
    ds = open_dataset(ecfg)
    train, test = train_test(ecfg, ds, scored_sessions(ecfg, ds))
    assert train_ids(cfg) == [s.id for s in train] and len(train) == 2
    assert train_ids_of(str(data)) == train_ids(cfg)
    assert len(train_ids_of(str(data), train_fraction=0.75)) == 3
    rows = table_rows_of()
    assert set(CONTRACT) <= set(rows["all"]) and {r for _, a, b in OUTCOMES for r in (a, b)} <= set(rows["all"])
    assert rows["fingerprint"] == ("KNN-WiFi", "KNN-BLE", "KNN-WiFi+BLE", "LocNet-WiFi", "TransNet+LocNet-WiFi",
                                   "Net-WiFi+BLE")
    assert "WiFi+PDR+learned-map" in rows["fused"] and "PDR+map" not in rows["fused"]
    assert {"fused-online", "fused-offline"} <= set(rows["fused"])


def test_sparse_role_hears_only_its_beacons(tmp_path):
    """One KNN-BLE shared by a full and a sparse role: the sparse fixes come from the chosen beacons only (the
    localizer's beacons set for that run and restored), so they differ from the full role's; sources fix-ble and
    fix-sparse2."""
    from blenav.data import Dataset
    from blenav.eval.fixes import FixProvider
    from blenav.localizers.fingerprint import FingerprintLocalizer

    data = as_waypoint_walks(simulate_small(tmp_path / "d", 3, 30, 3))
    ss = list(Dataset.open(data).sessions(labelled=True))
    knn = FingerprintLocalizer("KNN-BLE", features="ble", k=3)
    knn.fit(ss[:2])
    prov = FixProvider({"ble": None, "sparse": None}, {"ble": knn, "sparse": knn}, 2, tmp_path / "o")
    t_all, xy_all, _, src_all, _ = prov._fixes("ble", ss[2])
    t_sp, xy_sp, _, src_sp, _ = prov._fixes("sparse", ss[2])
    assert knn.beacons is None and (src_all, src_sp) == ("fix-ble", "fix-sparse2")
    chosen = prov.beacon_ids[str(ss[2].building.id)]
    assert len(chosen) == 2
    knn.beacons = tuple(chosen)
    est = knn.run(ss[2], 1, 0)
    knn.beacons = None
    np.testing.assert_array_equal(t_sp, est.t)
    np.testing.assert_allclose(xy_sp, est.position[0])
    assert len(t_sp) != len(t_all) or not np.allclose(xy_sp, xy_all)


def test_step_flags_are_detected_once_per_walk(tiny_dataset, monkeypatch):
    """The PDR odometry and the step-length fit of one walk share its step flags through the cache."""
    from blenav.data import Dataset
    import blenav.filters.pdr_odometry as odo

    calls = []
    real = odo.detect_steps
    monkeypatch.setattr(odo, "detect_steps", lambda *a, **k: calls.append(1) or real(*a, **k))
    s = next(iter(Dataset.open(tiny_dataset).sessions()))
    cache: dict = {}
    a = odo._step_flags(s, None, cache)
    assert np.array_equal(odo._step_flags(s, StepDetectorConfig(), cache), a) and len(calls) == 1


def test_coverage_bins_the_fix_errors_by_distance_to_the_train_walks(tmp_path):
    """python -m blenav.cli.realwalks coverage: a fingerprint row fitted on the train walks, its test fixes binned by
    how far their true position lies from the train walks; the shares sum to one, the bins are ordered."""
    from blenav.cli.realwalks import experiment_config
    from blenav.eval.realwalks import COVERAGE_BINS_M, coverage

    data = as_waypoint_walks(simulate_small(tmp_path / "d", 3, 30, 4))
    rep = coverage(experiment_config(f"data={data}"), "knn_ble")
    assert rep["row"] == "KNN-BLE" and rep["fixes"] > 0 and rep["train_walks"] == 2
    assert len(rep["bins"]) == len(COVERAGE_BINS_M) - 1 and np.isclose(sum(b["share"] for b in rep["bins"]), 1.0)
    with pytest.raises(ValueError, match="no method"):
        coverage(experiment_config(f"data={data}"), "knn_nothing")
    with pytest.raises(ValueError, match="not a fingerprint localizer"):
        coverage(experiment_config(f"data={data}"), "pdr_map")
    from blenav.cli.realwalks import main

    png = tmp_path / "cover.png"  # the command's figure: the floor, the train walks, the test fixes by error
    assert main(["coverage", str(data), "knn_ble", "--plot", str(png)]) == 0
    assert png.is_file() and png.stat().st_size > 10_000
