"""ILC 2.0 floor plans: floor_info.json and geojson_map.json -> the floor's units in metres of the upstream floor
frame and its occupancy raster."""

from __future__ import annotations

import json
import math
import re
from dataclasses import dataclass

import numpy as np
import shapely
from PIL import Image, ImageDraw
from shapely.geometry import MultiPolygon, Polygon, shape

from blenav.data import FREE, OCCUPIED, UNKNOWN
from blenav.errors import ImportError_

from .. import ImportReport

RESOLUTION_M = 0.1
#: metres per degree of latitude, and of longitude at the equator (WGS84 mean values, for the scale check only)
M_PER_DEG_LAT = 110_574.0
M_PER_DEG_LON = 111_320.0


def floor_level(name: str, floor_num) -> int:
    m = re.fullmatch(r"(?:F|L)(\d+)|(\d+)F", name, flags=re.I)
    if m:
        return int(m.group(1) or m.group(2)) - 1
    m = re.fullmatch(r"B(\d+)|(\d+)B", name, flags=re.I)
    if m:
        return -int(m.group(1) or m.group(2))
    try:
        return int(floor_num) - 1
    except (TypeError, ValueError):
        return 0


def _json(display: str, data: bytes):
    try:
        return json.loads(data.decode("utf-8-sig"))
    except UnicodeDecodeError as exc:
        raise ImportError_(display, data[: exc.start].count(b"\n") + 1, f"not UTF-8 text ({exc.reason})") from None
    except json.JSONDecodeError as exc:
        raise ImportError_(display, exc.lineno, f"not valid JSON ({exc.msg})") from None
    except RecursionError:
        raise ImportError_(display, None, "JSON nested too deeply") from None


@dataclass
class Plan:
    occupancy: np.ndarray
    outline: shapely.Geometry
    units: list                     # (id, name, geometry in metres)
    width: float
    height: float
    lonlat_box: tuple[float, float, float, float]
    scale_ratio: tuple[float, float]
    floor_num: object


def _polygons(g) -> list[Polygon]:
    if isinstance(g, Polygon):
        return [g]
    if isinstance(g, MultiPolygon):
        return list(g.geoms)
    if hasattr(g, "geoms"):
        return [p for x in g.geoms for p in _polygons(x)]
    return []


def read_plan(info_display: str, info_data: bytes, geo_display: str, geo_data: bytes, floor: str,
              report: ImportReport) -> Plan:
    """The floor plan of one floor from its floor_info.json (size in m) and geojson_map.json (outline and
    unit polygons in longitude/latitude): units in metres of the upstream floor frame and the occupancy
    raster at RESOLUTION_M m/px."""
    width, height = _plan_size(info_display, info_data)
    geoms, props, k = _plan_features(geo_display, geo_data)
    outline_ll = geoms[k]
    lon0, lat0, lon1, lat1 = outline_ll.bounds
    if not (lon1 > lon0 and lat1 > lat0):
        raise ImportError_(geo_display, None, f"features[{k}]: the floor outline has an empty bounding box")

    def to_m(g):
        return shapely.transform(g, lambda c: np.column_stack([(c[:, 0] - lon0) / (lon1 - lon0) * width,
                                                               (c[:, 1] - lat0) / (lat1 - lat0) * height]))

    outline = shapely.make_valid(to_m(outline_ll))
    lat_mid = math.radians((lat0 + lat1) / 2)
    scale = (width / ((lon1 - lon0) * M_PER_DEG_LON * math.cos(lat_mid)), height / ((lat1 - lat0) * M_PER_DEG_LAT))
    units = _plan_units(geoms, props, k, to_m, floor, report)
    occ = _plan_occupancy(outline, units, width, height)
    return Plan(occ, outline, units, width, height, (lon0, lat0, lon1, lat1), scale,
                props[k].get("floor_num"))


def _plan_size(info_display: str, info_data: bytes) -> tuple[float, float]:
    """(width, height) m of a floor from floor_info.json ``map_info``, each in (0, 2000]."""
    info = _json(info_display, info_data)
    try:
        width = float(info["map_info"]["width"])
        height = float(info["map_info"]["height"])
    except (KeyError, TypeError, ValueError):
        raise ImportError_(info_display, None, "expected {'map_info': {'width': metres, 'height': metres}}") from None
    if not (math.isfinite(width) and math.isfinite(height) and 0 < width <= 2000 and 0 < height <= 2000):
        raise ImportError_(info_display, None, f"map_info width {width:g} x height {height:g} m is not a floor size")
    return width, height


def _plan_features(geo_display: str, geo_data: bytes) -> tuple[list, list[dict], int]:
    """(geometries (F,) in longitude/latitude, properties (F,), index of the floor outline: the first feature of
    type "floor", else 0) of a geojson_map.json FeatureCollection; every coordinate finite."""
    doc = _json(geo_display, geo_data)
    feats = doc.get("features") if isinstance(doc, dict) else None
    if not isinstance(feats, list) or not feats:
        raise ImportError_(geo_display, None, "expected a GeoJSON FeatureCollection with the floor outline first")
    geoms = []
    for i, f in enumerate(feats):
        try:
            g = shape(f["geometry"])
        except Exception as exc:  # shapely raises several types for malformed coordinates
            raise ImportError_(geo_display, None, f"features[{i}]: malformed geometry ({exc})") from None
        if not np.isfinite(shapely.get_coordinates(g)).all():
            raise ImportError_(geo_display, None, f"features[{i}]: a coordinate is not a finite number")
        geoms.append(g)
    props = [f.get("properties") or {} for f in feats]
    k = next((i for i, p in enumerate(props) if p.get("type") == "floor"), 0)
    return geoms, props, k


def _plan_units(geoms: list, props: list[dict], k: int, to_m, floor: str, report: ImportReport) -> list:
    """The unit polygons (id, name, geometry in m) of a floor: every feature but the outline ``k``, mapped by
    ``to_m`` (longitude/latitude -> m), repaired when invalid; non-polygons and empty ones dropped (counted in
    ``report``). Ids are the features' ``id`` (else ``<floor>-unit<i>``), made unique with trailing '_'."""
    units, used_ids = [], set()
    for i, (g, p) in enumerate(zip(geoms, props)):
        if i == k:
            continue
        polys = _polygons(g)
        if not polys:
            report.drop(f"GeoJSON features that are not polygons (floor {floor})")
            continue
        gm = to_m(g)
        if not gm.is_valid:
            gm = shapely.make_valid(gm)
            report.drop(f"unit polygons repaired with make_valid (floor {floor})")
            parts = _polygons(gm)
            gm = parts[0] if len(parts) == 1 else MultiPolygon(parts) if parts else None
        if gm is None or gm.is_empty or gm.area <= 0:
            report.drop(f"empty unit polygons (floor {floor})")
            continue
        uid = str(p.get("id") or f"{floor}-unit{i}")
        while uid in used_ids:
            uid += "_"
        used_ids.add(uid)
        units.append((uid, str(p.get("name") or p.get("display") or ""), gm))
    return units


def _plan_occupancy(outline, units: list, width: float, height: float) -> np.ndarray:
    """Occupancy (H, W) int8 at RESOLUTION_M m/px (row 0 at the top) of a ``width`` x ``height`` m floor:
    FREE inside the outline (m) and outside every unit, UNKNOWN inside a unit, OCCUPIED outside the outline."""
    # rasterise: pixel centre (col + 0.5, row + 0.5) in PIL coordinates -> integer PIL coordinates
    w_px, h_px = int(math.ceil(width / RESOLUTION_M - 1e-9)), int(math.ceil(height / RESOLUTION_M - 1e-9))
    inside = _raster(_polygons(outline), True, w_px, h_px)
    in_unit = _raster([p for _, _, g in units for p in _polygons(g)], False, w_px, h_px)
    return np.where(inside, np.where(in_unit, UNKNOWN, FREE), OCCUPIED).astype(np.int8)


def _ring_px(ring, h_px: int) -> list[tuple[float, float]]:
    """A ring's vertices (m) as PIL pixel coordinates (x right, y down) of an image ``h_px`` pixels high."""
    c = np.asarray(ring.coords)
    px = c[:, 0] / RESOLUTION_M - 0.5
    py = h_px - c[:, 1] / RESOLUTION_M - 0.5
    return list(zip(px.tolist(), py.tolist()))


def _raster(polys: list[Polygon], holes: bool, w_px: int, h_px: int) -> np.ndarray:
    """(h_px, w_px) bool: pixels inside one of ``polys`` (m), minus their interior rings when ``holes``."""
    im = Image.new("1", (w_px, h_px), 0)
    d = ImageDraw.Draw(im)
    for poly in polys:
        d.polygon(_ring_px(poly.exterior, h_px), fill=1)
        if holes:
            for r in poly.interiors:
                d.polygon(_ring_px(r, h_px), fill=0)
    return np.asarray(im, dtype=bool)
