"""The CRF of Duembgen et al. (004): features, grid, Viterbi (blenav.crf) and the localizer through the harness."""

from __future__ import annotations

import itertools
import math
import shutil
from pathlib import Path

import numpy as np
import pytest
import yaml

from blenav.crf.calibration import heading_offset, rtt_offsets
from blenav.crf.features import (cell_anchor_distances, imu_edge_log, normalise_log, rssi_log_feature,
                                 rtt_log_feature, visual_log_feature)
from blenav.crf.grid import build_grid, grid_from_occupancy
from blenav.crf.preprocess import rtt_keep_mask, window_medians
from blenav.crf.viterbi import ViterbiDecoder, maxprod_step, maxprod_step_numpy, transition_log_numpy
from blenav.data import FREE, OCCUPIED


def _room(w_m=12.0, h_m=10.0, res=0.1):
    occ = np.full((int(round(h_m / res)), int(round(w_m / res))), FREE, np.int8)
    occ[0, :] = occ[-1, :] = occ[:, 0] = occ[:, -1] = OCCUPIED
    return occ


@pytest.fixture(scope="module")
def room():
    return grid_from_occupancy(_room(), 0.1, (0.0, 0.0), 0.5, 2.0)


TRUE = np.array([7.25, 3.75])  # a cell centre


def test_rtt_feature_peaks_at_the_true_position(room):
    aps = np.array([[1.0, 1.0, 2.8], [11.0, 1.0, 2.8], [6.0, 9.0, 2.8]])
    d = cell_anchor_distances(room.xy, 1.2, aps)
    truth = cell_anchor_distances(TRUE[None], 1.2, aps)[0]
    f = normalise_log(rtt_log_feature(d, truth, 1.0))
    np.testing.assert_allclose(room.xy[np.argmax(f)], TRUE)
    np.testing.assert_allclose(np.exp(f).sum(), 1.0)
    # an AP without a range (NaN) is left out: two APs still peak on the true cell among their two solutions
    f2 = rtt_log_feature(d, np.r_[truth[:2], np.nan], 1.0)
    assert np.linalg.norm(room.xy[np.argmax(f2)] - TRUE) < 1e-9 or abs(room.xy[np.argmax(f2)][1] - TRUE[1]) > 1.0


def test_rssi_feature_peaks_at_the_true_position_and_the_mode_correction_at_the_measured_distance(room):
    n, tx = 2.0, -60.0
    beacons = np.array([[1.0, 1.0, 2.5], [11.0, 1.0, 2.5], [1.0, 9.0, 2.5], [11.0, 9.0, 2.5]])
    ld = np.log(cell_anchor_distances(room.xy, 1.2, beacons))
    d_true = cell_anchor_distances(TRUE[None], 1.2, beacons)[0]
    rssi = tx - 10 * n * np.log10(d_true)
    f = rssi_log_feature(ld, rssi, np.full(4, tx), n, 6.0)
    np.testing.assert_allclose(room.xy[np.argmax(f)], TRUE)
    # one beacon, measured distance 4 m: eq. 11 peaks on the 4 m ring; without it, closer (d exp(-sigma_d^2))
    one = ld[:, :1]
    r4 = np.array([tx - 10 * n * np.log10(4.0)])
    fc = rssi_log_feature(one, r4, np.array([tx]), n, 6.0, mode_correction=True)
    fu = rssi_log_feature(one, r4, np.array([tx]), n, 6.0, mode_correction=False)
    assert abs(np.exp(one[np.argmax(fc), 0]) - 4.0) < 0.2
    sd = np.log(10) / (10 * n) * 6.0
    assert abs(np.exp(one[np.argmax(fu), 0]) - 4.0 * np.exp(-sd**2)) < 0.3


def test_imu_edge_feature_peaks_at_the_step_vector(room):
    src = int(room.cell_of(np.array([[6.25, 5.25]]))[0])
    a, b = room.src_ptr[src], room.src_ptr[src + 1]
    w = imu_edge_log(1.0, math.pi / 2, room.dist[a:b], room.angle[a:b], 0.3, 0.1)
    tgt = room.dst[a + np.argmax(w)]
    np.testing.assert_allclose(room.xy[tgt] - room.xy[src], [0.0, 1.0], atol=1e-9)
    # no step: staying put is most likely (distance term only)
    w0 = imu_edge_log(0.0, 0.0, room.dist[a:b], room.angle[a:b], 0.3, 0.1, use_heading=False)
    assert room.dst[a + np.argmax(w0)] == src


def test_visual_reset_peaks_at_the_fix(room):
    f = normalise_log(visual_log_feature(room.xy, np.array([3.3, 8.2]), 0.05))
    np.testing.assert_allclose(room.xy[np.argmax(f)], [3.25, 8.25])
    assert np.sort(np.exp(f))[-2] < 1e-10  # 0.05 m on a 0.5 m grid: one cell holds the mass


def test_transitions_never_cross_a_wall():
    occ = _room(10.0, 6.0)
    occ[:, 50:52] = OCCUPIED  # wall at x = 5.0..5.2 with a door at y = 2.5..3.5
    occ[25:35, 50:52] = FREE
    g = grid_from_occupancy(occ, 0.1, (0.0, 0.0), 0.5, 2.0)
    src = np.repeat(np.arange(g.n_cells), np.diff(g.src_ptr))
    a, b = g.xy[src], g.xy[g.dst]
    f = np.linspace(0, 1, 400)[None, :, None]
    pts = a[:, None, :] + f * (b - a)[:, None, :]
    col = np.floor(pts[..., 0] / 0.1).astype(int)
    row = occ.shape[0] - 1 - np.floor(pts[..., 1] / 0.1).astype(int)
    assert (occ[row, col] == FREE).all()
    cross = (a[:, 0] < 5.0) != (b[:, 0] < 5.0)
    assert cross.any()  # through the door
    fx = (5.1 - a[cross, 0]) / (b[cross, 0] - a[cross, 0])  # where the segment meets the wall's middle
    y_at_wall = a[cross, 1] + fx * (b[cross, 1] - a[cross, 1])
    assert ((y_at_wall > 2.5) & (y_at_wall < 3.5)).all()  # only through the door
    assert (g.dist <= 2.0 + 1e-9).all() and (np.diff(g.src_ptr) >= 1).all()  # every cell has its self edge


def test_viterbi_on_three_states_equals_brute_force():
    occ = np.full((1, 3), FREE, np.int8)
    g = grid_from_occupancy(occ, 0.5, (0.0, 0.0), 0.5, 1.0)  # 3 cells in a row, all connected
    assert g.n_cells == 3 and g.n_edges == 9
    rng = np.random.default_rng(3)
    T = 6
    unary = rng.normal(0, 2, (T, 3))
    imus = [(float(rng.uniform(0, 1)), float(rng.choice([0.0, math.pi])), bool(rng.integers(2))) for _ in range(T)]
    dec = ViterbiDecoder(g, prune=0.0, sigma_l=0.4, sigma_theta=0.5)
    for k in range(T):
        dec.step(unary[k], imus[k])
    W = [transition_log_numpy(g, imus[k], 0.4, 0.5) for k in range(T)]
    edge = {(int(s), int(d)): e for e, (s, d) in enumerate(zip(np.repeat(np.arange(3), np.diff(g.src_ptr)), g.dst))}
    best, best_seq = {}, {}
    for seq in itertools.product(range(3), repeat=T + 1):  # seq[0]: the (uniform) start state
        v = sum(W[k][edge[(seq[k], seq[k + 1])]] + unary[k, seq[k + 1]] for k in range(T))
        if v > best.get(seq[-1], -np.inf):
            best[seq[-1]], best_seq[seq[-1]] = v, seq
    b = np.array([best[i] for i in range(3)])
    np.testing.assert_allclose(dec.score - dec.score.max(), b - b.max(), atol=1e-9)
    end = int(np.argmax(b))
    np.testing.assert_array_equal(dec.backtrack(), best_seq[end][1:])


def test_compiled_step_equals_the_numpy_reference(room):
    rng = np.random.default_rng(0)
    score = normalise_log(rng.normal(0, 8, room.n_cells))
    for imu in (None, (1.2, 0.7, True), (0.0, 0.0, False)):
        out, back, _ = maxprod_step(room, score, math.log(1e-10), imu, 1.0, 0.3)
        ref, rback = maxprod_step_numpy(room, score, math.log(1e-10), imu, 1.0, 0.3)
        np.testing.assert_allclose(out, ref, atol=1e-9)
        fin = np.isfinite(ref)
        assert (back[fin] == rback[fin]).mean() > 0.999  # float ties aside


def test_preprocess_and_calibration_helpers():
    med = window_medians(np.array([0.1, 0.2, 0.9, 1.5]), np.array([0, 0, 0, 1]), np.array([1.0, 5.0, 2.0, 7.0]), 2,
                         0.0, 2, 1.0)
    np.testing.assert_allclose(med, [[2.0, np.nan], [np.nan, 7.0]])
    np.testing.assert_array_equal(rtt_keep_mask(np.array([1.0, 2.0, 3.0]), np.array([-60.0, -70.0, np.nan])),
                                  [True, False, True])
    np.testing.assert_array_equal(rtt_keep_mask(np.array([1.0, np.nan]), None), [True, False])
    np.testing.assert_allclose(rtt_offsets(np.array([0, 0, 0, 1]), np.array([3.0, 4.0, 9.0, 1.0]),
                                           np.array([2.0, 2.0, 2.0, 1.5]), 3), [2.0, -0.5, np.nan])
    assert abs(heading_offset(3.1, np.array([-3.1, -3.05, -3.12])) - (-0.08)) < 0.03  # across the +-pi seam


# ------------------------------------------------------------------ the small building and the harness
@pytest.fixture(scope="module")
def small(tmp_path_factory):
    from helpers import simulate_small

    return simulate_small(tmp_path_factory.mktemp("crf") / "small", 2, 60, 1)


def test_pruning_does_not_change_the_argmax_on_the_small_building(small):
    from blenav.data import Dataset
    from blenav.localizers.crf import CrfLocalizer

    s = next(Dataset.open(small).sessions())
    runs = {}
    for prune in (1e-10, 0.0):
        loc = CrfLocalizer("CRF", modalities="RTT+BLE+IMU", calibration="none", prune=prune)
        runs[prune] = loc.run(s, 1, 0)
    np.testing.assert_allclose(runs[1e-10].position, runs[0.0].position)
    act = runs[1e-10].outputs["active_cells"]
    assert act[5:].mean() < 0.5 * build_grid(s.floor).n_cells  # pruning does prune


@pytest.fixture(scope="module")
def renamed(tmp_path_factory):
    """crf_004 sessions (2 walks + 1 static survey, 40 s) with building, sessions and receivers renamed."""
    from blenav.cli.sim import run as sim_run
    from blenav.configs import compose

    out = tmp_path_factory.mktemp("crf_sim") / "d"
    sim_run(compose("sim", "sim=crf_004", "seed=1", f"out={out}", "duration_s=40", "sessions=4", "progress=false",
                    "sim.carriers=[pedestrian,pedestrian,static]"))
    (out / "buildings" / "crf_004").rename(out / "buildings" / "Hall B")
    for i, f in enumerate(sorted((out / "sessions").glob("*/session.yaml"))):
        meta = yaml.safe_load(f.read_text())
        meta["building"], meta["device_model"] = "Hall B", f"phone-{i}"
        f.write_text(yaml.safe_dump(meta, sort_keys=False))
        f.parent.rename(f.parent.parent / f"walk {chr(65 + i)}")
    return out


def _eval(data, out, *over):
    from blenav.configs import compose
    from blenav.eval.harness import evaluate

    cfg = compose("eval", "experiment=crf_004_table1", f"data={data}", f"out={out}", "plots=false", "progress=false",
                  *over)
    return evaluate(cfg)


KEEP = ("rtt_ble_imu_online", "rtt_ble_imu_offline", "imu_none", "ble_none", "rtt_none")


def _only(*keep):
    from blenav.configs import compose

    cfg = compose("eval", "experiment=crf_004_table1", "data=X")
    return [f"methods.{k}=null" for k in cfg.methods if k not in keep]


def test_table1_runs_through_the_harness_on_renamed_sessions(renamed, tmp_path):
    res = _eval(renamed, tmp_path / "a", "runs=2", *_only(*KEEP))
    ms = res["methods"]
    assert set(ms) == {"RTT+BLE+IMU/online", "RTT+BLE+IMU/offline", "IMU/none", "BLE/none", "RTT/none"}
    for name, m in ms.items():
        assert np.isfinite(m["error_m"]["mean"]) and np.isfinite(m["error_m"]["median"]), name
        assert all(v["rmse_m"]["std"] == 0.0 for v in m["per_session"].values())  # deterministic: runs identical
    assert ms["RTT+BLE+IMU/online"]["error_m"]["mean"] < 8.0
    assert (tmp_path / "a" / "results.md").is_file()


def test_rows_without_their_streams_are_skipped_with_the_reason(renamed, tmp_path):
    data = Path(shutil.copytree(renamed, tmp_path / "d"))
    for s in (data / "sessions").iterdir():
        (s / "rtt.csv").unlink()
        (s / "visual.csv").unlink(missing_ok=True)
    for s in (data / "sessions").glob("*/session.yaml"):  # drop the survey: offline has no static points
        if yaml.safe_load(s.read_text())["carrier"] == "static":
            shutil.rmtree(s.parent)
    res = _eval(data, tmp_path / "b", *_only("rtt_none", "ble_imu_online", "ble_imu_offline", "ble_none", "imu_none"))
    ms = res["methods"]
    assert "rtt.csv" in next(iter(ms["RTT/none"]["skipped"].values()))
    assert "visual" in next(iter(ms["BLE+IMU/online"]["skipped"].values()))
    assert "static" in next(iter(ms["BLE+IMU/offline"]["skipped"].values()))
    assert np.isfinite(ms["BLE/none"]["error_m"]["median"]) and np.isfinite(ms["IMU/none"]["error_m"]["mean"])


def test_compiled_step_detector_equals_the_project_detector(small):
    from blenav.filters.steps import step_flags
    from blenav.data import Dataset
    from blenav.filters.steps import StepDetector, StepDetectorConfig

    imu = next(Dataset.open(small).sessions()).imu
    t, acc = imu["t"].to_numpy(), imu[["ax", "ay", "az"]].to_numpy()
    for cfg in (StepDetectorConfig(), StepDetectorConfig(threshold=0.8, min_interval_s=0.25, smooth_s=0.05)):
        det = StepDetector(cfg, 200.0)
        ref = np.fromiter((det.update(a, v) for a, v in zip(t, acc)), bool, len(t))
        got = step_flags(t, acc, cfg, 200.0)
        assert ref.sum() > 20
        np.testing.assert_array_equal(got, ref)


def test_online_calibration_uses_the_second_after_each_fix_and_applies_from_its_end():
    from blenav.crf.calibration import Calibration, CalibrationTrack, online_track
    from blenav.filters.measurement import AnchorTable

    wifi = AnchorTable(np.array(["ap"]), np.array([[0.0, 0.0, 1.2]]), np.array([np.nan]))
    ble = AnchorTable(np.array(["b"]), np.array([[4.0, 0.0, 1.2]]), np.array([-60.0]))
    base = CalibrationTrack.constant(Calibration.empty(1, 1), np.array([-60.0]))
    fixes = np.array([[10.0, 3.0, 0.0, 1.2, 0.5], [30.0, 6.0, 0.0, 1.2, np.nan]])
    t = np.array([5.0, 10.2, 10.5, 10.8, 30.5])
    rtt = (t, np.zeros(5, np.int64), np.array([9.0, 4.4, 4.5, 4.6, 7.0]))  # true 3 m, then 6 m: offsets 1.5, 1.0
    rssi = (t, np.zeros(5, np.int64), np.array([-50.0, -66.0, -66.0, -66.0, -70.0]))  # 1 m from b, then 2 m
    yaw = (np.array([10.1, 10.6, 30.2]), np.array([0.3, 0.3, 2.0]))
    tr = online_track(base, fixes, wifi, ble, 2.0, rtt, rssi, yaw, 1.0)
    np.testing.assert_allclose(tr.t_avail, [11.0, 31.0])
    np.testing.assert_allclose(tr.rtt_offset[:, 0], [0.0, 1.5, 1.0])
    np.testing.assert_allclose(tr.ble_tx[:, 0], [-60.0, -66.0, -70.0 + 20 * np.log10(2.0)])
    np.testing.assert_allclose(tr.heading_offset, [0.0, 0.2, 0.2])  # no yaw at the second fix: kept
    np.testing.assert_array_equal(tr.rows(np.array([10.9, 11.0, 40.0])), [0, 1, 2])
    pooled = online_track(base, fixes, wifi, ble, 2.0, rtt, rssi, yaw, 1.0, pool=True)
    np.testing.assert_allclose(pooled.rtt_offset[:, 0], [0.0, 1.5, np.median([1.4, 1.5, 1.6, 1.0])])


def test_the_wifi_rssi_rule_applies_when_rtt_csv_has_the_column_and_is_skipped_with_a_note_when_not(renamed, tmp_path):
    import pandas as pd

    from blenav.crf.preprocess import preprocess
    from blenav.data import Dataset

    data = Path(shutil.copytree(renamed, tmp_path / "d"))
    s = next(s for s in Dataset.open(data).sessions() if s.carrier != "static")
    with_col = preprocess(s)
    assert with_col.dropped.get("rtt_weak_wifi_rssi", 0) > 0 and not with_col.notes
    kept = len(with_col.rtt_raw[0])
    f = s.root / "rtt.csv"
    pd.read_csv(f).drop(columns=["rssi"]).to_csv(f, index=False)
    s2 = Dataset.open(data).session(s.id)
    without = preprocess(s2)
    assert "no rssi column" in without.notes[0] and len(without.rtt_raw[0]) > kept
    assert np.isfinite(without.rtt).sum() >= np.isfinite(with_col.rtt).sum()
