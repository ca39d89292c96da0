"""The ILC 2.0 sources (folder, tar or zip): the path files and floor metadata files they hold, matched to the
repository and challenge layouts and bounded before they are read."""

from __future__ import annotations

import lzma
import os
import re
import tarfile
import zipfile
import zlib
from dataclasses import dataclass
from pathlib import Path
from typing import Iterator

from blenav.errors import ImportError_
from blenav.limits import MIB, max_member_bytes

from .. import ImportReport
from .._common import iter_tar, iter_zip, skipped_note

_REPO_RE = re.compile(r"^(?:.*/)?([^/]+)/([^/]+)/path_data_files/([^/]+)\.txt$")
_CHALLENGE_RE = re.compile(r"^(?:.*/)?train/([^/]+)/([^/]+)/([^/]+)\.txt$")
_META_RE = re.compile(r"^(?:.*/)?([^/]+)/([^/]+)/(floor_info|geojson_map)\.json$")


@dataclass
class _Entry:
    vpath: str        # posix path used for layout matching
    display: str      # what error messages name
    data: bytes


def classify(vpath: str) -> tuple[str, tuple[str, str], str] | None:
    """('walk' | 'meta', (site, floor), stem or meta name) for a relevant path, else None."""
    name = vpath.rsplit("/", 1)[-1]
    if name.startswith("._") or "__MACOSX/" in vpath:
        return None
    m = _REPO_RE.match(vpath)
    if m:
        return "walk", (m.group(1), m.group(2)), m.group(3)
    m = _CHALLENGE_RE.match(vpath)
    if m:
        return "walk", (m.group(1), m.group(2)), m.group(3)
    m = _META_RE.match(vpath)
    if m:
        return "meta", (m.group(1), m.group(2)), m.group(3)
    return None


def iter_source(src: Path, want, report: ImportReport | None = None) -> Iterator[_Entry]:
    """Relevant files of ``src`` (folder, tar or zip) in storage order; ``want(vpath)`` filters before reading.
    Every file is bounded before it is read (:class:`~blenav.importers._common.ArchiveBudget`: member size, and an
    archive's expansion ratio); archive members that are links or special files are not read and are counted in
    ``report``'s notes."""
    name = src.name.lower()
    skipped: list[str] = []
    if src.is_dir():
        base = src.resolve()
        max_file = max_member_bytes()
        for root, dirs, files in os.walk(base):
            dirs.sort()
            for f in sorted(files):
                p = Path(root) / f
                vpath = p.as_posix().lstrip("/")
                if want(vpath):
                    if p.stat().st_size > max_file:
                        raise ImportError_(p, None, f"file of {p.stat().st_size / MIB:,.1f} MiB, larger than the "
                                           f"{max_file / MIB:g} MiB a file may have (BLENAV_MAX_ARCHIVE_MEMBER_MB)")
                    yield _Entry(vpath, str(p), p.read_bytes())
        # challenge layout given as its train/ folder: the metadata/ sibling
        if base.name == "train" and (base.parent / "metadata").is_dir():
            yield from iter_source(base.parent / "metadata", want, report)
        return
    if name.endswith((".tar.gz", ".tgz", ".tar")):
        members, errors, what = iter_tar, (tarfile.TarError, EOFError, OSError), "tar"
    elif name.endswith(".zip"):
        # zipfile lets a decompressor's own error through: a corrupt deflate or LZMA stream, an unknown method
        members, errors, what = iter_zip, (zipfile.BadZipFile, EOFError, OSError, zlib.error, lzma.LZMAError,
                                           NotImplementedError), "zip"
    else:
        raise ImportError_(src, None, "expected a folder, a .tar.gz/.tgz/.tar or a .zip archive")
    try:
        for vpath, data in members(src, want, skipped):
            yield _Entry(vpath, f"{src}:{vpath}", data)
    except errors as exc:
        raise ImportError_(src, None, f"not a readable {what} archive ({exc})") from None
    note = skipped_note(skipped)
    if note and report is not None:
        report.notes.append(note)
