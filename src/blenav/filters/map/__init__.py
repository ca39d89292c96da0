"""Map fusion for the particle filter (Patel et al., Sec. V and VI.C), one module per idea:

- :mod:`.geometry`: :class:`MapGeometry`, a floor's rooms, navigation edges and occupancy grid, read from the
  building (what is missing derived), with the map queries the filter asks (room, nearest edge, free space);
- :mod:`.initial`: eq. 3 initialisation on edges and in rooms, uniform and local free-space sampling;
- :mod:`.conditioning`: eqs. 4-5 conditioning of resampled particles (jitter, shrunk rooms, edges, obstacles);
- :mod:`.index`: the spatial indexes behind conditioning (the paper's 1 m grid, shapely's STRtree);
- :mod:`.walls`: :class:`WallCrossing`, whether a motion step crosses an obstacle;
- :mod:`.rooms`, :mod:`.routes`: rooms and routes derived from the occupancy grid (for maps without them);
- :mod:`.shapes`, :mod:`.raster`: the geometry and raster helpers they share.
"""

from .conditioning import CASE_FAR, CASE_IN_SHRUNK, CASE_TO_EDGE, CASE_TO_SHRUNK, OBSTACLE_COND
from .geometry import MapGeometry
from .index import DEFAULT_INDEX, INDEX_KINDS
from .initial import OBSTACLE_INIT
from .rooms import derive_rooms
from .routes import derive_routes
from .walls import WallCrossing

__all__ = ["CASE_FAR", "CASE_IN_SHRUNK", "CASE_TO_EDGE", "CASE_TO_SHRUNK", "DEFAULT_INDEX", "INDEX_KINDS",
           "OBSTACLE_COND", "OBSTACLE_INIT", "MapGeometry", "WallCrossing", "derive_rooms", "derive_routes"]
