"""The ILC 2.0 importer (blenav.importers.ilc20) and the format extensions it needs (wifi.csv, orientation.csv,
anchors without a position, sparse ground truth).

Synthetic path files are written here (independent of ../shared); tests marked ``realdata`` unpack a few walks
of ../shared/data/raw/ilc20/site1_F1.tar.gz into a temporary folder and skip when it is absent. Expected counts
are computed from the raw lines with plain Python, independently of the importer's parser.
"""

from __future__ import annotations

import json
import math
import tarfile
import zipfile
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
import yaml

from blenav.cli.importer import main as import_main
from blenav.data import Dataset, validate
from blenav.data.building import AnchorPositionsUnknown
from blenav.errors import ImportError_
from blenav.importers import run_import

from ilc20_helpers import UUID, walk_lines, write_floor, write_walk

def errors_of(out: Path) -> list:
    return [i for i in validate(out) if i.is_error]


@pytest.fixture
def floor(tmp_path) -> Path:
    d = write_floor(tmp_path / "raw")
    write_walk(d, "walkA", walk_lines())
    write_walk(d, "walkB", walk_lines(start=1_600_000_100_000, waypoints=((3.0, 3.0), (30.0, 5.0))))
    return d


# --------------------------------------------------------------------------- synthetic: what is written


def test_floor_folder_imports_and_validates(floor, tmp_path):
    out = tmp_path / "ds"
    rep = run_import("ilc20", floor, out)
    assert rep.sessions == 2 and rep.buildings == 1
    assert errors_of(out) == []
    ds = Dataset.open(out)
    assert ds.session_ids == ["mall_F1_walkA", "mall_F1_walkB"]
    s = ds.session("mall_F1_walkA")
    assert s.meta["device_model"] == "ACME X1" and s.labelled and s.groundtruth_sparse
    assert s.meta["sensor_time_offset_s"] == 0.0
    assert s.meta["gyro_calibrated"] is True and s.gyro_calibrated  # TYPE_GYROSCOPE: Android's bias-corrected rates
    # ground truth: the three waypoints, nothing interpolated, positions as written
    gt = s.groundtruth
    np.testing.assert_allclose(gt[["x", "y"]].to_numpy(), [[5, 5], [15, 6], [20, 8]])
    np.testing.assert_allclose(gt["t"].to_numpy(), [0.010, 2.510, 5.010])
    assert gt[["qw", "qx", "qy", "qz"]].isna().all().all()
    # IMU: accelerometer and gyroscope paired on equal times; session clock from startTime
    assert len(s.imu) == 300
    np.testing.assert_allclose(s.imu["t"].to_numpy()[:2], [0.100, 0.120])
    np.testing.assert_allclose(s.imu[["ax", "ay", "az"]].to_numpy()[0], [0.1, 0.2, 9.8])
    np.testing.assert_allclose(s.imu["gz"].to_numpy()[:3], [0.0, 0.001, 0.002])
    assert len(s.mag) == 300
    # orientation: unit quaternion from the rotation vector, qw = sqrt(1 - 0.36) = 0.8
    np.testing.assert_allclose(s.orientation[["qw", "qx", "qy", "qz"]].to_numpy()[0], [0.8, 0, 0, 0.6], atol=1e-7)
    # WiFi: one row per AP per scan, bssid lower case, SSID with a comma survives (quoted), t_seen on the clock
    wifi = s.wifi
    assert len(wifi) == 12 and set(wifi["bssid"]) == {"aa:bb:cc:00:00:01", "aa:bb:cc:00:00:02"}
    raw = pd.read_csv(s.root / "wifi.csv")
    assert raw["ssid"].iloc[0] == "shop,wifi"
    np.testing.assert_allclose(raw["t_seen"].iloc[:2], [0.2, -1.5])
    np.testing.assert_allclose(wifi["freq_mhz"].iloc[:2], [2412, 5180])
    # beacons: ids UUID:major:minor:MAC (the triple alone is shared by both beacons), positions unknown
    b = ds.building("mall")
    assert sorted(b.anchors["anchor_id"]) == [f"{UUID}:0:0:E0:78:A3:00:00:01", f"{UUID}:0:0:E0:78:A3:00:00:02"]
    assert b.anchors[["x", "y", "z"]].isna().all().all() and (b.anchors["tx_power_dbm"] == -56).all()
    assert len(s.rssi) == 12 and s.dropped == {}  # kept, not dropped as unknown anchors
    assert len(b.anchors_without_position("ble")) == 2
    with pytest.raises(AnchorPositionsUnknown, match="no.*|none"):
        b.require_anchor_positions("ble", "PF-PL")
    # the plan: free corridor, the shop unknown (not a wall), outside the outline occupied; the shop is a room
    fl = b.floor("F1")
    assert fl.resolution == 0.1 and fl.shape == (200, 400)
    assert fl.lookup(np.array([[5.0, 5.0], [30.0, 14.5], [39.95, 19.95]])).tolist() == [0, -1, 0]
    assert [r.id for r in b.rooms_on("F1")] == ["shop1"]
    np.testing.assert_allclose(b.rooms_on("F1")[0].geometry.bounds, [25, 12, 35, 17], atol=1e-6)
    assert b.meta["alignment"]["F1"]["on_walkable"] == 1.0 and b.meta["alignment"]["F1"]["waypoints"] == 5
    assert rep.dropped["rows of TYPE_ACCELEROMETER_UNCALIBRATED (documented, not imported)"] == 600


def test_archives_and_challenge_layout_give_the_same_sessions(floor, tmp_path):
    ref = tmp_path / "ref"
    run_import("ilc20", floor, ref)
    site = floor.parent
    tgz = tmp_path / "mall.tar.gz"
    with tarfile.open(tgz, "w:gz") as tf:
        tf.add(site, arcname="mall")
    zp = tmp_path / "mall.zip"
    with zipfile.ZipFile(zp, "w") as zf:
        for p in sorted(site.rglob("*")):
            zf.write(p, p.relative_to(site.parent).as_posix())
    chal = tmp_path / "kaggle"
    (chal / "train" / "mall" / "F1").mkdir(parents=True)
    (chal / "metadata" / "mall" / "F1").mkdir(parents=True)
    for p in (floor / "path_data_files").iterdir():
        (chal / "train" / "mall" / "F1" / p.name).write_bytes(p.read_bytes())
    for n in ("floor_info.json", "geojson_map.json"):
        (chal / "metadata" / "mall" / "F1" / n).write_bytes((floor / n).read_bytes())
    for i, src in enumerate((tgz, zp, site, chal, chal / "train")):
        out = tmp_path / f"o{i}"
        run_import("ilc20", src, out)
        for sid in ("mall_F1_walkA", "mall_F1_walkB"):
            for f in ("imu.csv", "wifi.csv", "rssi.csv", "groundtruth.csv", "orientation.csv", "mag.csv"):
                assert (out / "sessions" / sid / f).read_bytes() == (ref / "sessions" / sid / f).read_bytes(), (src, f)
        assert (out / "buildings/mall/anchors.csv").read_bytes() == (ref / "buildings/mall/anchors.csv").read_bytes()


def test_floors_option_and_cli(tmp_path, capsys):
    root = tmp_path / "raw"
    for fl in ("F1", "F2"):
        write_walk(write_floor(root, floor=fl), "w", walk_lines())
    out = tmp_path / "one"
    assert import_main(["ilc20", str(root / "mall"), str(out), "--floors", "mall/F2"]) == 0
    assert Dataset.open(out).session_ids == ["mall_F2_w"]
    assert errors_of(out) == []
    assert import_main(["ilc20", str(root / "mall"), str(tmp_path / "bad"), "--floors", "mall/F9"]) == 1
    err = capsys.readouterr().err
    assert "mall/F9" in err and "mall/F1, mall/F2" in err
    assert not (tmp_path / "bad").exists()
    both = tmp_path / "both"
    assert import_main(["ilc20", str(root), str(both)]) == 0
    b = Dataset.open(both).building("mall")
    assert list(b.floors) == ["F1", "F2"] and b.floor("F2").z == 5.0


# --------------------------------------------------------------------------- synthetic: bad input


@pytest.mark.parametrize("edit,line,what", [
    # line 10 is the second accelerometer row (3 header lines, a waypoint, the five rows of the first sample)
    (lambda L: L[:9] + [L[9].replace("0.2", "0.2x", 1)] + L[10:], 10, "'y': '0.2x' is not a finite number"),
    (lambda L: L[:9] + ["\t".join(L[9].split("\t")[:4])] + L[10:], 10, "4 tab-separated fields, expected 5 or 6"),
    (lambda L: L[:9] + ["16000x0000110\tTYPE_WAYPOINT\t1\t2"] + L[9:], 10, "is not an integer"),
    (lambda L: L[:9] + [""] + L[9:], 10, "blank line"),
    (lambda L: L[:9] + [L[9].replace("9.8", "nan")] + L[10:], 10, "'z': 'nan' is not a finite number"),
    (lambda L: L[:9] + [L[9] + "\t1" * 20] + L[10:], 10, "26 tab-separated fields, expected 5 or 6"),
    (lambda L: L[:9] + ["1600000000120\tTYPE_ACCELEROMETER\t1\t2"] + L[9:], 10, "4 tab-separated fields"),
])
def test_malformed_line_names_file_and_line(tmp_path, edit, line, what):
    d = write_floor(tmp_path / "raw")
    p = write_walk(d, "bad", edit(walk_lines()))
    out = tmp_path / "ds"
    with pytest.raises(ImportError_) as exc:
        run_import("ilc20", d, out)
    assert exc.value.path == str(p.resolve()) and exc.value.line == line and what in exc.value.problem
    assert not out.exists() and not list(tmp_path.glob(".ds.partial-*"))


def test_wide_header_lines_are_fine(tmp_path):
    d = write_floor(tmp_path / "raw")
    lines = walk_lines()
    write_walk(d, "w", lines[:1] + ["#\t" + "\t".join(f"k{i}:v{i}" for i in range(30))] + lines[1:])
    out = tmp_path / "ds"
    assert run_import("ilc20", d, out).sessions == 1 and errors_of(out) == []


def test_truncated_file_names_its_last_line(tmp_path):
    d = write_floor(tmp_path / "raw")
    lines = walk_lines()[:-1]
    lines[-1] = lines[-1][:-3]  # cut in the middle of a number
    p = write_walk(d, "cut", lines, newline_at_end=False)
    with pytest.raises(ImportError_) as exc:
        run_import("ilc20", d, tmp_path / "ds")
    assert exc.value.path == str(p.resolve()) and exc.value.line == len(lines) and "newline" in exc.value.problem


def test_unknown_record_types_are_counted_not_fatal(tmp_path):
    d = write_floor(tmp_path / "raw")
    extra = [(1_600_000_000_300 + k, f"{1_600_000_000_300 + k}\tTYPE_FUTURE_SENSOR\t1\t2\t3\t4\t5") for k in range(3)]
    write_walk(d, "w", walk_lines(extra=extra))
    out = tmp_path / "ds"
    rep = run_import("ilc20", d, out)
    assert rep.dropped["rows of undocumented record type TYPE_FUTURE_SENSOR (not imported)"] == 3
    assert "TYPE_FUTURE_SENSOR" in str(rep)
    assert errors_of(out) == []
    assert yaml.safe_load((out / "sessions/mall_F1_w/session.yaml").read_text())["records"]["TYPE_FUTURE_SENSOR"] == 3


@pytest.mark.parametrize("waypoints", [((5.0, 5.0),), ()])
def test_walk_without_two_waypoints_is_unlabelled(tmp_path, waypoints):
    d = write_floor(tmp_path / "raw")
    write_walk(d, "one", walk_lines(waypoints=waypoints))
    write_walk(d, "two", walk_lines())
    out = tmp_path / "ds"
    rep = run_import("ilc20", d, out)
    assert errors_of(out) == []
    s = Dataset.open(out).session("mall_F1_one")
    assert not s.labelled and not (s.root / "groundtruth.csv").exists()
    assert len(s.imu) == 300 and len(s.wifi) == 12
    assert s.meta.get("waypoints", []) == ([[0.01, 5.0, 5.0]] if waypoints else [])
    assert "1 walks with fewer than two waypoints (written as unlabelled sessions)" in str(rep)
    assert Dataset.open(out).session("mall_F1_two").labelled


def test_gyroscope_on_its_own_times_is_interpolated(tmp_path):
    d = write_floor(tmp_path / "raw")
    write_walk(d, "w", walk_lines(gyro_shift_ms=5))
    out = tmp_path / "ds"
    rep = run_import("ilc20", d, out)
    imu = Dataset.open(out).session("mall_F1_w").imu
    # the first accelerometer sample precedes the gyroscope: dropped; gz = 0.001 per 20 ms, shifted by 5 ms
    assert rep.dropped["accelerometer samples outside the gyroscope's time span"] == 1
    assert len(imu) == 299
    np.testing.assert_allclose(imu["t"].to_numpy()[0], 0.120)
    np.testing.assert_allclose(imu["gz"].to_numpy()[:3], [0.00075, 0.00175, 0.00275], atol=1e-9)


def test_sensor_clock_offset_is_detected_and_removed(tmp_path):
    d = write_floor(tmp_path / "raw")
    write_walk(d, "w", walk_lines(sensor_offset_ms=-3_600_000))  # sensors an hour early (another clock)
    out = tmp_path / "ds"
    rep = run_import("ilc20", d, out)
    s = Dataset.open(out).session("mall_F1_w")
    # the first sensor sample is moved onto the walk's start (startTime)
    assert s.meta["sensor_time_offset_s"] == pytest.approx(-3600.0 + 0.100)
    assert s.imu["t"].iloc[0] == 0.0 and s.imu["t"].iloc[-1] < 7
    assert "1 walks whose sensor clock was shifted" in str(rep)
    assert errors_of(out) == []


def test_rssi_outside_range_is_dropped_and_counted(tmp_path):
    d = write_floor(tmp_path / "raw")
    lines = [ln.replace("\t-75\t5180", "\t0\t5180") for ln in walk_lines()]
    write_walk(d, "w", lines)
    out = tmp_path / "ds"
    rep = run_import("ilc20", d, out)
    assert rep.dropped["WiFi readings outside (-150, 0) dBm"] == 6
    assert len(Dataset.open(out).session("mall_F1_w").wifi) == 6


# --------------------------------------------------------------------------- the data layer's extensions


def test_format_extensions_are_checked(floor, tmp_path):
    out = tmp_path / "ds"
    run_import("ilc20", floor, out)
    sdir = out / "sessions/mall_F1_walkA"
    (sdir / "orientation.csv").write_text("t,qw,qx,qy,qz\n0.1,0.1,0.1,0.1,0.1\n")
    (sdir / "wifi.csv").write_text("t,bssid,rssi_dbm,freq_mhz\n0.1,aa:bb,-40,2.412\n0.2,aa:bb,0,\n")
    y = sdir / "session.yaml"
    y.write_text(y.read_text().replace("groundtruth_kind: waypoints", "groundtruth_kind: sometimes"))
    a = out / "buildings/mall/anchors.csv"
    a.write_text(a.read_text().replace(",ble,,,,", ",ble,1.0,,,", 1))
    rules = {(Path(i.path).name, i.rule, i.line) for i in errors_of(out)}
    assert rules == {("orientation.csv", "quaternion-norm", 2), ("wifi.csv", "wifi-range", 2),
                     ("wifi.csv", "rssi-range", 3), ("session.yaml", "session-groundtruth-kind", None),
                     ("anchors.csv", "non-finite", 2)}


# --------------------------------------------------------------------------- real walks


@pytest.mark.realdata
def test_real_walks_from_the_archive(raw_dir, tmp_path):
    """Three walks and the metadata of site1/F1 unpacked into a temporary folder; counts from the raw lines."""
    tgz = raw_dir / "ilc20" / "site1_F1.tar.gz"
    if not tgz.is_file():
        pytest.skip(f"{tgz} is absent")
    root = tmp_path / "raw"
    walks = []
    with tarfile.open(tgz, "r|gz") as tf:
        for m in tf:
            name = m.name
            take = name.endswith(("floor_info.json", "geojson_map.json")) or (
                name.endswith(".txt") and len(walks) < 3)
            if m.isfile() and take:
                p = root / name
                p.parent.mkdir(parents=True, exist_ok=True)
                p.write_bytes(tf.extractfile(m).read())
                if name.endswith(".txt"):
                    walks.append(p)
    floor = root / "site1" / "F1"
    out = tmp_path / "ds"
    rep = run_import("ilc20", floor, out)
    assert rep.sessions == 3 and errors_of(out) == []
    ds = Dataset.open(out)
    for p in walks:
        rows = [ln.split("\t") for ln in p.read_text(encoding="utf-8").splitlines() if not ln.startswith("#")]
        kinds = [r[1] for r in rows]
        s = ds.session(f"site1_F1_{p.stem}")
        assert len(s.groundtruth) == kinds.count("TYPE_WAYPOINT")
        assert len(s.imu) == kinds.count("TYPE_ACCELEROMETER") == kinds.count("TYPE_GYROSCOPE")
        assert len(s.wifi) == kinds.count("TYPE_WIFI") and len(s.rssi) == kinds.count("TYPE_BEACON")
        assert len(s.orientation) == kinds.count("TYPE_ROTATION_VECTOR")
        assert s.device_model == "OPPO PBCM10" and s.groundtruth_sparse
        wp = sorted((int(r[0]), float(r[2]), float(r[3])) for r in rows if r[1] == "TYPE_WAYPOINT")
        np.testing.assert_allclose(s.groundtruth[["x", "y"]].to_numpy(), [w[1:] for w in wp], atol=1e-6)
        norms = np.linalg.norm(s.orientation[["qw", "qx", "qy", "qz"]].to_numpy(), axis=1)
        assert np.allclose(norms, 1.0)
        assert math.isclose(s.imu["az"].median(), 9.8, abs_tol=1.0)  # gravity, m/s^2
    al = ds.building("site1").meta["alignment"]["F1"]
    assert al["inside_outline"] == 1.0 and al["on_walkable"] >= 0.95
    b = ds.building("site1")
    assert len(b.anchors) > 0 and len(b.anchors_without_position()) == len(b.anchors)


def test_floor_level_from_geojson_sets_the_ground_truth_z_once(tmp_path):
    """A floor name without a level ("G"): the walk pass guesses level 0, the GeoJSON's floor_num 3 gives level 2
    (z = 10 m); groundtruth.csv is written once with z = 10 + 1.2 m, in the importer's own number format (a
    second, pandas-written pass would turn x "5" into "5.0")."""
    d = write_floor(tmp_path / "raw", floor="G")
    geo = json.loads((d / "geojson_map.json").read_text())
    geo["features"][0]["properties"]["floor_num"] = 3
    (d / "geojson_map.json").write_text(json.dumps(geo))
    write_walk(d, "walkA", walk_lines())
    out = tmp_path / "ds"
    run_import("ilc20", d, out)
    assert errors_of(out) == []
    ds = Dataset.open(out)
    assert ds.building("mall").floor("G").z == pytest.approx(10.0)
    s = ds.session("mall_G_walkA")
    np.testing.assert_allclose(s.groundtruth["z"].to_numpy(), [11.2, 11.2, 11.2], atol=1e-9)
    raw = pd.read_csv(s.root / "groundtruth.csv", dtype=str, keep_default_na=False)
    assert list(raw["x"]) == ["5", "15", "20"] and list(raw["z"]) == ["11.2"] * 3
