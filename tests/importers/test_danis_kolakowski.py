"""Importers of the Danis BLE tracks and the Kolakowski BLE calibration data (real data, skipped when absent).

Expected row counts are computed here straight from the raw files, independently of the importers' code.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from helpers import copy_raw, edit_line, refused_import

from blenav.cli.importer import main as import_main
from blenav.data import Dataset, validate
from blenav.importers import run_import

pytestmark = pytest.mark.realdata

DANIS = "danis_ble_tracks"
KOLA = "kolakowski_ble_calib"
KOLA_SYSTEM_IDS = (3, 4, 5, 8, 10, 11)


def _errors(root: Path) -> list[str]:
    return [str(i) for i in validate(root) if i.is_error]


def _rows(path: Path) -> int:
    return len(pd.read_csv(path)) if path.is_file() else 0


def _set_field(sep: str, k: int, value: str):
    def edit(s: str) -> str:
        f = s.split(sep)
        f[k] = value
        return sep.join(f)
    return edit


def _check_common(out: Path) -> Dataset:
    assert _errors(out) == []
    ds = Dataset.open(out)
    for s in ds.sessions():
        fl = s.floor
        x0, x1, y0, y1 = fl.extent
        if s.labelled:
            gt = s.groundtruth
            assert len(gt) > 0
            assert np.all(np.diff(gt["t"].to_numpy()) >= 0)
            assert gt["x"].between(x0, x1).all() and gt["y"].between(y0, y1).all(), s.id
        r = s.rssi["rssi"].to_numpy()
        assert len(r) > 0
        assert np.all((r > -110) & (r < -20)), (s.id, r.min(), r.max())
        assert np.all(np.diff(s.rssi["t"].to_numpy()) >= 0)
    return ds


# --------------------------------------------------------------------------------------------------
# Danis


def _danis_expected(raw: Path) -> dict[str, tuple[int, int, int]]:
    """session id -> (raw rows, valid rssi rows, distinct packet times on the 0.1 ms grid)."""
    exp = {}
    for f in sorted((raw / "trk").glob("*_all_sensors.mbd")):
        d = pd.read_csv(f, header=None)
        assert d.shape[1] == 16
        valid = int(((d[3] < 0) & (d[3] > -150)).sum())
        t = np.round(d[0].to_numpy() - d[0].min(), 4)
        exp[f.name.replace("_all_sensors.mbd", "")] = (len(d), valid, len(np.unique(t)))
    return exp


def test_danis_real_import(raw_dir, tmp_path):
    src, out = raw_dir / DANIS, tmp_path / "danis"
    report = run_import(DANIS, src, out)
    ds = _check_common(out)
    exp = _danis_expected(src)
    assert sorted(ds.session_ids) == sorted(exp)
    assert report.sessions == 9 and report.buildings == 1
    written = 0
    for sid, (_, n_valid, n_times) in exp.items():
        sroot = out / "sessions" / sid
        assert _rows(sroot / "rssi.csv") == n_valid, sid
        assert _rows(sroot / "groundtruth.csv") == n_times, sid
        assert not (sroot / "imu.csv").exists()
        s = ds.session(sid)
        assert s.carrier == "pedestrian" and s.device_model == "danis-beacon" and s.labelled
        assert s.groundtruth[["qw", "qx", "qy", "qz"]].isna().all().all()  # see importer docstring
        assert np.all(np.diff(s.groundtruth["t"].to_numpy()) > 0)  # one row per distinct time
        written += n_valid
    # every raw row is either written or counted as dropped
    assert sum(n for n, _, _ in exp.values()) - written == sum(report.dropped.values())

    b = ds.building("tetam")
    assert len(b.anchors) == 12 and set(b.anchors["kind"]) == {"ble"}
    assert b.anchors["channel_model"].str.contains("fixed receiver; moving transmitter").all()
    fl = b.floor(0)
    gt = pd.concat([s.groundtruth for s in ds.sessions()])
    assert fl.is_free(gt[["x", "y"]].to_numpy()).mean() > 0.95
    assert any("ground truth in FREE cells" in n for n in report.notes)


def test_danis_invalid_rssi_is_dropped_and_counted(raw_dir, tmp_path):
    src, out = raw_dir / DANIS, tmp_path / "danis"
    raw = pd.read_csv(src / "trk" / "straight_05_all_sensors.mbd", header=None)
    n_bad = int((raw[3] >= 0).sum())
    assert 42 in set(raw[3])
    report = run_import(DANIS, src, out)
    key = [k for k in report.dropped if "invalid RSSI" in k]
    assert len(key) == 1 and report.dropped[key[0]] == n_bad >= 1
    rssi = pd.read_csv(out / "sessions" / "straight_05" / "rssi.csv")
    assert len(rssi) == len(raw) - n_bad
    assert (rssi["rssi"] < 0).all()


@pytest.mark.parametrize("rel, line, sep, field, value", [
    ("trk/straight_01_all_sensors.mbd", 100, ",", 3, "abc"),       # RSSI not a number
    ("trk/zigzagging_with_rotation_all_sensors.mbd", 7, ",", 4, "1.0,2.0"),  # 17 fields
    ("occ/tetam_0.1.occ", 50, "::", 1, "7"),                          # occupancy not 0/1
])
def test_danis_bad_line_names_file_and_line(raw_dir, tmp_path, rel, line, sep, field, value):
    src = copy_raw(raw_dir / DANIS, tmp_path / "raw")
    edit_line(src / rel, line, _set_field(sep, field, value))
    assert refused_import(DANIS, src, tmp_path / "out", rel, line).path.endswith(rel)


# --------------------------------------------------------------------------------------------------
# Kolakowski


def _kola_packets(path: Path) -> list[tuple[float, int, int, int]]:
    """(unix s, system id, tag id, rssi) of every BLE packet of a system log (plain loop, independent)."""
    out = []
    for line in path.read_text().splitlines():
        if not line.strip():
            continue
        f = line.split("\t")
        nb = int(f[5])
        for k in range(nb):
            p = f[7 + 8 * k: 15 + 8 * k]
            out.append((int(f[0]) / 1000.0, int(f[1]), int(p[1]), int(p[3])))
    return out


def _valid(rssi: int | float) -> bool:
    return -150 < rssi < 0


def test_kolakowski_real_import(raw_dir, tmp_path):
    src, out = raw_dir / KOLA, tmp_path / "kola"
    report = run_import(KOLA, src, out)
    ds = _check_common(out)
    sess = out / "sessions"
    raw_total = written = 0

    # robot test: packets of tag 1 with a valid RSSI inside the ground-truth span
    rdf = pd.read_csv(src / "tests" / "test_robot_df.csv", index_col=0)
    t0, t1 = rdf["ts"].min() / 1e9, rdf["ts"].max() / 1e9
    pk = _kola_packets(src / "tests" / "test_robot_ble.txt")
    exp = sum(1 for t, a, tag, r in pk if tag == 1 and _valid(r) and t0 <= t <= t1)
    assert _rows(sess / "test_robot" / "rssi.csv") == exp
    assert _rows(sess / "test_robot" / "groundtruth.csv") == len(rdf)
    raw_total += len(pk)
    written += exp

    # walk test: all valid packets, no ground truth
    pk = _kola_packets(src / "tests" / "test_walk_ble.txt")
    exp = sum(1 for t, a, tag, r in pk if tag == 1 and _valid(r))
    assert _rows(sess / "test_walk" / "rssi.csv") == exp
    assert not (sess / "test_walk" / "groundtruth.csv").exists()
    assert not ds.session("test_walk").labelled
    raw_total += len(pk)
    written += exp

    # calibration runs: one per restart of the unnamed index; rssi rows = non-empty cells
    cal = pd.read_csv(src / "calibration" / "calibration_df.csv")
    run = np.cumsum(np.r_[True, np.diff(cal.iloc[:, 0].to_numpy()) <= 0])
    rcols = [c for c in cal.columns if c.startswith("rssi_")]
    assert run.max() == 4
    for k in range(1, 5):
        part = cal[run == k]
        cells = part[rcols].to_numpy()
        exp = int((~np.isnan(cells) & (cells < 0)).sum())
        assert _rows(sess / f"calibration_run{k}" / "rssi.csv") == exp
        assert _rows(sess / f"calibration_run{k}" / "groundtruth.csv") == len(part)
        raw_total += cells.size
        written += exp

    # the unaligned earlier run: rssi + odometry, unlabelled
    old = pd.read_csv(src / "calibration" / "calib_df.csv")
    cells = old[[c for c in old.columns if c.startswith("rssi_")]].to_numpy()
    exp = int((~np.isnan(cells) & (cells < 0)).sum())
    assert _rows(sess / "calib_df_unaligned" / "rssi.csv") == exp
    assert _rows(sess / "calib_df_unaligned" / "odometry.csv") == len(old)
    assert not ds.session("calib_df_unaligned").labelled
    raw_total += cells.size
    written += exp

    assert raw_total - written == sum(report.dropped.values())
    assert report.sessions == 7 == len(ds.session_ids)

    b = ds.building("kolakowski_flat")
    a = b.anchors.sort_values("anchor_id")
    assert list(a["anchor_id"]) == ["1", "2", "3", "4", "5", "6"]
    assert list(a["system_id"].astype(int)) == list(KOLA_SYSTEM_IDS)
    assert [r.id for r in b.navgraph] == ["test_walk_reference_path"]
    gt = pd.concat([s.groundtruth for s in ds.sessions(labelled=True)])
    assert b.floor(0).is_free(gt[["x", "y"]].to_numpy()).mean() > 0.95
    assert np.allclose(gt["z"], 1.3)
    assert any("correlates best" in n for n in report.notes)
    assert not any("WARNING" in n for n in report.notes)


@pytest.mark.parametrize("rel, line, sep, field, value", [
    ("tests/test_robot_ble.txt", 300, "\t", 10, "-5x"),       # a packet's field not an integer
    ("tests/test_walk_ble.txt", 12, "\t", 5, "7"),            # announces more BLE packets than it holds
    ("calibration/calibration_df.csv", 30, ",", 2, "abc"),   # x not a number
    ("calibration/calib_df.csv", 5, ",", 1, ""),              # empty ts
])
def test_kolakowski_bad_line_names_file_and_line(raw_dir, tmp_path, rel, line, sep, field, value):
    src = copy_raw(raw_dir / KOLA, tmp_path / "raw")
    edit_line(src / rel, line, _set_field(sep, field, value))
    refused_import(KOLA, src, tmp_path / "out", rel, line)


# --------------------------------------------------------------------------------------------------
# CLI


@pytest.mark.parametrize("kind, rel, sep, field", [
    (DANIS, "trk/straight_04_all_sensors.mbd", ",", 5),
    (KOLA, "calibration/calibration_df.csv", ",", 4),
])
def test_cli_import(raw_dir, tmp_path, capsys, kind, rel, sep, field):
    assert import_main([kind, str(raw_dir / kind), str(tmp_path / "ok")]) == 0
    assert "wrote 1 building(s)" in capsys.readouterr().out
    assert _errors(tmp_path / "ok") == []

    src = copy_raw(raw_dir / kind, tmp_path / "raw")
    edit_line(src / rel, 3, _set_field(sep, field, "nan"))
    assert import_main([kind, str(src), str(tmp_path / "bad")]) == 1
    err = capsys.readouterr().err
    assert f"{Path(rel).name}:3" in err
