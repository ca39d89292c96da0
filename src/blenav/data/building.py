"""Buildings: floors as occupancy grids, radio anchors, rooms and navigation graph.

Frames and units (docs/dataset-format.md): world frame x east, y north, z up, metres, one origin per
building. A floor image follows ROS map_server: ``resolution`` m/pixel, ``origin`` the world (x, y) of
the lower-left corner of the lower-left pixel. Image row 0 is the *top* row (largest y).

Occupancy values (:attr:`Floor.occupancy`, int8, shape (H, W), image row order):
``FREE = 0``, ``OCCUPIED = 1``, ``UNKNOWN = -1``.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from functools import cached_property
from pathlib import Path

import numpy as np
import pandas as pd
import yaml
from PIL import Image
from shapely.geometry import LineString, MultiLineString, MultiPolygon, Polygon, shape

from .issues import Issue, error, raise_or_log, warning
from .schema import (
    ANCHOR_COLUMNS,
    ANCHOR_KINDS,
    ANCHOR_POSITION_COLUMNS,
    DEFAULT_FREE_THRESH,
    DEFAULT_OCCUPIED_THRESH,
    FLOOR_KEYS,
    PLAUSIBLE,
)
from .tables import read_table, read_text

FREE, OCCUPIED, UNKNOWN = 0, 1, -1

#: An anchor further than max(ANCHOR_OFF_FLOOR_MIN_M, ANCHOR_OFF_FLOOR_FRAC x the plan's larger side) outside
#: its floor's plan is an error: the plan's resolution (or origin) disagrees with the anchors' positions.
ANCHOR_OFF_FLOOR_MIN_M = 5.0
ANCHOR_OFF_FLOOR_FRAC = 0.5
#: At least this many anchors on a floor spanning less than ANCHOR_SPAN_MIN_FRAC of its plan in both x and y
#: is a warning (a resolution too large, e.g. cm/pixel written as m/pixel).
ANCHOR_SPAN_MIN_COUNT = 3
ANCHOR_SPAN_MIN_FRAC = 0.1
#: A floor plan (image size x resolution) larger than this on a side is an error: no building floor is; the
#: resolution is in cm or mm per pixel, not m (and maps of such a size would not fit in memory).
FLOOR_MAX_SIDE_M = 2000.0


def load_yaml(path: Path) -> tuple[dict | None, list[Issue]]:
    """Parse a YAML mapping; syntax errors name the line. UTF-8 only (a byte-order mark is fine). Like a CSV file,
    a YAML file whose last byte is not a line end is refused ('truncated'): its last value may have been cut and
    still parse, to another value (``free_thresh: 0.19`` from ``0.196``)."""
    if not path.is_file():
        return None, [error(path, "missing-file", "file does not exist")]
    text, issues = read_text(path)
    if text is None:
        return None, issues
    if text and not text.endswith(("\n", "\r")):
        return None, [error(path, "truncated", "the file does not end with a newline, so its last line may be cut "
                            "short (a number missing digits): add a newline at the end if the line is complete, or "
                            "fix the line", line=len(text.splitlines()))]
    try:
        doc = yaml.safe_load(text)
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        line = mark.line + 1 if mark is not None else None
        return None, [error(path, "yaml-syntax", str(getattr(exc, "problem", exc)), line=line)]
    except RecursionError:  # '[[[[...' thousands deep: Python's parser gives up, so do we, in one line
        return None, [error(path, "yaml-syntax", "nested too deeply to read (thousands of [ or { levels)")]
    if not isinstance(doc, dict):
        return None, [error(path, "yaml-not-mapping", "top level must be a mapping of keys to values")]
    if _yaml_nodes_exceed(doc, YAML_MAX_NODES):
        return None, [error(path, "yaml-size", f"the document expands to more than {YAML_MAX_NODES} values (YAML "
                            "aliases repeating aliases?): no dataset file is that large")]
    return doc, []


#: A YAML document that expands to more values than this is refused ('yaml-size'): a few lines of aliases of
#: aliases expand to billions (a 'billion laughs'), and printing one value of it would never end.
YAML_MAX_NODES = 1_000_000


def _yaml_nodes_exceed(doc, budget: int) -> bool:
    """Whether ``doc``, with its aliases expanded, has more than ``budget`` values (stops counting there)."""
    stack, n = [doc], 0
    while stack:
        x = stack.pop()
        n += 1
        if n > budget:
            return True
        if isinstance(x, dict):
            stack.extend(x.keys())
            stack.extend(x.values())
        elif isinstance(x, (list, tuple)):
            stack.extend(x)
    return False


@dataclass
class Floor:
    """One floor: an occupancy grid with world<->pixel transforms.

    ``origin`` is (x, y) in metres of the lower-left image corner; ``z`` the floor height in metres.
    """

    id: int | str
    image_path: Path
    resolution: float
    origin: tuple[float, float]
    z: float = 0.0
    occupied_thresh: float = DEFAULT_OCCUPIED_THRESH
    free_thresh: float = DEFAULT_FREE_THRESH
    negate: bool = False

    @cached_property
    def image(self) -> np.ndarray:
        """8-bit grayscale pixels, shape (H, W), row 0 at the top."""
        with Image.open(self.image_path) as im:
            if im.mode != "L":
                im = im.convert("L")
            return np.asarray(im, dtype=np.uint8)

    @cached_property
    def occupancy(self) -> np.ndarray:
        """int8 (H, W): FREE 0, OCCUPIED 1, UNKNOWN -1 by ROS map_server thresholds."""
        v = self.image.astype(np.float32) / 255.0
        dark = v if self.negate else 1.0 - v
        occ = np.full(dark.shape, UNKNOWN, dtype=np.int8)
        occ[dark > self.occupied_thresh] = OCCUPIED
        occ[dark < self.free_thresh] = FREE
        return occ

    @property
    def shape(self) -> tuple[int, int]:
        return self.occupancy.shape

    @property
    def extent(self) -> tuple[float, float, float, float]:
        """(xmin, xmax, ymin, ymax) of the image in world metres."""
        h, w = self.shape
        x0, y0 = self.origin
        return x0, x0 + w * self.resolution, y0, y0 + h * self.resolution

    @property
    def free_mask(self) -> np.ndarray:
        return self.occupancy == FREE

    def world_to_pixel(self, xy: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """World (..., 2) metres -> integer (row, col) of the containing pixel (may be out of range)."""
        xy = np.asarray(xy, dtype=float)
        h, _ = self.shape
        col = np.floor((xy[..., 0] - self.origin[0]) / self.resolution).astype(np.int64)
        row = (h - 1) - np.floor((xy[..., 1] - self.origin[1]) / self.resolution).astype(np.int64)
        return row, col

    def pixel_to_world(self, row: np.ndarray, col: np.ndarray) -> np.ndarray:
        """Pixel centres -> world (..., 2) metres."""
        h, _ = self.shape
        x = self.origin[0] + (np.asarray(col, dtype=float) + 0.5) * self.resolution
        y = self.origin[1] + (h - 1 - np.asarray(row, dtype=float) + 0.5) * self.resolution
        return np.stack([x, y], axis=-1)

    def lookup(self, xy: np.ndarray, outside: int = UNKNOWN) -> np.ndarray:
        """Occupancy value at world points (...,2); ``outside`` for points off the image."""
        row, col = self.world_to_pixel(xy)
        h, w = self.shape
        inside = (row >= 0) & (row < h) & (col >= 0) & (col < w)
        out = np.full(row.shape, outside, dtype=np.int8)
        out[inside] = self.occupancy[row[inside], col[inside]]
        return out

    def is_free(self, xy: np.ndarray) -> np.ndarray:
        """Boolean (...) whether each world point lies in a free pixel."""
        return self.lookup(xy) == FREE

    def free_points(self) -> np.ndarray:
        """World coordinates (N, 2) of the centres of all free pixels."""
        r, c = np.nonzero(self.free_mask)
        return self.pixel_to_world(r, c)


@dataclass
class Region:
    """A room polygon or a navigation route, with its ``id`` and ``floor`` (GeoJSON properties)."""

    id: str
    floor: int | str
    geometry: Polygon | MultiPolygon | LineString | MultiLineString
    properties: dict = field(default_factory=dict)


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
        key = _floor_key(floor_id, self.floors)
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


def _floor_key(floor_id, floors: dict):
    for k in floors:
        if str(k) == str(floor_id):
            return k
    return None


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
        fl, fi = _parse_floor(root, ypath, i, f, check_images)
        issues += fi
        if fl is not None:
            if _floor_key(fl.id, floors) is not None:
                issues.append(error(ypath, "floor-duplicate", f"floor id {fl.id!r} appears twice", where=f"floors[{i}]"))
            floors[fl.id] = fl

    # anchors and features are checked against every floor *declared* in building.yaml, so that one broken
    # floor (e.g. an unreadable image) is reported once, not again for every anchor and room on it
    declared = {**{f["id"]: None for f in raw_floors if isinstance(f, dict) and "id" in f}, **floors}
    anchors, ai = _load_anchors(root / "anchors.csv", declared)
    issues += ai
    if check_images and not any(i.is_error for i in ai):
        issues += check_anchors_on_floors(root / "anchors.csv", anchors, floors)
    rooms, ri = _load_geojson(root / "rooms.geojson", declared, ("Polygon", "MultiPolygon"), check_images)
    issues += ri
    routes, ni = _load_geojson(root / "navgraph.geojson", declared, ("LineString", "MultiLineString"), check_images)
    issues += ni
    b = Building(id=root.name, root=root, name=str(doc.get("name", root.name)), floors=floors,
                 anchors=anchors, rooms=rooms, navgraph=routes, meta=doc)
    return b, issues


def _parse_floor(root: Path, ypath: Path, i: int, f, check_images: bool) -> tuple[Floor | None, list[Issue]]:
    where = f"floors[{i}]"
    if not isinstance(f, dict):
        return None, [error(ypath, "floor", "each floor must be a mapping", where=where)]
    missing = [k for k in FLOOR_KEYS if k not in f]
    if missing:
        return None, [error(ypath, "floor-keys", f"floor lacks key(s) {', '.join(missing)}", where=where)]
    issues: list[Issue] = []
    try:
        res = float(f["resolution"])
        origin = [float(v) for v in f["origin"]]
        occ = float(f.get("occupied_thresh", DEFAULT_OCCUPIED_THRESH))
        free = float(f.get("free_thresh", DEFAULT_FREE_THRESH))
        z = float(f.get("z", 0.0) or 0.0)
    except (TypeError, ValueError) as exc:
        return None, [error(ypath, "floor-value", f"resolution, origin, z and thresholds must be numbers ({exc})",
                            where=where)]
    if not np.isfinite(res) or res <= 0:
        issues.append(error(ypath, "floor-resolution", f"resolution must be > 0 m/pixel, got {res}", where=where))
    if len(origin) < 2 or not np.all(np.isfinite(origin)):
        issues.append(error(ypath, "floor-origin", "origin must be [x, y] or [x, y, yaw] in metres", where=where))
    elif len(origin) > 2 and origin[2] != 0:
        issues.append(warning(ypath, "floor-origin-yaw", f"origin yaw {origin[2]} is ignored (as most ROS tools do)",
                              where=where))
    if not (0 <= free < occ <= 1):
        issues.append(error(ypath, "floor-thresholds",
                            f"need 0 <= free_thresh ({free}) < occupied_thresh ({occ}) <= 1", where=where))
    img = root / str(f["image"])
    if not img.is_file():
        issues.append(error(img, "missing-file", f"floor image named in {ypath.name} {where} does not exist"))
    elif check_images:
        issues += _check_image(img)
    if any(i.is_error for i in issues):
        return None, issues
    fl = Floor(id=f["id"], image_path=img, resolution=res, origin=(origin[0], origin[1]), z=z,
               occupied_thresh=occ, free_thresh=free, negate=bool(f.get("negate", False)))
    if check_images:
        issues += check_floor_size(ypath, fl, where) or check_free_space(ypath, fl, where)
        if any(i.is_error for i in issues):
            return None, issues
    return fl, issues


def check_free_space(ypath: Path, floor: Floor, where: str) -> list[Issue]:
    """A floor whose image has no FREE pixel under its thresholds is an error: nothing can be localized on it."""
    if floor.free_mask.any():
        return []
    h, w = floor.shape
    return [error(ypath, "floor-no-free-space",
                  f"building '{ypath.parent.name}' floor {floor.id!r} has no free space: no pixel of "
                  f"{floor.image_path.name} ({w}x{h}) is free (darkness below free_thresh {floor.free_thresh:g}"
                  f"{', negate: 1' if floor.negate else ''}): an all-black or "
                  "all-unknown image, an inverted one (negate), or wrong thresholds", where=where)]


def check_floor_size(ypath: Path, floor: Floor, where: str) -> list[Issue]:
    """A floor plan larger than :data:`FLOOR_MAX_SIDE_M` on a side is an error (its resolution is not in m/pixel)."""
    x0, x1, y0, y1 = floor.extent
    side = max(x1 - x0, y1 - y0)
    if side <= FLOOR_MAX_SIDE_M:
        return []
    h, w = floor.shape
    return [error(ypath, "floor-size", f"building '{ypath.parent.name}' floor {floor.id!r}: {w}x{h} px at resolution "
                  f"{floor.resolution:g} m/pixel is a plan of {x1 - x0:g} x {y1 - y0:g} m, larger than any floor "
                  f"({FLOOR_MAX_SIDE_M:g} m): is the resolution in metres per pixel (not cm or mm)?", where=where)]


def check_anchors_on_floors(path: Path, anchors: pd.DataFrame, floors: dict) -> list[Issue]:
    """Anchors against their floor's plan (image size x resolution from the origin): an anchor far outside it
    is an error at its line (the plan's scale or origin, or the anchor's position, is wrong); anchors that
    span a tiny part of a large plan are a warning (a resolution too large)."""
    issues: list[Issue] = []
    if len(anchors) == 0 or not floors:
        return issues
    xy = anchors[["x", "y"]].to_numpy(dtype=float)
    z = anchors["z"].to_numpy(dtype=float)
    fl_col = anchors["floor"].astype(str).str.strip().to_numpy()
    for key, floor in floors.items():
        on = np.flatnonzero((fl_col == str(key)) & np.isfinite(xy).all(axis=1) & np.isfinite(z))
        if not len(on):
            continue
        x0, x1, y0, y1 = floor.extent
        h, w = floor.shape
        plan = (f"floor {floor.id!r}'s plan x {x0:.1f}..{x1:.1f}, y {y0:.1f}..{y1:.1f} m ({w}x{h} px at "
                f"{floor.resolution:g} m/px)")
        margin = max(ANCHOR_OFF_FLOOR_MIN_M, ANCHOR_OFF_FLOOR_FRAC * max(x1 - x0, y1 - y0))
        p = xy[on]
        dist = np.maximum.reduce([x0 - p[:, 0], p[:, 0] - x1, y0 - p[:, 1], p[:, 1] - y1, np.zeros(len(p))])
        dz = z[on] - floor.z  # the same margin above or below the floor's height
        far = np.flatnonzero((dist > margin) | (np.abs(dz) > margin))
        for k in far[:20]:
            r = int(on[k])
            where = (f"at ({p[k, 0]:g}, {p[k, 1]:g}) m lies {dist[k]:.1f} m outside {plan}: is the floor's resolution "
                     "(m/pixel) or origin in building.yaml right, or the anchor's position?" if dist[k] > margin else
                     f"at z {z[on][k]:g} m lies {abs(dz[k]):g} m {'above' if dz[k] > 0 else 'below'} floor "
                     f"{floor.id!r} (z {floor.z:g} m): is its z in metres, in the building's frame?")
            issues.append(error(path, "anchor-off-floor", f"anchor {anchors['anchor_id'].iloc[r]!r} {where}",
                                line=r + 2))
        if len(far) > 20:
            issues.append(error(path, "anchor-off-floor", f"{len(far) - 20} more anchors outside {plan}"))
        if not len(far) and len(on) >= ANCHOR_SPAN_MIN_COUNT:
            span = p.max(axis=0) - p.min(axis=0)
            if span[0] < ANCHOR_SPAN_MIN_FRAC * (x1 - x0) and span[1] < ANCHOR_SPAN_MIN_FRAC * (y1 - y0):
                issues.append(warning(path, "anchor-span",
                                      f"the {len(on)} anchors of floor {floor.id!r} span only {span[0]:.1f} x "
                                      f"{span[1]:.1f} m of {plan}: is the resolution (m/pixel) right?"))
    return issues


def _check_image(img: Path) -> list[Issue]:
    try:
        with Image.open(img) as im:
            mode = im.mode
            im.load()  # decode fully: verify() does not detect a truncated PGM
    except Exception as exc:  # PIL raises many types for broken files
        return [error(img, "image-unreadable", f"not a readable PNG/PGM image ({exc})")]
    if mode == "L":
        return []
    if mode in ("1", "P", "RGB", "RGBA", "LA"):
        return [warning(img, "image-not-grayscale", f"image mode {mode} is converted to 8-bit grayscale")]
    return [error(img, "image-mode", f"image mode {mode} is not 8-bit grayscale")]


def _load_anchors(path: Path, floors: dict) -> tuple[pd.DataFrame, list[Issue]]:
    empty = pd.DataFrame({c: pd.Series(dtype=float if c in ("x", "y", "z", "tx_power_dbm") else str)
                          for c in ANCHOR_COLUMNS})
    if not path.is_file():
        return empty, []
    # x, y, z may be empty together (the position is unknown); one or two of them empty is an error
    df, issues = read_table(path, ("anchor_id", "kind", "floor"), ANCHOR_POSITION_COLUMNS + ("tx_power_dbm",
                            "channel_model"), string=("anchor_id", "kind", "floor", "channel_model"), time_column=None)
    if df is None:
        return empty, issues
    pos = df[list(ANCHOR_POSITION_COLUMNS)].to_numpy(dtype=float)
    partial = np.isnan(pos).any(axis=1) & ~np.isnan(pos).all(axis=1)
    partial[[i.line - 2 for i in issues if i.is_error and i.line is not None and 2 <= i.line < len(df) + 2]] = False
    for r in np.flatnonzero(partial)[:20]:
        c = ANCHOR_POSITION_COLUMNS[int(np.argmax(np.isnan(pos[r])))]
        issues.append(error(path, "non-finite", f"column '{c}' is NaN/empty but not all of x, y, z are: a position "
                            "is known (all three finite) or unknown (all three empty)", line=int(r) + 2))
    df["anchor_id"] = df["anchor_id"].astype(str).str.strip()
    kinds = df["kind"].astype(str).str.strip()
    for r in np.flatnonzero(~kinds.isin(ANCHOR_KINDS).to_numpy())[:20]:
        issues.append(error(path, "anchor-kind", f"kind {df['kind'].iloc[r]!r} is not one of {ANCHOR_KINDS}",
                            line=int(r) + 2))
    df["kind"] = kinds
    issues += _anchor_ranges(path, df)
    dup = df["anchor_id"].duplicated(keep="first").to_numpy()
    for r in np.flatnonzero(dup)[:20]:
        issues.append(error(path, "anchor-unique", f"anchor_id {df['anchor_id'].iloc[r]!r} appears twice",
                            line=int(r) + 2))
    if floors:
        known = {str(k) for k in floors}
        fl = df["floor"].astype(str).str.strip()
        # floors written as 0.0 by float formatting still name floor 0
        fl = fl.str.replace(r"^(-?\d+)\.0$", r"\1", regex=True)
        df["floor"] = fl
        for r in np.flatnonzero(~fl.isin(known).to_numpy())[:20]:
            issues.append(error(path, "anchor-floor", f"floor {fl.iloc[r]!r} is not a floor of building.yaml "
                                f"({sorted(known)})", line=int(r) + 2))
    return df.reset_index(drop=True), issues


def _anchor_ranges(path: Path, df: pd.DataFrame) -> list[Issue]:
    """Values of anchors.csv outside their plausible range (:data:`blenav.data.schema.PLAUSIBLE`); empty cells pass."""
    issues: list[Issue] = []
    for (stream, c), p in PLAUSIBLE.items():
        if stream != "anchors" or c not in df:
            continue
        v = df[c].to_numpy(dtype=float)
        for r in np.flatnonzero(p.outside(v))[:20]:
            issues.append(error(path, p.rule, f"{c} {v[r]:g} {p.unit} is outside {p.describe()}: {p.hint}",
                                line=int(r) + 2))
    return issues


def _load_geojson(path: Path, floors: dict, kinds: tuple[str, ...], check_plan: bool = False
                  ) -> tuple[list[Region], list[Issue]]:
    if not path.is_file():
        return [], []
    text, issues = read_text(path)  # a byte-order mark is not JSON, but is no reason to refuse a file
    if text is None:
        return [], issues
    if not text.strip():
        return [], []
    try:
        doc = json.loads(text)
    except json.JSONDecodeError as exc:
        return [], [error(path, "json-syntax", exc.msg, line=exc.lineno)]
    except RecursionError:
        return [], [error(path, "json-syntax", "nested too deeply to read (thousands of [ or { levels)")]
    if not isinstance(doc, dict) or doc.get("type") != "FeatureCollection":
        return [], [error(path, "geojson-type", "top level must be a GeoJSON FeatureCollection")]
    out: list[Region] = []
    issues: list[Issue] = []
    known = {str(k) for k in floors}
    feats = doc.get("features") or []
    if not isinstance(feats, list):
        return [], [error(path, "geojson-type", "'features' must be a list of GeoJSON Features")]
    for i, feat in enumerate(feats):
        where = f"features[{i}]"
        if not isinstance(feat, dict):
            issues.append(error(path, "geojson-type", "feature must be a GeoJSON Feature object", where=where))
            continue
        props = feat.get("properties") or {}
        geom = feat.get("geometry") or {}
        if not isinstance(props, dict) or "id" not in props or "floor" not in props:
            issues.append(error(path, "geojson-properties", "feature needs properties.id and properties.floor",
                                where=where))
            continue
        if not isinstance(geom, dict) or geom.get("type") not in kinds:
            gtype = geom.get("type") if isinstance(geom, dict) else geom
            issues.append(error(path, "geojson-geometry", f"geometry type {gtype!r} is not one of {kinds}",
                                where=where))
            continue
        try:
            with np.errstate(invalid="ignore"):  # NaN coordinates: reported below, not as a numpy warning
                g = shape(geom)
        except Exception as exc:  # shapely raises several types for malformed coordinates
            issues.append(error(path, "geojson-coordinates", f"malformed coordinates ({exc})", where=where))
            continue
        if g.is_empty:
            issues.append(error(path, "geojson-coordinates", "empty geometry", where=where))
            continue
        bad = _geometry_problem(g)
        if bad:
            issues.append(error(path, "geojson-coordinates", bad, where=where))
            continue
        if known and str(props["floor"]) not in known:
            issues.append(error(path, "geojson-floor", f"floor {props['floor']!r} is not a floor of building.yaml",
                                where=where))
            continue
        fl = floors.get(_floor_key(props["floor"], floors)) if check_plan else None
        if isinstance(fl, Floor):
            issues += _region_off_floor(path, where, g, fl)
        out.append(Region(id=str(props["id"]), floor=props["floor"], geometry=g, properties=props))
    return out, issues


def _geometry_problem(g) -> str | None:
    """Why a room or route cannot be used (coordinates not finite, a polygon that is not valid, a route of no
    length), or None. Python's json reads NaN and Infinity; GEOS and the map methods cannot use them."""
    import shapely

    if not np.isfinite(shapely.get_coordinates(g)).all():
        return "a coordinate is not a finite number (NaN or Infinity)"
    if g.geom_type in ("Polygon", "MultiPolygon") and not g.is_valid:
        return f"not a valid polygon ({shapely.is_valid_reason(g)}): a room is a simple ring of positive area"
    if g.geom_type in ("LineString", "MultiLineString") and g.length <= 0:
        return "a route of length zero"
    return None


def _region_off_floor(path: Path, where: str, g, floor: Floor) -> list[Issue]:
    """A room or route further outside its floor's plan than an anchor may be (``anchor-off-floor``'s margin)."""
    x0, x1, y0, y1 = floor.extent
    bx0, by0, bx1, by1 = g.bounds
    margin = max(ANCHOR_OFF_FLOOR_MIN_M, ANCHOR_OFF_FLOOR_FRAC * max(x1 - x0, y1 - y0))
    dist = max(x0 - bx0, bx1 - x1, y0 - by0, by1 - y1, 0.0)
    if dist <= margin:
        return []
    return [error(path, "geojson-off-floor", f"reaches {dist:.1f} m outside floor {floor.id!r}'s plan (x {x0:.1f}.."
                  f"{x1:.1f}, y {y0:.1f}..{y1:.1f} m): are its coordinates in the building's metres, and the floor's "
                  "resolution and origin right?", where=where)]
