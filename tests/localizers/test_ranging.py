"""The range baselines of 004 sec. VI-E (blenav.localizers.ranging, ranging_windows, ranging_solvers: grid-L2,
grid-L1, SRLS) and the optional ``rssi`` column of rtt.csv (the AP's WiFi RSSI of the -65 dBm rule, 004 sec. V-A)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from scipy.optimize import minimize

from blenav.data import Dataset
from blenav.data.floor import FREE, OCCUPIED
from blenav.data.validate import validate
from blenav.data.writer import write_building, write_dataset_meta, write_session
from blenav.localizers.base import RunInputs
from blenav.localizers.ranging import GridL1Localizer, GridL2Localizer, SrlsLocalizer
from blenav.localizers.ranging_solvers import grid_costs, srls
from blenav.localizers.ranging_windows import online_corrections, rtt_offsets, wifi_rssi
from helpers import lines, set_cell, simulate_small, write_lines

GRID = 0.5
AP_XYZ = np.array([[0.6, 0.6, 1.2], [11.4, 0.6, 1.2], [0.6, 9.4, 1.2], [11.4, 9.4, 1.2], [6.0, 5.0, 2.8]])
OFFSET = np.array([0.8, -0.4, 1.5, 0.0, 0.3])  # m, per AP (what offline calibration should recover)


def _cost(x, a, r2):
    return ((((x - a) ** 2).sum(-1) - r2) ** 2).sum()


def _grad(x, a, r2):
    return (4.0 * ((((x - a) ** 2).sum(-1) - r2))[:, None] * (x - a)).sum(0)


def _brute_force(a, r2):
    """argmin of the SRLS cost: a dense grid (0.25 m over the anchors' box + 15 m), then BFGS from its 5 best
    points (the cost is a smooth quartic; every local minimum is near a grid point)."""
    lo, hi = a.min(0) - 15.0, a.max(0) + 15.0
    gx, gy = np.meshgrid(np.arange(lo[0], hi[0], 0.25), np.arange(lo[1], hi[1], 0.25))
    pts = np.c_[gx.ravel(), gy.ravel()]
    c = ((((pts[:, None] - a[None]) ** 2).sum(-1) - r2) ** 2).sum(1)
    best = None
    for i in np.argsort(c)[:5]:
        res = minimize(_cost, pts[i], args=(a, r2), jac=_grad, method="BFGS", options=dict(gtol=1e-9))
        if best is None or res.fun < best.fun:
            best = res
    return best.x, best.fun


def test_srls_equals_a_brute_force_minimiser_on_random_geometries():
    rng = np.random.default_rng(15)
    K, A = 30, 6
    a = rng.uniform(0.0, 25.0, (K, A, 2))
    x0 = rng.uniform(0.0, 25.0, (K, 2))
    r = np.linalg.norm(a - x0[:, None], axis=2) + rng.normal(0.0, 1.5, (K, A))
    mask = rng.random((K, A)) < 0.8
    mask[:, :3] = True  # at least 3 ranges each
    x = srls(a, np.where(mask, r * r, np.nan))  # NaN = a range not measured
    for k in range(K):
        ak, r2 = a[k][mask[k]], (r[k] ** 2)[mask[k]]
        xb, fb = _brute_force(ak, r2)
        assert _cost(x[k], ak, r2) <= fb * (1 + 1e-9) + 1e-9, k
        np.testing.assert_allclose(x[k], xb, atol=1e-4)


def test_srls_on_collinear_anchors_equals_brute_force_up_to_the_mirror():
    """A corridor's APs on one line: A^T A is singular; the cost's minimum is off the line (two mirror points)
    or on it (ranges shorter than the geometry allows)."""
    rng = np.random.default_rng(4)
    for k in range(12):
        p0, ang = rng.uniform(0, 20, 2), rng.uniform(0, np.pi)
        u = np.array([np.cos(ang), np.sin(ang)])
        a = p0 + rng.uniform(-15, 15, (4, 1)) * u
        x0 = p0 + rng.uniform(-10, 10) * u + (rng.uniform(-6, 6) if k % 3 else 0.0) * np.array([-u[1], u[0]])
        r2 = (np.linalg.norm(a - x0, axis=1) + rng.normal(0, 1.0, 4)) ** 2
        x = srls(a, r2[None])[0]
        xb, fb = _brute_force(a, r2)
        assert _cost(x, a, r2) <= fb * (1 + 1e-8) + 1e-8, k
        rel = x - p0
        mirror = p0 + 2 * (rel @ u) * u - rel
        assert min(np.linalg.norm(x - xb), np.linalg.norm(mirror - xb)) < 1e-4, k


def test_srls_noise_free_is_exact_and_too_few_ranges_give_nan():
    a = np.array([[0.0, 0.0], [10.0, 0.0], [0.0, 8.0], [7.0, 9.0]])
    x0 = np.array([[3.0, 4.0], [8.5, 1.0]])
    r2 = ((x0[:, None] - a[None]) ** 2).sum(-1)
    r2[1, 2:] = np.nan  # two ranges: no 2-D position
    x = srls(a, r2)
    np.testing.assert_allclose(x[0], x0[0], atol=1e-7)
    assert np.isnan(x[1]).all()


def test_grid_costs_pick_the_true_cell_for_l2_and_l1():
    gx, gy = np.meshgrid(np.arange(0.25, 12, GRID), np.arange(0.25, 10, GRID))
    cells = np.c_[gx.ravel(), gy.ravel()]
    truth = cells[[17, 230, 401]]
    d = np.sqrt(((truth[:, None] - AP_XYZ[None, :, :2]) ** 2).sum(-1) + (AP_XYZ[None, :, 2] - 1.2) ** 2)
    d[2, 1] = np.nan  # a missing range
    for loss in ("l2", "l1"):
        best = grid_costs(cells, AP_XYZ, d, 1.2, loss, chunk_elems=1000)  # small chunks: several passes
        np.testing.assert_array_equal(best, [17, 230, 401])
    assert grid_costs(cells, AP_XYZ, np.full((1, 5), np.nan), 1.2)[0] == -1
    with pytest.raises(ValueError, match="loss"):
        grid_costs(cells, AP_XYZ, d, 1.2, "huber")


# ---------------------------------------------------------------------------------------- a synthetic building
def _ranges(xy, t, rng=None, offset=True):
    """One RTT reading per AP per time: 3-D distance + the AP's offset (noise-free unless rng)."""
    n = len(t)
    tt = np.repeat(t, len(AP_XYZ)) + np.tile(np.arange(len(AP_XYZ)) * 0.01, n)
    p = np.repeat(xy, len(AP_XYZ), axis=0)
    a = np.tile(AP_XYZ, (n, 1))
    d = np.sqrt(((p - a[:, :2]) ** 2).sum(1) + (a[:, 2] - 1.2) ** 2) + (np.tile(OFFSET, n) if offset else 0.0)
    if rng is not None:
        d = d + rng.normal(0.0, 0.05, d.size)
    return pd.DataFrame({"t": tt, "anchor_id": np.tile([f"ap{i}" for i in range(len(AP_XYZ))], n), "range_m": d,
                         "range_std_m": np.nan})


def _gt(t, xy):
    return pd.DataFrame({"t": t, "x": xy[:, 0], "y": xy[:, 1], "z": 1.2, "qw": np.nan, "qx": np.nan, "qy": np.nan,
                         "qz": np.nan})


@pytest.fixture(scope="module")
def hall(tmp_path_factory) -> Path:
    """A 12 m x 10 m hall (walls at the border), 5 RTT APs with known range offsets; a walk whose positions are
    0.5 m cell centres, one per second (RTT readings noise-free), a visual fix in two of its seconds, and a
    labelled static survey (noisy readings) for offline calibration."""
    root = tmp_path_factory.mktemp("ranging") / "hall"
    write_dataset_meta(root, "hall", "test_ranging", "CC0", "tests/localizers/test_ranging.py")
    occ = np.full((100, 120), FREE, np.int8)  # 0.1 m/px
    occ[:1, :] = occ[-1:, :] = occ[:, :1] = occ[:, -1:] = OCCUPIED
    anchors = pd.DataFrame({"anchor_id": [f"ap{i}" for i in range(5)], "kind": "wifi_rtt", "x": AP_XYZ[:, 0],
                            "y": AP_XYZ[:, 1], "z": AP_XYZ[:, 2], "floor": 0, "tx_power_dbm": np.nan,
                            "channel_model": "test"})
    write_building(root, "atrium-b", "hall", [{"id": 0, "occupancy": occ, "resolution": 0.1, "origin": (0.0, 0.0)}],
                   anchors)
    t = np.arange(20.0)
    xy = np.c_[1.75 + 0.5 * t, 2.25 + 0.25 * (t // 2) * 2]  # cell centres of the 0.5 m grid
    rtt = _ranges(xy, t + 0.2)
    vis = pd.DataFrame({"t": [5.5, 12.5], "x": [9.0, 2.0], "y": [8.0, 3.0], "z": 1.2, "yaw": 0.0})
    write_session(root, "walk-7", {"building": "atrium-b", "floor": 0, "device_model": "phone-x",
                                   "carrier": "pedestrian", "labelled": True},
                  {"rtt": rtt, "visual": vis, "groundtruth": _gt(t + 0.5, xy)})
    rng = np.random.default_rng(3)
    pts = np.repeat(np.array([[3.0, 3.0], [8.0, 7.0], [6.0, 2.0], [10.0, 5.0]]), 10, axis=0)
    ts = np.arange(len(pts), dtype=float)
    write_session(root, "survey-2", {"building": "atrium-b", "floor": 0, "device_model": "phone-x",
                                     "carrier": "static", "labelled": True},
                  {"rtt": _ranges(pts, ts, rng), "groundtruth": _gt(ts, pts)})
    return root


def _truth(ds):
    gt = ds.session("walk-7").groundtruth
    return gt[["x", "y"]].to_numpy()


@pytest.mark.parametrize("cls", [GridL2Localizer, GridL1Localizer, SrlsLocalizer])
def test_baselines_recover_a_noise_free_position(hall, cls):
    ds = Dataset.open(hall)
    s = ds.session("walk-7")
    # offline calibration removes the APs' offsets exactly enough for the grid (noise 5 cm on the survey)
    loc = cls("m", sources=["rtt"], calibration="offline", visual=False, stamp="last")
    est = loc.run(s, 2, 0, RunInputs())
    assert est.position.shape == (2, 20, 2) and np.array_equal(est.position[0], est.position[1])
    np.testing.assert_allclose(est.t, np.arange(20.0) + 0.24)  # each window's last reading
    err = np.linalg.norm(est.position[0] - _truth(ds), axis=1)
    assert err.max() < (0.05 if cls is not SrlsLocalizer else 0.15), err
    assert any("offline calibration on survey-2" in n for n in est.notes)
    # uncalibrated, offsets of up to 1.5 m move the estimates
    raw = cls("m", sources=["rtt"], calibration="none", visual=False).run(s, 1, 0, RunInputs())
    assert np.linalg.norm(raw.position[0] - _truth(ds), axis=1).mean() > 0.3
    np.testing.assert_allclose(raw.t, np.arange(20.0) + 1.2)  # stamp: end (the default): windows from 0.2 s


def test_rtt_offsets_recovered_from_the_survey(hall):
    ds = Dataset.open(hall)
    s = ds.session("walk-7")
    from blenav.localizers.ranging_windows import rtt_readings

    anchors = rtt_readings(s)[3]
    off = rtt_offsets([ds.session("survey-2")], anchors, device_z=1.2)
    np.testing.assert_allclose(off, OFFSET, atol=0.05)
    # online: the medians of the second after each fix, from then on, forward-filled per anchor
    t = np.array([1.0, 1.2, 1.5, 5.0, 5.3])
    idx = np.array([0, 0, 1, 0, 0])
    v = np.array([3.0, 5.0, 7.0, 10.0, 12.0])
    ta, c = online_corrections(np.array([1.0, 5.0]), np.zeros((2, 2)), t, idx, v, lambda v, i, xy: v, 2, 1.0)
    np.testing.assert_allclose(ta, [2.0, 6.0])
    np.testing.assert_allclose(c, [[4.0, 7.0], [11.0, 7.0]])


def test_offline_calibration_is_the_crf_one_at_a_fixed_height(hall):
    """ranging_windows.rtt_offsets is blenav.crf.calibration.offline_calibration at the device height: numbers
    against a median computed here from the survey's rows; with the ground truth's own z (1.2 m) the CRF's default
    agrees; the 004 sec. V-A thresholds have one definition; ble_tx_powers' d0 shifts the level by 10 n log10(d0)."""
    from blenav.crf import preprocess as P
    from blenav.crf.calibration import ble_tx_powers, offline_calibration
    from blenav.localizers import crf as crf_loc
    from blenav.localizers import ranging_windows as R

    ds = Dataset.open(hall)
    survey = ds.session("survey-2")
    anchors = R.rtt_readings(ds.session("walk-7"))[3]
    rtt, gt = survey.rtt, survey.groundtruth
    t = rtt["t"].to_numpy(float)
    xy = np.c_[np.interp(t, gt["t"], gt["x"]), np.interp(t, gt["t"], gt["y"])]
    row = anchors.index_of(rtt["anchor_id"].astype(str).to_numpy())
    for z in (1.2, 2.0):
        d = np.sqrt(((anchors.xyz[row, :2] - xy) ** 2).sum(1) + (anchors.xyz[row, 2] - z) ** 2)
        ref = [np.median(rtt["range_m"].to_numpy(float)[row == a] - d[row == a]) for a in range(len(anchors.ids))]
        np.testing.assert_allclose(R.rtt_offsets([survey], anchors, device_z=z), ref, rtol=0, atol=1e-12)
    none = R.NO_ANCHORS
    np.testing.assert_allclose(offline_calibration([survey], anchors, none, 2.0).rtt_offset,
                               R.rtt_offsets([survey], anchors, device_z=1.2), rtol=0, atol=1e-12)
    assert (R.WIFI_MIN_RSSI_DBM, R.BLE_MIN_RSSI_DBM) == (P.WIFI_MIN_RSSI_DBM, P.BLE_MIN_RSSI_DBM) == (-65.0, -90.0)
    assert crf_loc.WIFI_MIN_RSSI_DBM is P.WIFI_MIN_RSSI_DBM
    tx = ble_tx_powers(np.array([0, 0, 1]), np.array([-60.0, -62.0, -70.0]), np.array([2.0, 2.0, 0.05]), 2.0, 2, d0=2.0)
    np.testing.assert_allclose(tx, [-61.0, -70.0 + 20.0 * np.log10(0.1 / 2.0)], rtol=0, atol=1e-12)


def test_visual_fix_is_the_estimate_of_its_window(hall):
    ds = Dataset.open(hall)
    s = ds.session("walk-7")
    for cls in (GridL2Localizer, GridL1Localizer, SrlsLocalizer):
        est = cls("m", sources=["rtt"], calibration="online").run(s, 1, 0, RunInputs())
        np.testing.assert_allclose(est.position[0, 5], [9.0, 8.0])  # the fix at 5.5 s (window [5, 6))
        np.testing.assert_allclose(est.position[0, 12], [2.0, 3.0])
        off = cls("m", sources=["rtt"], calibration="online", visual=False).run(s, 1, 0, RunInputs())
        assert np.linalg.norm(off.position[0, 5] - [9.0, 8.0]) > 3.0
        assert any("online calibration at 2 visual fix(es)" in n for n in est.notes)


def test_missing_streams_and_bad_settings(hall):
    s = Dataset.open(hall).session("walk-7")
    from blenav.errors import MissingStream

    with pytest.raises(MissingStream, match="no BLE reading"):
        GridL2Localizer("m", sources=["ble"]).run(s, 1, 0, RunInputs())
    # both sources asked, only RTT present: runs on RTT and says so
    est = GridL2Localizer("m", calibration="none").run(s, 1, 0, RunInputs())
    assert any("ranges from the other modality only" in n for n in est.notes)
    with pytest.raises(MissingStream, match="static sessions"):
        GridL2Localizer("m", sources=["rtt"], calibration="offline", calibration_sessions=[]).run(
            Dataset.open(hall).session("survey-2"), 1, 0, RunInputs())
    # calibration_modalities: [] switches the correction off (online == none)
    a = GridL2Localizer("m", sources=["rtt"], calibration="online", calibration_modalities=[]).run(s, 1, 0, RunInputs())
    b = GridL2Localizer("m", sources=["rtt"], calibration="none").run(s, 1, 0, RunInputs())
    np.testing.assert_array_equal(a.position, b.position)
    for bad in ({"calibration": "sometimes"}, {"sources": ["uwb"]}, {"stamp": "mid"}, {"min_ranges": 0},
                {"calibration_modalities": ["wifi"]}):
        with pytest.raises(ValueError):
            GridL2Localizer("m", **bad)


# ---------------------------------------------------------------------------------------- rtt.csv rssi column
@pytest.fixture(scope="module")
def small(tmp_path_factory):
    return simulate_small(tmp_path_factory.mktemp("ranging_sim") / "small", 5, 40, 1)


def test_rssi_column_written_by_sim_read_validated_and_optional(small, tmp_path):
    import shutil

    assert not [i for i in validate(small) if i.is_error]
    s = next(Dataset.open(small).sessions())
    rtt = s.rtt
    assert "rssi" in rtt.columns and rtt["rssi"].dtype == float and len(rtt)
    v = wifi_rssi(rtt)
    assert np.isfinite(v).all() and (v < 0).all() and (v > -150).all() and np.all(v == np.round(v))
    assert (v < -65).any() and (v >= -65).any()  # the -65 dBm rule has something to do
    # the -65 dBm rule: weak ranges are dropped and counted
    est = GridL2Localizer("m", calibration="none").run(s, 1, 0, RunInputs())
    assert any(f"{int((v < -65).sum())} RTT ranges below -65 dBm dropped" in n for n in est.notes)
    # a sentinel in the column: an error naming file, line and rule; an empty cell is fine
    bad = tmp_path / "bad"
    shutil.copytree(small, bad)
    path = next((bad / "sessions").iterdir()) / "rtt.csv"
    set_cell(path, 3, "rssi", "0")
    set_cell(path, 4, "rssi", "")
    errs = [i for i in validate(bad) if i.is_error]
    assert [(i.rule, Path(i.path).name, i.line) for i in errs] == [("rssi-range", "rtt.csv", 3)], errs
    # without the column: still a valid dataset; the reader's frame has no rssi column, wifi_rssi gives NaN
    set_cell(path, 3, "rssi", "-70")
    ls = lines(path)
    write_lines(path, [",".join(row.split(",")[:-1]) for row in ls])
    assert not [i for i in validate(bad) if i.is_error]
    r = Dataset.open(bad).session(path.parent.name).rtt
    assert "rssi" not in r.columns and np.isnan(wifi_rssi(r)).all()
    np.testing.assert_allclose(r["range_m"], rtt["range_m"])


def test_simulator_outputs_other_than_the_rssi_column_are_unchanged(tmp_path):
    a = simulate_small(tmp_path / "a", 8, 15, 1)
    b = simulate_small(tmp_path / "b", 8, 15, 1, "sim.rtt.write_rssi=false")
    fa = sorted(p.relative_to(a) for p in a.rglob("*") if p.is_file())
    assert fa == sorted(p.relative_to(b) for p in b.rglob("*") if p.is_file())
    for f in fa:
        if f.name == "rtt.csv":
            ra, rb = pd.read_csv(a / f), pd.read_csv(b / f)
            assert list(ra.columns) == list(rb.columns) + ["rssi"]
            pd.testing.assert_frame_equal(ra.drop(columns="rssi"), rb)
        elif f.name == "dataset.yaml":  # it records the simulator's settings (blenav.sim.world.sim_parameters): the switch differs
            import yaml

            ya, yb = (yaml.safe_load((d / f).read_text()) for d in (a, b))
            assert ya["simulator"]["config"]["rtt"].pop("write_rssi") is True
            assert yb["simulator"]["config"]["rtt"].pop("write_rssi") is False
            assert ya == yb
        else:
            assert (a / f).read_bytes() == (b / f).read_bytes(), f


# ---------------------------------------------------------------------------------------- real data
@pytest.mark.realdata
def test_feng_rtt_points_with_and_without_calibration(raw_dir, tmp_path):
    """The Feng et al. lecture theatre (line of sight, 5 APs): RTT-only grid-L2 at the test points, offline
    calibration on the train points (measured: 0.78 m -> 0.69 m mean without the -65 dBm rule)."""
    from blenav.importers.feng_wifi_rtt import import_feng_wifi_rtt

    out = tmp_path / "feng"
    import_feng_wifi_rtt(raw_dir / "feng_wifi_rtt", out)
    s = Dataset.open(out).session("lecture_theatre_test")
    assert "rssi" in s.rtt.columns and np.isfinite(wifi_rssi(s.rtt)).all()
    gt = s.groundtruth
    errs = {}
    for cal in ("none", "offline"):
        loc = GridL2Localizer("m", sources=["rtt"], calibration=cal, visual=False, stamp="last", hold=False,
                              min_wifi_rssi_dbm=None)
        est = loc.run(s, 1, 0, RunInputs())
        ref = np.c_[np.interp(est.t, gt["t"], gt["x"]), np.interp(est.t, gt["t"], gt["y"])]
        errs[cal] = float(np.linalg.norm(est.position[0] - ref, axis=1).mean())
    assert errs["offline"] < errs["none"] < 1.2, errs
    assert errs["offline"] < 0.8, errs
