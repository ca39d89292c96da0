"""A format-v1 dataset folder: ``dataset.yaml``, ``buildings/``, ``sessions/``.

>>> ds = Dataset.open("data/office")            # doctest: +SKIP
>>> s = ds.session(ds.session_ids[0]); s.rssi   # doctest: +SKIP
"""

from __future__ import annotations

from functools import cached_property
from pathlib import Path

from blenav.errors import DatasetError

from .building import Building
from .yaml_file import load_yaml
from .issues import error, raise_or_log
from .schema import FORMAT
from .session import Session, check_session_files, check_session_meta


class Dataset:
    """Lazy view of a dataset folder. Buildings load on first use; sessions on :meth:`session`."""

    def __init__(self, root: Path, meta: dict):
        self.root = Path(root)
        self.meta = meta

    @classmethod
    def open(cls, root: str | Path) -> "Dataset":
        root = Path(root)
        if not root.is_dir():
            raise DatasetError(error(root, "missing-dataset", "dataset folder does not exist"))
        meta, issues = load_yaml(root / "dataset.yaml")
        if meta is not None and str(meta.get("format")) != FORMAT:
            issues.append(error(root / "dataset.yaml", "format", f"format is {meta.get('format')!r}, expected {FORMAT!r}"))
        raise_or_log(issues)
        return cls(root, meta)

    @property
    def name(self) -> str:
        return str(self.meta.get("name", self.root.name))

    @cached_property
    def building_ids(self) -> list[str]:
        d = self.root / "buildings"
        return sorted(p.name for p in d.iterdir() if p.is_dir()) if d.is_dir() else []

    @cached_property
    def session_ids(self) -> list[str]:
        d = self.root / "sessions"
        return sorted(p.name for p in d.iterdir() if p.is_dir()) if d.is_dir() else []

    def building(self, building_id: str) -> Building:
        cache = self.__dict__.setdefault("_buildings", {})
        if building_id not in cache:
            if building_id not in self.building_ids:
                raise DatasetError(error(self.root / "buildings", "missing-building",
                                         f"no building {building_id!r}; buildings are {self.building_ids}"))
            cache[building_id] = Building.load(self.root / "buildings" / building_id)
        return cache[building_id]

    def session(self, session_id: str) -> Session:
        root = self.root / "sessions" / session_id
        ypath = root / "session.yaml"
        meta, issues = load_yaml(ypath)
        if meta is None:
            raise_or_log(issues)
        known = {b: None for b in self.building_ids}
        issues += check_session_meta(ypath, meta, known)
        issues += check_session_files(root, meta)
        raise_or_log(issues)
        b = self.building(str(meta["building"]))
        issues += check_session_meta(ypath, meta, {b.id: b})
        raise_or_log(issues)
        return Session(id=session_id, root=root, meta=meta, building=b)

    def sessions(self, ids: list[str] | None = None, labelled: bool | None = None):
        """Iterate sessions (all, or ``ids``), optionally only (un)labelled ones. Unknown ids are a
        ValueError naming them (before any session is read)."""
        unknown = [i for i in ids or [] if i not in self.session_ids]
        if unknown:
            raise ValueError(f"sessions {unknown} are not in {self.root}")
        for sid in ids or self.session_ids:
            s = self.session(sid)
            if labelled is None or s.labelled == labelled:
                yield s
