"""The typed reader (``blenav.data.Dataset`` / ``Building`` / ``Floor`` / ``Session``).

Covers: errors raised as :class:`DatasetError` naming file, line and rule; unknown-anchor rows dropped
and kept in ``session.issues``; quaternion normalisation; floor geometry (world <-> pixel, ROS
map_server occupancy thresholds incl. ``negate``); and datasets written by hand, the way another tool
would write them (PGM and PNG floors, extra columns and files, empty optional files, odd anchor ids).
"""

from __future__ import annotations

import json
import logging
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
import yaml
from hypothesis import given, settings
from hypothesis import strategies as st
from PIL import Image

from blenav.data import FREE, OCCUPIED, UNKNOWN, Dataset, Floor, validate
from blenav.errors import DatasetError


S = "sessions/walk0"
B = "buildings/house"




def set_cell(path: Path, line: int, column: str, value: str) -> None:
    ls = path.read_text().splitlines()
    col = ls[0].split(",").index(column)
    cells = ls[line - 1].split(",")
    cells[col] = value
    ls[line - 1] = ",".join(cells)
    path.write_text("\n".join(ls) + "\n")


def edit_yaml(path: Path, **changes) -> None:
    doc = yaml.safe_load(path.read_text())
    doc.update(changes)
    path.write_text(yaml.safe_dump(doc, sort_keys=False))


# --------------------------------------------------------------------------- Dataset / Building / Session


def test_open_tiny_dataset(tiny_dataset):
    ds = Dataset.open(tiny_dataset)
    assert ds.name == "tiny"
    assert ds.building_ids == ["house"] and ds.session_ids == ["walk0"]
    b = ds.building("house")
    assert b.name == "tiny house" and list(b.floors) == [0]
    assert b.anchors["anchor_id"].tolist() == ["b1", "b2", "b3", "b4", "ap1"]
    assert b.anchors["anchor_id"].map(type).eq(str).all()
    assert np.isnan(b.anchors["tx_power_dbm"].iloc[2]) and b.anchors["tx_power_dbm"].iloc[0] == -59.0
    assert len(b.anchors_of("ble")) == 4 and b.anchors_of("wifi_rtt")["anchor_id"].tolist() == ["ap1"]
    assert len(b.anchors_of(floor=0)) == 5 and len(b.anchors_of(floor="0")) == 5 and len(b.anchors_of(floor=1)) == 0
    assert [r.id for r in b.rooms_on(0)] == ["west", "east"] and [r.id for r in b.routes_on(0)] == ["e0"]

    s = ds.session("walk0")
    assert (s.device_model, s.carrier, s.labelled) == ("test-phone", "pedestrian", True)
    assert s.floor is b.floor(0)
    assert s.imu.shape == (2000, 7) and s.rssi.shape == (400, 3) and s.groundtruth.shape == (200, 8)
    assert s.rssi["anchor_id"].tolist()[:4] == ["b1", "b2", "b3", "b4"]
    assert s.duration_s == pytest.approx(19.99)
    assert s.has("imu") and not s.has("mag") and s.issues == []
    np.testing.assert_allclose(s.positions_at(np.array([0.0, 10.0, 19.9])), [[2.5, 4.0], [5.0, 4.0], [7.475, 4.0]])
    assert [x.id for x in ds.sessions()] == ["walk0"] and list(ds.sessions(labelled=False)) == []


@pytest.mark.parametrize("name,columns", [
    ("mag", ["t", "mx", "my", "mz"]), ("rtt", ["t", "anchor_id", "range_m", "range_std_m"]),
    ("visual", ["t", "x", "y", "z", "yaw"]), ("odometry", ["t", "x", "y"]),
    ("fixes", ["t", "x", "y", "std", "source"]),
])
def test_absent_optional_stream_reads_empty_with_columns(tiny_dataset, name, columns):
    s = Dataset.open(tiny_dataset).session("walk0")
    df = s.stream(name)
    assert len(df) == 0 and list(df.columns) == columns
    assert not s.has(name)


def test_unknown_stream_name(tiny_dataset):
    with pytest.raises(KeyError, match="unknown stream"):
        Dataset.open(tiny_dataset).session("walk0").stream("gps")


def test_open_missing_folder(tmp_path):
    with pytest.raises(DatasetError) as e:
        Dataset.open(tmp_path / "nothing")
    assert [i.rule for i in e.value.issues] == ["missing-dataset"]
    assert isinstance(e.value, ValueError)


def test_open_wrong_format(tiny_dataset):
    edit_yaml(tiny_dataset / "dataset.yaml", format="blenav/2")
    with pytest.raises(DatasetError, match=r"dataset\.yaml: \[format\] format is 'blenav/2', expected 'blenav/1'"):
        Dataset.open(tiny_dataset)


def test_open_without_dataset_yaml(tiny_dataset):
    (tiny_dataset / "dataset.yaml").unlink()
    with pytest.raises(DatasetError, match=r"dataset\.yaml: \[missing-file\]"):
        Dataset.open(tiny_dataset)


def test_unknown_building_id(tiny_dataset):
    with pytest.raises(DatasetError, match=r"\[missing-building\].*'castle'"):
        Dataset.open(tiny_dataset).building("castle")


@pytest.mark.parametrize("changes,rule", [
    ({"building": "castle"}, "session-building"), ({"floor": 2}, "session-floor"),
    ({"carrier": "drone"}, "session-carrier"), ({"labelled": "yes please"}, "session-labelled"),
    ({"gyro_calibrated": "yes"}, "session-gyro-calibrated"),
])
def test_session_yaml_errors(tiny_dataset, changes, rule):
    edit_yaml(tiny_dataset / S / "session.yaml", **changes)
    ds = Dataset.open(tiny_dataset)
    with pytest.raises(DatasetError, match=rf"session\.yaml: \[{rule}\]") as e:
        ds.session("walk0")
    assert e.value.issues[0].rule == rule


def test_session_in_a_broken_building(tiny_dataset):
    set_cell(tiny_dataset / B / "anchors.csv", 4, "kind", "zigbee")
    ds = Dataset.open(tiny_dataset)
    with pytest.raises(DatasetError, match=r"anchors\.csv:4: \[anchor-kind\]"):
        ds.session("walk0")


# (stream, file, line, column, value, rule)
STREAM_ERRORS = [
    ("imu", "imu.csv", 7, "ax", "nan", "non-finite"),
    ("imu", "imu.csv", 12, "gz", "x", "not-a-number"),
    ("imu", "imu.csv", 50, "t", "0.001", "time-backwards"),
    ("rssi", "rssi.csv", 9, "rssi", "-200", "rssi-range"),
    ("rssi", "rssi.csv", 9, "rssi", "0", "rssi-range"),
    ("rssi", "rssi.csv", 9, "t", "inf", "non-finite"),
    ("groundtruth", "groundtruth.csv", 30, "qw", "0.2", "quaternion-norm"),
    ("groundtruth", "groundtruth.csv", 30, "qy", "", "quaternion-partial"),
    ("groundtruth", "groundtruth.csv", 30, "y", "", "non-finite"),
]


@pytest.mark.parametrize("stream,file,line,column,value,rule", STREAM_ERRORS,
                         ids=[f"{c[0]}:{c[2]}:{c[3]}={c[4]!r}" for c in STREAM_ERRORS])
def test_stream_error_names_file_line_and_rule(tiny_dataset, stream, file, line, column, value, rule):
    set_cell(tiny_dataset / S / file, line, column, value)
    s = Dataset.open(tiny_dataset).session("walk0")  # streams are read lazily
    with pytest.raises(DatasetError) as e:
        getattr(s, stream)
    msg = str(e.value)
    assert f"{S}/{file}:{line}: [{rule}]" in msg and msg.startswith("ERROR ")
    assert [(i.rule, i.line, Path(i.path).name) for i in e.value.issues] == [(rule, line, file)]
    # the other streams are still readable
    for other in {"imu", "rssi", "groundtruth"} - {stream}:
        assert len(getattr(s, other)) > 0


def test_missing_column_error(tiny_dataset):
    p = tiny_dataset / S / "imu.csv"
    ls = p.read_text().splitlines()
    p.write_text("\n".join(ln.rsplit(",", 1)[0] for ln in ls) + "\n")
    with pytest.raises(DatasetError, match=r"imu\.csv:1: \[missing-column\] header lacks column\(s\) gz"):
        Dataset.open(tiny_dataset).session("walk0").imu


def test_empty_required_file_error(tiny_dataset):
    (tiny_dataset / S / "imu.csv").write_text("t,ax,ay,az,gx,gy,gz\n")
    (tiny_dataset / S / "groundtruth.csv").write_text("")
    s = Dataset.open(tiny_dataset).session("walk0")
    with pytest.raises(DatasetError, match=r"imu\.csv: \[empty-required\]"):
        s.imu
    with pytest.raises(DatasetError, match=r"groundtruth\.csv: \[empty-required\]"):
        s.groundtruth


def test_missing_groundtruth_of_labelled_session(tiny_dataset):
    (tiny_dataset / S / "groundtruth.csv").unlink()
    with pytest.raises(DatasetError, match=r"groundtruth\.csv: \[groundtruth-missing\]"):
        Dataset.open(tiny_dataset).session("walk0").groundtruth


def test_radio_without_anchors_error(tiny_dataset):
    (tiny_dataset / B / "anchors.csv").unlink()
    s = Dataset.open(tiny_dataset).session("walk0")
    with pytest.raises(DatasetError, match=r"rssi\.csv: \[anchors-missing\]"):
        s.rssi
    assert len(s.imu) == 2000


def test_unknown_anchor_rows_are_dropped_and_kept_in_issues(tiny_dataset, caplog):
    p = tiny_dataset / S / "rssi.csv"
    set_cell(p, 5, "anchor_id", "zz")
    set_cell(p, 9, "anchor_id", "zz")
    set_cell(p, 13, "anchor_id", "C0:FF:EE:00:00:01")
    s = Dataset.open(tiny_dataset).session("walk0")
    with caplog.at_level(logging.WARNING, logger="blenav.data"):
        rssi = s.rssi
    assert len(rssi) == 397 and set(rssi["anchor_id"]) == {"b1", "b2", "b3", "b4"}
    assert rssi.index.tolist() == list(range(397))
    (w,) = s.issues
    assert (w.severity, w.rule, Path(w.path).name) == ("warning", "unknown-anchor", "rssi.csv")
    assert "3 rows" in w.message and "2 ids" in w.message and "zz, C0:FF:EE:00:00:01" in w.message
    assert "unknown-anchor" in caplog.text
    s.rssi  # cached: read and reported once
    assert len(s.issues) == 1


def test_unknown_anchor_rtt_rows_are_dropped(tiny_dataset):
    (tiny_dataset / S / "rtt.csv").write_text(
        "t,anchor_id,range_m,range_std_m\n0.0,ap1,3.1,0.5\n0.1,ap9,4.0,\n0.2,ap1,3.0,\n0.3,b1,2.0,0.3\n")
    s = Dataset.open(tiny_dataset).session("walk0")
    rtt = s.rtt
    assert rtt["anchor_id"].tolist() == ["ap1", "ap1", "b1"]
    np.testing.assert_allclose(rtt["range_std_m"], [0.5, np.nan, 0.3])
    assert [i.rule for i in s.issues] == ["unknown-anchor"]


def test_quaternions_are_normalised_on_read(tiny_dataset):
    p = tiny_dataset / S / "groundtruth.csv"
    rng = np.random.default_rng(3)
    q = rng.normal(size=(200, 4))
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    scale = rng.uniform(0.5, 3.0, size=(200, 1))
    gt = pd.read_csv(p)
    gt[["qw", "qx", "qy", "qz"]] = q * scale
    gt.loc[0, ["qw", "qx", "qy", "qz"]] = [2.0, 0.0, 0.0, 0.0]
    q[0] = [1.0, 0.0, 0.0, 0.0]
    gt.to_csv(p, index=False)
    out = Dataset.open(tiny_dataset).session("walk0").groundtruth[["qw", "qx", "qy", "qz"]].to_numpy()
    np.testing.assert_allclose(np.linalg.norm(out, axis=1), 1.0, rtol=1e-12)
    np.testing.assert_allclose(out, q, atol=1e-12)


def test_position_only_groundtruth_reads_nan_orientation(tiny_dataset):
    p = tiny_dataset / S / "groundtruth.csv"
    gt = pd.read_csv(p)
    gt[["qw", "qx", "qy", "qz"]] = np.nan
    gt.to_csv(p, index=False)
    g = Dataset.open(tiny_dataset).session("walk0").groundtruth
    assert g[["qw", "qx", "qy", "qz"]].isna().all().all()
    np.testing.assert_allclose(g["x"].to_numpy(), gt["x"].to_numpy())


def test_unlabelled_session_ignores_groundtruth_rows(tiny_dataset):
    edit_yaml(tiny_dataset / S / "session.yaml", labelled=False)
    ds = Dataset.open(tiny_dataset)
    s = ds.session("walk0")
    assert len(s.groundtruth) == 0 and [i.rule for i in s.issues] == ["groundtruth-unlabelled"]
    with pytest.raises(ValueError, match="no ground truth"):
        s.positions_at(np.array([1.0]))
    assert [x.id for x in ds.sessions(labelled=False)] == ["walk0"]


# --------------------------------------------------------------------------- Floor geometry


def floor_from_array(img: np.ndarray, resolution: float = 0.1, origin=(0.0, 0.0), **kw) -> Floor:
    """A Floor whose pixels come from memory (no file): ``Floor.image`` is a cached_property."""
    f = Floor(id=0, image_path=Path("/nonexistent.png"), resolution=resolution, origin=tuple(origin), **kw)
    f.__dict__["image"] = np.asarray(img, dtype=np.uint8)
    return f


@settings(max_examples=300, deadline=None)
@given(
    h=st.integers(1, 60), w=st.integers(1, 60),
    res=st.floats(0.01, 2.0), ox=st.floats(-500, 500), oy=st.floats(-500, 500),
    u=st.floats(-0.5, 1.5), v=st.floats(-0.5, 1.5),
)
def test_world_pixel_round_trip_within_half_a_pixel(h, w, res, ox, oy, u, v):
    f = floor_from_array(np.full((h, w), 254), res, (ox, oy))
    p = np.array([ox + u * w * res, oy + v * h * res])
    row, col = f.world_to_pixel(p)
    back = f.pixel_to_world(row, col)
    tol = res / 2 + 1e-9 * (1 + np.abs(p).max())
    assert np.all(np.abs(back - p) <= tol), (p, back, res)
    inside = 0 <= u < 1 and 0 <= v < 1
    if inside and 1e-9 < u * w % 1 and 1e-9 < v * h % 1:  # clear of pixel edges: lands on the image
        assert 0 <= row < h and 0 <= col < w


@settings(max_examples=100, deadline=None)
@given(h=st.integers(1, 40), w=st.integers(1, 40), res=st.floats(0.01, 2.0),
       ox=st.floats(-500, 500), oy=st.floats(-500, 500), data=st.data())
def test_pixel_world_pixel_is_identity(h, w, res, ox, oy, data):
    f = floor_from_array(np.zeros((h, w)), res, (ox, oy))
    r = np.array(data.draw(st.lists(st.integers(0, h - 1), min_size=1, max_size=10)))
    c = np.array(data.draw(st.lists(st.integers(0, w - 1), min_size=len(r), max_size=len(r))))
    row, col = f.world_to_pixel(f.pixel_to_world(r, c))
    np.testing.assert_array_equal(row, r)
    np.testing.assert_array_equal(col, c)


def test_lower_left_pixel_is_at_origin_plus_half_resolution():
    f = floor_from_array(np.zeros((30, 50)), 0.2, (-3.0, 7.0))
    np.testing.assert_allclose(f.pixel_to_world(29, 0), [-3.0 + 0.1, 7.0 + 0.1])
    np.testing.assert_allclose(f.pixel_to_world(0, 49), [-3.0 + 49.5 * 0.2, 7.0 + 29.5 * 0.2])  # upper right
    assert f.world_to_pixel(np.array([-2.99, 7.01])) == (29, 0)
    assert f.world_to_pixel(np.array([-3.0 + 50 * 0.2 - 1e-6, 7.0 + 30 * 0.2 - 1e-6])) == (0, 49)
    assert f.extent == pytest.approx((-3.0, 7.0, 7.0, 13.0))
    assert f.shape == (30, 50)


# pixel value -> occupancy with ROS defaults (occupied 0.65, free 0.196) where darkness = 1 - v/255
PIXELS = np.array([[0, 50, 89, 90, 100, 166, 200, 205, 206, 230, 254, 255]], dtype=np.uint8)


def test_occupancy_thresholds_ros_defaults():
    f = floor_from_array(PIXELS)
    # darkness:     1.0  .80  .651  .647  .61  .35  .216 .196+ .192 .098 .004 0
    expected = [OCCUPIED, OCCUPIED, OCCUPIED, UNKNOWN, UNKNOWN, UNKNOWN, UNKNOWN, UNKNOWN, FREE, FREE, FREE, FREE]
    assert f.occupancy.tolist() == [expected] and f.occupancy.dtype == np.int8
    assert f.free_mask.tolist() == [[e == FREE for e in expected]]


def test_occupancy_thresholds_custom():
    f = floor_from_array(PIXELS, occupied_thresh=0.5, free_thresh=0.3)
    expected = [OCCUPIED] * 5 + [UNKNOWN] + [FREE] * 6
    assert f.occupancy.tolist() == [expected]


def test_occupancy_negate():
    """negate: darkness = v/255 (white is an obstacle)."""
    f = floor_from_array(PIXELS, negate=True)
    # darkness:      0   .196+ .349 .353 .39 .65+ .78  .80  .81  .90  .996 1
    expected = [FREE, UNKNOWN, UNKNOWN, UNKNOWN, UNKNOWN, OCCUPIED, OCCUPIED, OCCUPIED, OCCUPIED, OCCUPIED,
                OCCUPIED, OCCUPIED]
    assert f.occupancy.tolist() == [expected]


def test_negate_is_read_from_building_yaml(tiny_dataset):
    p = tiny_dataset / B / "building.yaml"
    doc = yaml.safe_load(p.read_text())
    doc["floors"][0]["negate"] = 1
    p.write_text(yaml.safe_dump(doc))
    fl = Dataset.open(tiny_dataset).building("house").floor(0)
    assert fl.negate
    assert fl.lookup(np.array([2.5, 4.0])) == OCCUPIED and fl.lookup(np.array([0.05, 4.0])) == FREE


def test_is_free_on_tiny_floor(tiny_dataset):
    fl = Dataset.open(tiny_dataset).building("house").floor("0")
    assert fl.shape == (80, 100) and fl.extent == (0.0, 10.0, 0.0, 8.0)
    pts = np.array([
        [2.5, 4.0],    # west room
        [7.5, 1.0],    # east room
        [0.05, 4.0],   # outer wall (2 px = 0.2 m)
        [5.05, 1.0],   # inner wall x in [5.0, 5.2)
        [5.05, 4.0],   # the door in the inner wall
        [9.95, 7.95],  # upper-right corner wall
        [-1.0, 4.0],   # off the image
        [5.0, 8.5],    # off the image
    ])
    assert fl.is_free(pts).tolist() == [True, True, False, False, True, False, False, False]
    assert fl.lookup(pts).tolist() == [FREE, FREE, OCCUPIED, OCCUPIED, FREE, OCCUPIED, UNKNOWN, UNKNOWN]
    assert fl.lookup(pts[-2:], outside=OCCUPIED).tolist() == [OCCUPIED, OCCUPIED]
    assert fl.is_free(pts.reshape(2, 4, 2)).shape == (2, 4)  # any leading shape
    free = fl.free_points()
    assert len(free) == int(fl.free_mask.sum()) and fl.is_free(free).all()


# --------------------------------------------------------------------------- datasets written by other tools


def _write(path: Path, text: str, newline: str = "\n", bom: bool = False) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    data = text.replace("\n", newline).encode("utf-8")
    path.write_bytes((b"\xef\xbb\xbf" if bom else b"") + data)


PLANT_PIXELS = np.array([
    [0, 0, 0, 0, 0, 0],
    [0, 254, 254, 205, 254, 0],
    [0, 254, 254, 254, 254, 0],
    [0, 0, 0, 0, 0, 0],
], dtype=np.uint8)


@pytest.fixture
def foreign_dataset(tmp_path) -> Path:
    """A dataset written with plain file writes, the way a script of another project would."""
    root = tmp_path / "foreign"
    _write(root / "dataset.yaml", "format: blenav/1\nname: foreign\ndescription: hand written\nlicence: CC-BY-4.0\n"
                                  "source: a lab notebook\nrecorded_by: someone else\n")
    _write(root / "README.md", "# not part of the format\n")

    # building 'plant': a PGM (P5) floor, ROS-style yaml with extra keys, odd anchor ids
    plant = root / "buildings" / "plant"
    plant.mkdir(parents=True)
    (plant / "map.pgm").write_bytes(b"P5\n# CREATOR: map_saver\n6 4\n255\n" + PLANT_PIXELS.tobytes())
    _write(plant / "building.yaml", """\
name: Plant hall
address: 1 Example Road
floors:
  - id: 0
    image: map.pgm
    resolution: 0.5
    origin: [-2.0, -1.0, 0.0]
    z: 0.0
    negate: 0
    occupied_thresh: 0.65
    free_thresh: 0.196
    mode: trinary
""")
    _write(plant / "anchors.csv", """\
anchor_id,kind,x,y,z,floor,tx_power_dbm,channel_model,vendor,battery_pct
AA:BB:CC:DD:EE:FF,ble,-1.5,-0.5,2.0,0,-59,log-distance,acme,90
23,ble,0.5,0.5,2.5,0.0,,,acme,
00:11:22:33:44:55,wifi_rtt,0.0,0.0,2.2,0,,,other,
""", newline="\r\n")
    hall = [[[-1.5, -0.5], [0.5, -0.5], [0.5, 0.5], [-1.5, 0.5], [-1.5, -0.5]]]
    _write(plant / "rooms.geojson", json.dumps({
        "type": "FeatureCollection", "name": "rooms",
        "features": [{"type": "Feature", "properties": {"id": 7, "floor": 0, "name": "hall", "area_m2": 3.0},
                      "geometry": {"type": "Polygon", "coordinates": hall}}]}))
    route = [[[-1, 0], [0, 0]], [[0, 0], [0, 0.5]]]
    _write(plant / "navgraph.geojson", json.dumps({
        "type": "FeatureCollection",
        "features": [{"type": "Feature", "properties": {"id": "r1", "floor": "0", "width_m": 1.2},
                      "geometry": {"type": "MultiLineString", "coordinates": route}}]}))
    _write(plant / "survey_notes.txt", "anchor 23 was moved on day 2\n")

    # building 'annex': a PNG floor with a string floor id
    annex = root / "buildings" / "annex"
    annex.mkdir(parents=True)
    img = np.full((8, 12), 254, dtype=np.uint8)
    img[:, 0] = 0
    Image.fromarray(img).save(annex / "plan.png")
    _write(annex / "building.yaml", "name: Annex\nfloors:\n  - {id: ground, image: plan.png, resolution: 0.25, "
                                    "origin: [10.0, 20.0], z: 3.5}\n")

    # session rec1 in the plant: CRLF, a BOM, extra columns, empty optional files, position-only ground truth
    s1 = root / "sessions" / "rec1"
    _write(s1 / "session.yaml", "building: plant\nfloor: 0\ndevice_model: Galaxy S21\ncarrier: pedestrian\n"
                                "labelled: true\nnotes: walked twice around the hall\noperator: ab\n")
    _write(s1 / "imu.csv", "t,ax,ay,az,gx,gy,gz,temperature_c\n0.0,0.1,0.2,9.8,0.01,0.02,0.03,25.5\n"
                           "0.01,0.1,0.2,9.81,0.01,0.02,0.03,25.5\n0.01,0.1,0.2,9.79,0,0,0,\n", newline="\r\n")
    (s1 / "mag.csv").write_bytes(b"")
    _write(s1 / "rtt.csv", "t,anchor_id,range_m,range_std_m,rssi_ap\n")
    _write(s1 / "rssi.csv", "t,anchor_id,rssi,channel\n0.0,23,-61,37\n0.0,AA:BB:CC:DD:EE:FF,-70.5,38\n"
                            "0.5,23,-63,39\n0.9,00:11:22:33:44:55,-80,\n", bom=True)
    _write(s1 / "groundtruth.csv", "t,x,y,z,qw,qx,qy,qz,source\n0.0,-1.0,0.0,1.3,,,,,total station\n"
                                   "0.5,-0.5,0.0,1.3,,,,,total station\n1.0,0.0,0.25,1.3,,,,,\n")
    _write(s1 / "odometry.csv", "t, x, y\n0.0, 0.0, 0.0\n1.0, 0.5, 0.1\n")
    _write(s1 / "camera_frames.txt", "frame_0001.jpg\n")

    # session rec2 in the annex: a robot with only ground truth, fixes and visual poses
    s2 = root / "sessions" / "rec2"
    _write(s2 / "session.yaml", "building: annex\nfloor: ground\ndevice_model: robot-lidar\ncarrier: robot\n"
                                "labelled: true\n")
    _write(s2 / "groundtruth.csv", "t,x,y,z,qw,qx,qy,qz\n0,11,21,3.8,2,0,0,0\n0.5,11.5,21,3.8,0,0,0,3\n"
                                   "0.5,11.5,21,3.8,1,1,1,1\n")
    _write(s2 / "fixes.csv", "t,x,y,std,source\n0.2,11.1,21.0,,wknn-ble-4\n0.4,11.3,21.1,1.5,pdr+pf\n")
    _write(s2 / "visual.csv", "t,x,y,z,yaw\n0.25,11.2,21.0,3.8,1.5708\n")
    return root


def test_foreign_dataset_validates_without_issues(foreign_dataset):
    issues = validate(foreign_dataset)
    assert issues == [], "\n".join(map(str, issues))


def test_foreign_dataset_reads_expected_values(foreign_dataset):
    ds = Dataset.open(foreign_dataset)
    assert ds.name == "foreign" and ds.building_ids == ["annex", "plant"] and ds.session_ids == ["rec1", "rec2"]

    plant = ds.building("plant")
    fl = plant.floor(0)
    assert fl.image.tolist() == PLANT_PIXELS.tolist()
    assert fl.extent == (-2.0, 1.0, -1.0, 1.0) and not fl.negate
    assert fl.occupancy[1].tolist() == [OCCUPIED, FREE, FREE, UNKNOWN, FREE, OCCUPIED]
    assert fl.is_free(np.array([[-1.25, 0.25], [-0.25, 0.25], [-1.75, 0.25]])).tolist() == [True, False, False]

    a = plant.anchors
    assert a["anchor_id"].tolist() == ["AA:BB:CC:DD:EE:FF", "23", "00:11:22:33:44:55"]
    assert a["kind"].tolist() == ["ble", "ble", "wifi_rtt"]
    assert a["floor"].tolist() == ["0", "0", "0"]  # '0.0' written by float formatting names floor 0
    np.testing.assert_allclose(a["tx_power_dbm"], [-59.0, np.nan, np.nan])
    np.testing.assert_allclose(a[["x", "y", "z"]].to_numpy(), [[-1.5, -0.5, 2.0], [0.5, 0.5, 2.5], [0.0, 0.0, 2.2]])
    assert a["vendor"].tolist() == ["acme", "acme", "other"]  # extra columns are kept
    (room,) = plant.rooms_on(0)
    assert room.id == "7" and room.properties["name"] == "hall" and room.geometry.area == pytest.approx(2.0)
    (route,) = plant.routes_on(0)
    assert route.id == "r1" and route.geometry.length == pytest.approx(1.5)

    s1 = ds.session("rec1")
    assert s1.device_model == "Galaxy S21" and s1.floor is fl
    np.testing.assert_allclose(s1.imu[["t", "az"]].to_numpy(), [[0.0, 9.8], [0.01, 9.81], [0.01, 9.79]])
    assert "temperature_c" in s1.imu.columns
    assert s1.rssi["anchor_id"].tolist() == ["23", "AA:BB:CC:DD:EE:FF", "23", "00:11:22:33:44:55"]
    np.testing.assert_allclose(s1.rssi["rssi"], [-61.0, -70.5, -63.0, -80.0])
    assert s1.rssi["rssi"].dtype == np.float64 and "channel" in s1.rssi.columns
    assert len(s1.mag) == 0 and list(s1.mag.columns) == ["t", "mx", "my", "mz"]
    assert len(s1.rtt) == 0 and not s1.has("rtt")
    gt = s1.groundtruth
    np.testing.assert_allclose(gt[["t", "x", "y", "z"]].to_numpy(),
                               [[0.0, -1.0, 0.0, 1.3], [0.5, -0.5, 0.0, 1.3], [1.0, 0.0, 0.25, 1.3]])
    assert gt[["qw", "qx", "qy", "qz"]].isna().all().all()
    np.testing.assert_allclose(s1.odometry[["t", "x", "y"]].to_numpy(), [[0, 0, 0], [1.0, 0.5, 0.1]])
    np.testing.assert_allclose(s1.positions_at(np.array([0.25])), [[-0.75, 0.0]])
    assert s1.issues == []

    annex = ds.building("annex")
    s2 = ds.session("rec2")
    assert s2.floor.id == "ground" and s2.floor is annex.floor("ground") and s2.floor.z == 3.5
    assert s2.floor.extent == (10.0, 13.0, 20.0, 22.0)
    assert s2.floor.is_free(np.array([[10.1, 21.0], [11.0, 21.0]])).tolist() == [False, True]
    np.testing.assert_allclose(s2.groundtruth[["qw", "qx", "qy", "qz"]].to_numpy(),
                               [[1, 0, 0, 0], [0, 0, 0, 1], [0.5, 0.5, 0.5, 0.5]])
    fx = s2.fixes
    np.testing.assert_allclose(fx["std"], [np.nan, 1.5])
    assert fx["source"].tolist() == ["wknn-ble-4", "pdr+pf"]
    assert s2.visual["yaw"].tolist() == [1.5708]
    assert s2.duration_s == pytest.approx(0.5)
    assert not s2.has("imu") and not s2.has("rssi")


@pytest.mark.parametrize("changes,calibrated", [
    ({}, False),  # no word of it, no phone's rotation vector: a raw gyroscope
    ({"orientation_frame": "enu-magnetic"}, True),  # Android's rotation vector comes with its calibrated gyroscope
    ({"orientation_frame": "enu-magnetic", "gyro_calibrated": False}, False),  # the file's word wins
    ({"gyro_calibrated": True}, True),
])
def test_gyro_calibrated_is_the_files_word_or_the_phones(tiny_dataset, changes, calibrated):
    edit_yaml(tiny_dataset / S / "session.yaml", **changes)
    assert Dataset.open(tiny_dataset).session("walk0").gyro_calibrated is calibrated
