"""What the fuzz tests (issue 19, section 2) share: a small valid dataset with every stream, the faults, and
the oracles.

A fault is a :class:`Fault`: a named, printable change to a copy of the template dataset whose ``apply(root)``
returns what the readers must do with the result:

* ``SAME``: accept it, and everything read (every stream, anchor, floor, warning) is identical to the clean
  dataset's (``rename`` maps new ids back to the template's: anchors, sessions, buildings);
* ``REFUSED``: refuse it with a :class:`blenav.errors.DatasetError` naming a file of the dataset (and, when
  ``rules`` is given, with one of these rules);
* ``DROPPED``: accept it and count exactly ``dropped`` rows in :attr:`Session.dropped`, else identical; or
  refuse it (an id the reader cannot use);
* ``ANY``: refuse it cleanly, or accept data that keeps every promise of the readers (:func:`check_promises`).

Profiles (hypothesis settings; every example is derandomized, so a failure reproduces):
``blenav-ci`` (the default ``make test`` run, a few examples per test) and ``blenav-slow`` (the ``slow``
tests, ``make test-slow``). ``BLENAV_FUZZ_EXAMPLES=N`` overrides the number of examples of both.
"""

from __future__ import annotations

import csv
import io
import math
import os
import shutil
import unicodedata
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pandas as pd
import yaml
from hypothesis import HealthCheck, Phase, settings
from hypothesis import strategies as st

from blenav.data import Dataset, validate
from blenav.data.schema import (
    ANCHOR_COLUMNS,
    ANCHOR_KINDS,
    IMU_MAX_MEAN_DT_S,
    IMU_RATE_MIN_ROWS,
    STREAMS,
    T_MAX_S,
    plausible,
)
from blenav.data.writer import write_csv
from helpers import make_tiny_dataset

_N = os.environ.get("BLENAV_FUZZ_EXAMPLES")
_COMMON = dict(derandomize=True, database=None, deadline=None, print_blob=True,
               phases=[Phase.explicit, Phase.reuse, Phase.generate, Phase.shrink],  # no 'explain': minutes here
               suppress_health_check=[HealthCheck.too_slow, HealthCheck.function_scoped_fixture,
                                      HealthCheck.data_too_large])
settings.register_profile("blenav-ci", max_examples=int(_N or 20), **_COMMON)
settings.register_profile("blenav-slow", max_examples=int(_N or 400), **_COMMON)
CI = settings.get_profile("blenav-ci")
SLOW = settings.get_profile("blenav-slow")

S = "sessions/walk0"
B = "buildings/house"
SAME, REFUSED, DROPPED, ANY = "same", "refused", "dropped", "any"

CSV_FILES = [f"{B}/anchors.csv"] + [f"{S}/{n}.csv" for n in
                                     ("imu", "mag", "rssi", "rtt", "visual", "odometry", "fixes", "groundtruth")]
YAML_FILES = ["dataset.yaml", f"{B}/building.yaml", f"{S}/session.yaml"]
JSON_FILES = [f"{B}/rooms.geojson", f"{B}/navgraph.geojson"]
TEXT_FILES = CSV_FILES + YAML_FILES + JSON_FILES
ALL_FILES = TEXT_FILES + [f"{B}/floor_0.png"]
STREAM_OF = {f"{S}/{n}.csv": n for n in STREAMS}
#: Free-text columns: spaces in them are content, not padding.
FREE_TEXT = {"channel_model", "source"}


# --------------------------------------------------------------------------- the template


def make_fuzz_dataset(root: Path) -> Path:
    """tests/helpers.py's tiny dataset plus every optional stream (mag, rtt, visual, odometry, fixes), each
    spanning the 20 s session; valid (``validate(root) == []``)."""
    root = make_tiny_dataset(root)
    s = root / S
    rng = np.random.default_rng(7)
    t = np.arange(0.0, 20.0, 0.5)
    n = len(t)
    write_csv(s / "mag.csv", pd.DataFrame({"t": t, "mx": 20 + rng.normal(0, 1, n), "my": -3 + rng.normal(0, 1, n),
                                           "mz": -40 + rng.normal(0, 1, n)}))
    std = np.round(rng.uniform(0.2, 0.6, n), 2)
    std[::5] = np.nan  # the nullable column: some empty cells
    write_csv(s / "rtt.csv", pd.DataFrame({"t": t, "anchor_id": "ap1", "range_m": np.round(rng.uniform(1, 5, n), 3),
                                           "range_std_m": std}))
    write_csv(s / "visual.csv", pd.DataFrame({"t": t[::4], "x": 2.5 + t[::4] / 4, "y": 4.0, "z": 1.2,
                                              "yaw": 0.1}))
    write_csv(s / "odometry.csv", pd.DataFrame({"t": t, "x": t / 4, "y": 0.01 * t}))
    fstd = np.full(n, 1.5)
    fstd[3] = np.nan
    write_csv(s / "fixes.csv", pd.DataFrame({"t": t, "x": 2.5 + t / 4, "y": 4.1, "std": fstd,
                                             "source": np.where(np.arange(n) % 2, "pfps", "other")}))
    return root


def make_sim_fuzz_dataset(root: Path, seed: int = 3, duration_s: float = 15.0) -> Path:
    """The simulator's ``small`` preset (one 15 s pedestrian walk: IMU with a moving gyroscope, magnetometer, BLE,
    RTT, odometry, ground truth with orientation), laid out like :func:`make_fuzz_dataset` (building ``house``,
    session ``walk0``, every stream with rows) so that the same faults apply."""
    from helpers import simulate_small

    root = simulate_small(Path(root), seed, duration_s, 1)
    (root / "buildings" / "small").rename(root / B)
    (sid,) = [d.name for d in (root / "sessions").iterdir()]
    (root / "sessions" / sid).rename(root / S)
    _yaml_edit(root / S / "session.yaml", lambda d: d.update(building="house"))
    t = np.arange(0.0, duration_s, 0.5)
    gt = pd.read_csv(root / S / "groundtruth.csv")
    x, y = np.interp(t, gt["t"], gt["x"]), np.interp(t, gt["t"], gt["y"])
    write_csv(root / S / "visual.csv", pd.DataFrame({"t": t, "x": x, "y": y, "z": 1.2, "yaw": 0.0}))
    write_csv(root / S / "fixes.csv", pd.DataFrame({"t": t, "x": x, "y": y, "std": 1.5, "source": "pfps"}))
    return root


def fresh_copy(template: Path, base: Path, name: str = "d") -> Path:
    """A writable copy of ``template`` at ``base/name`` (replacing what was there)."""
    dst = Path(base) / name
    shutil.rmtree(dst, ignore_errors=True)
    shutil.copytree(template, dst)
    return dst


# --------------------------------------------------------------------------- reading everything


class Snapshot:
    """Everything the readers give for a dataset, in a form that compares exactly."""

    def __init__(self, buildings: dict, sessions: dict, dropped: dict, warnings: list):
        self.buildings, self.sessions, self.dropped, self.warnings = buildings, sessions, dropped, warnings

    def __repr__(self) -> str:
        return f"Snapshot({sorted(self.buildings)}, {sorted(self.sessions)})"

    def assert_same(self, other: "Snapshot") -> None:
        assert sorted(self.buildings) == sorted(other.buildings)
        for b, mine in self.buildings.items():
            theirs = other.buildings[b]
            assert mine["floors"] == theirs["floors"], b
            pd.testing.assert_frame_equal(mine["anchors"], theirs["anchors"], check_exact=True)
            assert mine["regions"] == theirs["regions"], b
        assert sorted(self.sessions) == sorted(other.sessions)
        for sid, mine in self.sessions.items():
            theirs = other.sessions[sid]
            assert mine["meta"] == theirs["meta"], sid
            assert sorted(mine["streams"]) == sorted(theirs["streams"])
            for name, df in mine["streams"].items():
                pd.testing.assert_frame_equal(df, theirs["streams"][name], check_exact=True, obj=f"{sid}/{name}")
        assert self.dropped == other.dropped
        assert self.warnings == other.warnings


def _norm_id(x, rename: dict) -> str:
    return rename.get(x, x)


def read_everything(root: Path, rename: dict | None = None) -> Snapshot:
    """Open the dataset and read every building and every stream of every session (the readers' full path);
    raises what the readers raise. ``rename``: new id -> template id, applied to anchors, sessions, buildings."""
    rename = rename or {}
    ds = Dataset.open(root)
    buildings = {}
    for bid in ds.building_ids:
        b = ds.building(bid)
        floors = {str(k): (f.resolution, tuple(f.origin), f.z, f.occupied_thresh, f.free_thresh, f.negate,
                           f.occupancy.tobytes(), f.shape) for k, f in b.floors.items()}
        a = b.anchors.copy()
        a["anchor_id"] = a["anchor_id"].map(lambda x: _norm_id(x, rename))
        a = a[list(ANCHOR_COLUMNS)].sort_values("anchor_id", kind="stable").reset_index(drop=True)
        regions = sorted((r.id, str(r.floor), r.geometry.wkb) for r in b.rooms + b.navgraph)
        buildings[_norm_id(bid, rename)] = {"floors": floors, "anchors": a, "regions": regions}
    sessions, dropped = {}, {}
    for sid in ds.session_ids:
        s = ds.session(sid).load_all()
        streams = {}
        for name, spec in STREAMS.items():
            df = s.stream(name)[list(spec.columns)].copy()
            if "anchor_id" in df:
                df["anchor_id"] = df["anchor_id"].map(lambda x: _norm_id(x, rename))
            streams[name] = df.reset_index(drop=True)
        meta = dict(s.meta)
        meta["building"] = _norm_id(str(meta.get("building")), rename)
        meta["floor"] = str(meta.get("floor"))
        sessions[_norm_id(sid, rename)] = {"meta": meta, "streams": streams, "session": s}
        if s.dropped:
            dropped[_norm_id(sid, rename)] = s.dropped
    warnings = sorted((i.rule, _rel(root, i.path, rename)) for i in validate(root) if not i.is_error)
    return Snapshot(buildings, sessions, dropped, warnings)


def _rel(root: Path, path: str, rename: dict | None = None) -> str:
    try:
        parts = Path(path).relative_to(root).parts
    except ValueError:
        return path
    return "/".join(_norm_id(p, rename or {}) for p in parts)


# --------------------------------------------------------------------------- what the readers promise


def check_promises(snap: Snapshot) -> None:
    """What every accepted dataset satisfies (docs/dataset-format.md, 'Rules a reader enforces' and
    'Plausible ranges'): finite required values, times in range and non-decreasing, known anchors, unit
    quaternions, unique anchors on declared floors, floors with free space."""
    for bid, b in snap.buildings.items():
        a = b["anchors"]
        assert a["anchor_id"].is_unique and (a["anchor_id"].str.strip() != "").all()
        assert a["kind"].isin(ANCHOR_KINDS).all()
        assert np.isfinite(a[["x", "y", "z"]].to_numpy(float)).all()
        tx = a["tx_power_dbm"].to_numpy(float)
        assert not np.isinf(tx).any()
        assert set(a["floor"].astype(str)) <= set(b["floors"])
        for fid, (res, origin, z, occ_t, free_t, _neg, occ, shape) in b["floors"].items():
            assert math.isfinite(res) and res > 0 and all(math.isfinite(v) for v in origin) and math.isfinite(z)
            assert (np.frombuffer(occ, dtype=np.int8) == 0).any(), f"floor {fid} of {bid} has no free space"
    for sid, s in snap.sessions.items():
        bld = snap.buildings[s["meta"]["building"]]
        ids = set(bld["anchors"]["anchor_id"])
        for name, df in s["streams"].items():
            spec = STREAMS[name]
            for c in spec.columns:
                if c in spec.string:
                    if c in spec.required:
                        assert df[c].map(lambda v: isinstance(v, str) and v.strip() != "").all(), (sid, name, c)
                    continue
                v = df[c].to_numpy(float)
                if c in spec.required:
                    assert np.isfinite(v).all(), (sid, name, c)
                else:
                    assert not np.isinf(v).any(), (sid, name, c)
                p = plausible(name, c)
                if p is not None:
                    assert not p.outside(v).any(), (sid, name, c, v[p.outside(v)][:3])
            if len(df):
                t = df["t"].to_numpy(float)
                assert (np.diff(t) >= 0).all() and t.min() >= 0 and t.max() <= T_MAX_S, (sid, name)
            if name in ("rssi", "rtt"):
                assert set(df["anchor_id"]) <= ids, (sid, name)
            if name == "imu" and len(df) >= IMU_RATE_MIN_ROWS:
                assert (df["t"].iloc[-1] - df["t"].iloc[0]) / (len(df) - 1) <= IMU_MAX_MEAN_DT_S
            if name == "groundtruth" and len(df):
                q = df[["qw", "qx", "qy", "qz"]].to_numpy(float)
                if not np.isnan(q).all():
                    assert np.isfinite(q).all() and np.allclose(np.linalg.norm(q, axis=1), 1.0), sid
        if s["meta"].get("labelled") is True:
            assert len(s["streams"]["groundtruth"]) > 0, sid


def names_a_file(root: Path, message: str) -> bool:
    """Whether an error message names a file or folder of the dataset at ``root``."""
    return str(root) in message


# --------------------------------------------------------------------------- faults


@dataclass(frozen=True)
class Outcome:
    """What a fault requires (see the module docstring)."""

    expect: str
    rules: frozenset = frozenset()  # REFUSED: one of these rules (empty: any rule)
    dropped: int = 0  # DROPPED: rows dropped in total
    rename: dict = field(default_factory=dict)  # SAME: new id -> template id


@dataclass(frozen=True)
class Fault:
    """A change to a dataset copy; ``fn(root, *args) -> Outcome``. Printed by hypothesis as its name and arguments."""

    name: str
    fn: object
    args: tuple = ()

    def apply(self, root: Path) -> Outcome:
        return self.fn(Path(root), *self.args)

    def __repr__(self) -> str:
        return f"{self.name}{self.args!r}"


def _lines(p: Path) -> list[str]:
    return p.read_text(encoding="utf-8").splitlines()


def _write_lines(p: Path, ls: list[str]) -> None:
    p.write_text("\n".join(ls) + "\n", encoding="utf-8")


def _rows(p: Path) -> tuple[list[str], list[list[str]]]:
    rows = list(csv.reader(io.StringIO(p.read_text(encoding="utf-8"))))
    return rows[0], rows[1:]


def _write_rows(p: Path, header: list[str], rows: list[list[str]], **kw) -> None:
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n", **kw)
    w.writerow(header)
    w.writerows(rows)
    p.write_text(buf.getvalue(), encoding="utf-8")


def _yaml_edit(p: Path, fn) -> None:
    doc = yaml.safe_load(p.read_text(encoding="utf-8"))
    fn(doc)
    p.write_text(yaml.safe_dump(doc, sort_keys=False, allow_unicode=True), encoding="utf-8")


# ---- faults that change nothing a reader returns


def f_bom(root, f):
    p = root / f
    p.write_bytes(b"\xef\xbb\xbf" + p.read_bytes())
    return Outcome(SAME)


def f_line_ends(root, f, end):
    p = root / f
    p.write_bytes(p.read_bytes().replace(b"\n", end.encode()))
    return Outcome(SAME)


def f_pad_cells(root, f, seed):
    """Spaces around numbers and ids (not free text: there they are content)."""
    p = root / f
    header, rows = _rows(p)
    rng = np.random.default_rng(seed)
    pad = lambda v: " " * int(rng.integers(0, 3)) + v + " " * int(rng.integers(0, 3))  # noqa: E731
    keep = [c in FREE_TEXT for c in header]
    rows = [[v if k else pad(v) for v, k in zip(r, keep)] for r in rows]
    header = [h if k else pad(h) for h, k in zip(header, keep)]
    _write_rows(p, header, rows)
    return Outcome(SAME)


def f_reorder_columns(root, f, seed):
    p = root / f
    header, rows = _rows(p)
    perm = np.random.default_rng(seed).permutation(len(header))
    _write_rows(p, [header[i] for i in perm], [[r[i] for i in perm] for r in rows])
    return Outcome(SAME)


def f_extra_column(root, f, name, seed):
    p = root / f
    header, rows = _rows(p)
    if name in header:
        name = name + "_x"
    rng = np.random.default_rng(seed)
    pos = int(rng.integers(0, len(header) + 1))
    vals = [str(v) for v in rng.choice(["1", "2.5", "a", "", "x y", "NA"], size=len(rows))]
    _write_rows(p, header[:pos] + [name] + header[pos:], [r[:pos] + [v] + r[pos:] for r, v in zip(rows, vals)])
    return Outcome(SAME)


def f_shuffle_anchors(root, seed):
    p = root / B / "anchors.csv"
    header, rows = _rows(p)
    perm = np.random.default_rng(seed).permutation(len(rows))
    _write_rows(p, header, [rows[i] for i in perm])
    return Outcome(SAME)


def f_quote(root, f):
    p = root / f
    header, rows = _rows(p)
    _write_rows(p, header, rows, quoting=csv.QUOTE_ALL)
    return Outcome(SAME)


def f_zeros(root, f, k):
    """'1.5' -> '1.5000' in every number with a decimal point."""
    p = root / f
    header, rows = _rows(p)
    def z(v):
        try:
            float(v)
        except ValueError:
            return v
        return v + "0" * k if "." in v and "e" not in v.lower() else v
    _write_rows(p, header, [[z(v) for v in r] for r in rows])
    return Outcome(SAME)


def f_extra_files(root, where):
    d = root / where
    (d / "README.txt").write_text("notes, not data\n")
    (d / ".DS_Store").write_bytes(b"\x00\x01junk")
    (d / "notes.csv").write_text("a,b\n1,2\n")
    return Outcome(SAME)


def f_floor_spelling(root, spelling):
    """The session's floor written as a string, or anchors' floor as a float (0.0)."""
    if spelling == "session-str":
        _yaml_edit(root / S / "session.yaml", lambda d: d.update(floor="0"))
    else:
        p = root / B / "anchors.csv"
        header, rows = _rows(p)
        i = header.index("floor")
        _write_rows(p, header, [r[:i] + ["0.0"] + r[i + 1:] for r in rows])
    return Outcome(SAME)


def f_yaml_style(root, f, seed):
    """Keys in another order, flow style, a comment and trailing spaces."""
    p = root / f
    doc = yaml.safe_load(p.read_text(encoding="utf-8"))
    keys = list(doc)
    perm = np.random.default_rng(seed).permutation(len(keys))
    doc = {keys[i]: doc[keys[i]] for i in perm}
    text = yaml.safe_dump(doc, sort_keys=False, default_flow_style=bool(seed % 2), allow_unicode=True)
    text = "# written by hand\n" + "\n".join(ln + "  " for ln in text.splitlines()) + "\n"
    p.write_text(text, encoding="utf-8")
    return Outcome(SAME)


def _rename_anchor_everywhere(root, old, new):
    for f in (f"{B}/anchors.csv", f"{S}/rssi.csv", f"{S}/rtt.csv"):
        p = root / f
        header, rows = _rows(p)
        i = header.index("anchor_id")
        _write_rows(p, header, [r[:i] + [new if r[i].strip() == old else r[i]] + r[i + 1:] for r in rows])


def f_rename_ids(root, anchors, session, building):
    """Anchors, the session folder and the building folder renamed consistently (Unicode, spaces, commas)."""
    rename = {}
    for old, new in anchors:
        _rename_anchor_everywhere(root, old, new)
        rename[new.strip()] = old
    if building is not None:
        (root / "buildings" / "house").rename(root / "buildings" / building)
        _yaml_edit(root / S / "session.yaml", lambda d: d.update(building=building))
        rename[building] = "house"
    if session is not None:
        (root / S).rename(root / "sessions" / session)
        rename[session] = "walk0"
    return Outcome(SAME, rename=rename)


# ---- faults that must be refused, counted, or may be anything the readers promise


def f_truncate(root, f, pos):
    p = root / f
    data = p.read_bytes()
    k = pos % len(data)
    p.write_bytes(data[:k])
    if f.endswith(".png") or f.endswith(".geojson"):
        return Outcome(ANY)  # JSON and PNG know where they end: refused (or, cut in a trailer, the same)
    if k == 0 or data[k - 1:k] in (b"\n", b"\r"):
        return Outcome(ANY)  # cut at a line end: a shorter file, no reader can tell
    return Outcome(REFUSED, frozenset({"truncated"}))


def f_flip(root, f, pos, byte):
    p = root / f
    data = bytearray(p.read_bytes())
    data[pos % len(data)] = byte
    p.write_bytes(bytes(data))
    return Outcome(ANY)


def _set_cells(root, f, cells: dict) -> None:
    """cells: {(row, column): text}; row 0 is the first data row."""
    p = root / f
    header, rows = _rows(p)
    for (r, c), v in cells.items():
        rows[r][header.index(c)] = v
    _write_rows(p, header, rows)


def _n_rows(root, f) -> int:
    return len(_rows(root / f)[1])


def f_shuffle_block(root, f, start, length, seed):
    p = root / f
    header, rows = _rows(p)
    a = start % len(rows)
    block = rows[a:a + length]
    perm = np.random.default_rng(seed).permutation(len(block))
    rows[a:a + length] = [block[i] for i in perm]
    _write_rows(p, header, rows)
    t = np.array([float(r[header.index("t")]) for r in rows])
    if (np.diff(t) >= 0).all():
        return Outcome(ANY)  # rows of equal time swapped
    return Outcome(REFUSED, frozenset({"time-backwards"}))


def f_duplicate_row(root, f, row, same_time_only):
    p = root / f
    header, rows = _rows(p)
    r = row % len(rows)
    if same_time_only and r > 0:  # another reading at the previous row's time
        rows[r][header.index("t")] = rows[r - 1][header.index("t")]
    else:
        rows.insert(r, list(rows[r]))
    _write_rows(p, header, rows)
    return Outcome(ANY)


def f_time_value(root, f, row, value):
    """One row's t set to ``value``: negative, above T_MAX_S or not finite."""
    r = row % _n_rows(root, f)
    _set_cells(root, f, {(r, "t"): value})
    return Outcome(REFUSED, frozenset({"time-range", "non-finite", "not-a-number", "time-backwards"}))


def f_late_end(root, f, value):
    """The last row of one stream far later than the rest of the session (a clock or unit mistake)."""
    n = _n_rows(root, f)
    _set_cells(root, f, {(n - 1, "t"): repr(value)})
    return Outcome(REFUSED)


def f_scale(root, f, columns, factor):
    """A unit mistake: columns multiplied by ``factor`` (ms for s, mg for m/s^2, nT for uT, mm for m)."""
    p = root / f
    df = pd.read_csv(p, keep_default_na=False, dtype=str)
    for c in columns:
        df[c] = [repr(float(v) * factor) if v != "" else v for v in df[c]]
    df.to_csv(p, index=False, lineterminator="\n")
    return Outcome(REFUSED)


NON_FINITE = ["nan", "NaN", "inf", "-inf", "Infinity", "", "NA", "null", "None", "1e999", "-1e999", "N/A", "x",
              "1..5", "--3", "0x10"]


def f_bad_cell(root, f, column, row, token):
    """A required cell that is not a finite number (or an empty id)."""
    r = row % _n_rows(root, f)
    _set_cells(root, f, {(r, column): token})
    if column == "anchor_id" and token.strip():
        # a non-empty text is an id: in rssi/rtt an unknown anchor (dropped and counted); in anchors.csv another
        # anchor (the rows of the old id are dropped and counted, or it is a duplicate)
        return Outcome(ANY) if f.endswith("anchors.csv") else Outcome(DROPPED, dropped=1)
    if column in ("anchor_id", "kind", "floor"):
        return Outcome(REFUSED)
    return Outcome(REFUSED, frozenset({"non-finite", "not-a-number"}))


def f_empty(root, f):
    (root / f).write_bytes(b"")
    if f.endswith(".yaml") or f.endswith(".png"):
        return Outcome(REFUSED)
    return Outcome(ANY)


def f_delete(root, f):
    (root / f).unlink()
    return Outcome(ANY)


def f_rssi(root, row, value):
    r = row % _n_rows(root, f"{S}/rssi.csv")
    _set_cells(root, f"{S}/rssi.csv", {(r, "rssi"): value})
    v = float(value)
    if -150 < v < 0:
        return Outcome(ANY)
    return Outcome(REFUSED, frozenset({"rssi-range"}))


def f_duplicate_anchor(root, row, dx):
    p = root / B / "anchors.csv"
    header, rows = _rows(p)
    src = list(rows[row % len(rows)])
    src[header.index("x")] = repr(float(src[header.index("x")]) + dx)
    rows.append(src)
    _write_rows(p, header, rows)
    return Outcome(REFUSED, frozenset({"anchor-unique"}))


def f_missing_floor(root, how):
    if how == "session":
        _yaml_edit(root / S / "session.yaml", lambda d: d.update(floor=7))
    elif how == "anchor":
        _set_cells(root, f"{B}/anchors.csv", {(1, "floor"): "7"})
    elif how == "renamed":
        _yaml_edit(root / B / "building.yaml", lambda d: d["floors"][0].update(id=3))
    elif how == "no-floors":
        _yaml_edit(root / B / "building.yaml", lambda d: d.update(floors=[]))
    else:  # the floors key itself
        _yaml_edit(root / B / "building.yaml", lambda d: d.pop("floors"))
    return Outcome(REFUSED)


def f_unknown_anchor(root, f, rows, new_id):
    n = _n_rows(root, f)
    rs = sorted({r % n for r in rows})
    _set_cells(root, f, {(r, "anchor_id"): new_id for r in rs})
    return Outcome(DROPPED, dropped=len(rs))


def f_header(root, f, how, col):
    p = root / f
    header, rows = _rows(p)
    i = col % len(header)
    if how == "typo":
        header[i] = header[i] + "x"
    elif how == "twice":
        header.append(header[i])
        rows = [r + [r[i]] for r in rows]
    else:  # no header line
        header, rows = rows[0], rows[1:]
    _write_rows(p, header, rows)
    if how == "typo" and header[i][:-1] not in STREAMS.get(STREAM_OF.get(f, ""), STREAMS["imu"]).columns \
            and not f.endswith("anchors.csv"):
        return Outcome(ANY)  # an extra column renamed
    if how == "typo" and f.endswith("anchors.csv") and header[i][:-1] not in ANCHOR_COLUMNS:
        return Outcome(ANY)
    return Outcome(REFUSED)


def f_ragged(root, f, row, more):
    p = root / f
    ls = _lines(p)
    r = 1 + row % (len(ls) - 1)
    ls[r] = ls[r] + ",1" if more else ls[r].rsplit(",", 1)[0]
    _write_lines(p, ls)
    return Outcome(REFUSED)


def f_bad_encoding(root, f, pos, raw):
    """Bytes that are not UTF-8 (a Latin-1 'é', a lone continuation byte) in a text file."""
    p = root / f
    data = p.read_bytes()
    # after a comma or at a line start, so the rest of the file keeps its structure
    cuts = [i + 1 for i, b in enumerate(data) if b in b",\n"][:-1] or [0]
    k = cuts[pos % len(cuts)]
    p.write_bytes(data[:k] + raw + data[k:])
    return Outcome(REFUSED)


def f_plan_scale(root, what, value):
    if what == "resolution":
        _yaml_edit(root / B / "building.yaml", lambda d: d["floors"][0].update(resolution=value))
    elif what == "origin":
        _yaml_edit(root / B / "building.yaml", lambda d: d["floors"][0].update(origin=[value, 0.0, 0.0]))
    return Outcome(REFUSED)


def f_anchor_value(root, row, column, value):
    """An anchor's position or tx power far outside anything physical."""
    _set_cells(root, f"{B}/anchors.csv", {(row % 5, column): value})
    return Outcome(REFUSED)


def f_huge_position(root, f, row, column, value):
    """One position of a stream far away: world positions more than 2 km off the plan (the templates' plans are
    under 100 m) are refused ('position-off-floor'); odometry has an arbitrary frame (ANY, never NaN downstream)."""
    r = row % _n_rows(root, f)
    _set_cells(root, f, {(r, column): value})
    if f.endswith("odometry.csv") or abs(float(value)) < 2100:
        return Outcome(ANY)
    return Outcome(REFUSED, frozenset({"position-off-floor"}))


def f_keep_rows(root, f, k):
    """Only the first ``k`` rows of a stream (a recording that stopped at once, a single survey point)."""
    p = root / f
    ls = _lines(p)
    _write_lines(p, ls[: 1 + k])
    return Outcome(ANY)


def f_one_time(root, f, value):
    """Every row of a stream at the same time."""
    p = root / f
    header, rows = _rows(p)
    _write_rows(p, header, [r[:header.index("t")] + [value] + r[header.index("t") + 1:] for r in rows])
    return Outcome(ANY)


def f_image(root, kind):
    """The floor image replaced: the same pixels in RGB (converted, with a warning), 16-bit, 1 x 1 px, or
    inverted without ``negate``."""
    from PIL import Image

    p = root / B / "floor_0.png"
    im = Image.open(p)
    a = np.asarray(im)
    if kind == "rgb":
        im.convert("RGB").save(p)
        return Outcome(ANY)
    if kind == "16bit":
        Image.fromarray(a.astype(np.uint16) * 257).save(p)
    elif kind == "tiny":
        Image.fromarray(a[:1, :1]).save(p)
    else:
        Image.fromarray(255 - a).save(p)
    return Outcome(REFUSED)


GEOJSON_FAULTS = ["nan", "inf", "huge", "far", "bowtie", "two-points", "one-point", "point", "null-geometry",
                  "no-features", "features-null", "floor-list", "id-list", "no-properties", "text-coordinates"]


def f_geojson(root, f, kind, i):
    """One feature of rooms.geojson or navgraph.geojson broken (or merely odd: no features, a room far away)."""
    import json

    p = root / f
    doc = json.loads(p.read_text(encoding="utf-8"))
    feats = doc["features"]
    feat = feats[i % len(feats)]
    g = feat["geometry"]
    ring = g["coordinates"][0] if g["type"] == "Polygon" else g["coordinates"]
    expect = REFUSED
    if kind in ("nan", "inf", "huge"):
        ring[0][0] = {"nan": float("nan"), "inf": float("inf"), "huge": 1e300}[kind]
        if g["type"] == "Polygon":
            ring[-1][0] = ring[0][0]
    elif kind == "far":  # a room or route 100 km away: valid GeoJSON, not on the floor ('geojson-off-floor')
        for pt in ring:
            pt[0] += 1e5
        if g["type"] == "Polygon":
            ring[-1] = list(ring[0])
    elif kind == "bowtie":  # a self-intersecting polygon (a route may cross itself)
        if g["type"] == "Polygon":
            ring[1], ring[2] = ring[2], ring[1]
        else:
            expect = ANY
    elif kind == "two-points":
        g["coordinates"] = [ring[:2] + [ring[0]]] if g["type"] == "Polygon" else ring[:2]
        expect = ANY if g["type"] != "Polygon" else REFUSED
    elif kind == "one-point":
        g["coordinates"] = [ring[:1]] if g["type"] == "Polygon" else ring[:1]
    elif kind == "point":
        feat["geometry"] = {"type": "Point", "coordinates": ring[0]}
    elif kind == "null-geometry":
        feat["geometry"] = None
    elif kind == "no-features":
        doc["features"] = []
        expect = ANY
    elif kind == "features-null":
        doc["features"] = None
        expect = ANY
    elif kind == "floor-list":
        feat["properties"]["floor"] = [0]
    elif kind == "id-list":
        feat["properties"]["id"] = ["a", "b"]
        expect = ANY
    elif kind == "no-properties":
        feat["properties"] = None
    else:  # text-coordinates
        ring[0][0] = "x"
    p.write_text(json.dumps(doc, allow_nan=True), encoding="utf-8")  # NaN and Infinity, as Python writes them
    return Outcome(expect)


def f_both(root, first, second):
    """Two faults, one after the other (the second may find the first's file gone or unreadable: then it is
    not applied). Whatever the two require, together the result is refused cleanly or keeps every promise."""
    first.apply(root)
    try:
        second.apply(root)
    except (OSError, ArithmeticError, ValueError, LookupError, csv.Error, yaml.YAMLError, TypeError, AttributeError):
        pass  # the helper could not apply it to what the first left (not the readers' problem)
    return Outcome(ANY)


# --------------------------------------------------------------------------- strategies

_pos = st.integers(0, 10**6)
_seed = st.integers(0, 2**16)


def _id_text():
    """Ids a user might write: Unicode letters, spaces, commas, quotes; unique after stripping."""
    alphabet = st.characters(blacklist_categories=("Cs", "Cc", "Zl", "Zp"), blacklist_characters="\x00")
    special = st.sampled_from(["NA", "nan", "None", "null", "N/A", "1", "01", "1.0", "b 1", "é", "e\u0301",
                               "mac 00:11:22:33:44:55", "major,minor", 'say "hi"', "#1", "-1"])
    return st.one_of(special, st.text(alphabet, min_size=1, max_size=12)).map(
        lambda s: unicodedata.normalize("NFC", s)).filter(lambda s: s.strip() != "" and s == s.strip())


@st.composite
def renames(draw):
    olds = draw(st.lists(st.sampled_from(["b1", "b2", "b3", "b4", "ap1"]), unique=True, min_size=0, max_size=5))
    news = draw(st.lists(_id_text(), unique_by=str.strip, min_size=len(olds), max_size=len(olds)))
    taken = {"b1", "b2", "b3", "b4", "ap1"} - set(olds)
    news = [n for n in news if n not in taken]
    pairs = tuple(zip(olds, news))
    folder = _id_text().filter(lambda s: "/" not in s and "\\" not in s and s not in (".", "..")
                               and not s.startswith(".") and len(s.encode()) < 100)
    session = draw(st.none() | folder)
    building = draw(st.none() | folder)
    # one rename map for every kind of id: the new names must be distinct across kinds (and not old names)
    news = {n.strip() for _, n in pairs} | {"b1", "b2", "b3", "b4", "ap1", "house", "walk0"}
    session = None if session in news else session
    building = None if building in news or building == session else building
    if not pairs and session is None and building is None:
        session = "walk 0 é"
    return Fault("rename_ids", f_rename_ids, (pairs, session, building))


def same_faults():
    """Faults after which the readers must return exactly what they return for the template."""
    text = st.sampled_from(TEXT_FILES)
    csvs = st.sampled_from(CSV_FILES)
    return st.one_of(
        st.builds(lambda f: Fault("bom", f_bom, (f,)), text),
        st.builds(lambda f, e: Fault("line_ends", f_line_ends, (f, e)), text, st.sampled_from(["\r\n", "\r"])),
        st.builds(lambda f, s: Fault("pad_cells", f_pad_cells, (f, s)), csvs, _seed),
        st.builds(lambda f, s: Fault("reorder_columns", f_reorder_columns, (f, s)), csvs, _seed),
        st.builds(lambda f, n, s: Fault("extra_column", f_extra_column, (f, n, s)), csvs,
                  st.sampled_from(["note", "t2", "x_true", "point", "ünïcode col"]), _seed),
        st.builds(lambda s: Fault("shuffle_anchors", f_shuffle_anchors, (s,)), _seed),
        st.builds(lambda f: Fault("quote", f_quote, (f,)), csvs),
        st.builds(lambda f, k: Fault("zeros", f_zeros, (f, k)), csvs, st.integers(1, 6)),
        st.builds(lambda w: Fault("extra_files", f_extra_files, (w,)), st.sampled_from([".", "sessions", S, B,
                                                                                         "buildings"])),
        st.builds(lambda s: Fault("floor_spelling", f_floor_spelling, (s,)), st.sampled_from(["session-str",
                                                                                              "anchor-float"])),
        st.builds(lambda f, s: Fault("yaml_style", f_yaml_style, (f, s)), st.sampled_from(YAML_FILES), _seed),
        renames(),
    )


STREAM_FILES = [f for f in CSV_FILES if f in STREAM_OF]
REQUIRED_CELLS = [(f, c) for f in STREAM_FILES for c in STREAMS[STREAM_OF[f]].required] + [
    (f"{B}/anchors.csv", c) for c in ("anchor_id", "kind", "x", "y", "z", "floor")]
BIG = ["1000001", "1e7", "1.7e9", "1e300", "1e308", "-0.001", "-1", "-1e300"]
#: (file, columns, factor): unit mistakes a reader must catch on the template's values
UNIT_MISTAKES = [
    (f"{S}/imu.csv", ("t",), 1000.0),                      # ms for s (100 Hz: one sample per 10 s)
    (f"{S}/rssi.csv", ("t",), 1000.0),                     # ms for s in one stream of the session
    (f"{S}/groundtruth.csv", ("t",), 1000.0),
    (f"{S}/mag.csv", ("t",), 1000.0),
    (f"{S}/rtt.csv", ("t",), 1000.0),
    (f"{S}/visual.csv", ("t",), 1000.0),
    (f"{S}/odometry.csv", ("t",), 1000.0),
    (f"{S}/fixes.csv", ("t",), 1000.0),
    (f"{S}/imu.csv", ("ax", "ay", "az"), 1000.0 / 9.80665),  # mg for m/s^2
    (f"{S}/imu.csv", ("ax", "ay", "az"), 100.0),           # cm/s^2
    (f"{S}/mag.csv", ("mx", "my", "mz"), 1000.0),          # nT for uT
    (f"{S}/rtt.csv", ("range_m",), 1000.0),                 # mm for m
    (f"{S}/rssi.csv", ("rssi",), 100.0),                    # centi-dBm
    (f"{S}/rssi.csv", ("rssi",), -1.0),                     # the sign lost
    (f"{S}/groundtruth.csv", ("x", "y"), 1000.0),          # mm for m
    (f"{S}/groundtruth.csv", ("x", "y"), 100.0),           # cm for m
    (f"{B}/anchors.csv", ("x", "y"), 1000.0),               # mm for m
    (f"{B}/anchors.csv", ("x", "y"), 100.0),
]


def bad_faults():
    """Faults the readers must refuse, count, or read into data that keeps their promises."""
    files = st.sampled_from(ALL_FILES)
    text = st.sampled_from(TEXT_FILES)
    csvs = st.sampled_from(CSV_FILES)
    streams = st.sampled_from(STREAM_FILES)
    return st.one_of(
        st.builds(lambda f, p: Fault("truncate", f_truncate, (f, p)), files, _pos),
        st.builds(lambda f, p, b: Fault("flip", f_flip, (f, p, b)), files, _pos, st.integers(0, 255)),
        st.builds(lambda f, a, n, s: Fault("shuffle_block", f_shuffle_block, (f, a, n, s)), streams, _pos,
                  st.integers(2, 6), _seed),
        st.builds(lambda f, r, s: Fault("duplicate_row", f_duplicate_row, (f, r, s)), streams, _pos, st.booleans()),
        st.builds(lambda f, r, v: Fault("time_value", f_time_value, (f, r, v)), streams, _pos,
                  st.sampled_from(BIG + ["nan", "inf", "-inf"])),
        st.builds(lambda f, v: Fault("late_end", f_late_end, (f, v)), streams, st.sampled_from(
            [1e4, 5e4, 2.5e5, 999999.0])),
        st.builds(lambda m: Fault("unit", f_scale, m), st.sampled_from(UNIT_MISTAKES)),
        st.builds(lambda fc, r, tok: Fault("bad_cell", f_bad_cell, (fc[0], fc[1], r, tok)),
                  st.sampled_from(REQUIRED_CELLS), _pos, st.sampled_from(NON_FINITE)),
        st.builds(lambda f: Fault("empty", f_empty, (f,)), files),
        st.builds(lambda f: Fault("delete", f_delete, (f,)), files),
        st.builds(lambda r, v: Fault("rssi", f_rssi, (r, v)), _pos, st.sampled_from(
            ["0", "-0", "0.0", "1", "127", "-150", "-150.0", "-200", "-1e9", "1e9", "-149.99", "-0.01", "-30"])),
        st.builds(lambda r, dx: Fault("duplicate_anchor", f_duplicate_anchor, (r, dx)), _pos,
                  st.sampled_from([0.0, 1.0])),
        st.builds(lambda h: Fault("missing_floor", f_missing_floor, (h,)), st.sampled_from(
            ["session", "anchor", "renamed", "no-floors", "no-key"])),
        st.builds(lambda f, rs, i: Fault("unknown_anchor", f_unknown_anchor, (f, tuple(rs), i)),
                  st.sampled_from([f"{S}/rssi.csv", f"{S}/rtt.csv"]), st.lists(_pos, min_size=1, max_size=5),
                  st.sampled_from(["B1", "b1x", "ghost", "b 1", "bé"])),
        st.builds(lambda f, h, c: Fault("header", f_header, (f, h, c)), csvs,
                  st.sampled_from(["typo", "twice", "none"]), st.integers(0, 10)),
        st.builds(lambda f, r, m: Fault("ragged", f_ragged, (f, r, m)), csvs, _pos, st.booleans()),
        st.builds(lambda f, p, raw: Fault("bad_encoding", f_bad_encoding, (f, p, raw)), text, _pos,
                  st.sampled_from([b"\xe9", b"\x80", b"\xff\xfe", b"\xc3"])),
        st.builds(lambda w, v: Fault("plan_scale", f_plan_scale, (w, v)), st.sampled_from(["resolution"]),
                  st.sampled_from([1e-300, 1e-5, 100.0, 1e6, 1e300])),
        st.builds(lambda v: Fault("plan_scale", f_plan_scale, ("origin", v)), st.sampled_from([1e9, 1e300])),
        st.builds(lambda r, c, v: Fault("anchor_value", f_anchor_value, (r, c, v)), _pos,
                  st.sampled_from(["x", "y", "z"]), st.sampled_from(["1e300", "-1e300", "1e9", "-5e4"])),
        st.builds(lambda r, v: Fault("anchor_value", f_anchor_value, (r, "tx_power_dbm", v)), _pos,
                  st.sampled_from(["1e300", "-1e300", "0", "20", "-200"])),
        st.builds(lambda f, k: Fault("keep_rows", f_keep_rows, (f, k)), streams, st.integers(0, 3)),
        st.builds(lambda f, v: Fault("one_time", f_one_time, (f, v)), streams, st.sampled_from(["0", "5.0", "19.9"])),
        st.builds(lambda k: Fault("image", f_image, (k,)), st.sampled_from(["rgb", "16bit", "tiny", "inverted"])),
        st.builds(lambda f, k, i: Fault("geojson", f_geojson, (f, k, i)), st.sampled_from(JSON_FILES),
                  st.sampled_from(GEOJSON_FAULTS), st.integers(0, 3)),
        st.builds(lambda f, r, c, v: Fault("huge_position", f_huge_position, (f, r, c, v)),
                  st.sampled_from([f"{S}/groundtruth.csv", f"{S}/visual.csv", f"{S}/fixes.csv",
                                   f"{S}/odometry.csv"]), _pos, st.sampled_from(["x", "y"]),
                  st.sampled_from(["1e300", "-1e300", "1e12", "5e3", "1500", "-900"])),
    )


def two_bad_faults():
    return st.builds(lambda a, b: Fault("both", f_both, (a, b)), bad_faults(), bad_faults())
