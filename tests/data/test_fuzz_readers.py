"""Issue 19, section 2: corrupted datasets against every reader and blenav-validate (property-based).

Each example copies a small valid dataset with every stream (tests/fuzz_helpers.py), applies one generated fault
(truncation at any byte, byte flips, shuffled or duplicated rows, huge or non-finite times, unit mistakes, BOM
and CRLF, duplicate anchors, missing floors, Unicode and spaces in ids, NaN/inf cells, empty or missing files,
extreme RSSI, ...) and checks:

* a fault that changes nothing (BOM, CRLF, padding, column order, anchor order, consistent renames, ...) is
  accepted and everything read is identical to the clean dataset's;
* any other fault is refused with a :class:`DatasetError` naming a file of the dataset -- the validator reports
  the same errors, ``blenav-validate`` exits 1 -- or it is accepted, the validator agrees, and what is read
  keeps every promise of the readers (finite values, plausible ranges, time order, known anchors, ...); rows
  that were left out are counted in ``Session.dropped``;
* never another exception (a traceback for the user) and never a hang (pytest-timeout).

``make test`` runs the ``blenav-ci`` profile (derandomized, 20 examples per test); the ``slow`` tests run the same
properties with ``blenav-slow`` (400 each). ``BLENAV_FUZZ_EXAMPLES=N`` changes both.
"""

from __future__ import annotations

import contextlib
import io
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from hypothesis import event, given, settings
from hypothesis import strategies as st

from blenav.cli.validate import main as validate_main
from blenav.data import validate
from blenav.errors import DatasetError
from fuzz_helpers import (
    ANY,
    CI,
    DROPPED,
    REFUSED,
    SAME,
    SLOW,
    bad_faults,
    check_promises,
    fresh_copy,
    make_fuzz_dataset,
    make_sim_fuzz_dataset,
    names_a_file,
    read_everything,
    same_faults,
    two_bad_faults,
)

pytestmark = pytest.mark.timeout(900)


@pytest.fixture(scope="module")
def template(tmp_path_factory):
    root = make_fuzz_dataset(tmp_path_factory.mktemp("fuzz") / "template")
    assert validate(root) == []
    return root


@pytest.fixture(scope="module")
def clean(template):
    return read_everything(template)


@pytest.fixture(scope="module")
def sim_template(tmp_path_factory):
    root = make_sim_fuzz_dataset(tmp_path_factory.mktemp("fuzz_sim") / "template")
    assert validate(root) == []
    return root


@pytest.fixture(scope="module")
def sim_clean(sim_template):
    return read_everything(sim_template)


@pytest.fixture(scope="module")
def work(tmp_path_factory):
    return tmp_path_factory.mktemp("work")


def run_validate_cli(root: Path) -> tuple[int, str, str]:
    """``blenav-validate ROOT`` in-process: (exit code, stdout, stderr); any exception but SystemExit propagates."""
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        try:
            code = validate_main([str(root)])
        except SystemExit as e:  # a known error: one line, exit 1
            code = e.code
    return code, out.getvalue(), err.getvalue()


def errors_of(issues) -> set:
    return {(i.rule, i.path, i.line) for i in issues if i.is_error}


def check_same(template, clean, work, fault) -> None:
    root = fresh_copy(template, work)
    outcome = fault.apply(root)
    assert outcome.expect == SAME
    snap = read_everything(root, outcome.rename)
    snap.assert_same(clean)
    code, out, err = run_validate_cli(root)
    assert code == 0 and "ERROR" not in out, out


def check_bad(template, clean, work, fault) -> None:
    root = fresh_copy(template, work)
    outcome = fault.apply(root)
    found = validate(root)  # never raises
    code, out, err = run_validate_cli(root)
    assert "Traceback" not in err
    try:
        snap = read_everything(root)
    except DatasetError as exc:
        assert outcome.expect != SAME
        assert names_a_file(root, str(exc)), str(exc)
        raised = errors_of(exc.issues)
        assert raised, exc.issues
        # one place owns the rules: what stops the readers is what the validator reports
        assert raised <= errors_of(found), (raised, errors_of(found))
        if outcome.rules:
            assert {r for r, _, _ in raised} & outcome.rules, (outcome.rules, raised)
        assert code == 1 and "ERROR" in out
        for line in out.splitlines():
            assert not line.startswith("ERROR") or str(root) in line, line
        event(f"{fault.name}: refused ({', '.join(sorted({r for r, _, _ in raised}))})")
        return
    assert not errors_of(found), f"the readers accept what the validator refuses: {errors_of(found)}"
    assert code == 0, out
    assert outcome.expect != REFUSED, f"{fault!r} was accepted (it must be refused)"
    check_promises(snap)
    event(f"{fault.name}: accepted")
    dropped = sum(n for d in snap.dropped.values() for reasons in d.values() for n in reasons.values())
    if outcome.expect == DROPPED:
        assert dropped == outcome.dropped, snap.dropped
        assert ("unknown-anchor", "sessions/walk0/rssi.csv") in snap.warnings or \
               ("unknown-anchor", "sessions/walk0/rtt.csv") in snap.warnings
    if outcome.expect == ANY and dropped:  # what was left out is said where the user looks
        assert any(r == "unknown-anchor" for r, _ in snap.warnings)


@settings(CI)
@given(fault=same_faults())
def test_faults_that_change_nothing_leave_everything_identical(template, clean, work, fault):
    check_same(template, clean, work, fault)


@settings(CI)
@given(fault=bad_faults())
def test_corrupted_datasets_are_refused_cleanly_or_read_with_every_promise(template, clean, work, fault):
    check_bad(template, clean, work, fault)


@settings(CI)
@given(faults=st.lists(same_faults(), min_size=2, max_size=4))
def test_several_harmless_faults_together_change_nothing(template, clean, work, faults):
    root = fresh_copy(template, work)
    # rewrites first, then byte-level BOM and line ends (once per file: a second BOM is a character of the
    # header), renames last (the others name the template's paths)
    order = {"bom": 1, "line_ends": 1, "rename_ids": 2}
    faults = sorted(faults, key=lambda f: order.get(f.name, 0))
    rename, seen = {}, set()
    for f in faults:
        key = (f.name, f.args[0]) if f.name in ("bom", "line_ends") else f.name if f.name == "rename_ids" else None
        if key is not None and key in seen:
            continue
        seen.add(key)
        rename.update(f.apply(root).rename)
    read_everything(root, rename).assert_same(clean)


@settings(CI)
@given(fault=two_bad_faults())
def test_two_corruptions_together_are_refused_cleanly_or_read_with_every_promise(template, clean, work, fault):
    check_bad(template, clean, work, fault)


@pytest.mark.slow
@settings(SLOW)
@given(fault=two_bad_faults())
def test_two_corruptions_slow(template, clean, work, fault):
    check_bad(template, clean, work, fault)


@pytest.mark.slow
@settings(SLOW)
@given(fault=same_faults())
def test_simulated_dataset_faults_that_change_nothing_slow(sim_template, sim_clean, work, fault):
    check_same(sim_template, sim_clean, work, fault)


@pytest.mark.slow
@settings(SLOW)
@given(fault=bad_faults())
def test_simulated_dataset_corrupted_slow(sim_template, sim_clean, work, fault):
    check_bad(sim_template, sim_clean, work, fault)


@pytest.mark.slow
@settings(SLOW)
@given(fault=same_faults())
def test_faults_that_change_nothing_slow(template, clean, work, fault):
    check_same(template, clean, work, fault)


@pytest.mark.slow
@settings(SLOW)
@given(fault=bad_faults())
def test_corrupted_datasets_slow(template, clean, work, fault):
    check_bad(template, clean, work, fault)


# --------------------------------------------------------------------------- regressions: what the fuzz tests found
# (tiny_dataset: tests/conftest.py; the session's rssi.csv lines 2..401, groundtruth.csv 2..201, imu.csv 2..2001)

S = "sessions/walk0"
B = "buildings/house"


def _errors(root):
    return {(i.rule, Path(i.path).relative_to(root).as_posix(), i.line) for i in validate(root) if i.is_error}


def _refused(root) -> set:
    with pytest.raises(DatasetError) as e:
        read_everything(root)
    assert str(root) in str(e.value)
    return {(i.rule, Path(i.path).relative_to(root).as_posix(), i.line) for i in e.value.issues if i.is_error}


def test_geojson_with_a_byte_order_mark_is_read(tiny_dataset):
    """Was: [json-syntax] Unexpected UTF-8 BOM (a BOM was fine in CSV and YAML only)."""
    clean = read_everything(tiny_dataset)
    p = tiny_dataset / B / "rooms.geojson"
    p.write_bytes(b"\xef\xbb\xbf" + p.read_bytes())
    read_everything(tiny_dataset).assert_same(clean)


@pytest.mark.parametrize("file, line", [(f"{S}/rssi.csv", 3), (f"{S}/session.yaml", 2), (f"{B}/rooms.geojson", 1),
                                        (f"{B}/anchors.csv", 3)])
def test_bytes_that_are_not_utf8_are_an_error_at_their_line(tiny_dataset, file, line):
    """Was: UnicodeDecodeError from pandas or pathlib, naming neither file nor line (blenav-validate crashed)."""
    p = tiny_dataset / file
    ls = p.read_bytes().split(b"\n")
    ls[line - 1] = b"\xe9" + ls[line - 1]  # a Latin-1 e-acute
    p.write_bytes(b"\n".join(ls))
    # (an unreadable anchors.csv leaves rssi.csv unchecked: 'anchors-missing', as in test_validate.py)
    assert _errors(tiny_dataset) - {("anchors-missing", f"{S}/rssi.csv", None)} == {("encoding", file, line)}
    assert ("encoding", file, line) in _refused(tiny_dataset)


@pytest.mark.parametrize("stream, n", [("rssi", 400), ("groundtruth", 200)])
def test_one_stream_in_milliseconds_is_refused(tiny_dataset, stream, n):
    """Was: accepted; PF-PL 2.31 m instead of 1.60 m on the tiny dataset with rssi.csv in ms, no word anywhere."""
    p = tiny_dataset / S / f"{stream}.csv"
    df = pd.read_csv(p)
    df["t"] *= 1000
    df.to_csv(p, index=False)
    assert _errors(tiny_dataset) == {("time-clock", f"{S}/{stream}.csv", None)}
    assert _refused(tiny_dataset) == {("time-clock", f"{S}/{stream}.csv", None)}
    assert "milliseconds" in str(validate(tiny_dataset)[0])


def test_one_stream_on_another_clock_is_refused(tiny_dataset):
    """Was: accepted; the evaluation then stepped its filters through 900000 s (15 GB, killed)."""
    p = tiny_dataset / S / "rssi.csv"
    df = pd.read_csv(p)
    df["t"] += 9e5
    df.to_csv(p, index=False)
    assert _refused(tiny_dataset) == {("time-clock", f"{S}/rssi.csv", None)}


def test_a_short_or_sparse_stream_is_not_a_clock_error(tiny_dataset):
    """Streams with few rows, or ending within the first second, may stop early."""
    (tiny_dataset / S / "visual.csv").write_text("t,x,y,z,yaw\n0.5,3,4,1.2,0\n1.5,3,4,1.2,0\n")
    (tiny_dataset / S / "fixes.csv").write_text("t,x,y,std,source\n" + "".join(
        f"{0.05 * i:.2f},3,4,1,a\n" for i in range(19)))  # 19 rows in 0.9 s
    (tiny_dataset / S / "mag.csv").write_text("t,mx,my,mz\n" + "".join(f"{0.2 * i:.1f},20,-3,-40\n"
                                                                      for i in range(1, 12)))  # 11 rows to 2.2 s
    assert _errors(tiny_dataset) == set()


@pytest.mark.parametrize("resolution", [100.0, 1e6, 1e300])
def test_a_floor_plan_larger_than_any_floor_is_refused(tiny_dataset, resolution):
    """Was: accepted (an 'anchor-span' warning); the evaluation gave an RMSE of inf (1e300) or died of a
    MemoryError building its 1 m grid (1e6: 100 km x 80 km)."""
    p = tiny_dataset / B / "building.yaml"
    p.write_text(p.read_text().replace("resolution: 0.1", f"resolution: {resolution}"))
    assert ("floor-size", f"{B}/building.yaml", None) in _errors(tiny_dataset)
    assert ("floor-size", f"{B}/building.yaml", None) in _refused(tiny_dataset)


@pytest.mark.parametrize("value", ["1e300", "0", "4", "-200"])
def test_tx_power_outside_the_rssi_range_is_refused(tiny_dataset, value):
    """Was: accepted; tx_power_dbm 1e300 changed PF-PL from 1.60 m to 5.42 m silently."""
    p = tiny_dataset / B / "anchors.csv"
    ls = p.read_text().splitlines()
    ls[1] = ls[1].replace("-59.0", value)
    p.write_text("\n".join(ls) + "\n")
    assert _errors(tiny_dataset) == {("anchor-range", f"{B}/anchors.csv", 2)}


def test_an_anchor_far_above_its_floor_is_refused(tiny_dataset):
    """Was: accepted; z = 1e300 changed PF-PL from 1.60 m to 1.46 m silently (x and y were checked, z not)."""
    p = tiny_dataset / B / "anchors.csv"
    ls = p.read_text().splitlines()
    assert ls[2].startswith("b2,ble,9.0,1.0,2.5,")
    ls[2] = ls[2].replace(",2.5,", ",1e300,")
    p.write_text("\n".join(ls) + "\n")
    assert _errors(tiny_dataset) == {("anchor-off-floor", f"{B}/anchors.csv", 3)}
    ls[2] = ls[2].replace(",1e300,", ",7.4,")  # 7.4 m above floor 0 (z 0): within max(5 m, half of 10 m)? no
    p.write_text("\n".join(ls) + "\n")
    assert _errors(tiny_dataset) == {("anchor-off-floor", f"{B}/anchors.csv", 3)}
    ls[2] = ls[2].replace(",7.4,", ",4.9,")
    p.write_text("\n".join(ls) + "\n")
    assert _errors(tiny_dataset) == set()


def test_quoted_fields_read_as_the_same(tiny_dataset):
    """Was: a header written "t","anchor_id","rssi" (spreadsheets quote every field) lacked every column."""
    clean = read_everything(tiny_dataset)
    for f in (f"{S}/rssi.csv", f"{B}/anchors.csv"):
        p = tiny_dataset / f
        p.write_text("".join(",".join(f'"{c}"' for c in ln.split(",")) + "\n" for ln in p.read_text().splitlines()))
    read_everything(tiny_dataset).assert_same(clean)


def test_a_row_with_a_field_more_or_less_is_refused(tiny_dataset):
    """Was: a first row with one field too many became pandas' row index, shifting every column (silently where
    the values still parsed); a row with a field missing read as an empty cell (silently, in a nullable column)."""
    p = tiny_dataset / S / "rssi.csv"
    ls = p.read_text().splitlines()
    ls[1] += ","  # a trailing comma on the first row
    p.write_text("\n".join(ls) + "\n")
    assert _errors(tiny_dataset) == {("malformed-csv", f"{S}/rssi.csv", 2)}
    (tiny_dataset / S / "rssi.csv").write_text("\n".join(ls[:1] + ls[2:]) + "\n")
    (tiny_dataset / S / "rtt.csv").write_text("t,anchor_id,range_m,range_std_m\n0.0,ap1,3.1,0.5\n0.1,ap1,4.0\n")
    assert _errors(tiny_dataset) == {("malformed-csv", f"{S}/rtt.csv", 3)}
    assert "3 field(s), the header has 4" in str(validate(tiny_dataset)[0])


@pytest.mark.parametrize("name", ["NA", "null", "None", "nan", "N/A"])
def test_ids_that_look_like_missing_values_are_ids(tiny_dataset, name):
    """Was: an anchor called 'NA' (or 'null', ...) read as an empty id: 'column anchor_id is empty'."""
    clean = read_everything(tiny_dataset)
    for f in (f"{B}/anchors.csv", f"{S}/rssi.csv"):
        p = tiny_dataset / f
        p.write_text("".join((name + ln[2:] if ln.startswith("b3,") else ln.replace(",b3,", f",{name},")) + "\n"
                             for ln in p.read_text().splitlines()))
    read_everything(tiny_dataset, {name: "b3"}).assert_same(clean)


def test_padded_header_names_keep_text_ids_as_text(tiny_dataset):
    """Was: with 'anchor_id ' in the header the column's type was guessed: ids 01, 02 read as 1, 2 (unknown)."""
    clean = read_everything(tiny_dataset)
    for f in (f"{B}/anchors.csv", f"{S}/rssi.csv"):
        p = tiny_dataset / f
        ls = p.read_text().splitlines()
        ls[0] = " ,".join(ls[0].split(","))
        p.write_text("\n".join(ln.replace("b1,", "01,").replace("b2,", "02,").replace("b3,", "03,")
                               .replace("b4,", "04,") for ln in ls) + "\n")
    read_everything(tiny_dataset, {"01": "b1", "02": "b2", "03": "b3", "04": "b4"}).assert_same(clean)


@pytest.mark.parametrize("file, cut", [(f"{B}/building.yaml", "free_thresh: 0.196\n"),
                                       (f"{S}/session.yaml", "labelled: true\n")])
def test_a_yaml_file_cut_in_its_last_line_is_refused(tiny_dataset, file, cut):
    """Was: building.yaml cut to 'free_thresh: 0.19' (or '0.1') read silently as that threshold."""
    p = tiny_dataset / file
    text = p.read_text()
    assert text.endswith(cut)
    p.write_text(text[:-3])
    n = len(text.splitlines())
    assert _errors(tiny_dataset) == {("truncated", file, n)}
    assert ("truncated", file, n) in _refused(tiny_dataset)
    p.write_text(text.rstrip("\n"))  # complete, but without its newline: the same rule, the same fix
    assert _errors(tiny_dataset) == {("truncated", file, n)}


def test_an_inverted_floor_image_is_refused(tiny_dataset):
    """Was: accepted (the inverted walls are free space, so 'floor-no-free-space' did not fire): the map methods
    ran in a plan whose rooms were obstacles. Now the ground truth, on obstacles, says so."""
    from PIL import Image

    p = tiny_dataset / B / "floor_0.png"
    Image.fromarray(255 - np.asarray(Image.open(p))).save(p)
    assert _errors(tiny_dataset) == {("groundtruth-in-obstacles", f"{S}/groundtruth.csv", None)}
    assert "inverted" in str([i for i in validate(tiny_dataset) if i.is_error][0])
    p2 = tiny_dataset / B / "building.yaml"
    p2.write_text(p2.read_text().replace("  free_thresh: 0.196\n", "  free_thresh: 0.196\n  negate: 1\n"))
    assert _errors(tiny_dataset) == set()  # with negate: 1 it is the same plan


def test_a_yaml_alias_bomb_is_refused_at_once(tiny_dataset):
    """Was: a hang. Ten lines of aliases of aliases ('billion laughs') expand to 9**9 values: the reader's
    str() of the session's building never returned."""
    lines = ['a0: &a0 ["x","x","x","x","x","x","x","x","x"]'] + [
        f"a{i}: &a{i} [" + ",".join([f"*a{i - 1}"] * 9) + "]" for i in range(1, 10)]
    p = tiny_dataset / S / "session.yaml"
    p.write_text("\n".join(lines) + "\n" + p.read_text().replace("building: house", "building: *a9"))
    assert _errors(tiny_dataset) == {("yaml-size", f"{S}/session.yaml", None)}


@pytest.mark.parametrize("file, text", [(f"{S}/session.yaml", "a: " + "[" * 100000 + "\n"),
                                        (f"{B}/rooms.geojson", "[" * 100000)])
def test_thousands_of_nested_brackets_are_a_syntax_error(tiny_dataset, file, text):
    """Was: RecursionError from PyYAML or json (a traceback, not a ValueError)."""
    (tiny_dataset / file).write_text(text)
    ((rule, f, _),) = _errors(tiny_dataset)
    assert rule in ("yaml-syntax", "json-syntax") and f == file


@pytest.mark.parametrize("file, value, i", [(f"{B}/rooms.geojson", "NaN", 0), (f"{B}/rooms.geojson", "Infinity", 1),
                                            (f"{B}/navgraph.geojson", "NaN", 0),
                                            (f"{B}/navgraph.geojson", "-Infinity", 0)])
def test_geojson_coordinates_that_are_not_finite_are_refused(tiny_dataset, file, value, i):
    """Was: accepted (Python's json reads NaN and Infinity); the evaluation then failed in GEOS with a traceback
    (rooms, Infinity) or with 'Probabilities contain NaN' naming no file (routes, Infinity)."""
    import json

    p = tiny_dataset / file
    doc = json.loads(p.read_text())
    doc["features"][i]["geometry"]["coordinates"][0][0] = float(value)
    p.write_text(json.dumps(doc))
    assert _errors(tiny_dataset) == {("geojson-coordinates", file, None)}
    assert f"features[{i}]" in str(validate(tiny_dataset)[0])


def test_geojson_far_off_the_plan_or_invalid_is_refused(tiny_dataset):
    """Was: accepted; a room corner at x = 1e300 failed the evaluation with 'Maximum allowed size exceeded' (its
    1 m grid), naming no file; a zero-area or self-intersecting room was used as a room."""
    import json

    p = tiny_dataset / B / "rooms.geojson"
    clean = p.read_text()
    for change, rule in [(lambda r: r[0].__setitem__(0, 1e300), "geojson-off-floor"),
                         (lambda r: r.__setitem__(slice(None), [r[0], r[1], r[0]]), "geojson-coordinates"),
                         (lambda r: r.__setitem__(slice(1, 3), [r[2], r[1]]), "geojson-coordinates")]:
        doc = json.loads(clean)
        change(doc["features"][0]["geometry"]["coordinates"][0])
        p.write_text(json.dumps(doc))
        assert _errors(tiny_dataset) == {(rule, f"{B}/rooms.geojson", None)}, change


@pytest.mark.parametrize("file, line", [(f"{S}/groundtruth.csv", 150), (f"{S}/groundtruth.csv", 2)])
def test_one_position_far_off_the_plan_is_refused(tiny_dataset, file, line):
    """Was: one ground-truth row at x = 1e300 among 200 was accepted (less than half off the plan): the
    evaluation's RMSE and error statistics became inf (found on the simulated walk with experiment=frontend_000)."""
    p = tiny_dataset / file
    ls = p.read_text().splitlines()
    cells = ls[line - 1].split(",")
    cells[1] = "1e300"
    ls[line - 1] = ",".join(cells)
    p.write_text("\n".join(ls) + "\n")
    assert _errors(tiny_dataset) == {("position-off-floor", file, line)}
    cells[1] = "1500"  # 1.5 km east of a 10 m plan: odd, but no floor is larger than 2 km
    ls[line - 1] = ",".join(cells)
    p.write_text("\n".join(ls) + "\n")
    assert _errors(tiny_dataset) == set()


def test_an_imu_whose_time_does_not_advance_is_refused(tiny_dataset):
    """Was: 2000 IMU rows at one time were accepted: the step detector's rate was infinite (OverflowError) and the
    orientation RMSE NaN (found with experiment=frontend_000)."""
    p = tiny_dataset / S / "imu.csv"
    df = pd.read_csv(p)
    df["t"] = 19.9
    df.to_csv(p, index=False)
    assert _errors(tiny_dataset) == {("imu-rate", f"{S}/imu.csv", None)}
    assert "advance" in str(validate(tiny_dataset)[0])
