"""The files of a building folder, read and checked: the floors of building.yaml (their images, size and free
space), anchors.csv (columns, kinds, plausible values, positions on their floor's plan) and the rooms and routes
of rooms.geojson / navgraph.geojson. Each function returns what it read and the issues it found
(:mod:`blenav.data.issues`), never raising on bad input.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pandas as pd
from PIL import Image
from shapely.geometry import shape

from .floor import Floor, Region, floor_key
from .issues import Issue, error, warning
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

__all__ = ["parse_floor", "check_free_space", "check_floor_size", "check_anchors_on_floors", "load_anchors",
           "load_geojson", "FLOOR_MAX_SIDE_M"]

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


def parse_floor(root: Path, ypath: Path, i: int, f, check_images: bool) -> tuple[Floor | None, list[Issue]]:
    """Entry ``i`` (``f``) of building.yaml's floors as a :class:`Floor` (None when it has an error), with the
    issues of its keys, values and (``check_images``) image, size and free space."""
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


def load_anchors(path: Path, floors: dict) -> tuple[pd.DataFrame, list[Issue]]:
    """anchors.csv (the columns of :data:`blenav.data.schema.ANCHOR_COLUMNS`; empty when the file is absent) and
    the issues of its rows: missing positions, unknown kinds and floors, duplicate ids, implausible values."""
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


def load_geojson(path: Path, floors: dict, kinds: tuple[str, ...], check_plan: bool = False
                  ) -> tuple[list[Region], list[Issue]]:
    """The features of a GeoJSON FeatureCollection (rooms.geojson, navgraph.geojson; none when the file is absent)
    of geometry types ``kinds`` as :class:`Region` objects, and the issues of the rest; with ``check_plan`` also
    features reaching far outside their floor's plan."""
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
        fl = floors.get(floor_key(props["floor"], floors)) if check_plan else None
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
