"""A bundle folder checked whole against its manifest before anything in it is read.

A bundle refuses a folder whose files are not exactly the ones its manifest records (sha256; an empty manifest, a
missing, changed or unlisted file); its settings are checked by :mod:`blenav.runtime.bundle.settings`, its building
by :mod:`blenav.runtime.signature`.
"""

from __future__ import annotations

from pathlib import Path

from .format import MANIFEST, REQUIRED_FILES, sha256_file


def verify_files(root: Path, manifest: dict) -> None:
    """The folder holds exactly the files the manifest lists (besides the manifest itself), each with its recorded
    size and sha256. Refused with a one-line ValueError naming the bundle and what differs: a manifest without a
    ``files`` table (or an empty one, or one that lacks settings.json, building.json or localizer.onnx), an entry
    that is not a plain relative path inside the folder, a missing or changed file, a file the manifest does not
    list (a bundle is verified whole: nothing unlisted is read beside the checked files)."""
    files = manifest.get("files")
    if not isinstance(files, dict) or not files:
        what = "empty" if files == {} else "missing" if files is None else f"a {type(files).__name__}, not a table"
        raise ValueError(f"bundle {root}: {MANIFEST} lists no files ('files' is {what}); a bundle that cannot be "
                         "verified is refused: export it again")
    lacking = [f for f in REQUIRED_FILES if f not in files]
    if lacking:
        raise ValueError(f"bundle {root}: {MANIFEST} does not list {', '.join(lacking)}; export it again")
    bad = []
    for rel, info in files.items():
        if not isinstance(rel, str) or rel.startswith("/") or "\\" in rel or any(
                part in ("", ".", "..") for part in rel.split("/")):
            bad.append(f"{str(rel)[:80]!r} is not a path inside the bundle")
            continue
        p = root / rel
        want = info.get("sha256") if isinstance(info, dict) else None
        size = info.get("bytes") if isinstance(info, dict) else None
        if not p.is_file():
            bad.append(f"{rel} missing")
        elif isinstance(size, int) and p.stat().st_size != size:
            bad.append(f"{rel} changed ({p.stat().st_size} bytes, manifest {size})")
        elif (got := sha256_file(p)) != want:
            bad.append(f"{rel} changed (sha256 {got[:12]}..., manifest {str(want)[:12]}...)")
    extra = sorted(q.relative_to(root).as_posix() for q in root.rglob("*")
                   if not q.is_dir() and q.relative_to(root).as_posix() not in files and q != root / MANIFEST)
    if extra:
        shown = ", ".join(extra[:5]) + (f" and {len(extra) - 5} more" if len(extra) > 5 else "")
        bad.append(f"{len(extra)} file(s) the manifest does not list: {shown}")
    if bad:
        raise ValueError(f"bundle {root} is not the one exported: {'; '.join(bad)}; export it again")
