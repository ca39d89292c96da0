"""Issue 18, section 4: property tests over every importer (blenav.importers: uji_ble, feng_wifi_rtt,
danis_ble_tracks, kolakowski_ble_calib, ilc20) on small raw inputs.

Each importer gets a small raw folder in its own format: the first lines of the public recordings in
../shared/data/raw (marker ``realdata``; skipped with the reason when absent) or, for ILC 2.0, a synthetic
floor and walk (tests/importers/test_ilc20.py's writer). Each example copies it, applies one generated fault to one
raw file (truncation at any byte, a byte flipped, a line dropped, duplicated or swapped with another --
shuffled and duplicated timestamps --, a cell set to NaN / inf / text / empty / a huge number, an RSSI far
outside (-150, 0) dBm, NaN in the IMU, a file with its header only or no bytes at all, an anchor line removed
from the building) and imports it. The oracle:

* refused: an :class:`~blenav.errors.ImportError_` naming a raw file of the source (and a line when the
  fault is on one line of a line-structured file), or a :class:`~blenav.errors.DatasetError` naming a file of
  the written dataset; ``blenav-import`` prints it as one line ``blenav-import: error: ...`` with exit 1;
  never another exception (a traceback);
* accepted: the written dataset passes the validator, and **no valid row is lost silently**: an independent
  ledger per importer, counted from the (faulty) raw files with plain Python, equals the rows written plus
  the rows counted in ``ImportReport.dropped`` (e.g. uji: every RSS cell of ``rss/<zone>_rss.csv`` is an
  ``rssi.csv`` row or a counted "not detected" cell; ilc20: every TYPE_BEACON line an ``rssi.csv`` row or a
  counted out-of-range reading).

Profiles: ``blenav-ci`` (default run; ``CI_IMPORT`` examples per importer) and ``blenav-slow`` (``slow``).
"""

from __future__ import annotations

import contextlib
import io
import re
import shutil
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

import pandas as pd
import pytest
from hypothesis import event, given, settings
from hypothesis import strategies as st

from blenav.cli.importer import main as import_main
from blenav.errors import DatasetError, ImportError_
from blenav.importers import ImportReport, run_import
from fuzz_helpers import CI, SLOW
from helpers import RAW

pytestmark = pytest.mark.timeout(900)
#: an import takes 0.1..3 s here (most faults are refused early): 10 examples per importer in the default run
CI_IMPORT = settings(CI, max_examples=max(CI.max_examples // 2, 1))
SLOW_IMPORT = settings(SLOW, max_examples=max(SLOW.max_examples // 4, 1))


# --------------------------------------------------------------------------- small raw inputs


def _head(src: Path, dst: Path, n: int) -> None:
    """The first ``n`` lines of ``src`` (newline-terminated) at ``dst``."""
    dst.parent.mkdir(parents=True, exist_ok=True)
    ls = src.read_bytes().split(b"\n")
    dst.write_bytes(b"\n".join(ls[:n]) + b"\n")


def _copy(src: Path, dst: Path) -> None:
    dst.parent.mkdir(parents=True, exist_ok=True)
    if src.is_dir():
        shutil.copytree(src, dst, copy_function=shutil.copyfile)
    else:
        shutil.copyfile(src, dst)


def _need_raw(kind: str) -> Path:
    p = RAW / kind
    if not p.is_dir():
        pytest.skip(f"public recordings not found at {p} (../shared/data/raw is absent)")
    return p


def build_uji(dst: Path) -> Path:
    """dep/ and obs/ as published, the first 40 fingerprints of each zone (2 sessions)."""
    raw = _need_raw("uji_ble")
    for sub in ("dep", "obs"):
        _copy(raw / sub, dst / sub)
    for f in sorted((raw / "rss").iterdir()):
        _head(f, dst / "rss" / f.name, 40)
    return dst


def build_feng(dst: Path) -> Path:
    """The AP positions and the first 30 rows of each of the 6 splits."""
    raw = _need_raw("feng_wifi_rtt")
    for f in sorted((raw / "data").iterdir()):
        if f.suffix == ".csv":
            _head(f, dst / "data" / f.name, 31)
        else:
            _copy(f, dst / "data" / f.name)
    return dst


def build_danis(dst: Path) -> Path:
    """cnf/, occ/ as published and the first 200 packets of one track."""
    raw = _need_raw("danis_ble_tracks")
    for sub in ("cnf", "occ"):
        _copy(raw / sub, dst / sub)
    _head(raw / "trk" / "straight_04_all_sensors.mbd", dst / "trk" / "straight_04_all_sensors.mbd", 200)
    return dst


def build_kolakowski(dst: Path) -> Path:
    """anchors.csv, layout.csv and the first 300 lines of every log and table."""
    raw = _need_raw("kolakowski_ble_calib")
    for f in ("anchors.csv", "layout.csv"):
        _copy(raw / f, dst / f)
    for sub in ("tests", "calibration"):
        for f in sorted((raw / sub).iterdir()):
            _head(f, dst / sub / f.name, 300)
    return dst


def build_ilc20(dst: Path) -> Path:
    """A synthetic 40 x 20 m floor and one 6 s walk (50 Hz sensors, beacons, WiFi, 3 waypoints)."""
    from ilc20_helpers import walk_lines, write_floor, write_walk

    d = write_floor(dst)
    write_walk(d, "walkA", walk_lines())
    return dst


# --------------------------------------------------------------------------- ledgers: no row lost silently


def _rows(out: Path, stream: str, sessions: str = "*") -> int:
    """Data rows of ``sessions/<sessions>/<stream>.csv`` in the written dataset (header excluded)."""
    n = 0
    for p in sorted(out.glob(f"sessions/{sessions}/{stream}.csv")):
        with open(p, encoding="utf-8") as fh:
            n += sum(1 for _ in fh) - 1
    return n


def _dropped(report: ImportReport, *words: str) -> int:
    return sum(n for reason, n in report.dropped.items() if any(w in reason for w in words))


def _table(path: Path, header: bool) -> pd.DataFrame:
    return pd.read_csv(path, header=0 if header else None, dtype=str, keep_default_na=False)


def ledger_uji(src: Path, out: Path, report: ImportReport) -> dict:
    got = {}
    for z in ("lib", "geo"):
        rss = _table(src / "rss" / f"{z}_rss.csv", False).to_numpy(dtype=float)
        got[f"{z}: RSS cells = rssi rows + counted 'not detected'"] = (
            rss.size, _rows(out, "rssi", f"{z}_*") + _dropped(report, f"RSS cells = 100 (beacon not detected; no "
                                                                        f"row written) in {z}"))
        got[f"{z}: fingerprints = groundtruth rows"] = (len(rss), _rows(out, "groundtruth", f"{z}_*"))
    return got


def ledger_feng(src: Path, out: Path, report: ImportReport) -> dict:
    cells = rows = 0
    for f in sorted((src / "data").glob("database_*.csv")):
        d = _table(f, True)
        cells += d.filter(like="RTT(mm)").size + d.filter(like="RSS(dBm)").size
        rows += len(d)
    return {"RTT and RSS cells = rows + counted": (cells, _rows(out, "rtt") + _rows(out, "rssi") + _dropped(
                report, "RTT cells", "RSS cells", "without a position")),
            "raw rows = groundtruth rows": (rows, _rows(out, "groundtruth"))}


def ledger_danis(src: Path, out: Path, report: ImportReport) -> dict:
    n = sum(len(_table(f, False)) for f in sorted((src / "trk").glob("*_all_sensors.mbd")))
    return {"packets = rssi rows + counted": (n, _rows(out, "rssi") + _dropped(
        report, "other than the beacon", "receiver not in", "invalid RSSI"))}


def ledger_kolakowski(src: Path, out: Path, report: ImportReport) -> dict:
    packets = 0
    for f in ("test_robot_ble.txt", "test_walk_ble.txt"):
        for ln in (src / "tests" / f).read_text(encoding="utf-8").splitlines():
            packets += int(ln.split("\t")[5])  # b: BLE packets of the line (the log's 6th field)
    got = {"logged BLE packets = rssi rows of the two tests + counted": (
        packets, _rows(out, "rssi", "test_*") + _dropped(report, "BLE packets"))}
    cells = 0
    for f in ("calibration_df.csv", "calib_df.csv"):
        cells += _table(src / "calibration" / f, True).filter(like="rssi_").size
    got["calibration rssi cells = rssi rows + counted"] = (
        cells, _rows(out, "rssi", "calib*") + _dropped(report, "rssi cells"))
    return got


def ledger_ilc20(src: Path, out: Path, report: ImportReport) -> dict:
    count: dict[str, int] = {}
    for p in sorted(src.rglob("path_data_files/*.txt")):
        for ln in p.read_text(encoding="utf-8").splitlines():
            f = ln.split("\t")
            if len(f) > 1 and not ln.startswith("#"):
                count[f[1]] = count.get(f[1], 0) + 1
    got = {"TYPE_BEACON lines = rssi rows + counted": (
               count.get("TYPE_BEACON", 0), _rows(out, "rssi") + _dropped(report, "iBeacon readings")),
           "TYPE_WIFI lines = wifi rows + counted": (
               count.get("TYPE_WIFI", 0), _rows(out, "wifi") + _dropped(report, "WiFi readings outside")),
           "TYPE_MAGNETIC_FIELD lines = mag rows": (count.get("TYPE_MAGNETIC_FIELD", 0), _rows(out, "mag")),
           "TYPE_ROTATION_VECTOR lines = orientation rows": (count.get("TYPE_ROTATION_VECTOR", 0),
                                                              _rows(out, "orientation"))}
    if count.get("TYPE_GYROSCOPE", 0):
        got["TYPE_ACCELEROMETER lines = imu rows + counted"] = (
            count.get("TYPE_ACCELEROMETER", 0), _rows(out, "imu") + _dropped(report, "accelerometer samples"))
    wp = count.get("TYPE_WAYPOINT", 0)
    got["TYPE_WAYPOINT lines = groundtruth rows (two or more)"] = (wp if wp >= 2 else 0, _rows(out, "groundtruth"))
    return got


# --------------------------------------------------------------------------- what each importer reads


@dataclass(frozen=True)
class Target:
    """A raw file faults apply to: ``header`` lines before the data, field separator, the RSSI field of a data line
    (``rssi(fields) -> index or None``), the IMU fields (``imu(fields) -> indices``), and the files whose line i
    describes the same record (``paired``: a dropped or swapped line applies to all of them, or to this one)."""

    path: str
    header: int
    sep: str
    rssi: Callable = lambda f: None
    imu: Callable = lambda f: ()
    paired: tuple = ()
    anchors: bool = False  # a line of this file is an anchor of the building


@dataclass(frozen=True)
class Importer:
    kind: str
    build: Callable
    targets: tuple
    ledger: Callable


def _uji_targets():
    out = []
    for z in ("lib", "geo"):
        group = tuple(f"rss/{z}_{k}.csv" for k in ("rss", "tms", "crd", "ids"))
        out += [Target(group[0], 0, ",", rssi=lambda f: 3 % len(f), paired=group)]
        out += [Target(g, 0, ",", paired=group) for g in group[1:]]
        out += [Target(f"dep/{z}.csv", 1, ",", anchors=True), Target(f"obs/{z}.csv", 1, ",")]
    return tuple(out)


def _ilc_rssi(f):
    return {"TYPE_BEACON": 6, "TYPE_WIFI": 4}.get(f[1]) if len(f) > 1 else None


def _ilc_imu(f):
    return (2, 3, 4) if len(f) > 4 and f[1] in ("TYPE_ACCELEROMETER", "TYPE_GYROSCOPE") else ()


IMPORTERS = {
    "uji_ble": Importer("uji_ble", build_uji, _uji_targets(), ledger_uji),
    "feng_wifi_rtt": Importer("feng_wifi_rtt", build_feng, tuple(
        Target(f"data/database_{e}_{s}.csv", 1, ",", rssi=lambda f: 9 % len(f))
        for e in ("lecture_theatre", "office", "corridor") for s in ("train", "test")) + (
        Target("data/lecture theatre+office+corridor_AP_position.txt", 0, ",", anchors=True),), ledger_feng),
    "danis_ble_tracks": Importer("danis_ble_tracks", build_danis, (
        Target("trk/straight_04_all_sensors.mbd", 0, ",", rssi=lambda f: 3 % len(f)),
        Target("cnf/tetam.dev", 0, ",", anchors=True)), ledger_danis),
    "kolakowski_ble_calib": Importer("kolakowski_ble_calib", build_kolakowski, (
        Target("tests/test_robot_ble.txt", 0, "\t", rssi=lambda f: 10 if len(f) > 10 else None),
        Target("tests/test_walk_ble.txt", 0, "\t", rssi=lambda f: 10 if len(f) > 10 else None),
        Target("tests/test_robot_df.csv", 1, ","),
        Target("calibration/calibration_df.csv", 1, ",", rssi=lambda f: 5 % len(f)),
        Target("calibration/calib_df.csv", 1, ",", rssi=lambda f: 4 % len(f)),
        Target("anchors.csv", 1, ",", anchors=True), Target("layout.csv", 1, ",")), ledger_kolakowski),
    "ilc20": Importer("ilc20", build_ilc20, (
        Target("mall/F1/path_data_files/walkA.txt", 3, "\t", rssi=_ilc_rssi, imu=_ilc_imu),
        Target("mall/F1/geojson_map.json", 0, ","), Target("mall/F1/floor_info.json", 0, ",")), ledger_ilc20),
}


# --------------------------------------------------------------------------- faults


def _lines(p: Path) -> list[bytes]:
    ls = p.read_bytes().split(b"\n")
    return ls[:-1] if ls and ls[-1] == b"" else ls


def _write(p: Path, ls: list[bytes]) -> None:
    p.write_bytes(b"".join(x + b"\n" for x in ls))


def _data_line(p: Path, t: Target, k: int) -> int | None:
    """0-based index of the ``k``-th data line (mod the number of data lines), None when there is none."""
    n = len(_lines(p)) - t.header
    return None if n <= 0 else t.header + k % n


@dataclass(frozen=True)
class Fault:
    """``kind`` applied to ``target`` with ``args``; ``apply(root) -> 1-based line changed (or None)``."""

    kind: str
    target: Target
    args: tuple = ()

    def __repr__(self) -> str:
        return f"{self.kind}({self.target.path!r}, {self.args!r})"

    def apply(self, root: Path) -> int | None:
        t, p = self.target, root / self.target.path
        return FAULTS[self.kind](root, t, p, *self.args)


def _f_truncate(root, t, p, pos):
    data = p.read_bytes()
    p.write_bytes(data[: pos % max(len(data), 1)])
    return None


def _f_flip(root, t, p, pos, byte):
    data = bytearray(p.read_bytes())
    if data:
        data[pos % len(data)] = byte
    p.write_bytes(bytes(data))
    return None


def _edit_lines(root, t, p, k, together, edit) -> None:
    """``edit(lines, i)`` on the ``k``-th data line ``i`` of ``p``, or of every file paired with it (``together``)."""
    i = _data_line(p, t, k)
    if i is None:
        return None
    for q in ([root / x for x in t.paired] if together and t.paired else [p]):
        ls = _lines(q)
        edit(ls, min(i, len(ls) - 1))
        _write(q, ls)
    return None


def _f_drop_line(root, t, p, k, together):
    return _edit_lines(root, t, p, k, together, lambda ls, i: ls.pop(i))


def _f_duplicate_line(root, t, p, k, together):
    return _edit_lines(root, t, p, k, together, lambda ls, i: ls.insert(i, ls[i]))


def _f_swap_lines(root, t, p, k, gap, together):
    """Line i and line i + gap exchanged (timestamps out of order)."""
    def swap(ls, i):
        j = min(i + gap, len(ls) - 1)
        ls[i], ls[j] = ls[j], ls[i]
    return _edit_lines(root, t, p, k, together, swap)


def _set_field(p: Path, t: Target, k: int, pick, value: bytes) -> int | None:
    i = _data_line(p, t, k)
    if i is None:
        return None
    ls = _lines(p)
    f = ls[i].split(t.sep.encode())
    c = pick([x.decode("utf-8", "replace") for x in f])
    if not isinstance(c, int) or c >= len(f):
        return None
    f[c] = value
    ls[i] = t.sep.encode().join(f)
    _write(p, ls)
    return i + 1


def _f_cell(root, t, p, k, col, token):
    return _set_field(p, t, k, lambda f: col % len(f), token)


def _f_rssi(root, t, p, k, value):
    return _set_field(p, t, k, t.rssi, value)


def _f_imu_nan(root, t, p, k, which):
    """NaN in an IMU field: the first line from the ``k``-th on that has IMU fields."""
    ls = _lines(p)
    n = len(ls)
    for d in range(n):
        i = t.header + (k + d) % max(n - t.header, 1)
        f = ls[i].decode("utf-8", "replace").split(t.sep)
        idx = t.imu(f)
        if idx:
            return _set_field(p, t, i - t.header, lambda f: idx[which % len(idx)], b"NaN")
    return None


def _f_header_only(root, t, p, zero_bytes):
    """An empty file: its header lines only, or no bytes at all (an empty session, a file never written)."""
    if zero_bytes:
        p.write_bytes(b"")
    else:
        _write(p, _lines(p)[: t.header])
    return None


def _f_crlf(root, t, p):
    p.write_bytes(p.read_bytes().replace(b"\n", b"\r\n"))
    return None


FAULTS = {"truncate": _f_truncate, "flip": _f_flip, "drop_line": _f_drop_line, "duplicate_line": _f_duplicate_line,
          "swap_lines": _f_swap_lines, "cell": _f_cell, "rssi": _f_rssi, "imu_nan": _f_imu_nan,
          "header_only": _f_header_only, "crlf": _f_crlf}
#: faults on one line of a line-structured file: a refusal must name the line
ON_A_LINE = {"cell", "rssi", "imu_nan"}
TOKENS = [b"nan", b"NaN", b"inf", b"-inf", b"", b"abc", b"1e308", b"-1e308", b"1,5", b"\xe9"]
RSSI = [b"0", b"1", b"42", b"127", b"-150", b"-150.5", b"-200", b"-1e9", b"1e9", b"-999", b"nan"]

_pos = st.integers(0, 10**6)


def faults(imp: Importer):
    targets = st.sampled_from(imp.targets)
    lined = st.sampled_from([t for t in imp.targets if not t.path.endswith(".json")])
    rssi_t = [t for t in imp.targets if t.rssi(["x"] * 16) is not None]
    imu_t = [t for t in imp.targets if t.imu(["0", "TYPE_ACCELEROMETER", "0", "0", "0", "0"])]
    anchors = [t for t in imp.targets if t.anchors]
    one = [
        st.builds(lambda t, p: Fault("truncate", t, (p,)), targets, _pos),
        st.builds(lambda t, p, b: Fault("flip", t, (p, b)), targets, _pos, st.integers(0, 255)),
        st.builds(lambda t, k, g: Fault("drop_line", t, (k, g)), lined, _pos, st.booleans()),
        st.builds(lambda t, k, g: Fault("duplicate_line", t, (k, g)), lined, _pos, st.booleans()),
        st.builds(lambda t, k, d, g: Fault("swap_lines", t, (k, d, g)), lined, _pos, st.integers(1, 5),
                  st.booleans()),
        st.builds(lambda t, k, c, v: Fault("cell", t, (k, c, v)), lined, _pos, st.integers(0, 20),
                  st.sampled_from(TOKENS)),
        st.builds(lambda t, z: Fault("header_only", t, (z,)), targets, st.booleans()),
        st.builds(lambda t: Fault("crlf", t), lined),
    ]
    if rssi_t:
        one.append(st.builds(lambda t, k, v: Fault("rssi", t, (k, v)), st.sampled_from(rssi_t), _pos,
                             st.sampled_from(RSSI)))
    if imu_t:
        one.append(st.builds(lambda t, k, w: Fault("imu_nan", t, (k, w)), st.sampled_from(imu_t), _pos,
                             st.integers(0, 2)))
    if anchors:  # an anchor missing from the building
        one.append(st.builds(lambda t, k: Fault("drop_line", t, (k, False)), st.sampled_from(anchors), _pos))
    return st.one_of(*one)


# --------------------------------------------------------------------------- the oracle


def cli_one_line(kind: str, src: Path, out: Path) -> str:
    """``blenav-import KIND SRC OUT`` in-process on a source the API refused: exit 1 and one line on stderr."""
    err = io.StringIO()
    with contextlib.redirect_stderr(err), contextlib.redirect_stdout(io.StringIO()):
        try:
            code = import_main([kind, str(src), str(out)])
        except SystemExit as e:
            code = e.code
    lines = [ln for ln in err.getvalue().splitlines() if ln.strip()]
    assert code == 1, err.getvalue()
    assert "Traceback" not in err.getvalue()
    assert len(lines) == 1 and lines[0].startswith("blenav-import: error: "), err.getvalue()
    return lines[0]


def check_import(imp: Importer, template: Path, work: Path, fault: Fault) -> None:
    src = work / "src"
    shutil.rmtree(work, ignore_errors=True)
    shutil.copytree(template, src)
    line = fault.apply(src)
    out = work / "out"
    try:
        report = run_import(imp.kind, src, out)
    except ImportError_ as exc:
        msg = str(exc)
        assert str(src) in exc.path, f"the error names no raw file of the source: {msg}"
        if fault.kind in ON_A_LINE and line is not None and Path(exc.path) == src / fault.target.path:
            assert exc.line is not None, f"a fault on line {line} but the error names no line: {msg}"
        assert "\n" not in msg, msg
        cli_one_line(imp.kind, src, work / "out_cli")
        event(f"{fault.kind}: refused (line {'given' if exc.line else 'none'})")
        return
    except DatasetError as exc:
        assert str(out) in str(exc), f"the validator's error names no written file: {exc}"
        cli_one_line(imp.kind, src, work / "out_cli")
        event(f"{fault.kind}: refused by the validator")
        return
    event(f"{fault.kind}: accepted")
    bad = {k: v for k, v in imp.ledger(src, out, report).items() if v[0] != v[1]}
    assert not bad, f"rows lost silently (raw, written + counted): {bad}\n{report}"


@pytest.fixture(scope="module")
def templates(tmp_path_factory):
    cache: dict = {}

    def get(kind: str) -> Path:
        if kind not in cache:
            root = tmp_path_factory.mktemp(f"raw_{kind}") / "src"
            IMPORTERS[kind].build(root)
            cache[kind] = root
        return cache[kind]
    return get


def _marks(kind):
    return [pytest.mark.realdata] if kind != "ilc20" else []


KINDS = [pytest.param(k, marks=_marks(k), id=k) for k in IMPORTERS]


@pytest.mark.parametrize("kind", KINDS)
def test_clean_small_inputs_import_and_every_row_is_accounted(kind, templates, tmp_path):
    src = templates(kind)
    out = tmp_path / "out"
    report = run_import(kind, src, out)
    bad = {k: v for k, v in IMPORTERS[kind].ledger(src, out, report).items() if v[0] != v[1]}
    assert not bad, bad


def _property(kind, profile):
    imp = IMPORTERS[kind]

    @profile
    @given(fault=faults(imp))
    def run(templates, tmp_path_factory, fault):
        work = tmp_path_factory.getbasetemp() / f"work_{kind}"
        check_import(imp, templates(kind), work, fault)
    return run


@pytest.mark.parametrize("kind", KINDS)
def test_faulty_raw_input_is_refused_naming_file_and_line_or_every_row_is_accounted(kind, templates,
                                                                                     tmp_path_factory):
    _property(kind, CI_IMPORT)(templates, tmp_path_factory)


@pytest.mark.slow
@pytest.mark.parametrize("kind", KINDS)
def test_faulty_raw_input_slow(kind, templates, tmp_path_factory):
    _property(kind, SLOW_IMPORT)(templates, tmp_path_factory)


# --------------------------------------------------------------------------- regressions: what these tests found


def _refusal(kind: str, templates, tmp_path, path: str, line: int, col: int, value: bytes) -> ImportError_:
    """Set field ``col`` of 1-based ``line`` of raw file ``path`` to ``value``; the import must refuse it naming that
    file and line, and blenav-import must say so in one line."""
    imp = IMPORTERS[kind]
    src = tmp_path / "src"
    shutil.copytree(templates(kind), src)
    (t,) = [x for x in imp.targets if x.path == path]
    assert Fault("cell", t, (line - 1 - t.header, col, value)).apply(src) == line
    with pytest.raises(ImportError_) as e:
        run_import(kind, src, tmp_path / "out")
    assert (e.value.path, e.value.line) == (str(src / path), line), str(e.value)
    assert f"{path}:{line}" in cli_one_line(kind, src, tmp_path / "out_cli")
    return e.value


@pytest.mark.realdata
@pytest.mark.parametrize("kind, path, line, col", [
    ("uji_ble", "rss/lib_crd.csv", 6, 0), ("uji_ble", "dep/geo.csv", 3, 2), ("uji_ble", "obs/lib.csv", 4, 1),
    ("feng_wifi_rtt", "data/database_office_test.csv", 4, 1),
    ("feng_wifi_rtt", "data/lecture theatre+office+corridor_AP_position.txt", 2, 1),
    ("kolakowski_ble_calib", "layout.csv", 3, 0)])
@pytest.mark.parametrize("value", [b"1e308", b"1e9", b"-5e4"])
def test_a_position_far_off_is_refused_at_its_line(kind, path, line, col, value, templates, tmp_path):
    """Was: OverflowError (1e308) or MemoryError (1e9: a 1.25 TiB grid) as tracebacks from the occupancy grid in
    uji_ble and feng_wifi_rtt; -5e4 rasterised a 50 km plan for 28 s before the validator refused the written
    dataset; kolakowski's layout said 'not a valid polygon' naming no line."""
    assert "further than any floor is large (2000 m)" in str(_refusal(kind, templates, tmp_path, path, line, col,
                                                                      value))


@pytest.mark.realdata
@pytest.mark.parametrize("kind, path, line, col, value", [
    ("danis_ble_tracks", "trk/straight_04_all_sensors.mbd", 11, 0, b"-1e308"),
    ("danis_ble_tracks", "trk/straight_04_all_sensors.mbd", 1, 0, b"2e9"),
    ("kolakowski_ble_calib", "tests/test_walk_ble.txt", 7, 0, b"1000000000000000000000"),
    ("kolakowski_ble_calib", "calibration/calib_df.csv", 5, 1, b"1e30")])
def test_a_time_far_off_is_refused_at_its_raw_line(kind, path, line, col, value, templates, tmp_path):
    """Was: written (every other time became inf or 1e308 s after the first), then refused by the validator naming
    rows of the written rssi.csv, not the raw line, in lines the CLI printed one per error."""
    assert "further than any session lasts" in str(_refusal(kind, templates, tmp_path, path, line, col, value))


def test_the_validators_refusal_is_one_cli_line(templates, tmp_path):
    """Was: blenav-import printed a DatasetError of several rows on several lines (one line per error)."""
    src = tmp_path / "src"
    shutil.copytree(templates("ilc20"), src)
    p = src / "mall/F1/path_data_files/walkA.txt"
    p.write_text(re.sub(r"TYPE_WAYPOINT\t[^\t]+", "TYPE_WAYPOINT\t5e4", p.read_text()))  # every waypoint 50 km east
    with pytest.raises(DatasetError) as e:
        run_import("ilc20", src, tmp_path / "out")
    assert "position-off-floor" in str(e.value) and "\n" in str(e.value)
    assert "position-off-floor" in cli_one_line("ilc20", src, tmp_path / "out_cli")
