"""The validator (``blenav.data.validate`` and ``blenav-validate``) against docs/dataset-format.md.

Every test corrupts a fresh copy of the tiny dataset (``tiny_dataset`` fixture) in one place and checks
that the validator names the rule, the file and the 1-based line (CSV header = line 1), and that it
reports nothing else (no cascade of follow-up errors).

Layout of the tiny dataset (tests/helpers.py): building ``house`` with floor 0 (floor_0.png, 10 m x 8 m
at 0.1 m/px), anchors b1..b4 (BLE, lines 2..5 of anchors.csv) and ap1 (WiFi RTT, line 6), rooms
``west``/``east``, one navgraph edge; session ``walk0``: imu.csv (100 Hz, 20 s), rssi.csv (4 rows
every 0.2 s: lines 2-5 at t=0, 6-9 at t=0.2, ...), groundtruth.csv (10 Hz, lines 2..201).
"""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest
import yaml
from PIL import Image

from blenav.cli.validate import main as validate_main
from blenav.data import validate
from blenav.data.schema import SESSION_KEYS
from helpers import errors, lines, rel, set_cell, write_lines


S = "sessions/walk0"
B = "buildings/house"


# --------------------------------------------------------------------------- helpers




def warnings_(issues):
    return [i for i in issues if not i.is_error]


def describe(root, issues) -> str:
    return "\n".join(f"  {i.severity} {rel(root, i)}:{i.line}:{i.where} [{i.rule}] {i.message}" for i in issues)


def assert_only(root: Path, issues, rule: str, file: str, line: int | None = None, where: str | None = None,
                severity: str = "error", count: int = 1):
    """Exactly ``count`` issues of ``severity`` exist and they are ``rule`` in ``file`` at ``line``/``where``."""
    same = [i for i in issues if i.severity == severity]
    assert len(same) == count, f"expected {count} {severity}(s) [{rule}], got:\n{describe(root, issues)}"
    for i in same:
        assert (i.rule, rel(root, i)) == (rule, file), describe(root, issues)
    if count == 1:
        assert same[0].line == line, describe(root, issues)
        assert same[0].where == where, describe(root, issues)
    if severity == "warning":
        assert not errors(issues), describe(root, issues)
    return same


def set_line(path: Path, line: int, text: str) -> None:
    ls = lines(path)
    ls[line - 1] = text
    write_lines(path, ls)


def drop_column(path: Path, column: str) -> None:
    ls = [line.split(",") for line in lines(path)]
    k = ls[0].index(column)
    write_lines(path, [",".join(c[:k] + c[k + 1:]) for c in ls])


def edit_yaml(path: Path, **changes) -> None:
    doc = yaml.safe_load(path.read_text())
    for k, v in changes.items():
        if v is DELETE:
            doc.pop(k)
        else:
            doc[k] = v
    path.write_text(yaml.safe_dump(doc, sort_keys=False))


def edit_floor(root: Path, **changes) -> None:
    p = root / B / "building.yaml"
    doc = yaml.safe_load(p.read_text())
    for k, v in changes.items():
        if v is DELETE:
            doc["floors"][0].pop(k)
        else:
            doc["floors"][0][k] = v
    p.write_text(yaml.safe_dump(doc, sort_keys=False))


def edit_geojson(root: Path, name: str, fn) -> None:
    p = root / B / name
    doc = json.loads(p.read_text())
    fn(doc)
    p.write_text(json.dumps(doc, indent=1))


DELETE = object()


# --------------------------------------------------------------------------- clean data


def test_tiny_dataset_is_valid(tiny_dataset):
    issues = validate(tiny_dataset)
    assert issues == [], describe(tiny_dataset, issues)


def test_missing_dataset_folder(tmp_path):
    issues = validate(tmp_path / "nope")
    assert [i.rule for i in issues] == ["missing-dataset"]


def test_duplicate_timestamps_are_allowed(tiny_dataset):
    p = tiny_dataset / S / "imu.csv"
    set_cell(p, 8, "t", lines(p)[6].split(",")[0])  # line 8 repeats line 7's time
    assert errors(validate(tiny_dataset)) == []


@pytest.mark.parametrize("value", ["-149.5", "-1", "-30.25", "-100"])
def test_plausible_rssi_values_are_accepted(tiny_dataset, value):
    set_cell(tiny_dataset / S / "rssi.csv", 9, "rssi", value)
    assert validate(tiny_dataset) == []


def test_orientation_empty_on_every_row_is_valid(tiny_dataset):
    """Position-only ground truth: qw..qz empty everywhere."""
    p = tiny_dataset / S / "groundtruth.csv"
    ls = lines(p)
    write_lines(p, [ls[0]] + [",".join(r.split(",")[:4] + [""] * 4) for r in ls[1:]])
    assert validate(tiny_dataset) == []


def test_building_without_anchors_and_no_radio_is_valid(tiny_dataset):
    """An inertial-only dataset has no anchors.csv and no rssi/rtt."""
    (tiny_dataset / B / "anchors.csv").unlink()
    (tiny_dataset / S / "rssi.csv").unlink()
    assert validate(tiny_dataset) == []


@pytest.mark.parametrize("content", ["", "t,anchor_id,rssi\n"], ids=["zero-bytes", "header-only"])
def test_empty_optional_radio_file_without_anchors_is_valid(tiny_dataset, content):
    (tiny_dataset / B / "anchors.csv").unlink()
    (tiny_dataset / S / "rssi.csv").write_text(content)
    (tiny_dataset / S / "rtt.csv").write_text(content.replace("rssi\n", "range_m,range_std_m\n"))
    (tiny_dataset / S / "mag.csv").write_text("")
    assert validate(tiny_dataset) == []


def test_unlabelled_session_without_groundtruth_is_valid(tiny_dataset):
    (tiny_dataset / S / "groundtruth.csv").unlink()
    edit_yaml(tiny_dataset / S / "session.yaml", labelled=False)
    assert validate(tiny_dataset) == []


@pytest.mark.parametrize("content", ["", "t,x,y,z,qw,qx,qy,qz\n"], ids=["zero-bytes", "header-only"])
def test_unlabelled_session_with_empty_groundtruth_is_valid(tiny_dataset, content):
    (tiny_dataset / S / "groundtruth.csv").write_text(content)
    edit_yaml(tiny_dataset / S / "session.yaml", labelled=False)
    assert validate(tiny_dataset) == []


# --------------------------------------------------------------------------- one bad cell


# (file, line, column, value, rule): set that cell, expect exactly that one error at that line
CELL_CASES = [
    # NaN / inf / empty in a required numeric column
    (f"{S}/imu.csv", 7, "ax", "nan", "non-finite"),
    (f"{S}/imu.csv", 7, "ax", "NaN", "non-finite"),
    (f"{S}/imu.csv", 7, "ax", "", "non-finite"),
    (f"{S}/imu.csv", 7, "gy", "inf", "non-finite"),
    (f"{S}/imu.csv", 1500, "az", "-inf", "non-finite"),
    (f"{S}/imu.csv", 7, "t", "", "non-finite"),
    (f"{S}/groundtruth.csv", 30, "x", "NaN", "non-finite"),
    (f"{S}/groundtruth.csv", 30, "z", "inf", "non-finite"),
    (f"{S}/groundtruth.csv", 30, "qw", "inf", "non-finite"),  # nullable, but never infinite
    (f"{S}/rssi.csv", 9, "rssi", "nan", "non-finite"),
    (f"{S}/rssi.csv", 9, "t", "", "non-finite"),
    (f"{S}/rssi.csv", 9, "t", "inf", "non-finite"),   # not also 'time-backwards' on the next line
    (f"{S}/rssi.csv", 9, "rssi", "-inf", "non-finite"),  # not also 'rssi-range'
    (f"{B}/anchors.csv", 3, "x", "nan", "non-finite"),
    (f"{B}/anchors.csv", 3, "y", "", "non-finite"),
    # text where a number belongs
    (f"{S}/imu.csv", 12, "gz", "1.2.3", "not-a-number"),
    (f"{S}/imu.csv", 12, "t", "abc", "not-a-number"),
    (f"{S}/rssi.csv", 9, "rssi", "strong", "not-a-number"),
    (f"{S}/groundtruth.csv", 30, "qx", "zero", "not-a-number"),
    (f"{B}/anchors.csv", 3, "z", "high", "not-a-number"),
    # empty text column
    (f"{S}/rssi.csv", 9, "anchor_id", "", "empty-value"),
    (f"{B}/anchors.csv", 4, "anchor_id", "", "empty-value"),
    # time goes backwards
    (f"{S}/imu.csv", 50, "t", "0.001", "time-backwards"),
    (f"{S}/rssi.csv", 9, "t", "0.1", "time-backwards"),
    (f"{S}/groundtruth.csv", 30, "t", "0.5", "time-backwards"),
    # RSSI sentinels and impossible values
    (f"{S}/rssi.csv", 9, "rssi", "0", "rssi-range"),
    (f"{S}/rssi.csv", 9, "rssi", "100", "rssi-range"),
    (f"{S}/rssi.csv", 9, "rssi", "-200", "rssi-range"),
    (f"{S}/rssi.csv", 9, "rssi", "-150", "rssi-range"),
    (f"{S}/rssi.csv", 9, "rssi", "12.5", "rssi-range"),
    # quaternions
    (f"{S}/groundtruth.csv", 30, "qw", "0.1", "quaternion-norm"),
    (f"{S}/groundtruth.csv", 30, "qw", "0", "quaternion-norm"),
    (f"{S}/groundtruth.csv", 30, "qx", "", "quaternion-partial"),
    (f"{S}/groundtruth.csv", 201, "qz", "", "quaternion-partial"),
    # anchors.csv
    (f"{B}/anchors.csv", 4, "kind", "zigbee", "anchor-kind"),
    (f"{B}/anchors.csv", 4, "kind", "BLE", "anchor-kind"),
    (f"{B}/anchors.csv", 4, "anchor_id", "b1", "anchor-unique"),
    (f"{B}/anchors.csv", 6, "floor", "3", "anchor-floor"),
]


@pytest.mark.parametrize("file,line,column,value,rule", CELL_CASES,
                         ids=[f"{Path(c[0]).stem}:{c[1]}:{c[2]}={c[3]!r}" for c in CELL_CASES])
def test_bad_cell_is_reported_with_rule_file_and_line(tiny_dataset, file, line, column, value, rule):
    set_cell(tiny_dataset / file, line, column, value)
    assert_only(tiny_dataset, validate(tiny_dataset), rule, file, line)


def test_orientation_empty_on_one_row_only(tiny_dataset):
    set_line(tiny_dataset / S / "groundtruth.csv", 30, "2.8,2.5,4.0,1.2,,,,")
    assert_only(tiny_dataset, validate(tiny_dataset), "quaternion-partial", f"{S}/groundtruth.csv", 30)


def test_orientation_present_on_one_row_only(tiny_dataset):
    """The reverse partial case: empty everywhere except one row."""
    p = tiny_dataset / S / "groundtruth.csv"
    ls = lines(p)
    body = [",".join(r.split(",")[:4] + [""] * 4) for r in ls[1:]]
    body[5] = ls[6]  # line 7 keeps its quaternion
    write_lines(p, [ls[0]] + body)
    issues = validate(tiny_dataset)
    errs = errors(issues)
    assert {i.rule for i in errs} == {"quaternion-partial"}
    assert {rel(tiny_dataset, i) for i in errs} == {f"{S}/groundtruth.csv"}
    # 199 rows are empty while one is not: every empty row is named, capped with a summary
    assert errs[0].line == 2 and any(i.line is None and "more rows" in i.message for i in errs)


def test_many_bad_rows_are_capped_with_a_summary(tiny_dataset):
    p = tiny_dataset / S / "imu.csv"
    ls = lines(p)
    for k in range(1, 101):
        cells = ls[k].split(",")
        cells[1] = "nan"
        ls[k] = ",".join(cells)
    write_lines(p, ls)
    errs = errors(validate(tiny_dataset))
    assert [i.line for i in errs[:20]] == list(range(2, 22))
    assert errs[20].line is None and "80 more rows" in errs[20].message and "lines 22..101" in errs[20].message
    assert len(errs) == 21


def test_not_a_number_is_reported_once(tiny_dataset):
    """A non-numeric cell is one violation (not also 'non-finite'), and other checks still run."""
    p = tiny_dataset / S / "imu.csv"
    set_cell(p, 12, "ax", "oops")
    set_cell(p, 40, "t", "0.0")  # and, independently, time going backwards
    issues = errors(validate(tiny_dataset))
    assert sorted((i.rule, i.line) for i in issues) == [("not-a-number", 12), ("time-backwards", 40)]


def test_blank_line_in_csv_is_reported_at_its_line(tiny_dataset):
    set_line(tiny_dataset / S / "imu.csv", 20, "")
    errs = errors(validate(tiny_dataset))
    assert errs and {(i.rule, i.line) for i in errs} == {("non-finite", 20)}
    assert {rel(tiny_dataset, i) for i in errs} == {f"{S}/imu.csv"}


def test_ragged_row_names_the_line(tiny_dataset):
    set_line(tiny_dataset / S / "groundtruth.csv", 10, "0.8,2.7,4.0,1.2,1,0,0,0,5,6")
    assert_only(tiny_dataset, validate(tiny_dataset), "malformed-csv", f"{S}/groundtruth.csv", 10)


# --------------------------------------------------------------------------- headers


@pytest.mark.parametrize("file,column", [
    (f"{S}/imu.csv", "gz"), (f"{S}/imu.csv", "t"), (f"{S}/rssi.csv", "anchor_id"), (f"{S}/rssi.csv", "rssi"),
    (f"{S}/groundtruth.csv", "z"), (f"{S}/groundtruth.csv", "qw"),  # nullable columns must still exist
    (f"{B}/anchors.csv", "kind"), (f"{B}/anchors.csv", "tx_power_dbm"),
])
def test_missing_column(tiny_dataset, file, column):
    drop_column(tiny_dataset / file, column)
    issues = validate(tiny_dataset)
    if file.endswith("anchors.csv"):
        # without usable anchors the session's rssi.csv cannot be checked: that is reported too
        assert {(i.rule, rel(tiny_dataset, i), i.line) for i in errors(issues)} == {
            ("missing-column", file, 1), ("anchors-missing", f"{S}/rssi.csv", None)}
        return
    found = assert_only(tiny_dataset, issues, "missing-column", file, 1)
    assert column in found[0].message


def test_duplicate_column(tiny_dataset):
    p = tiny_dataset / S / "imu.csv"
    write_lines(p, [ln + (",ax" if k == 0 else ",0") for k, ln in enumerate(lines(p))])
    assert_only(tiny_dataset, validate(tiny_dataset), "duplicate-column", f"{S}/imu.csv", 1)


def test_a_header_of_many_columns_is_read_in_linear_time(tiny_dataset):
    """Red-team (issue 28 sec. 2): the duplicate-column check was quadratic in the header (list.count per column):
    a 1 MB rssi.csv header of 100,000 columns took 95 s, 2,000,000 hours; now 200,000 columns take well under a
    second, with the duplicated names still reported."""
    import time

    p = tiny_dataset / S / "rssi.csv"
    rows = lines(p)
    write_lines(p, [rows[0] + "".join(f",c{i}" for i in range(200_000)) + ",c7"] + rows[1:])
    t0 = time.perf_counter()
    found = assert_only(tiny_dataset, validate(tiny_dataset), "duplicate-column", f"{S}/rssi.csv", 1)
    assert time.perf_counter() - t0 < 20 and "c7 appear twice" in found[0].message


# --------------------------------------------------------------------------- anchors and radio rows


def test_rssi_rows_for_unknown_anchors_are_a_warning_with_count_and_ids(tiny_dataset):
    p = tiny_dataset / S / "rssi.csv"
    set_cell(p, 5, "anchor_id", "zz")
    set_cell(p, 9, "anchor_id", "AA:BB:CC:DD:EE:FF")
    set_cell(p, 13, "anchor_id", "zz")
    (w,) = assert_only(tiny_dataset, validate(tiny_dataset), "unknown-anchor", f"{S}/rssi.csv",
                       severity="warning")
    assert "3 rows" in w.message and "2 ids" in w.message
    assert "zz" in w.message and "AA:BB:CC:DD:EE:FF" in w.message and "dropped" in w.message


def test_rtt_rows_for_unknown_anchors_are_a_warning(tiny_dataset):
    (tiny_dataset / S / "rtt.csv").write_text(
        "t,anchor_id,range_m,range_std_m\n0.0,ap1,3.1,0.5\n0.1,ap9,4.0,\n0.2,ap1,3.0,0.4\n")
    (w,) = assert_only(tiny_dataset, validate(tiny_dataset), "unknown-anchor", f"{S}/rtt.csv", severity="warning")
    assert "1 rows" in w.message and "ap9" in w.message


@pytest.mark.parametrize("anchors", ["absent", "zero-bytes", "header-only"])
@pytest.mark.parametrize("stream", ["rssi", "rtt"])
def test_radio_rows_without_anchors_are_an_error(tiny_dataset, anchors, stream):
    a = tiny_dataset / B / "anchors.csv"
    if anchors == "absent":
        a.unlink()
    else:
        a.write_text("" if anchors == "zero-bytes" else lines(a)[0] + "\n")
    if stream == "rtt":
        (tiny_dataset / S / "rssi.csv").unlink()
        (tiny_dataset / S / "rtt.csv").write_text("t,anchor_id,range_m,range_std_m\n0.0,ap1,3.1,0.5\n")
    assert_only(tiny_dataset, validate(tiny_dataset), "anchors-missing", f"{S}/{stream}.csv")


# --------------------------------------------------------------------------- empty and missing files


@pytest.mark.parametrize("content", ["", "t,ax,ay,az,gx,gy,gz\n"], ids=["zero-bytes", "header-only"])
def test_imu_present_but_empty(tiny_dataset, content):
    (tiny_dataset / S / "imu.csv").write_text(content)
    assert_only(tiny_dataset, validate(tiny_dataset), "empty-required", f"{S}/imu.csv")


@pytest.mark.parametrize("content", ["", "t,x,y,z,qw,qx,qy,qz\n"], ids=["zero-bytes", "header-only"])
def test_labelled_with_empty_groundtruth(tiny_dataset, content):
    (tiny_dataset / S / "groundtruth.csv").write_text(content)
    assert_only(tiny_dataset, validate(tiny_dataset), "empty-required", f"{S}/groundtruth.csv")


def test_labelled_without_groundtruth(tiny_dataset):
    (tiny_dataset / S / "groundtruth.csv").unlink()
    assert_only(tiny_dataset, validate(tiny_dataset), "groundtruth-missing", f"{S}/groundtruth.csv")


def test_unlabelled_with_groundtruth_rows_is_a_warning(tiny_dataset):
    edit_yaml(tiny_dataset / S / "session.yaml", labelled=False)
    assert_only(tiny_dataset, validate(tiny_dataset), "groundtruth-unlabelled", f"{S}/groundtruth.csv",
                severity="warning")


@pytest.mark.parametrize("labelled", [False, True])
def test_session_without_data_files(tiny_dataset, labelled):
    for f in ("imu.csv", "rssi.csv", "groundtruth.csv"):
        (tiny_dataset / S / f).unlink()
    (tiny_dataset / S / "notes.txt").write_text("not a data file")
    edit_yaml(tiny_dataset / S / "session.yaml", labelled=labelled)
    issues = validate(tiny_dataset)
    if not labelled:
        assert_only(tiny_dataset, issues, "session-empty", S)
    else:
        assert {(i.rule, rel(tiny_dataset, i)) for i in errors(issues)} == {
            ("session-empty", S), ("groundtruth-missing", f"{S}/groundtruth.csv")}


@pytest.mark.parametrize("only", ["groundtruth.csv", "imu.csv", "rssi.csv"])
def test_session_with_a_single_data_file_is_valid(tiny_dataset, only):
    for f in ("imu.csv", "rssi.csv", "groundtruth.csv"):
        if f != only:
            (tiny_dataset / S / f).unlink()
    edit_yaml(tiny_dataset / S / "session.yaml", labelled=only == "groundtruth.csv")
    assert validate(tiny_dataset) == []


def test_no_buildings_and_no_sessions(tiny_dataset):
    shutil.rmtree(tiny_dataset / "buildings")
    shutil.rmtree(tiny_dataset / "sessions")
    issues = validate(tiny_dataset)
    assert {(i.rule, rel(tiny_dataset, i)) for i in issues} == {("no-buildings", "buildings"),
                                                                 ("no-sessions", "sessions")}


# --------------------------------------------------------------------------- dataset.yaml


@pytest.mark.parametrize("fmt", ["blenav/2", "blenav/0", None, 1])
def test_dataset_format_value(tiny_dataset, fmt):
    edit_yaml(tiny_dataset / "dataset.yaml", format=DELETE if fmt is None else fmt)
    (e,) = assert_only(tiny_dataset, validate(tiny_dataset), "format", "dataset.yaml")
    assert "blenav/1" in e.message


def test_dataset_yaml_missing(tiny_dataset):
    (tiny_dataset / "dataset.yaml").unlink()
    assert_only(tiny_dataset, validate(tiny_dataset), "missing-file", "dataset.yaml")


def test_dataset_yaml_syntax_error_names_the_line(tiny_dataset):
    (tiny_dataset / "dataset.yaml").write_text("format: blenav/1\nname: tiny\n  bad: indent\nlicence: x\n")
    assert_only(tiny_dataset, validate(tiny_dataset), "yaml-syntax", "dataset.yaml", line=3)


def test_dataset_yaml_not_a_mapping(tiny_dataset):
    (tiny_dataset / "dataset.yaml").write_text("- format\n- blenav/1\n")
    assert_only(tiny_dataset, validate(tiny_dataset), "yaml-not-mapping", "dataset.yaml")


# --------------------------------------------------------------------------- session.yaml


@pytest.mark.parametrize("key", SESSION_KEYS)
def test_session_yaml_missing_key(tiny_dataset, key):
    edit_yaml(tiny_dataset / S / "session.yaml", **{key: DELETE})
    if key == "labelled":  # absent 'labelled' also means the ground truth is not expected
        issues = validate(tiny_dataset)
        assert {(i.rule, rel(tiny_dataset, i)) for i in errors(issues)} == {("session-keys", f"{S}/session.yaml")}
        return
    (e,) = assert_only(tiny_dataset, validate(tiny_dataset), "session-keys", f"{S}/session.yaml")
    assert key in e.message


@pytest.mark.parametrize("changes,rule", [
    ({"building": "castle"}, "session-building"),
    ({"building": None}, "session-building"),
    ({"floor": 3}, "session-floor"),
    ({"floor": "ground"}, "session-floor"),
    ({"carrier": "bicycle"}, "session-carrier"),
    ({"carrier": None}, "session-carrier"),
    ({"labelled": "maybe"}, "session-labelled"),
    ({"labelled": 1}, "session-labelled"),
    ({"gyro_calibrated": "true"}, "session-gyro-calibrated"),
], ids=lambda v: str(v) if not isinstance(v, dict) else ",".join(f"{k}={v[k]!r}" for k in v))
def test_session_yaml_values(tiny_dataset, changes, rule):
    edit_yaml(tiny_dataset / S / "session.yaml", **changes)
    issues = validate(tiny_dataset)
    if rule == "session-labelled":  # a non-boolean 'labelled' is not true: groundtruth is then extra
        assert {(i.rule, rel(tiny_dataset, i)) for i in errors(issues)} == {(rule, f"{S}/session.yaml")}
        return
    assert_only(tiny_dataset, issues, rule, f"{S}/session.yaml")


def test_session_building_folder_missing(tiny_dataset):
    (tiny_dataset / B).rename(tiny_dataset / "buildings" / "other")
    assert_only(tiny_dataset, validate(tiny_dataset), "session-building", f"{S}/session.yaml")


def test_session_floor_as_string_matches_integer_floor_id(tiny_dataset):
    edit_yaml(tiny_dataset / S / "session.yaml", floor="0")
    assert validate(tiny_dataset) == []


def test_session_yaml_missing(tiny_dataset):
    (tiny_dataset / S / "session.yaml").unlink()
    assert_only(tiny_dataset, validate(tiny_dataset), "missing-file", f"{S}/session.yaml")


# --------------------------------------------------------------------------- building.yaml and floors


@pytest.mark.parametrize("changes,rule", [
    ({"free_thresh": 0.7}, "floor-thresholds"),            # free above occupied
    ({"free_thresh": 0.65}, "floor-thresholds"),           # equal is not allowed either
    ({"occupied_thresh": 1.2}, "floor-thresholds"),
    ({"free_thresh": -0.1}, "floor-thresholds"),
    ({"occupied_thresh": "high"}, "floor-value"),
    ({"resolution": 0}, "floor-resolution"),
    ({"resolution": -0.05}, "floor-resolution"),
    ({"resolution": "fine"}, "floor-value"),
    ({"origin": [1.0]}, "floor-origin"),
    ({"origin": [0.0, float("nan"), 0.0]}, "floor-origin"),
    ({"origin": 5}, "floor-value"),
    ({"resolution": DELETE}, "floor-keys"),
    ({"image": DELETE}, "floor-keys"),
    ({"id": DELETE}, "floor-keys"),
], ids=lambda v: str(v) if not isinstance(v, dict) else ",".join(f"{k}={'DEL' if v[k] is DELETE else v[k]!r}"
                                                                    for k in v))
def test_floor_values(tiny_dataset, changes, rule):
    edit_floor(tiny_dataset, **changes)
    if "id" in changes:  # no floor is called 0 any more: the session's floor is rightly unknown too
        assert {(i.rule, rel(tiny_dataset, i)) for i in errors(validate(tiny_dataset))} == {
            (rule, f"{B}/building.yaml"), ("session-floor", f"{S}/session.yaml")}
        return
    # no cascade: the session's floor 0 and the anchors/rooms on it are not reported again
    assert_only(tiny_dataset, validate(tiny_dataset), rule, f"{B}/building.yaml", where="floors[0]")


def test_default_thresholds_are_used_when_absent(tiny_dataset):
    edit_floor(tiny_dataset, occupied_thresh=DELETE, free_thresh=DELETE)
    assert validate(tiny_dataset) == []


def test_origin_yaw_is_a_warning(tiny_dataset):
    edit_floor(tiny_dataset, origin=[0.0, 0.0, 0.3])
    assert_only(tiny_dataset, validate(tiny_dataset), "floor-origin-yaw", f"{B}/building.yaml", where="floors[0]",
                severity="warning")


@pytest.mark.parametrize("floors", [[], None, "floor_0.png"])
def test_floors_must_be_a_non_empty_list(tiny_dataset, floors):
    p = tiny_dataset / B / "building.yaml"
    doc = yaml.safe_load(p.read_text())
    doc["floors"] = floors
    p.write_text(yaml.safe_dump(doc))
    assert_only(tiny_dataset, validate(tiny_dataset), "floors", f"{B}/building.yaml")


def test_duplicate_floor_id(tiny_dataset):
    p = tiny_dataset / B / "building.yaml"
    doc = yaml.safe_load(p.read_text())
    doc["floors"].append(dict(doc["floors"][0]))
    p.write_text(yaml.safe_dump(doc))
    assert_only(tiny_dataset, validate(tiny_dataset), "floor-duplicate", f"{B}/building.yaml", where="floors[1]")


def test_building_yaml_missing(tiny_dataset):
    (tiny_dataset / B / "building.yaml").unlink()
    assert_only(tiny_dataset, validate(tiny_dataset), "missing-file", f"{B}/building.yaml")


def test_floor_image_missing(tiny_dataset):
    (tiny_dataset / B / "floor_0.png").unlink()
    (e,) = assert_only(tiny_dataset, validate(tiny_dataset), "missing-file", f"{B}/floor_0.png")
    assert "floors[0]" in e.message


def _truncate(p: Path) -> None:
    b = p.read_bytes()
    p.write_bytes(b[: len(b) // 2])


def _to_pgm_truncated(root: Path) -> None:
    img = root / B / "floor_0.png"
    Image.open(img).save(root / B / "floor_0.pgm")
    _truncate(root / B / "floor_0.pgm")
    edit_floor(root, image="floor_0.pgm")


@pytest.mark.parametrize("corrupt,file", [
    (lambda r: (r / B / "floor_0.png").write_bytes(b"this is not an image"), "floor_0.png"),
    (lambda r: (r / B / "floor_0.png").write_bytes(b""), "floor_0.png"),
    (lambda r: _truncate(r / B / "floor_0.png"), "floor_0.png"),
    (_to_pgm_truncated, "floor_0.pgm"),
], ids=["garbage", "zero-bytes", "truncated-png", "truncated-pgm"])
def test_floor_image_unreadable(tiny_dataset, corrupt, file):
    corrupt(tiny_dataset)
    # reported once, on the image: not again as "session floor 0 does not exist"
    assert_only(tiny_dataset, validate(tiny_dataset), "image-unreadable", f"{B}/{file}")


def test_floor_image_16_bit_is_an_error(tiny_dataset):
    p = tiny_dataset / B / "floor_0.png"
    a = np.asarray(Image.open(p)).astype(np.uint16) * 257
    Image.fromarray(a).save(p)
    assert Image.open(p).mode.startswith("I")
    assert_only(tiny_dataset, validate(tiny_dataset), "image-mode", f"{B}/floor_0.png")


def test_floor_image_rgb_is_a_warning(tiny_dataset):
    p = tiny_dataset / B / "floor_0.png"
    Image.open(p).convert("RGB").save(p)
    assert_only(tiny_dataset, validate(tiny_dataset), "image-not-grayscale", f"{B}/floor_0.png", severity="warning")


# --------------------------------------------------------------------------- GeoJSON


def _set(path_keys, value):
    def fn(doc):
        d = doc
        for k in path_keys[:-1]:
            d = d[k]
        if value is DELETE:
            del d[path_keys[-1]]
        else:
            d[path_keys[-1]] = value
    return fn


GEOJSON_CASES = [
    ("rooms.geojson", _set(["features", 0, "properties", "id"], DELETE), "geojson-properties", "features[0]"),
    ("rooms.geojson", _set(["features", 1, "properties", "floor"], DELETE), "geojson-properties", "features[1]"),
    ("rooms.geojson", _set(["features", 1, "properties"], None), "geojson-properties", "features[1]"),
    ("navgraph.geojson", _set(["features", 0, "properties"], {}), "geojson-properties", "features[0]"),
    ("rooms.geojson", _set(["features", 0, "geometry"], {"type": "Point", "coordinates": [1, 2]}),
     "geojson-geometry", "features[0]"),
    ("rooms.geojson", _set(["features", 1, "geometry"], {"type": "LineString", "coordinates": [[0, 0], [1, 1]]}),
     "geojson-geometry", "features[1]"),
    ("navgraph.geojson", _set(["features", 0, "geometry"],
                              {"type": "Polygon", "coordinates": [[[0, 0], [1, 0], [1, 1], [0, 0]]]}),
     "geojson-geometry", "features[0]"),
    ("rooms.geojson", _set(["features", 0, "geometry"], None), "geojson-geometry", "features[0]"),
    ("rooms.geojson", _set(["features", 0, "geometry", "coordinates"], [[[0, 0], [1]]]),
     "geojson-coordinates", "features[0]"),
    ("rooms.geojson", _set(["features", 1, "properties", "floor"], 4), "geojson-floor", "features[1]"),
    ("navgraph.geojson", _set(["features", 0, "properties", "floor"], "1"), "geojson-floor", "features[0]"),
    ("rooms.geojson", _set(["type"], "Feature"), "geojson-type", None),
    ("rooms.geojson", lambda d: d["features"].append(7), "geojson-type", "features[2]"),
    ("rooms.geojson", _set(["features"], {"west": 1}), "geojson-type", None),
]


@pytest.mark.parametrize("file,fn,rule,where", GEOJSON_CASES,
                         ids=[f"{c[0].split('.')[0]}-{c[2]}-{k}" for k, c in enumerate(GEOJSON_CASES)])
def test_geojson_rules(tiny_dataset, file, fn, rule, where):
    edit_geojson(tiny_dataset, file, fn)
    assert_only(tiny_dataset, validate(tiny_dataset), rule, f"{B}/{file}", where=where)


def test_geojson_floor_as_string_matches_integer_floor_id(tiny_dataset):
    edit_geojson(tiny_dataset, "rooms.geojson", _set(["features", 0, "properties", "floor"], "0"))
    assert validate(tiny_dataset) == []


def test_geojson_syntax_error_names_the_line(tiny_dataset):
    p = tiny_dataset / B / "rooms.geojson"
    ls = lines(p)
    ls[3] = ls[3] + " ,,"
    write_lines(p, ls)
    assert_only(tiny_dataset, validate(tiny_dataset), "json-syntax", f"{B}/rooms.geojson", line=4)


def test_empty_geojson_file_is_fine(tiny_dataset):
    (tiny_dataset / B / "rooms.geojson").write_text("")
    assert validate(tiny_dataset) == []


# --------------------------------------------------------------------------- several problems at once


def test_all_violations_are_collected(tiny_dataset):
    set_cell(tiny_dataset / S / "imu.csv", 7, "ax", "nan")
    set_cell(tiny_dataset / S / "rssi.csv", 9, "rssi", "-200")
    set_cell(tiny_dataset / B / "anchors.csv", 4, "kind", "zigbee")
    edit_floor(tiny_dataset, free_thresh=0.9)
    got = {(i.rule, rel(tiny_dataset, i), i.line or i.where) for i in errors(validate(tiny_dataset))}
    assert got == {("non-finite", f"{S}/imu.csv", 7), ("rssi-range", f"{S}/rssi.csv", 9),
                   ("anchor-kind", f"{B}/anchors.csv", 4), ("floor-thresholds", f"{B}/building.yaml", "floors[0]")}


# --------------------------------------------------------------------------- blenav-validate


def test_cli_clean_dataset_exits_0(tiny_dataset, capsys):
    assert validate_main([str(tiny_dataset)]) == 0
    out, err = capsys.readouterr()
    assert out == ""
    assert "OK" in err and "0 violation(s)" in err


def test_cli_warnings_only_exits_0_and_prints_them(tiny_dataset, capsys):
    set_cell(tiny_dataset / S / "rssi.csv", 5, "anchor_id", "zz")
    assert validate_main([str(tiny_dataset)]) == 0
    out, err = capsys.readouterr()
    (line,) = out.splitlines()
    assert line.startswith("WARNING ") and "rssi.csv" in line and "[unknown-anchor]" in line
    assert "OK" in err and "1 warning(s)" in err
    assert validate_main([str(tiny_dataset), "--quiet"]) == 0
    assert capsys.readouterr().out == ""


def test_cli_invalid_dataset_exits_1_with_one_line_per_violation(tiny_dataset, capsys):
    set_cell(tiny_dataset / S / "imu.csv", 7, "ax", "nan")
    set_cell(tiny_dataset / S / "groundtruth.csv", 30, "t", "0.5")
    set_cell(tiny_dataset / S / "rssi.csv", 9, "rssi", "100")
    set_cell(tiny_dataset / S / "rssi.csv", 13, "anchor_id", "zz")  # a warning, printed too
    assert validate_main([str(tiny_dataset)]) == 1
    out, err = capsys.readouterr()
    out_lines = out.splitlines()
    error_lines = [ln for ln in out_lines if ln.startswith("ERROR ")]
    assert len(error_lines) == 3 and len(out_lines) == 4
    joined = "\n".join(error_lines)
    assert f"{S}/imu.csv:7: [non-finite]" in joined
    assert f"{S}/groundtruth.csv:30: [time-backwards]" in joined
    assert f"{S}/rssi.csv:9: [rssi-range]" in joined
    assert "INVALID" in err and "3 violation(s)" in err


def test_cli_missing_folder_exits_1(tmp_path, capsys):
    assert validate_main([str(tmp_path / "nothing")]) == 1
    assert "[missing-dataset]" in capsys.readouterr().out


def test_line_numbers_are_not_shifted_by_dropped_unknown_anchor_rows(tiny_dataset):
    """Rows for unknown anchors are dropped, but later rows keep their own line numbers."""
    p = tiny_dataset / S / "rssi.csv"
    set_cell(p, 3, "anchor_id", "zz")
    set_cell(p, 6, "anchor_id", "zz")
    set_cell(p, 9, "rssi", "-200")
    issues = validate(tiny_dataset)
    assert_only(tiny_dataset, issues, "rssi-range", f"{S}/rssi.csv", 9)
    assert [i.rule for i in warnings_(issues)] == ["unknown-anchor"]
