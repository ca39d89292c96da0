"""Importers of the UJI BLE and Feng WiFi RTT public recordings (blenav.importers.uji_ble / feng_wifi_rtt).

Tests marked ``realdata`` read ../shared/data/raw and skip when it is absent. Expected counts are
computed here from the raw files with plain pandas/numpy, independently of the importers' parsers.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd
import pytest
import yaml

from helpers import copy_raw, edit_line, refused_import

from blenav.cli.importer import main as import_main
from blenav.data import Dataset, validate
from blenav.errors import ImportError_
from blenav.importers import run_import
from blenav.importers.uji_ble import occupancy_grid, read_cells

UJI_ZONES = ("lib", "geo")
FENG_ENVS = ("lecture_theatre", "office", "corridor")


@pytest.fixture(scope="module")
def imported(tmp_path_factory):
    """Import each real set once per module: ``get(kind, raw_dir) -> (out, report)``."""
    cache: dict = {}

    def get(kind: str, raw_dir: Path):
        if kind not in cache:
            out = tmp_path_factory.mktemp(kind) / "ds"
            cache[kind] = (out, run_import(kind, raw_dir / kind, out))
        return cache[kind]

    return get


def errors_of(out: Path) -> list:
    return [i for i in validate(out) if i.is_error]


def load_csv(out: Path, session: str, stream: str) -> pd.DataFrame:
    return pd.read_csv(out / "sessions" / session / f"{stream}.csv", dtype={"anchor_id": str, "los_aps": str})


def sessions_meta(out: Path) -> dict[str, dict]:
    return {p.name: yaml.safe_load((p / "session.yaml").read_text()) for p in sorted((out / "sessions").iterdir())}


# --------------------------------------------------------------------------------------------------
# UJI BLE


def uji_expected(raw: Path) -> dict:
    """(zone, P, W, C) -> (fingerprints, detected cells), straight from the raw files."""
    exp = {}
    for z in UJI_ZONES:
        rss = pd.read_csv(raw / "rss" / f"{z}_rss.csv", header=None).to_numpy()
        ids = pd.read_csv(raw / "rss" / f"{z}_ids.csv", header=None)[0].to_numpy()
        key = pd.DataFrame({"P": ids // 10**7, "W": ids // 10**6 % 10, "C": ids // 10**5 % 10})
        key["n"] = 1
        key["det"] = (rss != 100).sum(axis=1)
        for (p, w, c), g in key.groupby(["P", "W", "C"]):
            exp[(z, int(p), int(w), int(c))] = (len(g), int(g["det"].sum()))
    return exp


@pytest.mark.realdata
def test_uji_import_is_valid(raw_dir, imported):
    out, report = imported("uji_ble", raw_dir)
    assert errors_of(out) == []
    assert (report.buildings, report.sessions) == (2, 9)
    ds = Dataset.open(out)
    assert ds.building_ids == ["geo", "lib"]
    for b in ds.building_ids:
        a = ds.building(b).anchors
        assert set(a["kind"]) == {"ble"} and a["tx_power_dbm"].isna().all()
    assert len(ds.building("lib").anchors) == 24 and len(ds.building("geo").anchors) == 22


@pytest.mark.realdata
def test_uji_row_counts_match_raw(raw_dir, imported):
    out, report = imported("uji_ble", raw_dir)
    exp = uji_expected(raw_dir / "uji_ble")
    got = {}
    for sid, meta in sessions_meta(out).items():
        assert meta["carrier"] == "static" and meta["labelled"] is True and meta["floor"] == 0
        assert meta["device_model"] in {"A5", "Bq", "S6"}
        codes = meta["raw_codes"]
        key = (meta["building"], codes["phone"], codes["power"], codes["campaign"])
        got[key] = (len(load_csv(out, sid, "groundtruth")), len(load_csv(out, sid, "rssi")))
    assert got == exp
    # the only dropped cells are the RSS = 100 "not detected" ones, and they are all accounted for
    n_missing = sum((pd.read_csv(raw_dir / "uji_ble" / "rss" / f"{z}_rss.csv", header=None).to_numpy() == 100).sum()
                    for z in UJI_ZONES)
    assert sum(report.dropped.values()) == n_missing
    assert all("= 100" in reason for reason in report.dropped)


@pytest.mark.realdata
def test_uji_units_and_frames(raw_dir, imported):
    out, _ = imported("uji_ble", raw_dir)
    ds = Dataset.open(out)
    raw_crd = {z: pd.read_csv(raw_dir / "uji_ble" / "rss" / f"{z}_crd.csv", header=None).to_numpy() for z in UJI_ZONES}
    for sid in ds.session_ids:
        s = ds.session(sid)
        rssi, gt = s.rssi, s.groundtruth
        assert rssi["rssi"].between(-110, -20, inclusive="neither").all()
        assert not (rssi["rssi"] == 100).any()
        assert set(rssi["anchor_id"]) <= set(s.building.anchors["anchor_id"])
        # the tms clock is in ns: consecutive fingerprints are about one second apart
        dt = np.diff(np.unique(gt["t"]))
        assert 0.5 < np.median(dt) < 2.0
        assert gt["t"].min() >= 0 and 60 < gt["t"].max() < 3600
        # every fingerprint time carries its rssi rows; t_rx lies within a few seconds before it
        assert set(rssi["t"]) <= set(gt["t"])
        lag = rssi["t"] - rssi["t_rx"]
        assert (lag >= -1e-3).all() and (lag < 5).all()
        # surveyed points: from the raw coordinates, on free pixels of the floor grid
        assert set(map(tuple, gt[["x", "y"]].round(3).to_numpy())) <= set(map(tuple, raw_crd[s.building.id].round(3)))
        assert s.floor.is_free(gt[["x", "y"]].to_numpy()).all()
        assert gt[["qw", "qx", "qy", "qz"]].isna().all().all()
        assert np.allclose(gt["z"], 1.2)


UJI_CORRUPTIONS = [
    # (file, 1-based line, edit, text expected in the message)
    ("rss/lib_rss.csv", 5, lambda s: "abc," + s.split(",", 1)[1], "not a finite number"),
    ("rss/geo_crd.csv", 7, lambda s: s.split(",")[0], "1 columns, expected 2"),
    ("rss/geo_rss.csv", 10, lambda s: "-200," + s.split(",", 1)[1], "not-detected code 100"),
    ("rss/lib_tms.csv", 12, lambda s: s + ",0", "25 columns, expected 24"),
    ("dep/geo.csv", 3, lambda s: s.replace(",", ",x", 1), "not a finite number"),
    ("rss/lib_ids.csv", 8, lambda s: "92200101", "phone code 9"),
]


@pytest.mark.realdata
@pytest.mark.parametrize("rel, line, edit, problem", UJI_CORRUPTIONS, ids=[c[0] for c in UJI_CORRUPTIONS])
def test_uji_bad_input_names_file_and_line(raw_dir, tmp_path, rel, line, edit, problem):
    src = copy_raw(raw_dir / "uji_ble", tmp_path / "raw")
    edit_line(src / rel, line, edit)
    e = refused_import("uji_ble", src, tmp_path / "out", rel, line)
    assert problem in str(e)


@pytest.mark.realdata
def test_uji_row_count_mismatch(raw_dir, tmp_path):
    src = copy_raw(raw_dir / "uji_ble", tmp_path / "raw")
    ids = src / "rss" / "lib_ids.csv"
    lines = ids.read_text().splitlines()
    ids.write_text("\n".join(lines[:-1]) + "\n")
    with pytest.raises(ImportError_) as ei:
        run_import("uji_ble", src, tmp_path / "out")
    assert Path(ei.value.path).name == "lib_ids.csv" and ei.value.line == len(lines)
    assert "rows" in ei.value.problem


@pytest.mark.realdata
def test_uji_cli(raw_dir, tmp_path, capsys):
    assert import_main(["uji_ble", str(raw_dir / "uji_ble"), str(tmp_path / "ok")]) == 0
    assert "9 session(s)" in capsys.readouterr().out
    src = copy_raw(raw_dir / "uji_ble", tmp_path / "raw")
    edit_line(src / "rss" / "geo_rss.csv", 5, lambda s: "zz," + s.split(",", 1)[1])
    assert import_main(["uji_ble", str(src), str(tmp_path / "bad")]) == 1
    assert "geo_rss.csv:5" in capsys.readouterr().err


# --------------------------------------------------------------------------------------------------
# Feng WiFi RTT


def feng_raw(raw: Path, env: str, split: str) -> pd.DataFrame:
    return pd.read_csv(raw / "data" / f"database_{env}_{split}.csv", dtype={"LOS APs": str})


@pytest.mark.realdata
def test_feng_import_is_valid(raw_dir, imported):
    out, report = imported("feng_wifi_rtt", raw_dir)
    assert errors_of(out) == []
    assert (report.buildings, report.sessions) == (3, 6)
    ds = Dataset.open(out)
    assert ds.building_ids == sorted(FENG_ENVS)
    assert ds.session_ids == sorted(f"{e}_{s}" for e in FENG_ENVS for s in ("train", "test"))
    assert list(ds.building("corridor").anchors["anchor_id"]) == ["AP2", "AP3", "AP4", "AP5"]
    assert list(ds.building("office").anchors["anchor_id"]) == [f"AP{k}" for k in range(1, 6)]
    for b in FENG_ENVS:
        assert set(ds.building(b).anchors["kind"]) == {"wifi_rtt"}
        assert "WiFi RSS" in ds.building(b).anchors["channel_model"].iloc[0]


@pytest.mark.realdata
def test_feng_row_counts_match_raw(raw_dir, imported):
    out, report = imported("feng_wifi_rtt", raw_dir)
    raw = raw_dir / "feng_wifi_rtt"
    n_rtt_missing = n_rss_missing = 0
    for env in FENG_ENVS:
        for split in ("train", "test"):
            d = feng_raw(raw, env, split)
            rtt = d.filter(like="RTT(mm)").to_numpy()
            rss = d.filter(like="RSS(dBm)").to_numpy()
            sid = f"{env}_{split}"
            meta = sessions_meta(out)[sid]
            assert (meta["building"], meta["carrier"], meta["labelled"], meta["device_model"]) == \
                (env, "static", True, "unknown")
            gt = load_csv(out, sid, "groundtruth")
            assert len(gt) == len(d)
            assert len(load_csv(out, sid, "rtt")) == (rtt != 100000).sum()
            assert len(load_csv(out, sid, "rssi")) == (rss != -200).sum()
            n_rtt_missing += (rtt == 100000).sum()
            n_rss_missing += (rss == -200).sum()
            # los_aps kept verbatim (empty stays empty)
            assert gt["los_aps"].fillna("").tolist() == d["LOS APs"].fillna("").tolist()
    drops = report.dropped
    assert sum(n for r, n in drops.items() if r.startswith("RTT cells")) == n_rtt_missing
    assert sum(n for r, n in drops.items() if r.startswith("RSS cells")) == n_rss_missing
    assert sum(n for r, n in drops.items() if "without a position" in r) == 0


@pytest.mark.realdata
def test_feng_units_and_frames(raw_dir, imported):
    out, _ = imported("feng_wifi_rtt", raw_dir)
    ds = Dataset.open(out)
    raw = raw_dir / "feng_wifi_rtt"
    for sid in ds.session_ids:
        s = ds.session(sid)
        env, split = sid.rsplit("_", 1)
        d = feng_raw(raw, env, split)
        gt, rtt, rssi = s.groundtruth, s.rtt, s.rssi
        # grid indices * 0.6 m
        assert np.allclose(gt["x"], d["X"] * 0.6) and np.allclose(gt["y"], d["Y"] * 0.6)
        assert s.floor.is_free(gt[["x", "y"]].to_numpy()).all()
        # RSS in dBm, RTT ranges in metres (not mm), bounded by the size of the floor grid
        assert rssi["rssi"].between(-110, -20, inclusive="neither").all()
        x0, x1, y0, y1 = s.floor.extent
        diag = np.hypot(x1 - x0, y1 - y0)
        assert 0 < rtt["range_m"].median() < diag
        assert rtt["range_m"].abs().max() < 1.5 * diag
        assert rtt["range_std_m"].isna().all()
        # the AP positions are in the same frame: per-point median range follows the distance
        pos = gt[["t", "x", "y"]].merge(rtt, on="t")
        a = s.building.anchors.set_index("anchor_id")
        pos["dist"] = np.hypot(pos["x"] - a.loc[pos["anchor_id"], "x"].to_numpy(),
                               pos["y"] - a.loc[pos["anchor_id"], "y"].to_numpy())
        med = pos.groupby(["anchor_id", "x", "y"])[["range_m", "dist"]].median().reset_index()
        for ap, g in med.groupby("anchor_id"):
            assert np.corrcoef(g["dist"], g["range_m"])[0, 1] > 0.9, (sid, ap)
        # synthetic clock: one raw row per second
        assert np.allclose(gt["t"], np.arange(len(d)))


FENG_CORRUPTIONS = [
    ("data/database_office_train.csv", 5, lambda s: ",".join(["0.0", "1.0", "x"] + s.split(",")[3:]),
     "not a finite number"),
    ("data/database_corridor_test.csv", 9, lambda s: s.rsplit(",", 1)[0], "12 columns, expected 13"),
    ("data/database_lecture_theatre_test.csv", 20, lambda s: ",".join(s.split(",")[:7] + ["5.0"] + s.split(",")[8:]),
     "not-received code -200"),
    ("data/database_office_test.csv", 4, lambda s: s.rsplit(",", 1)[0] + ",1 two", "LOS APs"),
    ("data/database_corridor_train.csv", 1, lambda s: s.replace("X,Y", "x,y"), "header"),
    ("data/lecture theatre+office+corridor_AP_position.txt", 2, lambda s: "AP X: 3,10,abc,3,19", "not a finite"),
    ("data/lecture theatre+office+corridor_AP_position.txt", 11, lambda s: "AP Y:7.5,6.8,9", "but 3 AP Y values"),
]


@pytest.mark.realdata
@pytest.mark.parametrize("rel, line, edit, problem", FENG_CORRUPTIONS,
                         ids=[f"{Path(c[0]).name}:{c[1]}" for c in FENG_CORRUPTIONS])
def test_feng_bad_input_names_file_and_line(raw_dir, tmp_path, rel, line, edit, problem):
    src = copy_raw(raw_dir / "feng_wifi_rtt", tmp_path / "raw")
    edit_line(src / rel, line, edit)
    out = tmp_path / "out"
    e = refused_import("feng_wifi_rtt", src, out, rel, line)
    assert problem in str(e)
    assert not (out / "sessions").exists()


@pytest.mark.realdata
def test_feng_cli(raw_dir, tmp_path, capsys):
    assert import_main(["feng_wifi_rtt", str(raw_dir / "feng_wifi_rtt"), str(tmp_path / "ok")]) == 0
    assert "6 session(s)" in capsys.readouterr().out
    src = copy_raw(raw_dir / "feng_wifi_rtt", tmp_path / "raw")
    edit_line(src / "data" / "database_office_test.csv", 5, lambda s: "nan" + s[s.index(","):])
    assert import_main(["feng_wifi_rtt", str(src), str(tmp_path / "bad")]) == 1
    assert "database_office_test.csv:5" in capsys.readouterr().err


# --------------------------------------------------------------------------------------------------
# helpers, no real data needed


def test_read_cells_reports_line(tmp_path):
    p = tmp_path / "a.csv"
    p.write_text("a,b\n1,2\n3,4\n5\n")
    with pytest.raises(ImportError_) as ei:
        read_cells(p, 2, header=("a", "b"))
    assert ei.value.line == 4 and "1 columns, expected 2" in ei.value.problem
    p.write_text("a,b\n1,2\n\n3,4\n")
    with pytest.raises(ImportError_, match=r"a\.csv:3: blank line"):
        read_cells(p, 2, header=("a", "b"))
    p.write_text("a,b\r\n1, 2\r\n\r\n")  # CRLF and trailing blank line are fine
    cells, first = read_cells(p, 2, header=("a", "b"))
    assert first == 2 and cells.tolist() == [["1", "2"]]


def test_occupancy_grid_covers_points_and_marks_obstacles():
    from shapely.geometry import box

    from blenav.data import FREE, OCCUPIED

    occ, origin = occupancy_grid(np.array([[0.0, 0.0], [4.0, 2.0]]), [box(1.0, 0.5, 2.0, 1.5)], 0.1, 1.0)
    assert origin == pytest.approx((-1.0, -1.0)) and occ.shape == (40, 60)
    # pixel containing world (1.5, 1.0): col 25, row from top 40 - 1 - 20
    assert occ[40 - 1 - 20, 25] == OCCUPIED and occ[0, 0] == FREE
    assert (occ == OCCUPIED).sum() == 100
