"""Checked CSV reading: every value problem is reported with file, 1-based line and column.

Fast path: pandas' C parser with float dtypes. Only if that fails (a non-numeric cell somewhere) is the
file re-read as text to find the offending lines, so clean files cost one ``read_csv``.
"""

from __future__ import annotations

import csv
import io
import re
from pathlib import Path

import numpy as np
import pandas as pd

from .issues import MAX_ROWS_PER_RULE, Issue, error
from .schema import StreamSpec

#: pandas' words for a missing value; empty (NaN) in numeric columns, text in text columns.
NA_WORDS = sorted(pd._libs.parsers.STR_NA_VALUES)


def _rows_issue(path: Path, rule: str, rows: np.ndarray, what: str) -> list[Issue]:
    """One issue per bad row (line = row + 2), capped, plus a summary of the rest."""
    out = [error(path, rule, what, line=int(r) + 2) for r in rows[:MAX_ROWS_PER_RULE]]
    if len(rows) > MAX_ROWS_PER_RULE:
        out.append(error(path, rule, f"{what}: {len(rows) - MAX_ROWS_PER_RULE} more rows like this "
                         f"(lines {int(rows[MAX_ROWS_PER_RULE]) + 2}..{int(rows[-1]) + 2})"))
    return out


def read_header(path: Path) -> list[str]:
    # utf-8-sig: a byte-order mark (spreadsheet "CSV UTF-8" exports) is not part of the first column name;
    # the csv module: a quoted name ("t","x") is the name, as pandas reads it
    with open(path, encoding="utf-8-sig", errors="replace", newline="") as f:
        first = f.readline()
    if not first.strip():
        return []
    return [c.strip() for c in next(csv.reader([first.rstrip("\r\n")]))]


def read_text(path: Path) -> tuple[str | None, list[Issue]]:
    """The text of a UTF-8 file without its byte-order mark, or ``None`` and an error ('encoding') naming the line
    of the first byte that is not UTF-8 (a file saved as Latin-1 or UTF-16, or a binary file)."""
    return decode(path, Path(path).read_bytes())


def decode(path: Path, data: bytes) -> tuple[str | None, list[Issue]]:
    """:func:`read_text` of bytes already read from ``path``."""
    try:
        return data.decode("utf-8-sig"), []
    except UnicodeDecodeError as exc:
        head = data[: exc.start]
        line = head.count(b"\n") + 1 if b"\n" in data else head.count(b"\r") + 1
        return None, [error(path, "encoding", f"byte {data[exc.start]:#04x} is not UTF-8 text: save the file as UTF-8",
                            line=line)]


def line_issues(path: Path, n_fields: int) -> list[Issue]:
    """Errors of whole lines, which pandas would not report: bytes that are not UTF-8 ('encoding'), and a line
    with more or fewer fields than the header ('malformed-csv'). pandas reads a row with a field missing as an
    empty cell (silently, in a nullable column), and a first row with one field too many as a row index,
    shifting every column."""
    data = Path(path).read_bytes()
    text, issues = decode(path, data)
    if text is None:
        return issues
    if b'"' in data:  # quoted fields may hold commas (and line ends: then lines are counted as records)
        counts = np.array([len(r) for r in csv.reader(io.StringIO(text))])
    else:  # the fields of every line at once, on the bytes (a 60 MB imu.csv in a fraction of a second)
        data = data.removeprefix(b"\xef\xbb\xbf")
        if b"\r" in data:
            data = data.replace(b"\r\n", b"\n").replace(b"\r", b"\n")
        n_lines = data.count(b"\n") + (not data.endswith(b"\n"))
        i = data.find(b"\n") + 1
        first = data[i:data.find(b"\n", i) if data.find(b"\n", i) >= 0 else len(data)] if i else b""
        if data.count(b",") == (n_fields - 1) * n_lines and (not first or first.count(b",") == n_fields - 1):
            return []  # as many commas as lines need, and the first row right (a second row with one field too
            # many and another with one too few would balance: pandas refuses the long one itself)
        a = np.frombuffer(data, dtype=np.uint8)
        ends = np.flatnonzero(a == 10)
        if len(a) and a[-1] != 10:
            ends = np.append(ends, len(a))
        starts = np.concatenate([[0], ends[:-1] + 1])
        commas = np.flatnonzero(a == 44)
        counts = np.searchsorted(commas, ends) - np.searchsorted(commas, starts) + 1
        counts[ends == starts] = 0
    # an empty line (0) reads as a row of empty cells: reported by the value checks, at its line
    bad = [int(i) for i in np.flatnonzero((counts != n_fields) & (counts != 0)) if i > 0]
    out = [error(path, "malformed-csv", f"{counts[i]} field(s), the header has {n_fields}", line=i + 1)
           for i in bad[:MAX_ROWS_PER_RULE]]
    if len(bad) > MAX_ROWS_PER_RULE:
        out.append(error(path, "malformed-csv", f"{len(bad) - MAX_ROWS_PER_RULE} more lines whose number of "
                         f"fields is not the header's {n_fields} (lines {bad[MAX_ROWS_PER_RULE] + 1}..{bad[-1] + 1})"))
    return out


def ends_without_newline(path: Path) -> bool:
    """Whether a non-empty file's last byte is not a line end: its last line may be cut short."""
    with open(path, "rb") as f:
        f.seek(0, 2)
        if f.tell() == 0:
            return False
        f.seek(-1, 2)
        return f.read(1) not in (b"\n", b"\r")


def truncation_issue(path: Path, header: list[str]) -> Issue:
    """The error for a file without a final newline, at its last line (see docs/dataset-format.md)."""
    text = Path(path).read_bytes().decode("utf-8", errors="replace")
    ls = text.splitlines()
    n = len(ls)
    what = "the header" if n == 1 else "its last line"
    nf = len(ls[-1].split(",")) if ls else 0
    if n > 1 and header and nf < len(header):
        what += f" ({nf} field(s), the header has {len(header)})"
    return error(path, "truncated", f"the file does not end with a newline, so {what} may be cut short (a number "
                 "missing digits, a lost field): add a newline at the end if the line is complete, or remove the "
                 "line", line=max(n, 1))


def read_table(
    path: Path,
    required: tuple[str, ...],
    nullable: tuple[str, ...] = (),
    string: tuple[str, ...] = (),
    time_column: str | None = "t",
) -> tuple[pd.DataFrame | None, list[Issue]]:
    """Read one CSV with a header line and check it.

    Returns ``(frame, issues)``; ``frame`` is ``None`` when the file cannot be used at all (missing
    columns, unparsable values). Numeric columns are float64; ``string`` columns are ``str``; extra
    columns are kept as pandas parsed them. An empty file (zero bytes or header only) gives an empty
    frame with the expected columns and no issue: whether emptiness is allowed is the caller's rule.
    A non-empty file whose last byte is not a line end is an error ('truncated') at its last line, which
    replaces that line's other issues (it is also skipped by later row checks, as a reported row).
    """
    header = read_header(path)
    cut = truncation_issue(path, header) if ends_without_newline(path) else None
    df, issues = _read_table(path, header, required, nullable, string, time_column)
    if cut is not None:  # the cut line's own problems are this one problem
        issues = [cut] + [i for i in issues if i.line != cut.line or cut.line == 1]
    return df, issues


def _read_table(path, header, required, nullable, string, time_column):
    issues: list[Issue] = []
    columns = required + nullable
    if not header:
        return pd.DataFrame({c: pd.Series(dtype=str if c in string else float) for c in columns}), issues
    missing = [c for c in columns if c not in header]
    if missing:
        issues.append(error(path, "missing-column", f"header lacks column(s) {', '.join(missing)}; "
                            f"expected {', '.join(columns)}", line=1))
        return None, issues
    seen: set[str] = set()
    dup = sorted({c for c in header if c in seen or seen.add(c)})  # linear: 2,000,000 columns took hours
    if dup:
        issues.append(error(path, "duplicate-column", f"column(s) {', '.join(dup)} appear twice", line=1))
        return None, issues

    issues += line_issues(path, len(header))
    if issues:
        return None, issues

    numeric = [c for c in columns if c not in string]
    dtypes = {c: float for c in numeric} | {c: str for c in string}
    unparsed: dict[str, np.ndarray] = {}  # cells already reported as not-a-number (not reported twice)
    # the header's stripped names (so dtypes apply to ' t'); no row index (a trailing comma is not one); pandas'
    # missing-value words ('NA', 'null', ...) mean empty in numeric columns only: in text columns they are text
    # (an anchor may be called 'NA'), and only an empty cell is empty
    kw = dict(header=0, names=header, index_col=False, skip_blank_lines=False, skipinitialspace=True,
              keep_default_na=False)
    try:
        df = pd.read_csv(path, dtype=dtypes, na_values={c: NA_WORDS for c in header if c not in string}, **kw)
    except (ValueError, pd.errors.ParserError) as exc:
        df, parse_issues, unparsed = _slow_parse(path, numeric, string, exc, kw)
        issues += parse_issues
        if df is None:
            return None, issues
    for c in string:
        if c in df:
            df[c] = df[c].where(df[c].isna() | (df[c].astype(str).str.strip() != ""), np.nan)

    for c in required:
        if c in string:
            bad = np.flatnonzero(df[c].isna().to_numpy() | (df[c].astype(str).str.strip() == "").to_numpy())
            if len(bad):
                issues += _rows_issue(path, "empty-value", bad, f"column '{c}' is empty")
            continue
        v = df[c].to_numpy(dtype=float)
        bad = np.flatnonzero(~np.isfinite(v) & ~unparsed.get(c, np.zeros(len(v), bool)))
        if len(bad):
            kinds = "NaN/empty" if np.isnan(v[bad]).all() else "NaN, empty or infinite"
            issues += _rows_issue(path, "non-finite", bad, f"column '{c}' is {kinds}")
    for c in nullable:
        if c in string:
            continue
        v = df[c].to_numpy(dtype=float)
        bad = np.flatnonzero(np.isinf(v))
        if len(bad):
            issues += _rows_issue(path, "non-finite", bad, f"column '{c}' is infinite")

    if time_column and len(df):
        t = df[time_column].to_numpy(dtype=float)
        ok = np.flatnonzero(np.isfinite(t))  # non-finite times are reported above, not compared
        back = ok[1:][np.diff(t[ok]) < 0]  # rows whose time is before the previous (finite) row's
        if len(back):
            issues += _rows_issue(path, "time-backwards", back,
                                  f"'{time_column}' goes backwards (earlier than the line before)")
    return df, issues


def _slow_parse(path: Path, numeric: list[str], string: tuple[str, ...], exc: Exception, kw: dict):
    """Re-read as text and name every cell that is not a number.

    Returns ``(frame, issues, unparsed)``; ``unparsed`` maps a column to the mask of its non-numeric cells.
    """
    issues: list[Issue] = []
    unparsed: dict[str, np.ndarray] = {}
    try:
        raw = pd.read_csv(path, dtype=str, **kw)
    except pd.errors.ParserError as e:  # ragged rows: pandas names the (1-based, header = 1) line
        m = re.search(r"in line (\d+)", str(e))
        issues.append(error(path, "malformed-csv", str(e).strip(), line=int(m.group(1)) if m else None))
        return None, issues, unparsed
    raw.columns = [c.strip() for c in raw.columns]
    out = pd.DataFrame(index=raw.index)
    for c in raw.columns:
        if c in string:
            out[c] = raw[c].replace("", np.nan)
            continue
        if c not in numeric:
            out[c] = raw[c]
            continue
        s = raw[c].str.strip()
        num = pd.to_numeric(s, errors="coerce")
        empty = s.isin(NA_WORDS)
        notnum = num.isna().to_numpy() & ~empty.to_numpy()
        unparsed[c] = notnum
        bad = np.flatnonzero(notnum)
        for r in bad[:MAX_ROWS_PER_RULE]:
            issues.append(error(path, "not-a-number", f"column '{c}' value {raw[c].iloc[r]!r} is not a number",
                                line=int(r) + 2))
        if len(bad) > MAX_ROWS_PER_RULE:
            issues.append(error(path, "not-a-number", f"column '{c}': {len(bad) - MAX_ROWS_PER_RULE} more rows"))
        out[c] = num.astype(float)
    if not issues:  # the fast parser failed for a reason we did not find: say what pandas said
        issues.append(error(path, "malformed-csv", str(exc)))
    return out, issues, unparsed


def read_stream(path: Path, spec: StreamSpec) -> tuple[pd.DataFrame | None, list[Issue]]:
    """Read a session stream file with the columns of ``spec`` (see :mod:`blenav.data.schema`); its optional
    columns, where the header has them, are read as nullable numeric columns."""
    opt = tuple(c for c in spec.optional if c in read_header(path)) if spec.optional else ()
    return read_table(path, spec.required, spec.nullable + opt, spec.string)
