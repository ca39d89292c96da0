"""The labelled sessions a training task reads from ``data.path`` and ``data.extra_paths`` (the map prior, the inertial
odometry), with the checks every task makes: an id of ``data.sessions`` that no dataset has is an error naming it, and
so is a session id (or, where the task needs it, a floor) found in two datasets."""

from __future__ import annotations

from blenav.data import Dataset


def labelled_sessions(paths: list[str], sessions: list | None, min_groundtruth: int = 2,
                      unique_floors: bool = False) -> list:
    """The labelled sessions of ``paths`` with at least ``min_groundtruth`` ground-truth rows (only the ids of
    ``sessions`` when given), in the datasets' order. ValueError for an unknown id of ``sessions``, a session id in two
    datasets, or (``unique_floors``) a building floor in two datasets."""
    keep = None if sessions is None else {str(i) for i in sessions}
    out, origin, floors, seen = [], {}, {}, set()
    for p in paths:
        ds = Dataset.open(p)
        seen |= set(ds.session_ids)
        for s in ds.sessions(labelled=True):
            if keep is not None and s.id not in keep:
                continue
            if len(s.groundtruth) < min_groundtruth:
                continue
            if s.id in origin:
                raise ValueError(f"session {s.id} is in both {origin[s.id]} and {p}: data.extra_paths must be "
                                 "datasets with distinct session ids")
            if unique_floors:
                key = (s.building.id, str(s.meta.get("floor")))
                if floors.setdefault(key, p) != p:
                    raise ValueError(f"floor {key[1]} of building {key[0]} is in both {floors[key]} and {p}: "
                                     "data.extra_paths must not repeat a floor")
            origin[s.id] = p
            out.append(s)
    unknown = sorted((keep or set()) - seen)
    if unknown:
        raise ValueError(f"data.sessions {unknown[:5]}{' ...' if len(unknown) > 5 else ''} ({len(unknown)}) are not "
                         f"sessions of {', '.join(paths)}")
    return out
