"""Issue 19, section 1, the data layer: truncated files, plausible ranges, counted drops, and one place for the
rules that ``blenav-validate`` and the readers (hence the evaluation) apply.

Every fault is made on a fresh copy of the tiny dataset (tests/helpers.py: building ``house``, floor 0 is
10 m x 8 m at 0.1 m/px from (0, 0), anchors b1..b4 + ap1 on lines 2..6 of anchors.csv; session ``walk0``
with imu.csv (100 Hz, 20 s), rssi.csv (b1..b4 every 0.2 s), groundtruth.csv (10 Hz)). For each, the test
checks what the validator says (rule, file, line) and that loading the dataset the way the evaluation does
refuses it with the same rule, or reads it and counts what it dropped.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd
import pytest
import yaml
from PIL import Image

from blenav.cli.validate import main as validate_main
from blenav.data import Dataset, check_session_in_building, sum_dropped, validate
from blenav.data.schema import PLAUSIBLE, T_MAX_S
from blenav.data.writer import write_csv, write_fixes
from blenav.errors import DatasetError
from helpers import REPO, errors, lines, rel, set_cell

S = "sessions/walk0"
B = "buildings/house"


# --------------------------------------------------------------------------- helpers


def found(root, issues) -> set:
    """{(rule, file, line)} of the errors."""
    return {(i.rule, rel(root, i), i.line) for i in errors(issues)}


def load_everything(root: Path) -> Dataset:
    """Open the dataset as the evaluation does: every building, every session, every stream."""
    ds = Dataset.open(root)
    for b in ds.building_ids:
        ds.building(b)
    for sid in ds.session_ids:
        ds.session(sid).load_all()
    return ds


def refused(root: Path) -> set:
    """{(rule, file, line)} of the error that stops loading (raises if loading succeeds)."""
    with pytest.raises(DatasetError) as e:
        load_everything(root)
    return {(i.rule, rel(root, i), i.line) for i in e.value.issues if i.is_error}


def edit_yaml(path: Path, fn) -> None:
    doc = yaml.safe_load(path.read_text())
    fn(doc)
    path.write_text(yaml.safe_dump(doc, sort_keys=False))


def assert_same_rule(root: Path, rule: str, file: str, line: int | None = None):
    """The validator reports exactly this one error, and loading refuses the dataset with it."""
    v = found(root, validate(root))
    assert v == {(rule, file, line)}, v
    assert (rule, file, line) in refused(root)


# --------------------------------------------------------------------------- truncation


def test_rssi_cut_in_its_last_number_is_refused_by_both(tiny_dataset):
    """Issue 19, row 1: `...,b4,-8` (was -78.0), no final newline."""
    p = tiny_dataset / S / "rssi.csv"
    data = p.read_bytes()
    assert data.endswith(b".0\n")
    p.write_bytes(data[:-4])  # '-78.0\n' -> '-78' minus one digit: '-7'
    n = len(lines(p))
    issues = validate(tiny_dataset)
    assert found(tiny_dataset, issues) == {("truncated", f"{S}/rssi.csv", n)}
    (e,) = errors(issues)
    assert "does not end with a newline" in e.message and "add a newline" in e.message and "remove" in e.message
    assert f"rssi.csv:{n}: [truncated]" in str(e)
    assert refused(tiny_dataset) == {("truncated", f"{S}/rssi.csv", n)}


def test_cli_names_the_truncated_file_and_line(tiny_dataset, capsys):
    p = tiny_dataset / S / "imu.csv"
    p.write_bytes(p.read_bytes()[:-10])
    n = len(lines(p))
    assert validate_main([str(tiny_dataset)]) == 1
    out = capsys.readouterr().out
    assert f"imu.csv:{n}: [truncated]" in out


def test_last_line_with_fewer_fields_says_so(tiny_dataset):
    p = tiny_dataset / S / "groundtruth.csv"
    ls = lines(p)
    p.write_text("\n".join(ls[:-1] + [",".join(ls[-1].split(",")[:3])]))  # t,x,y of 8 fields
    (e,) = errors(validate(tiny_dataset))
    assert (e.rule, e.line) == ("truncated", len(ls)) and "3 field(s), the header has 8" in e.message


def test_cut_after_the_header_is_refused(tiny_dataset):
    """All rows lost: the header alone without its newline."""
    p = tiny_dataset / S / "rssi.csv"
    p.write_text(lines(p)[0])
    assert_same_rule(tiny_dataset, "truncated", f"{S}/rssi.csv", 1)


def test_cut_anchors_csv_is_refused(tiny_dataset):
    p = tiny_dataset / B / "anchors.csv"
    p.write_bytes(p.read_bytes().rstrip(b"\n"))
    assert ("truncated", f"{B}/anchors.csv", 6) in found(tiny_dataset, validate(tiny_dataset))
    assert ("truncated", f"{B}/anchors.csv", 6) in refused(tiny_dataset)


@pytest.mark.parametrize("ending", [b"\n", b"\r\n", b"\r"], ids=["LF", "CRLF", "CR"])
def test_any_line_ending_at_the_end_is_fine(tiny_dataset, ending):
    p = tiny_dataset / S / "rssi.csv"
    p.write_bytes(b"\n".join(p.read_bytes().splitlines()).replace(b"\n", ending) + ending)
    assert validate(tiny_dataset) == []


def test_zero_byte_file_is_not_truncated(tiny_dataset):
    (tiny_dataset / S / "mag.csv").write_bytes(b"")
    assert validate(tiny_dataset) == []


def test_writer_ends_every_file_with_a_newline(tiny_dataset, tmp_path):
    """The simulator's output is validated for every preset (tests/sim/test_world.py) and every importer validates
    what it wrote, so the truncation rule holds for them too."""
    files = list(tiny_dataset.rglob("*.csv")) + list(tiny_dataset.rglob("*.yaml"))
    assert len(files) >= 6
    for f in files:
        assert f.read_bytes().endswith(b"\n"), f
    # an empty frame and write_fixes, too
    write_csv(tmp_path / "empty.csv", pd.DataFrame({"t": pd.Series(dtype=float)}))
    assert (tmp_path / "empty.csv").read_bytes() == b"t\n"
    f = write_fixes(tiny_dataset / S, [0.5, 1.0], [[1.0, 2.0], [2.0, 3.0]], source="test")
    assert f.read_bytes().endswith(b"\n") and validate(tiny_dataset) == []


# --------------------------------------------------------------------------- plausible ranges


# (file, line, column, value, rule)
OUT_OF_RANGE = [
    ("imu.csv", 7, "ax", "9810", "imu-range"),        # mg
    ("imu.csv", 7, "az", "-981", "imu-range"),        # cm/s^2
    ("imu.csv", 7, "gz", "180", "imu-range"),         # deg/s
    ("imu.csv", 2, "t", "-0.5", "time-range"),        # before the start
    ("rssi.csv", 9, "rssi", "-200", "rssi-range"),    # sentinel
    ("rssi.csv", 9, "rssi", "0", "rssi-range"),
    ("groundtruth.csv", 201, "t", "1700000000", "time-range"),  # a Unix time
    ("rtt.csv", 3, "range_m", "3100", "rtt-range"),   # mm
    ("rtt.csv", 3, "range_m", "-60", "rtt-range"),
    ("rtt.csv", 3, "range_std_m", "-0.2", "rtt-range"),
    ("mag.csv", 3, "mx", "45000", "mag-range"),       # nT
    ("fixes.csv", 3, "std", "-1", "fixes-range"),
]

EXTRA_FILES = {
    "rtt.csv": "t,anchor_id,range_m,range_std_m\n0.0,ap1,3.1,0.5\n0.1,ap1,4.0,\n0.2,ap1,3.0,0.4\n",
    "mag.csv": "t,mx,my,mz\n0.0,20.1,-3.2,-40.0\n0.02,20.0,-3.1,-40.2\n",
    "fixes.csv": "t,x,y,std,source\n0.5,3.0,4.0,1.5,a\n1.0,3.1,4.0,2.0,a\n",
}


def add_extra_files(root: Path) -> None:
    for name, text in EXTRA_FILES.items():
        (root / S / name).write_text(text)


@pytest.mark.parametrize("file,line,column,value,rule", OUT_OF_RANGE,
                         ids=[f"{c[0]}:{c[2]}={c[3]}" for c in OUT_OF_RANGE])
def test_value_outside_its_plausible_range(tiny_dataset, file, line, column, value, rule):
    add_extra_files(tiny_dataset)
    assert validate(tiny_dataset) == []
    set_cell(tiny_dataset / S / file, line, column, value)
    assert_same_rule(tiny_dataset, rule, f"{S}/{file}", line)
    (e,) = errors(validate(tiny_dataset))
    assert column in e.message and "outside" in e.message


@pytest.mark.parametrize("file,line,column,value", [
    ("imu.csv", 7, "ax", "-156.9"), ("imu.csv", 7, "gx", "34.9"), ("mag.csv", 3, "mz", "-4900"),
    ("rtt.csv", 3, "range_m", "-10.6"), ("rtt.csv", 3, "range_m", "41.7"), ("rssi.csv", 9, "rssi", "-149.5"),
    ("fixes.csv", 3, "std", "0"),
])
def test_extreme_but_plausible_values_are_accepted(tiny_dataset, file, line, column, value):
    add_extra_files(tiny_dataset)
    set_cell(tiny_dataset / S / file, line, column, value)
    assert validate(tiny_dataset) == []


def test_the_last_time_in_range_is_accepted_when_the_session_agrees(tiny_dataset):
    """t = 999999 s (just below T_MAX_S) ends a session without an IMU (whose rate it would break) when its
    streams end together; one stream alone ending there is on another clock ('time-clock', test_fuzz_readers.py)."""
    (tiny_dataset / S / "imu.csv").unlink()
    set_cell(tiny_dataset / S / "groundtruth.csv", 201, "t", "999999")
    assert found(tiny_dataset, validate(tiny_dataset)) == {("time-clock", f"{S}/groundtruth.csv", None)}
    set_cell(tiny_dataset / S / "rssi.csv", 401, "t", "999999")
    assert validate(tiny_dataset) == []


def test_every_row_in_milliseconds_is_capped(tiny_dataset):
    p = tiny_dataset / S / "imu.csv"
    df = pd.read_csv(p)
    df["t"] = df["t"] * 1000 + 1e6  # shifted past T_MAX_S everywhere but the first row
    df.to_csv(p, index=False)
    errs = errors(validate(tiny_dataset))
    assert {i.rule for i in errs} == {"time-range"}
    assert len(errs) == 21 and "more rows" in errs[-1].message


def test_imu_in_milliseconds_of_a_short_session_is_caught_by_its_rate(tiny_dataset):
    """20 s at 100 Hz in ms: t stays below T_MAX_S, but one sample per 10 s is no IMU."""
    p = tiny_dataset / S / "imu.csv"
    df = pd.read_csv(p)
    df["t"] = df["t"] * 1000
    assert df["t"].max() < T_MAX_S
    df.to_csv(p, index=False)
    assert_same_rule(tiny_dataset, "imu-rate", f"{S}/imu.csv")
    assert "milliseconds" in errors(validate(tiny_dataset))[0].message


def test_ranges_are_documented():
    doc = (REPO / "docs" / "dataset-format.md").read_text()
    for (stream, column), p in PLAUSIBLE.items():
        assert f"`{stream}.csv`" in doc and column in doc and p.rule in doc
    for rule in ("truncated", "time-range", "imu-rate", "floor-no-free-space", "anchor-off-floor",
                 "groundtruth-off-floor", "unknown-anchor", "groundtruth-unlabelled"):
        assert f"`{rule}`" in doc, rule


# --------------------------------------------------------------------------- drops are counted


def test_unknown_anchor_drops_are_counted_per_stream_and_reason(tiny_dataset):
    """Issue 19, row 2: the drop is in the Session, for the evaluation's summary."""
    p = tiny_dataset / S / "rssi.csv"
    for line in (5, 9, 13):
        set_cell(p, line, "anchor_id", "zz")
    (tiny_dataset / S / "rtt.csv").write_text(EXTRA_FILES["rtt.csv"].replace("0.1,ap1", "0.1,ap9"))
    s = Dataset.open(tiny_dataset).session("walk0")
    assert s.dropped == {}
    s.imu
    assert s.dropped == {}  # nothing dropped from imu: not listed
    assert len(s.rssi) == 397
    assert s.dropped == {"rssi": {"unknown-anchor": 3}}
    assert s.load_all() is s
    assert s.dropped == {"rssi": {"unknown-anchor": 3}, "rtt": {"unknown-anchor": 1}}
    s.dropped["rssi"]["unknown-anchor"] = 99  # a copy
    assert s.dropped["rssi"]["unknown-anchor"] == 3
    # the validator's warning says the same count
    (w,) = [i for i in validate(tiny_dataset) if i.rule == "unknown-anchor" and i.path.endswith("rssi.csv")]
    assert "3 rows" in w.message


def test_drops_are_shared_with_another_version_of_the_building(tiny_dataset):
    set_cell(tiny_dataset / S / "rssi.csv", 5, "anchor_id", "zz")
    ds = Dataset.open(tiny_dataset)
    s = ds.session("walk0")
    other = s.with_building(ds.building("house"))
    other.rssi
    assert s.dropped == other.dropped == {"rssi": {"unknown-anchor": 1}}


def test_unlabelled_ground_truth_is_counted_as_dropped(tiny_dataset):
    edit_yaml(tiny_dataset / S / "session.yaml", lambda d: d.update(labelled=False))
    s = Dataset.open(tiny_dataset).session("walk0").load_all()
    assert s.dropped == {"groundtruth": {"groundtruth-unlabelled": 200}}


def test_clean_session_drops_nothing(tiny_dataset):
    assert Dataset.open(tiny_dataset).session("walk0").load_all().dropped == {}


def test_sum_dropped():
    assert sum_dropped([{"rssi": {"unknown-anchor": 3}}, {}, {"rssi": {"unknown-anchor": 2}, "rtt": {"x": 1}}]) == {
        "rssi": {"unknown-anchor": 5}, "rtt": {"x": 1}}


# --------------------------------------------------------------------------- one place owns the rules


def _black_floor(root):
    p = root / B / "floor_0.png"
    Image.fromarray(np.zeros_like(np.asarray(Image.open(p)))).save(p)


def _unknown_floor(root):
    p = root / B / "floor_0.png"
    Image.fromarray(np.full_like(np.asarray(Image.open(p)), 205)).save(p)


def _resolution(res):
    def f(root):
        edit_yaml(root / B / "building.yaml", lambda d: d["floors"][0].update(resolution=res))
    return f


def _session(**changes):
    def f(root):
        edit_yaml(root / S / "session.yaml", lambda d: d.update(changes))
    return f


def _gt_shift(dx):
    def f(root):
        p = root / S / "groundtruth.csv"
        df = pd.read_csv(p)
        df["x"] += dx
        df.to_csv(p, index=False)
    return f


def _no_data_files(root):
    for f in ("imu.csv", "rssi.csv", "groundtruth.csv"):
        (root / S / f).unlink()
    _session(labelled=False)(root)


# (id, fault, rule, file, line)
SAME_RULE = [
    # issue 19, row 3: validate passed, the evaluation failed with "no free space"
    ("all-black-floor", _black_floor, "floor-no-free-space", f"{B}/building.yaml", None),
    ("all-unknown-floor", _unknown_floor, "floor-no-free-space", f"{B}/building.yaml", None),
    # a floor image whose size disagrees with its resolution: cm/pixel read as... 0.001 m/px -> 0.1 x 0.08 m
    ("resolution-100x-too-small", _resolution(0.001), "anchor-off-floor", f"{B}/anchors.csv", 3),
    # issue 19, row 4
    ("building.yaml-missing", lambda r: (r / B / "building.yaml").unlink(), "missing-file", f"{B}/building.yaml",
     None),
    ("unknown-building", _session(building="castle"), "session-building", f"{S}/session.yaml", None),
    ("labelled-without-groundtruth", lambda r: (r / S / "groundtruth.csv").unlink(), "groundtruth-missing",
     f"{S}/groundtruth.csv", None),
    ("session-without-data", lambda r: _no_data_files(r), "session-empty", S, None),
    # check_session_in_building of the harness, now a data rule
    ("groundtruth-off-floor", _gt_shift(30.0), "groundtruth-off-floor", f"{S}/groundtruth.csv", None),
    ("wrong-floor-size-groundtruth", lambda r: (_resolution(0.02)(r), (r / B / "anchors.csv").unlink(),
                                                (r / S / "rssi.csv").unlink(), (r / B / "rooms.geojson").unlink(),
                                                (r / B / "navgraph.geojson").unlink()),  # (else: geojson-off-floor)
     "groundtruth-off-floor", f"{S}/groundtruth.csv", None),
]


@pytest.mark.parametrize("fault,rule,file,line", [c[1:] for c in SAME_RULE], ids=[c[0] for c in SAME_RULE])
def test_validator_and_readers_refuse_with_the_same_rule(tiny_dataset, fault, rule, file, line):
    fault(tiny_dataset)
    issues = validate(tiny_dataset)
    assert (rule, file, line) in found(tiny_dataset, issues), found(tiny_dataset, issues)
    assert (rule, file, line) in refused(tiny_dataset)


def test_anchor_off_floor_names_every_anchor_outside(tiny_dataset):
    _resolution(0.001)(tiny_dataset)
    errs = errors(validate(tiny_dataset))
    # the plan is 0.1 x 0.08 m: b1 (1, 1) and ap1 (5, 4) are within the 5 m margin, b2..b4 are not
    assert {(i.rule, i.line) for i in errs if i.rule == "anchor-off-floor"} == {("anchor-off-floor", k)
                                                                                 for k in (3, 4, 5)}
    assert "resolution" in errs[0].message and "'b2'" in errs[0].message


def test_one_anchor_a_little_outside_the_plan_is_fine(tiny_dataset):
    set_cell(tiny_dataset / B / "anchors.csv", 3, "x", "14.5")  # 4.5 m east of a 10 m plan
    assert validate(tiny_dataset) == []


def test_anchors_in_a_corner_of_a_huge_plan_are_a_warning(tiny_dataset):
    _resolution(2.0)(tiny_dataset)  # 200 x 160 m: the anchors' 8 x 6 m is less than a tenth of both
    issues = validate(tiny_dataset)
    assert not errors(issues)
    (w,) = issues
    assert w.rule == "anchor-span" and "resolution" in w.message


def test_check_session_in_building_for_the_harness(tiny_dataset):
    ds = Dataset.open(tiny_dataset)
    check_session_in_building(ds.session("walk0"))  # fine
    _gt_shift(30.0)(tiny_dataset)
    s = Dataset.open(tiny_dataset).session("walk0")  # opening does not read ground truth
    with pytest.raises(DatasetError, match=r"groundtruth\.csv: \[groundtruth-off-floor\] 100% of the ground truth"):
        check_session_in_building(s)


def test_ground_truth_half_off_the_plan_is_fine(tiny_dataset):
    """The harness's threshold: more than half outside is an error, half is not."""
    p = tiny_dataset / S / "groundtruth.csv"
    df = pd.read_csv(p)
    df.loc[df.index[:100], "x"] += 30.0  # 100 of 200 rows
    df.to_csv(p, index=False)
    assert validate(tiny_dataset) == []


def test_checks_use_the_datasets_own_plan_not_a_wrong_version(tiny_dataset):
    """Ground truth read through a session seen in a shifted plan is checked against the dataset's plan."""
    from dataclasses import replace

    ds = Dataset.open(tiny_dataset)
    b = ds.building("house")
    moved = replace(b, floors={k: replace(f, origin=(100.0, 100.0)) for k, f in b.floors.items()})
    s = ds.session("walk0").with_building(moved)
    assert len(s.groundtruth) == 200


def test_positions_at_with_a_fixed_device_height(tiny_dataset):
    """Session.positions_at(with_z=True, device_z=h): x, y of the ground truth, z = h (the calibrations' receiver
    height); without device_z the ground truth's z."""
    import numpy as np

    from blenav.data import Dataset

    s = next(iter(Dataset.open(tiny_dataset).sessions()))
    t = s.groundtruth["t"].to_numpy(float)[:5] + 0.25
    p = s.positions_at(t, with_z=True, device_z=1.5)
    assert p.shape == (5, 3) and np.all(p[:, 2] == 1.5)
    np.testing.assert_array_equal(p[:, :2], s.positions_at(t))
    assert np.all(np.isfinite(s.positions_at(t, with_z=True)[:, 2]))
