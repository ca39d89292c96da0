"""Check every rule of dataset format v1 and collect all issues (``blenav-validate``)."""

from __future__ import annotations

from pathlib import Path

from .building import load_building
from .issues import Issue, error
from .schema import FORMAT, STREAMS
from .session import check_session_files, check_session_meta
from .streams import load_stream
from .yaml_file import load_yaml


def validate(root: str | Path) -> list[Issue]:
    """Every violation (severity 'error') and remark ('warning') in the dataset at ``root``."""
    root = Path(root)
    if not root.is_dir():
        return [error(root, "missing-dataset", "dataset folder does not exist")]
    issues: list[Issue] = []
    meta, mi = load_yaml(root / "dataset.yaml")
    issues += mi
    if meta is not None and str(meta.get("format")) != FORMAT:
        issues.append(error(root / "dataset.yaml", "format", f"format is {meta.get('format')!r}, expected {FORMAT!r}"))

    buildings = {}
    bdir = root / "buildings"
    for b in sorted(p for p in bdir.iterdir() if p.is_dir()) if bdir.is_dir() else []:
        bld, bi = load_building(b)
        issues += bi
        buildings[b.name] = bld
    if not buildings:
        issues.append(error(bdir, "no-buildings", "dataset has no building folder under buildings/"))

    sdir = root / "sessions"
    sessions = sorted(p for p in sdir.iterdir() if p.is_dir()) if sdir.is_dir() else []
    if not sessions:
        issues.append(error(sdir, "no-sessions", "dataset has no session folder under sessions/"))
    for s in sessions:
        issues += validate_session(s, buildings)
    return issues


def validate_session(root: Path, buildings: dict) -> list[Issue]:
    ypath = root / "session.yaml"
    meta, issues = load_yaml(ypath)
    if meta is None:
        return issues
    issues += check_session_meta(ypath, meta, buildings)
    issues += check_session_files(root, meta)
    building = buildings.get(str(meta.get("building")))
    labelled = meta.get("labelled") is True
    for name, spec in STREAMS.items():
        if (root / spec.filename).is_file():
            _, si, _ = load_stream(root, name, building, labelled, meta.get("floor"))
            issues += si
    return issues
