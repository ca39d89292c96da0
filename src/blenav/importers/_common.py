"""Helpers shared by the importers: strict text/CSV reading, RSSI checks, occupancy grids, bounded archive
reading, output checks.

Every reading helper raises :class:`~blenav.errors.ImportError_` naming the file, the 1-based line
(``None`` when the problem is the whole file) and the problem; nothing here writes anything. Line
numbers count every physical line of the file, header included.
"""

from __future__ import annotations

import stat
import tarfile
import zipfile
from pathlib import Path
from typing import Callable, Iterator, Sequence

import numpy as np
import pandas as pd
import shapely
from shapely.geometry import Polygon

from blenav import limits
from blenav.data import FREE, OCCUPIED, UNKNOWN, validate
from blenav.data.building_files import FLOOR_MAX_SIDE_M
from blenav.data.schema import RSSI_MAX_DBM, RSSI_MIN_DBM, T_MAX_S
from blenav.errors import DatasetError, ImportError_

from . import ImportReport

# --------------------------------------------------------------------------------------------------
# strict reading


def read_lines(path: Path) -> list[str]:
    """Text lines of ``path`` (UTF-8, optional BOM; any line ending), trailing blank lines dropped.

    A missing file raises with line ``None``; bytes that are not UTF-8 raise naming the line they are on.
    """
    path = Path(path)
    if not path.is_file():
        raise ImportError_(path, None, "file does not exist")
    raw = path.read_bytes()
    try:
        text = raw.decode("utf-8-sig")
    except UnicodeDecodeError as exc:
        raise ImportError_(path, raw[: exc.start].count(b"\n") + 1, f"not UTF-8 text ({exc.reason})") from None
    lines = text.splitlines()
    while lines and not lines[-1].strip():
        lines.pop()
    return lines


def first_true(mask: np.ndarray) -> int | None:
    """Index of the first True element of ``mask`` (flattened), or ``None`` if there is none."""
    idx = np.flatnonzero(mask)
    return int(idx[0]) if idx.size else None


def raise_at(path: Path, mask: np.ndarray, first_line: int, problem: Callable[[int, int], str]) -> None:
    """Raise :class:`ImportError_` at the first True row of ``mask`` (n,) or (n, k); do nothing if none.

    Row ``r`` of ``mask`` is file line ``r + first_line``. ``problem(r, c)`` returns the message for the
    first True cell in row-major order (``c`` is 0 for 1-D masks).
    """
    if mask.any():
        idx = np.argwhere(mask.reshape(mask.shape[0], -1))[0]
        r, c = int(idx[0]), int(idx[1])
        raise ImportError_(path, r + first_line, problem(r, c))


def split_cells(path: Path, lines: Sequence[str], first_line: int, ncols: int, what: str = "") -> np.ndarray:
    """Whitespace-stripped cells of comma-separated ``lines`` (no quoting) as a str array (n, ncols).

    ``lines[0]`` is file line ``first_line``. A blank line or a line with another number of columns
    raises ("<k> columns, expected <ncols><what>").
    """
    if not len(lines):
        return np.empty((0, ncols), dtype=str)
    s = pd.Series(list(lines), dtype=object)
    counts = s.str.count(",").to_numpy(dtype=np.int64) + 1
    blank = s.str.strip().eq("").to_numpy(dtype=bool)
    i = first_true((counts != ncols) | blank)
    if i is not None:
        problem = "blank line" if blank[i] else f"{counts[i]} columns, expected {ncols}{what}"
        raise ImportError_(path, i + first_line, problem)
    cells = s.str.split(",", expand=True).to_numpy(dtype=str)
    return np.char.strip(cells)


def read_cells(path: Path, ncols: int, header: Sequence[str] | None = None, what: str = "",
               require_rows: bool = False) -> tuple[np.ndarray, int]:
    """Cells of a plain comma-separated file (no quoting), whitespace-stripped.

    Returns ``(cells, first_line)``: a str array (n, ncols) and the 1-based file line of ``cells[0]``.
    Trailing blank lines are ignored; a blank line elsewhere, a line with another number of columns
    (see :func:`split_cells`), or a first line other than ``header`` (when given) raises. With
    ``require_rows`` a file without data rows raises too (line ``None``).
    """
    lines = read_lines(path)
    first = 1
    if header is not None:
        if not lines:
            raise ImportError_(path, 1, f"file is empty; expected the header {','.join(header)!r}")
        got = [c.strip() for c in lines[0].split(",")]
        if got != list(header):
            raise ImportError_(path, 1, f"header is {lines[0]!r}, expected {','.join(header)!r}")
        lines, first = lines[1:], 2
    if require_rows and not lines:
        raise ImportError_(path, None, "file has a header but no rows" if header is not None else "file is empty")
    return split_cells(path, lines, first, ncols, what), first


def parse_numbers(path: Path, cells: np.ndarray, first_line: int, names: Sequence[str], integer: bool = False,
                  nullable: bool = False) -> np.ndarray:
    """float64 array of the str ``cells`` (n, k) (row ``r`` = file line ``r + first_line``).

    The first bad cell in row-major order raises naming its line and its column ``names[c]``: empty
    ("column 'x': empty"), non-numeric or non-finite ("... 'abc' is not a finite number"), or with
    ``integer`` not a whole number ("... is not an integer"). With ``nullable`` empty cells are allowed
    and become NaN.
    """
    flat = pd.to_numeric(pd.Series(cells.ravel(), dtype=object), errors="coerce")
    v = flat.to_numpy(dtype=float, na_value=np.nan).reshape(cells.shape)
    empty = cells == ""
    bad = ~np.isfinite(v) & ~(nullable & empty)
    if integer:
        bad |= np.isfinite(v) & (v != np.round(v))
    kind = "an integer" if integer else "a finite number"
    raise_at(path, bad, first_line, lambda r, c: f"column {names[c]!r}: "
             + ("empty" if empty[r, c] else f"{str(cells[r, c])!r} is not {kind}"))
    return v


def source_line(src: Path, default: str) -> str:
    """First non-blank line of ``src/SOURCE.txt`` (the citation of the raw copy), else ``default``."""
    p = Path(src) / "SOURCE.txt"
    if p.is_file():
        for line in p.read_text(encoding="utf-8", errors="replace").splitlines():
            if line.strip():
                return line.strip()
    return default


#: raise_far's arguments for times in seconds
FAR_TIME = dict(limit=T_MAX_S, unit="s", bound="any session lasts")


def raise_far(path: Path, xy: np.ndarray, line_of: int | Callable[[int, int], int], names: Sequence[str],
              limit: float = FLOOR_MAX_SIDE_M, unit: str = "m", bound: str = "any floor is large") -> None:
    """Raise at the first value of ``xy`` (n, k) further than ``limit`` from the median of its column.

    Positions (m, default): no floor is larger than ``FLOOR_MAX_SIDE_M`` (2 km, the validator's 'floor-size'
    bound), so the value is corrupt or in another unit, and an occupancy grid covering it would not fit in memory
    (1e9 m: a MemoryError; 1e308: an OverflowError). Times: ``limit=T_MAX_S, unit="s", bound="any session
    lasts"`` (a 1e308 s time made every other session time infinite). ``line_of``: the file line of row 0 (row
    ``r`` is line ``r + line_of``), or ``(r, c) -> line``; ``names[c]``: how the message names column ``c``.
    """
    xy = np.asarray(xy, dtype=float)
    if not len(xy):
        return
    xy = xy.reshape(len(xy), -1)
    med = np.median(xy, axis=0)
    with np.errstate(invalid="ignore", over="ignore"):
        far = ~(np.abs(xy - med) <= limit)
    if far.any():
        r, c = (int(i) for i in np.argwhere(far)[0])
        line = line_of(r, c) if callable(line_of) else r + line_of
        raise ImportError_(path, line, f"{names[c]}: {xy[r, c]:g} {unit} lies {abs(xy[r, c] - med[c]):g} {unit} from "
                           f"the median of the others ({med[c]:g} {unit}), further than {bound} ({limit:g} {unit}): "
                           "a corrupt value, or another unit?")


# --------------------------------------------------------------------------------------------------
# RSSI


def rssi_in_range(rssi: np.ndarray) -> np.ndarray:
    """Whether each value (dBm) is a possible reading, i.e. inside (RSSI_MIN_DBM, RSSI_MAX_DBM); NaN -> False."""
    return (rssi > RSSI_MIN_DBM) & (rssi < RSSI_MAX_DBM)


def raise_bad_rssi(path: Path, rss: np.ndarray, first_line: int, sentinel: float, label: Callable[[int], str],
                   code: str) -> None:
    """Raise at the first cell of ``rss`` (n, k) dBm that is neither ``sentinel`` nor in range.

    Message: ``"<label(c)> <value> is neither a reading in (-150, 0) dBm nor the <code>"``.
    """
    raise_at(path, (rss != sentinel) & ~rssi_in_range(rss), first_line,
             lambda r, c: f"{label(c)} {rss[r, c]:g} is neither a reading in ({RSSI_MIN_DBM:g}, {RSSI_MAX_DBM:g}) "
                          f"dBm nor the {code}")


def drop_rssi(report: ImportReport, rssi: np.ndarray, missing: np.ndarray, missing_reason: str,
              invalid_reason: str) -> np.ndarray:
    """Rows to keep (bool mask) among ``rssi`` (n,) dBm; the others are counted in ``report.dropped``.

    Rows flagged in ``missing`` (not received / unusable) are counted under ``missing_reason``; of the
    rest, values outside the RSSI range (see :func:`rssi_in_range`) under ``invalid_reason``.
    """
    invalid = ~missing & ~rssi_in_range(rssi)
    report.drop(missing_reason, int(missing.sum()))
    report.drop(invalid_reason, int(invalid.sum()))
    return ~missing & ~invalid


# --------------------------------------------------------------------------------------------------
# occupancy grids (int8 (H, W), row 0 = largest y, origin = world (x, y) m of the lower-left corner)


def grid_covering(xy: np.ndarray, resolution: float, margin: float) -> tuple[tuple[int, int], tuple[float, float]]:
    """Shape (H, W) and origin of a grid covering the bounding box of ``xy`` (N, 2) m plus ``margin`` m.

    The edges are snapped outwards to multiples of ``resolution`` (m/px); the origin is rounded to 1e-9 m.
    """
    xy = np.asarray(xy, dtype=float).reshape(-1, 2)
    lo_px = np.floor((xy.min(axis=0) - margin) / resolution)
    hi_px = np.ceil((xy.max(axis=0) + margin) / resolution)
    w, h = (int(v) for v in hi_px - lo_px)
    lo = np.round(lo_px * resolution, 9)
    return (h, w), (float(lo[0]), float(lo[1]))


def pixel_centres(shape: tuple[int, int], origin: tuple[float, float],
                  resolution: float) -> tuple[np.ndarray, np.ndarray]:
    """World x and y (m) of every pixel centre, two float arrays of ``shape`` (H, W) (row 0 on top)."""
    h, w = shape
    xc = origin[0] + (np.arange(w) + 0.5) * resolution
    yc = origin[1] + (h - 1 - np.arange(h) + 0.5) * resolution
    return np.meshgrid(xc, yc)


def occupancy_grid(xy: np.ndarray, obstacles: Sequence[Polygon], resolution: float,
                   margin: float) -> tuple[np.ndarray, tuple[float, float]]:
    """FREE grid covering the bounding box of ``xy`` (N, 2) m plus ``margin``, obstacles OCCUPIED.

    Returns ``(occupancy, origin)``: int8 (H, W) with row 0 on top (largest y), and the world (x, y)
    of the lower-left corner, snapped to a multiple of ``resolution`` (m/px). A pixel is occupied when
    its centre lies inside (or on the edge of) an obstacle polygon.
    """
    shape, origin = grid_covering(xy, resolution, margin)
    occ = np.full(shape, FREE, dtype=np.int8)
    if len(obstacles):
        gx, gy = pixel_centres(shape, origin, resolution)
        occ[shapely.intersects_xy(shapely.union_all(list(obstacles)), gx, gy)] = OCCUPIED
    return occ, origin


def grid_lookup(occ: np.ndarray, origin: tuple[float, float], xy: np.ndarray, resolution: float,
                outside: int = UNKNOWN) -> np.ndarray:
    """Values of grid ``occ`` (H, W) (row 0 on top) at world points ``xy`` (N, 2) m; ``outside`` off the grid."""
    h, w = occ.shape
    col = np.floor((xy[:, 0] - origin[0]) / resolution).astype(np.int64)
    row = (h - 1) - np.floor((xy[:, 1] - origin[1]) / resolution).astype(np.int64)
    inside = (row >= 0) & (row < h) & (col >= 0) & (col < w)
    out = np.full(len(xy), outside, dtype=occ.dtype)
    out[inside] = occ[row[inside], col[inside]]
    return out


# --------------------------------------------------------------------------------------------------
# archives: members streamed one at a time, each size bounded before it is read


class ArchiveBudget:
    """The expansion an archive may have (:mod:`blenav.limits`): no member read above ``max_member_bytes()``, and
    the members' total at most ``max_archive_ratio()`` times the archive's size plus ``ARCHIVE_RATIO_FREE_MB``.
    Sizes are the members' declared ones, checked before a member is read; the archive libraries never return
    more than a member declares (tarfile reads exactly its size; zipfile stops at it and checks the CRC)."""

    def __init__(self, src: Path):
        self.src = Path(src)
        self.max_member = limits.max_member_bytes()
        self.ratio = limits.max_archive_ratio()
        self.allowed = self.ratio * self.src.stat().st_size + limits.ARCHIVE_RATIO_FREE_MB * limits.MIB
        self.total = 0.0

    def take(self, name: str, size: int, read: bool = True) -> None:
        """Count ``size`` declared bytes of member ``name`` (``read``: it is to be read into memory); raise
        :class:`ImportError_` naming the member when it is too large or the archive expands too far."""
        where = f"{self.src}:{name}"
        if read and size > self.max_member:
            raise ImportError_(where, None, f"archive member of {size / limits.MIB:,.1f} MiB, larger than the "
                               f"{self.max_member / limits.MIB:g} MiB a member may have (set "
                               "BLENAV_MAX_ARCHIVE_MEMBER_MB to allow more); not read")
        self.total += size
        if self.total > self.allowed:
            raise ImportError_(where, None, f"the archive's members expand to {self.total / limits.MIB:,.1f} MiB by "
                               f"this one, over {self.ratio:g} times the archive's "
                               f"{self.src.stat().st_size / limits.MIB:,.1f} MiB (a compression bomb? set "
                               "BLENAV_MAX_ARCHIVE_RATIO to allow more); not read")


def _read_member(f, name: str, size: int, budget: ArchiveBudget) -> bytes:
    """The bytes of an open member, at most its declared ``size`` (a member that yields more is refused)."""
    data = f.read(size + 1)
    if len(data) > size:
        raise ImportError_(f"{budget.src}:{name}", None, f"archive member holds more than its declared {size} bytes")
    return data


def iter_tar(src: Path, want: Callable[[str], bool], skipped: list[str]) -> Iterator[tuple[str, bytes]]:
    """``(member name, bytes)`` of the regular members of tar archive ``src`` (any compression, one streaming pass)
    whose name ``want`` accepts, in storage order; nothing is written. Links, devices and FIFOs are not read:
    their names go to ``skipped`` (the importer reports them). Sizes: :class:`ArchiveBudget`. Tar errors
    propagate (the caller names the archive)."""
    budget = ArchiveBudget(src)
    with tarfile.open(src, mode="r|*") as tf:
        for m in tf:
            if m.isdir():
                continue
            if not m.isfile():  # symlink, hard link, character/block device, FIFO
                skipped.append(m.name)
                continue
            wanted = want(m.name)
            budget.take(m.name, m.size, read=wanted)  # skipped members are decompressed too (stream mode)
            if wanted:
                yield m.name, _read_member(tf.extractfile(m), m.name, m.size, budget)


def iter_zip(src: Path, want: Callable[[str], bool], skipped: list[str]) -> Iterator[tuple[str, bytes]]:
    """:func:`iter_tar` for a zip archive: members whose name ``want`` accepts, symlinks (Unix mode in the
    external attributes) listed in ``skipped``; only the members read count towards the ratio. An encrypted
    member wanted raises :class:`ImportError_` naming it."""
    budget = ArchiveBudget(src)
    with zipfile.ZipFile(src) as zf:
        for info in zf.infolist():
            if info.is_dir():
                continue
            kind = stat.S_IFMT(info.external_attr >> 16) if info.create_system == 3 else 0  # Unix mode bits
            if kind not in (0, stat.S_IFREG, stat.S_IFDIR):
                skipped.append(info.filename)
                continue
            if want(info.filename):
                if info.flag_bits & 0x1:  # zipfile would ask for a password (RuntimeError)
                    raise ImportError_(f"{src}:{info.filename}", None, "archive member is encrypted (a "
                                       "password-protected zip); not read")
                budget.take(info.filename, info.file_size)
                with zf.open(info) as f:
                    yield info.filename, _read_member(f, info.filename, info.file_size, budget)


def skipped_note(skipped: list[str]) -> str | None:
    """The report's line for archive members not read (links, devices), or None."""
    if not skipped:
        return None
    first = ", ".join(skipped[:5]) + (", ..." if len(skipped) > 5 else "")
    return f"{len(skipped)} archive member(s) not read: links or special files ({first})"


# --------------------------------------------------------------------------------------------------
# output folder


def check_out(out: Path) -> None:
    """Refuse to mix a new import into an existing dataset folder (raises naming ``out``, line ``None``)."""
    if (out / "sessions").exists() or (out / "buildings").exists() or (out / "dataset.yaml").exists():
        raise ImportError_(out, None, "output folder already holds a dataset; choose a new or empty folder")


def validate_or_raise(out: Path, report: ImportReport) -> None:
    """Run the format-v1 validator on the written dataset ``out``.

    Errors raise :class:`~blenav.errors.DatasetError` (listing them); warnings become ``validator: ...``
    notes of ``report``.
    """
    issues = validate(out)
    errors = [i for i in issues if i.is_error]
    if errors:
        raise DatasetError(errors)
    report.notes += [f"validator: {i}" for i in issues]
