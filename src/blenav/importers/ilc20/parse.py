"""ILC 2.0 path files: their lines split into cells, the header read, record types counted, and the rows of one
record type as checked numbers (errors name the file and line)."""

from __future__ import annotations

import csv
import io
import re
from collections import Counter
from dataclasses import dataclass

import numpy as np
import pandas as pd

from blenav.errors import ImportError_

SENSOR_TYPES = ("TYPE_ACCELEROMETER", "TYPE_GYROSCOPE", "TYPE_MAGNETIC_FIELD", "TYPE_ROTATION_VECTOR")
#: record type -> (allowed numbers of tab-separated fields, names of the fields after time and type)
USED = {
    **{t: ((5, 6), ("x", "y", "z", "accuracy")) for t in SENSOR_TYPES},
    "TYPE_WAYPOINT": ((4,), ("x", "y")),
    "TYPE_WIFI": ((7,), ("ssid", "bssid", "rssi", "frequency", "last_seen")),
    "TYPE_BEACON": ((10,), ("uuid", "major", "minor", "tx_power", "rssi", "distance", "mac", "unix_ms")),
}
IGNORED = ("TYPE_ACCELEROMETER_UNCALIBRATED", "TYPE_GYROSCOPE_UNCALIBRATED", "TYPE_MAGNETIC_FIELD_UNCALIBRATED",
           "TYPE_BLUE", "TYPE_BLU4", "TYPE_DIST1", "TYPE_DIST2")
_IGNORED_RE = re.compile(r"^TYPE_SENSOR_[A-Z_]+_ACCURACY_CHANGED$")

#: tab-separated fields read per line at least (the widest documented record, TYPE_BEACON, has 10)
MAX_FIELDS = 12


@dataclass
class Walk:
    header: dict[str, str]
    start_line: dict[str, int]
    cells: pd.DataFrame           # str cells, row r = file line r + 1, columns 0, 1, ... ('' when absent)
    nfields: np.ndarray           # (lines,) tab-separated fields per line
    kinds: np.ndarray             # (lines,) record type ('' on header lines)
    counts: Counter
    unknown: Counter
    ignored: Counter


def parse_lines(display: str, data: bytes) -> Walk:
    """Split a path file into cells (pandas' C parser; one row per physical line) and check the line structure."""
    try:
        data.decode("utf-8")
    except UnicodeDecodeError as exc:
        raise ImportError_(display, data[: exc.start].count(b"\n") + 1, f"not UTF-8 text ({exc.reason})") from None
    if data.startswith(b"\xef\xbb\xbf"):
        data = data[3:]
    if not data:
        raise ImportError_(display, None, "file is empty")
    if not data.endswith(b"\n"):
        raise ImportError_(display, data.count(b"\n") + 1, "the file does not end with a newline, so its last "
                           "line may be cut short (a number missing digits): was the walk cut while it was written "
                           "or copied?")
    a = np.frombuffer(data, dtype=np.uint8)
    ends = np.flatnonzero(a == 10)
    starts = np.concatenate([[0], ends[:-1] + 1])
    tabs = np.flatnonzero(a == 9)
    nfields = np.searchsorted(tabs, ends) - np.searchsorted(tabs, starts) + 1
    blank = (ends == starts) | ((ends - starts == 1) & (a[np.maximum(ends - 1, 0)] == 13))
    if blank.any():
        raise ImportError_(display, int(np.argmax(blank)) + 1, "blank line inside the file")
    # as many columns as the widest line (a header line may be wider; a data line too wide for its record type
    # is reported by :func:`table`, naming its line)
    ncols = max(MAX_FIELDS, int(nfields.max()))
    try:
        cells = pd.read_csv(io.BytesIO(data), sep="\t", header=None, names=range(ncols), dtype=object,
                            quoting=csv.QUOTE_NONE, keep_default_na=False, skip_blank_lines=False, engine="c")
    except (ValueError, pd.errors.ParserError) as exc:  # not expected after the checks above
        m = re.search(r"line (\d+)", str(exc))
        raise ImportError_(display, int(m.group(1)) if m else None, f"unreadable line ({exc})") from None
    if len(cells) != len(ends):
        raise ImportError_(display, None, f"{len(cells)} rows read from {len(ends)} lines (a stray carriage return?)")
    first = cells[0].to_numpy(dtype=object)
    is_header = a[starts] == ord("#")
    header: dict[str, str] = {}
    start_line: dict[str, int] = {}
    for r in np.flatnonzero(is_header):
        items = [first[r][1:]] + [str(x) for x in cells.iloc[r, 1:nfields[r]]]
        for item in items:
            k, sep, v = item.partition(":")
            if sep and k.strip():
                header[k.strip()] = v.strip()
                start_line[k.strip()] = int(r) + 1
    short = ~is_header & (nfields < 2)
    if short.any():
        r = int(np.argmax(short))
        raise ImportError_(display, r + 1, f"1 field, expected 'unix_time_ms<TAB>TYPE<TAB>values' ({first[r][:60]!r})")
    kinds = np.where(is_header, "", cells[1].to_numpy(dtype=object)).astype(object)
    vc = Counter(pd.Series(kinds[~is_header]).value_counts().to_dict())
    counts, unknown, ignored = Counter(), Counter(), Counter()
    for k, n in vc.items():
        if k in USED:
            counts[k] = n
        elif k in IGNORED or _IGNORED_RE.match(k):
            ignored[k] = n
        else:
            unknown[k or "(empty type)"] = n
    return Walk(header, start_line, cells, nfields, kinds, counts, unknown, ignored)


def floats(cells: np.ndarray) -> np.ndarray:
    """float64 of text cells (numpy's conversion, fast); cells that are not numbers become NaN."""
    try:
        return cells.astype(np.float64)
    except (ValueError, TypeError):
        return pd.to_numeric(pd.Series(cells, dtype=object), errors="coerce").to_numpy(dtype=float)


def table(display: str, walk: Walk, kind: str, numeric: tuple[int, ...]
          ) -> tuple[np.ndarray, np.ndarray, np.ndarray, pd.DataFrame]:
    """(lines (n,), unix ms (n,) int64, numbers (n, len(numeric)) float64, str cells (n, MAX_FIELDS)) of the rows
    of ``kind``, in file order. ``numeric`` indexes the fields after time and type (cell column 2 + i). Raises
    naming the line of the first bad row (field count, time, number)."""
    rows = np.flatnonzero(walk.kinds == kind)
    allowed, names = USED[kind]
    n = len(rows)
    if n == 0:
        return np.empty(0, np.int64), np.empty(0, np.int64), np.empty((0, len(numeric))), walk.cells.iloc[:0]
    lens = walk.nfields[rows]
    bad = ~np.isin(lens, allowed)
    if bad.any():
        r = int(rows[np.argmax(bad)])
        want = " or ".join(str(a) for a in allowed)
        raise ImportError_(display, r + 1, f"{kind}: {walk.nfields[r]} tab-separated fields, expected {want} "
                           f"(time, type, {', '.join(names)})")
    sub = walk.cells.iloc[rows]
    tf = floats(sub[0].to_numpy(dtype=object))
    with np.errstate(invalid="ignore"):
        isint = np.isfinite(tf) & (tf == np.round(tf)) & (np.abs(tf) < 2 ** 53)
    if not isint.all():
        r = int(rows[np.argmax(~isint)])
        raise ImportError_(display, r + 1, f"time {walk.cells.iat[r, 0]!r} is not an integer (Unix ms)")
    t = tf.astype(np.int64)
    v = np.empty((n, len(numeric)))
    for k, c in enumerate(numeric):
        col = floats(sub[2 + c].to_numpy(dtype=object))
        bad = ~np.isfinite(col)
        if bad.any():
            r = int(rows[np.argmax(bad)])
            raise ImportError_(display, r + 1, f"{kind} field {names[c]!r}: {walk.cells.iat[r, 2 + c]!r} is not a "
                               "finite number")
        v[:, k] = col
    return rows + 1, t, v, sub
