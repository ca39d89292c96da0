"""The map of one floor for the particle filter: rooms, navigation edges and the occupancy grid.

Patel, Girgensohn and Biehl, "Fusing Map Information with a Probabilistic Sensor Model for Indoor
Localization using RF Beacons" (``/work/shared/papers/002_*``). :class:`MapGeometry` reads a floor's rooms
and routes (or derives what is missing from the occupancy grid: :mod:`.rooms`, :mod:`.routes`), keeps
the spatial indexes (:mod:`.index`) and the wall test (:mod:`.walls`), and answers the filter's map
queries. The map enters the filter in three places, all vectorised over particles (state arrays (R, N, D):
R runs, N particles; the first two state dims are world x, y in metres; randomness only from an explicit
``numpy.random.Generator``):

* initialisation (eq. 3, :mod:`.initial`: :meth:`MapGeometry.sample_initial`);
* conditioning of resampled particles (eqs. 4-5, :mod:`.conditioning`: :meth:`MapGeometry.condition`);
* walls (:attr:`MapGeometry.walls`, a :class:`~.walls.WallCrossing`).
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import shapely
from scipy import ndimage

from blenav.data.building import Building
from blenav.data.floor import Floor

from . import conditioning, initial
from .index import DEFAULT_INDEX, INDEX_KINDS, GridIndex, STRtreeIndex, SpatialIndex
from .rooms import ROOM_OPTIONS, derive_rooms
from .routes import ROUTE_OPTIONS, derive_routes
from .shapes import ShrunkRooms, polygons_of, segments_of, shrink_rooms
from .walls import WallCrossing


@dataclass(repr=False, eq=False)
class MapGeometry:
    """Rooms and navigation edges of one floor, with the floor's occupancy grid.

    ``rooms``: list of shapely Polygons (MultiPolygons exploded); ``segments``: (E, 2, 2) array of
    2-point navigation segments (world metres). ``derived`` says which of the two were derived from the
    occupancy grid; ``notes`` records in words what was read, derived, repaired or is missing.

    Use with :class:`blenav.filters.engine.ParticleFilter`: the object is an ``initializer``
    (:meth:`sample`, :meth:`snap_free`), a ``conditioner`` (:meth:`condition`) and ``walls``
    (:attr:`walls`, a :class:`WallCrossing`).
    """

    floor: Floor
    rooms: list
    segments: np.ndarray
    building_id: str = ""
    floor_id: object = None
    room_ids: list = field(default_factory=list)
    derived: dict = field(default_factory=lambda: {"rooms": False, "routes": False})
    notes: list = field(default_factory=list)
    index: str = DEFAULT_INDEX

    def __post_init__(self):
        if self.index not in INDEX_KINDS:
            raise ValueError(f"index must be one of {INDEX_KINDS}, got {self.index!r}")
        self.segments = np.asarray(self.segments, dtype=float).reshape(-1, 2, 2)
        ids = list(self.room_ids) if len(self.room_ids) == len(self.rooms) else [f"room{i}" for i in
                                                                                range(len(self.rooms))]
        rooms, room_ids = [], []
        for rid, g in zip(ids, self.rooms):  # explode MultiPolygons, drop empty parts
            parts = [p for p in polygons_of(g) if p.area > 0]
            rooms += parts
            room_ids += [rid] if len(parts) == 1 else [f"{rid}#{j}" for j in range(len(parts))]
        self.rooms, self.room_ids = rooms, room_ids
        self._rooms_arr = np.empty(len(self.rooms), dtype=object)
        self._rooms_arr[:] = self.rooms
        shapely.prepare(self._rooms_arr)
        self._indexes: dict = {}
        self._shrunk: dict = {}
        self._nearest_free = None
        self._bbox = None
        self.walls = WallCrossing.from_floor(self.floor)

    # ------------------------------------------------------------------ construction
    @classmethod
    def from_building(cls, building: Building | str | Path, floor_id, derive_missing: bool = True,
                      index: str = DEFAULT_INDEX, **derive_kw) -> "MapGeometry":
        """Rooms and routes of ``floor_id`` from ``rooms.geojson`` / ``navgraph.geojson``; what is missing
        is derived from the occupancy grid when ``derive_missing`` (see :func:`derive_routes`,
        :func:`derive_rooms`; ``derive_kw`` are passed on). Raises ``ValueError`` when the floor has no
        free pixel.
        """
        unknown = set(derive_kw) - ROOM_OPTIONS - ROUTE_OPTIONS
        if unknown:
            raise TypeError(f"unknown derivation option(s) {sorted(unknown)}; known: "
                            f"{sorted(ROOM_OPTIONS | ROUTE_OPTIONS)}")
        if not isinstance(building, Building):
            building = Building.load(Path(building))
        floor = building.floor(floor_id)
        where = f"building '{building.id}' floor {floor_id!r}"
        if not floor.free_mask.any():
            raise ValueError(f"{where} has no free space: every pixel of {floor.image_path.name} is occupied or "
                             f"unknown (check the image and its free_thresh/occupied_thresh/negate)")
        notes: list[str] = []
        derived = {"rooms": False, "routes": False}
        rooms, room_ids = _read_rooms(building, floor, derive_missing, derive_kw, notes, derived)
        segs = _read_routes(building, floor, derive_missing, derive_kw, notes, derived)
        _note_missing(rooms, segs, notes, where)
        return cls(floor=floor, rooms=rooms, segments=segs, building_id=building.id, floor_id=floor.id,
                   room_ids=room_ids, derived=derived, notes=notes, index=index)

    # ------------------------------------------------------------------ properties
    @property
    def n_rooms(self) -> int:
        return len(self.rooms)

    @property
    def n_edges(self) -> int:
        return len(self.segments)

    @property
    def room_areas(self) -> np.ndarray:
        return shapely.area(self._rooms_arr) if self.n_rooms else np.zeros(0)

    @property
    def edge_lengths(self) -> np.ndarray:
        return np.hypot(*(self.segments[:, 1] - self.segments[:, 0]).T) if self.n_edges else np.zeros(0)

    def __repr__(self) -> str:
        return (f"MapGeometry(building={self.building_id!r}, floor={self.floor_id!r}, rooms={self.n_rooms}, "
                f"edges={self.n_edges}, derived={self.derived}, index={self.index!r})")

    def describe(self) -> str:
        return (f"MapGeometry(building={self.building_id!r}, floor={self.floor_id!r}: {self.n_rooms} rooms, "
                f"{self.n_edges} edges, derived={self.derived}, index={self.index!r})\n  "
                + "\n  ".join(self.notes))

    def _bounds(self):
        if self._bbox is None:
            xmin, xmax, ymin, ymax = self.floor.extent
            b = [xmin, ymin, xmax, ymax]
            if self.n_edges:
                b = [min(b[0], self.segments[..., 0].min()), min(b[1], self.segments[..., 1].min()),
                     max(b[2], self.segments[..., 0].max()), max(b[3], self.segments[..., 1].max())]
            if self.n_rooms:
                rb = shapely.total_bounds(self._rooms_arr)
                b = [min(b[0], rb[0]), min(b[1], rb[1]), max(b[2], rb[2]), max(b[3], rb[3])]
            self._bbox = tuple(float(v) for v in b)
        return self._bbox

    def shrunk_rooms(self, shrink: float = 1.0) -> ShrunkRooms:
        key = float(shrink)
        if key not in self._shrunk:
            self._shrunk[key] = shrink_rooms(self.rooms, key, self.notes)
        return self._shrunk[key]

    def get_index(self, kind: str | None = None, max_edge_dist: float = 3.0, shrink: float = 1.0) -> SpatialIndex:
        """The spatial index ``kind`` ('grid' | 'strtree'; default :attr:`index`), built once per
        (kind, max_edge_dist, shrink)."""
        kind = kind or self.index
        if kind not in INDEX_KINDS:
            raise ValueError(f"index must be one of {INDEX_KINDS}, got {kind!r}")
        key = (kind, float(max_edge_dist), float(shrink))
        if key not in self._indexes:
            sh = self.shrunk_rooms(shrink)
            if kind == "grid":
                self._indexes[key] = GridIndex(self.segments, self._rooms_arr, sh, max_edge_dist, self._bounds())
            else:
                self._indexes[key] = STRtreeIndex(self.segments, self._rooms_arr, sh, max_edge_dist)
        return self._indexes[key]

    # ------------------------------------------------------------------ queries
    def nearest_edge(self, xy: np.ndarray, max_edge_dist: float = 3.0, index: str | None = None):
        """For points (..., 2): the perpendicular (closest-point) projection onto the nearest navigation
        segment within ``max_edge_dist``, its distance and the segment index. Points with no segment that
        close keep their position, get distance inf and index -1."""
        xy = np.asarray(xy, dtype=float)
        flat = xy[..., :2].reshape(-1, 2)
        proj, dist, idx = self.get_index(index, max_edge_dist).nearest_edge(flat)
        shp = xy.shape[:-1]
        return proj.reshape(*shp, 2), dist.reshape(shp), idx.reshape(shp)

    def room_of(self, xy: np.ndarray, index: str | None = None, max_edge_dist: float = 3.0) -> np.ndarray:
        """Index of the room containing each point (lowest index if rooms overlap), -1 outside all rooms."""
        xy = np.asarray(xy, dtype=float)
        flat = xy[..., :2].reshape(-1, 2)
        return self.get_index(index, max_edge_dist).room_of(flat).reshape(xy.shape[:-1])

    def nearest_free_pixels(self) -> np.ndarray:
        """(2, H, W) int32: row and column of the nearest FREE pixel of every pixel (Euclidean distance
        transform, computed once)."""
        if self._nearest_free is None:
            _, ind = ndimage.distance_transform_edt(~self.floor.free_mask, return_indices=True)
            self._nearest_free = ind.astype(np.int32)
        return self._nearest_free

    def snap_free(self, xy: np.ndarray, only: np.ndarray | None = None) -> np.ndarray:
        """Move points whose pixel is not FREE (restricted to ``only`` if given) to the nearest point of the
        nearest free pixel; off-image points are first clipped onto the image. Returns a new array."""
        xy = np.array(xy, dtype=float, copy=True)
        p = xy[..., :2]
        bad = ~self.floor.is_free(p)
        if only is not None:
            bad &= only
        if not bad.any():
            return xy
        fl = self.floor
        h, w = fl.shape
        pts = p[bad]
        row, col = fl.world_to_pixel(pts)
        row, col = np.clip(row, 0, h - 1), np.clip(col, 0, w - 1)
        nf = self.nearest_free_pixels()
        fr, fc = nf[0, row, col], nf[1, row, col]
        res, (ox, oy) = fl.resolution, fl.origin
        eps = 1e-3 * res
        cx0 = ox + fc * res
        cy0 = oy + (h - 1 - fr) * res
        pts[:, 0] = np.clip(pts[:, 0], cx0 + eps, cx0 + res - eps)
        pts[:, 1] = np.clip(pts[:, 1], cy0 + eps, cy0 + res - eps)
        p[bad] = pts
        return xy

    # ------------------------------------------------------------------ initialisation and conditioning
    # defined in initial.py (eq. 3, free-space sampling) and conditioning.py (eqs. 4-5)
    sample_uniform_free = initial.sample_uniform_free
    sample_free_within = initial.sample_free_within
    sample_initial = initial.sample_initial
    condition = conditioning.condition

    def sample(self, rng: np.random.Generator, R: int, N: int) -> np.ndarray:
        """The filter engine's initializer hook: :meth:`sample_initial` with Table I's parameters."""
        return self.sample_initial(rng, R, N)


def _read_rooms(building: Building, floor: Floor, derive_missing: bool, derive_kw: dict, notes: list,
                derived: dict) -> tuple[list, list]:
    """The floor's rooms from rooms.geojson (invalid polygons repaired, MultiPolygons exploded), else derived."""
    rooms, room_ids = [], []
    for reg in building.rooms_on(floor.id):
        g = reg.geometry
        if not g.is_valid:
            g = shapely.make_valid(g)
            notes.append(f"room {reg.id}: invalid polygon repaired with make_valid")
        parts = [p for p in polygons_of(g) if p.area > 0]
        for j, p in enumerate(parts):
            rooms.append(p)
            room_ids.append(reg.id if len(parts) == 1 else f"{reg.id}#{j}")
    if rooms:
        notes.append(f"rooms: {len(rooms)} polygons from rooms.geojson")
    elif derive_missing:
        rooms = derive_rooms(floor, **{k: v for k, v in derive_kw.items() if k in ROOM_OPTIONS})
        room_ids = [f"derived{i:03d}" for i in range(len(rooms))]
        derived["rooms"] = True
        cover = sum(p.area for p in rooms) / (floor.free_mask.sum() * floor.resolution**2)
        notes.append(f"rooms: none in rooms.geojson for this floor; derived {len(rooms)} from the occupancy grid "
                     f"(free space split at doorways), covering {cover:.0%} of the free area")
    else:
        notes.append("rooms: none for this floor (derive_missing=False)")
    return rooms, room_ids


def _read_routes(building: Building, floor: Floor, derive_missing: bool, derive_kw: dict, notes: list,
                 derived: dict) -> np.ndarray:
    """The floor's navigation segments (E, 2, 2) from navgraph.geojson, else derived."""
    segs = segments_of([r.geometry for r in building.routes_on(floor.id)])
    if len(segs):
        notes.append(f"routes: {len(segs)} segments from navgraph.geojson")
    elif derive_missing:
        lines = derive_routes(floor, **{k: v for k, v in derive_kw.items() if k in ROUTE_OPTIONS})
        segs = segments_of(lines)
        derived["routes"] = True
        notes.append(f"routes: none in navgraph.geojson for this floor; derived {len(segs)} segments "
                     f"({sum(ln.length for ln in lines):.0f} m) from the skeleton of free space")
    else:
        notes.append("routes: none for this floor (derive_missing=False)")
    return segs


def _note_missing(rooms: list, segs: np.ndarray, notes: list, where: str) -> None:
    """Say what sampling and conditioning do when rooms or routes are missing."""
    if rooms and not len(segs):
        notes.append("no routes: sample_initial puts every particle in rooms (beta ignored) and condition never "
                     "projects onto a route")
    elif len(segs) and not rooms:
        notes.append("no rooms: sample_initial puts every particle around routes (beta ignored)")
    elif not rooms and not len(segs):
        notes.append("no rooms and no routes: sample_initial falls back to uniform over free space and "
                     "condition only keeps particles out of obstacles")
        warnings.warn(f"{where}: no rooms and no routes; map fusion is reduced to free-space checks",
                      stacklevel=3)
