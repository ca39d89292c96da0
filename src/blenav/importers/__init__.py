"""Importers that convert public recordings in ../shared/data/raw/ to dataset format v1.

Each importer is a function ``import_<kind>(src: Path, out: Path) -> ImportReport`` in its own module;
its docstring documents every unit, frame and assumption. Malformed input raises
:class:`blenav.errors.ImportError_` naming file, line and problem; rows an importer drops are counted in the report.
"""

from __future__ import annotations

import importlib
from dataclasses import dataclass, field
from pathlib import Path

from blenav.errors import ImportError_

KINDS = ("uji_ble", "danis_ble_tracks", "kolakowski_ble_calib", "feng_wifi_rtt", "ilc20")
#: kinds whose SRC may be an archive file as well as a folder
ARCHIVE_KINDS = ("ilc20",)


@dataclass
class ImportReport:
    """What an import wrote and what it dropped (with reasons)."""

    out: Path
    sessions: int = 0
    buildings: int = 0
    dropped: dict[str, int] = field(default_factory=dict)
    notes: list[str] = field(default_factory=list)

    def drop(self, reason: str, n: int = 1) -> None:
        if n:
            self.dropped[reason] = self.dropped.get(reason, 0) + int(n)

    def __str__(self) -> str:
        lines = [f"wrote {self.buildings} building(s), {self.sessions} session(s) to {self.out}"]
        lines += [f"dropped {n} {reason}" for reason, n in self.dropped.items()]
        lines += self.notes
        return "\n".join(lines)


def run_import(kind: str, src: Path | str, out: Path | str, **options) -> ImportReport:
    """Dispatch to ``blenav.importers.<kind>.import_<kind>``; ``options`` are passed on (e.g. ilc20's ``floors``)."""
    if kind not in KINDS:
        raise ValueError(f"unknown import kind {kind!r}; choose one of {', '.join(KINDS)}")
    src, out = Path(src), Path(out)
    if not src.is_dir() and not (kind in ARCHIVE_KINDS and src.is_file()):
        raise ImportError_(src, None, "source folder does not exist" if kind not in ARCHIVE_KINDS
                           else "source folder or archive does not exist")
    mod = importlib.import_module(f"blenav.importers.{kind}")
    return getattr(mod, f"import_{kind}")(src, out, **options)
