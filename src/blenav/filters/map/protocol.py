"""What the map functions of :mod:`.initial` and :mod:`.conditioning` read of their map: :class:`FloorMap`.

They are methods of :class:`~blenav.filters.map.geometry.MapGeometry` (bound in its class body, ``m`` is the map),
so geometry.py imports them; they name the map's type through this protocol instead of importing geometry.py, which
keeps the modules free of an import cycle, type-only imports included (``tests/test_layers.py``).
"""

from __future__ import annotations

from typing import Protocol

import numpy as np

from blenav.data import Floor

from .index import SpatialIndex


class FloorMap(Protocol):
    """The floor plan with its rooms and navigation edges (a :class:`~blenav.filters.map.geometry.MapGeometry`)."""

    floor: Floor
    segments: np.ndarray  # (n_edges, 2, 2) world m: the navigation edges
    _rooms_arr: np.ndarray  # (n_rooms,) object: the rooms' prepared shapely polygons

    @property
    def n_rooms(self) -> int: ...

    @property
    def n_edges(self) -> int: ...

    @property
    def room_areas(self) -> np.ndarray: ...

    @property
    def edge_lengths(self) -> np.ndarray: ...

    def get_index(self, kind: str | None = None, max_edge_dist: float = 3.0, shrink: float = 1.0) -> SpatialIndex: ...

    def nearest_free_pixels(self) -> np.ndarray: ...

    def snap_free(self, xy: np.ndarray, only: np.ndarray | None = None) -> np.ndarray: ...

    def sample_uniform_free(self, rng: np.random.Generator, R: int, N: int) -> np.ndarray: ...
