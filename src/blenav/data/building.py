"""Buildings: floors as occupancy grids, radio anchors, rooms and navigation graph (:class:`Building`), read and
checked from a building folder (:func:`load_building`).

The floors, rooms and routes are :mod:`blenav.data.floor`'s (frames, units and occupancy values there); the
files are read and checked by :mod:`blenav.data.building_files`.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import pandas as pd

from .building_files import check_anchors_on_floors, load_anchors, load_geojson, parse_floor
from .floor import Floor, Region, floor_key
from .issues import Issue, error, raise_or_log
from .schema import ANCHOR_POSITION_COLUMNS
from .yaml_file import load_yaml

__all__ = ["Building", "AnchorPositionsUnknown", "load_building"]


class AnchorPositionsUnknown(ValueError):
    """A method needs anchor positions that the dataset does not give; the message is the reason to skip it."""


@dataclass
class Building:
    """A building folder: ``building.yaml``, floor images, anchors, rooms, navigation graph.

    ``anchors`` columns: anchor_id (str), kind ('ble'|'wifi_rtt'), x, y, z (m, prior map), floor,
    tx_power_dbm (dBm RSSI at 1 m, NaN when unknown), channel_model, plus any extra columns (a simulator
    writes ``x_true, y_true, z_true``).
    """

    id: str
    root: Path
    name: str
    floors: dict
    anchors: pd.DataFrame
    rooms: list[Region]
    navgraph: list[Region]
    meta: dict = field(default_factory=dict)

    def floor(self, floor_id) -> Floor:
        key = floor_key(floor_id, self.floors)
        if key is None:
            raise KeyError(f"building '{self.id}' has no floor {floor_id!r}; floors are {list(self.floors)}")
        return self.floors[key]

    def anchors_of(self, kind: str | None = None, floor=None) -> pd.DataFrame:
        a = self.anchors
        if kind is not None:
            a = a[a["kind"] == kind]
        if floor is not None:
            a = a[a["floor"].astype(str) == str(floor)]
        return a

    def anchors_without_position(self, kind: str | None = None) -> pd.DataFrame:
        """Anchors (of ``kind``) whose position is unknown: x, y, z empty in anchors.csv (e.g. an imported
        recording that names its beacons but not where they are; ``blenav-map`` estimates them)."""
        a = self.anchors_of(kind)
        return a[a[list(ANCHOR_POSITION_COLUMNS)].isna().all(axis=1).to_numpy()]

    def require_anchor_positions(self, kind: str = "ble", who: str = "this method") -> None:
        """Raise :class:`AnchorPositionsUnknown` (a ValueError whose message is the reason to skip) when no anchor of
        ``kind`` has a known position. Methods that need positions call this instead of running on NaN;
        anchors without a position among positioned ones are left to the caller (see anchors_without_position)."""
        a = self.anchors_of(kind)
        unknown = len(self.anchors_without_position(kind))
        if len(a) == 0 or unknown == len(a):
            raise AnchorPositionsUnknown(
                f"{who} needs {kind} anchor positions, but building {self.id!r} has "
                + (f"no {kind} anchors" if len(a) == 0 else f"none: its {len(a)} {kind} anchors have empty x, y, z in "
                   "anchors.csv (estimate them from labelled walks with blenav-map)"))

    def rooms_on(self, floor) -> list[Region]:
        return [r for r in self.rooms if str(r.floor) == str(floor)]

    def routes_on(self, floor) -> list[Region]:
        return [r for r in self.navgraph if str(r.floor) == str(floor)]

    @classmethod
    def load(cls, root: Path) -> "Building":
        """Read and check a building folder; raises :class:`DatasetError` on any violation."""
        b, issues = load_building(Path(root))
        raise_or_log(issues)
        return b


def load_building(root: Path, check_images: bool = True) -> tuple[Building | None, list[Issue]]:
    """Parse and check everything in a building folder, collecting every issue."""
    ypath = root / "building.yaml"
    doc, issues = load_yaml(ypath)
    if doc is None:
        return None, issues
    floors: dict = {}
    raw_floors = doc.get("floors")
    if not isinstance(raw_floors, list) or not raw_floors:
        issues.append(error(ypath, "floors", "'floors' must be a non-empty list of floors"))
        return None, issues
    for i, f in enumerate(raw_floors):
        fl, fi = parse_floor(root, ypath, i, f, check_images)
        issues += fi
        if fl is not None:
            if floor_key(fl.id, floors) is not None:
                issues.append(error(ypath, "floor-duplicate", f"floor id {fl.id!r} appears twice", where=f"floors[{i}]"))
            floors[fl.id] = fl

    # anchors and features are checked against every floor *declared* in building.yaml, so that one broken
    # floor (e.g. an unreadable image) is reported once, not again for every anchor and room on it
    declared = {**{f["id"]: None for f in raw_floors if isinstance(f, dict) and "id" in f}, **floors}
    anchors, ai = load_anchors(root / "anchors.csv", declared)
    issues += ai
    if check_images and not any(i.is_error for i in ai):
        issues += check_anchors_on_floors(root / "anchors.csv", anchors, floors)
    rooms, ri = load_geojson(root / "rooms.geojson", declared, ("Polygon", "MultiPolygon"), check_images)
    issues += ri
    routes, ni = load_geojson(root / "navgraph.geojson", declared, ("LineString", "MultiLineString"), check_images)
    issues += ni
    b = Building(id=root.name, root=root, name=str(doc.get("name", root.name)), floors=floors,
                 anchors=anchors, rooms=rooms, navgraph=routes, meta=doc)
    return b, issues
