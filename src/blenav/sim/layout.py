"""Procedural rectilinear floor plans: corridors, rooms with doors, furniture, navigation graph.

A layout is drawn on an occupancy grid (int8, FREE/OCCUPIED, row 0 on top as in the dataset format)
of ``resolution`` m/pixel with origin (0, 0) at the lower-left corner; all geometry is in world metres.

Algorithm: ``n_h`` horizontal and ``n_v`` vertical corridors (width ``corridor_w``) split the building
into blocks. A block is cut into one or two rows of rooms, each row facing a corridor; a row is cut into
rooms of width U(room_min, room_max), or, with probability ``hall_prob``, left as one open hall. Every
room gets a door (``door_w``) onto its corridor at a random position and U(furniture) desks. The
navigation graph joins corridor centre lines (split at junctions and door stubs), door points and room
centres; the presets fix ``layout_seed`` so a preset is always the same building.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import shortest_path
from shapely.geometry import LineString, box

from blenav.data.floor import FREE, OCCUPIED


@dataclass
class LayoutConfig:
    width_m: float = 20.0
    height_m: float = 15.0
    resolution: float = 0.1
    n_h: int = 1  # horizontal corridors
    n_v: int = 0  # vertical corridors
    corridor_w: float = 2.0
    room_min: float = 3.0
    room_max: float = 6.0
    wall_t: float = 0.2
    door_w: float = 1.0
    hall_prob: float = 0.0
    furniture_min: int = 0
    furniture_max: int = 2
    layout_seed: int = 0


@dataclass
class Room:
    id: str
    rect: tuple[float, float, float, float]  # x0, y0, x1, y1 (m), inner wall faces
    door: tuple[float, float]  # door centre on the wall (m)
    centre: tuple[float, float]


@dataclass
class Layout:
    """A generated floor: occupancy grid, rooms, navigation graph (nodes + edges) and landmarks."""

    occupancy: np.ndarray
    resolution: float
    width_m: float
    height_m: float
    rooms: list[Room]
    nodes: np.ndarray  # (N, 2) m
    edges: np.ndarray  # (E, 2) node indices
    room_node: dict[str, int]  # room id -> node index of its centre
    junctions: list[int] = field(default_factory=list)  # corridor junction nodes (visual landmarks)

    @property
    def origin(self) -> tuple[float, float]:
        return (0.0, 0.0)

    def free(self, xy: np.ndarray) -> np.ndarray:
        h, w = self.occupancy.shape
        col = np.floor(xy[..., 0] / self.resolution).astype(int)
        row = h - 1 - np.floor(xy[..., 1] / self.resolution).astype(int)
        ok = (row >= 0) & (row < h) & (col >= 0) & (col < w)
        out = np.zeros(row.shape, bool)
        out[ok] = self.occupancy[row[ok], col[ok]] == FREE
        return out

    def route(self, a: int, b: int, pred: np.ndarray) -> list[int]:
        """Node path a -> b from a predecessor matrix of :meth:`all_pairs`."""
        path = [b]
        while path[-1] != a:
            p = pred[a, path[-1]]
            if p < 0:
                raise ValueError(f"navigation graph is disconnected between nodes {a} and {b}")
            path.append(int(p))
        return path[::-1]

    def all_pairs(self) -> tuple[np.ndarray, np.ndarray]:
        n = len(self.nodes)
        w = np.linalg.norm(self.nodes[self.edges[:, 0]] - self.nodes[self.edges[:, 1]], axis=1)
        g = coo_matrix((w, (self.edges[:, 0], self.edges[:, 1])), shape=(n, n)).tocsr()
        return shortest_path(g, directed=False, return_predecessors=True)

    def edge_lines(self) -> list[LineString]:
        return [LineString([self.nodes[i], self.nodes[j]]) for i, j in self.edges]


class _Canvas:
    def __init__(self, w_m: float, h_m: float, res: float):
        self.res = res
        self.h, self.w = int(round(h_m / res)), int(round(w_m / res))
        self.occ = np.full((self.h, self.w), FREE, dtype=np.int8)

    def fill(self, x0: float, y0: float, x1: float, y1: float, value: int) -> None:
        c0, c1 = int(np.floor(min(x0, x1) / self.res)), int(np.ceil(max(x0, x1) / self.res))
        r1, r0 = self.h - int(np.floor(min(y0, y1) / self.res)), self.h - int(np.ceil(max(y0, y1) / self.res))
        self.occ[max(r0, 0):max(r1, 0), max(c0, 0):max(c1, 0)] = value


def _spans(total: float, n: int, width: float) -> list[tuple[float, float]]:
    """n corridor spans across [0, total] so that outer blocks hold one row of rooms of depth d and inner
    blocks two rows: total = 2 d n + n width."""
    d = (total - n * width) / (2 * n) if n else 0.0
    starts = [d + k * (2 * d + width) for k in range(n)]
    return [(s, s + width) for s in starts]


def _gaps_simple(total: float, spans, wall: float):
    pts = [(wall, False)]
    for s0, s1 in spans:
        pts.append((s0, True))
        pts.append((s1, True))
    pts.append((total - wall, False))
    return [(pts[i][0], pts[i + 1][0], pts[i][1], pts[i + 1][1]) for i in range(0, len(pts), 2)]


def generate_layout(cfg: LayoutConfig) -> Layout:
    rng = np.random.default_rng(cfg.layout_seed)
    W, H, t = cfg.width_m, cfg.height_m, cfg.wall_t
    cv = _Canvas(W, H, cfg.resolution)
    hspans = _spans(H, cfg.n_h, cfg.corridor_w)
    vspans = _spans(W, cfg.n_v, cfg.corridor_w)
    if not hspans and not vspans:
        raise ValueError("a layout needs at least one corridor (n_h + n_v >= 1)")

    rooms: list[Room] = []
    # blocks: x-gaps between vertical corridors, y-gaps between horizontal corridors
    for bx0, bx1, cleft, cright in _gaps_simple(W, vspans, 0.0):
        for by0, by1, cbelow, cabove in _gaps_simple(H, hspans, 0.0):
            rooms += _fill_block(cfg, rng, len(rooms), (bx0, by0, bx1, by1), cbelow, cabove, cleft, cright)

    for r in rooms:  # walls around every room, then doors carved
        x0, y0, x1, y1 = r.rect
        for rect in ((x0 - t, y0 - t, x1 + t, y0), (x0 - t, y1, x1 + t, y1 + t), (x0 - t, y0, x0, y1), (x1, y0, x1 + t, y1)):
            cv.fill(*rect, OCCUPIED)
    cv.fill(0, 0, W, t, OCCUPIED), cv.fill(0, H - t, W, H, OCCUPIED)
    cv.fill(0, 0, t, H, OCCUPIED), cv.fill(W - t, 0, W, H, OCCUPIED)
    for r in rooms:
        dx, dy = r.door
        x0, y0, x1, y1 = r.rect
        half = cfg.door_w / 2
        if abs(dy - y0) < 1e-9 or abs(dy - y1) < 1e-9:
            cv.fill(dx - half, dy - t - 0.01, dx + half, dy + t + 0.01, FREE)
        else:
            cv.fill(dx - t - 0.01, dy - half, dx + t + 0.01, dy + half, FREE)
        _furnish(cv, cfg, rng, r)

    nodes, edges, room_node, junctions = _navgraph(cfg, rooms, hspans, vspans)
    return Layout(cv.occ, cfg.resolution, W, H, rooms, nodes, edges, room_node, junctions)


def _fill_block(cfg, rng, start, rect, cbelow, cabove, cleft, cright) -> list[Room]:
    x0, y0, x1, y1 = rect
    t = cfg.wall_t
    out: list[Room] = []
    if cbelow or cabove:
        depth = y1 - y0
        rows = []
        if cbelow and cabove and depth >= 2 * cfg.room_min + 2 * t:
            mid = (y0 + y1) / 2
            rows = [((y0 + t, mid), "below"), ((mid, y1 - t), "above")]
        else:
            rows = [((y0 + t, y1 - t), "below" if cbelow else "above")]
        for (ry0, ry1), side in rows:
            for a, b in _cuts(cfg, rng, x0 + t, x1 - t):
                dx = rng.uniform(a + cfg.door_w / 2 + 0.2, b - cfg.door_w / 2 - 0.2) if b - a > cfg.door_w + 0.5 else (a + b) / 2
                door = (dx, ry0 if side == "below" else ry1)
                out.append(Room(f"r{start + len(out):03d}", (a, ry0, b, ry1), door, ((a + b) / 2, (ry0 + ry1) / 2)))
    elif cleft or cright:
        width = x1 - x0
        if cleft and cright and width >= 2 * cfg.room_min + 2 * t:
            mid = (x0 + x1) / 2
            cols = [((x0 + t, mid), "left"), ((mid, x1 - t), "right")]
        else:
            cols = [((x0 + t, x1 - t), "left" if cleft else "right")]
        for (rx0, rx1), side in cols:
            for a, b in _cuts(cfg, rng, y0 + t, y1 - t):
                dy = rng.uniform(a + cfg.door_w / 2 + 0.2, b - cfg.door_w / 2 - 0.2) if b - a > cfg.door_w + 0.5 else (a + b) / 2
                door = (rx0 if side == "left" else rx1, dy)
                out.append(Room(f"r{start + len(out):03d}", (rx0, a, rx1, b), door, ((rx0 + rx1) / 2, (a + b) / 2)))
    return out


def _cuts(cfg, rng, a: float, b: float) -> list[tuple[float, float]]:
    """Split [a, b] into room widths U(room_min, room_max) (or one hall)."""
    if rng.random() < cfg.hall_prob:
        return [(a, b)]
    cuts, x = [a], a
    while b - x > cfg.room_max:
        x += rng.uniform(cfg.room_min, cfg.room_max)
        if b - x < cfg.room_min:
            break
        cuts.append(x)
    cuts.append(b)
    return list(zip(cuts[:-1], cuts[1:]))


def _furnish(cv: _Canvas, cfg: LayoutConfig, rng, r: Room) -> None:
    """Desks (1.6 x 0.8 m) placed away from the door and the room centre (which stays walkable)."""
    x0, y0, x1, y1 = r.rect
    for _ in range(int(rng.integers(cfg.furniture_min, cfg.furniture_max + 1))):
        w, h = (1.6, 0.8) if rng.random() < 0.5 else (0.8, 1.6)
        if x1 - x0 < w + 1.2 or y1 - y0 < h + 1.2:
            continue
        for _try in range(10):
            fx = rng.uniform(x0 + 0.1, x1 - w - 0.1)
            fy = rng.uniform(y0 + 0.1, y1 - h - 0.1)
            near_door = abs(fx + w / 2 - r.door[0]) < w / 2 + 1.2 and abs(fy + h / 2 - r.door[1]) < h / 2 + 1.2
            near_path = box(fx, fy, fx + w, fy + h).distance(LineString([r.door, r.centre])) < 0.7
            if not near_door and not near_path:
                cv.fill(fx, fy, fx + w, fy + h, OCCUPIED)
                break


def _navgraph(cfg, rooms, hspans, vspans):
    """Nodes/edges: corridor centre lines split at junctions and door projections, plus door stubs."""
    W, H, t = cfg.width_m, cfg.height_m, cfg.wall_t
    margin = t + cfg.corridor_w / 2
    nodes: list[tuple[float, float]] = []
    index: dict[tuple[float, float], int] = {}

    def node(p):
        key = (round(p[0], 3), round(p[1], 3))
        if key not in index:
            index[key] = len(nodes)
            nodes.append(key)
        return index[key]

    hy = [(a + b) / 2 for a, b in hspans]
    vx = [(a + b) / 2 for a, b in vspans]
    on_h: dict[int, list[float]] = {i: [margin, W - margin] + vx for i in range(len(hy))}
    on_v: dict[int, list[float]] = {j: [margin, H - margin] + hy for j in range(len(vx))}
    edges: list[tuple[int, int]] = []
    room_node: dict[str, int] = {}
    for r in rooms:
        dx, dy = r.door
        x0, y0, x1, y1 = r.rect
        horizontal_wall = abs(dy - y0) < 1e-9 or abs(dy - y1) < 1e-9
        if horizontal_wall:  # door opens onto a horizontal corridor: nearest centre line in y
            i = int(np.argmin([abs(dy - y) for y in hy]))
            on_h[i].append(dx)
            corridor_pt = (dx, hy[i])
            inside = (dx, dy + (0.6 if abs(dy - y0) < 1e-9 else -0.6))
        else:
            j = int(np.argmin([abs(dx - x) for x in vx]))
            on_v[j].append(dy)
            corridor_pt = (vx[j], dy)
            inside = (dx + (0.6 if abs(dx - x0) < 1e-9 else -0.6), dy)
        a, b, c = node(corridor_pt), node(inside), node(r.centre)
        edges += [(a, b), (b, c)]
        room_node[r.id] = c
    junctions = []
    for i, y in enumerate(hy):
        xs = sorted(set(round(x, 3) for x in on_h[i]))
        ids = [node((x, y)) for x in xs]
        edges += list(zip(ids[:-1], ids[1:]))
        junctions += [node((x, y)) for x in vx] + [ids[0], ids[-1]]
    for j, x in enumerate(vx):
        ys = sorted(set(round(y, 3) for y in on_v[j]))
        ids = [node((x, y)) for y in ys]
        edges += list(zip(ids[:-1], ids[1:]))
        junctions += [ids[0], ids[-1]]
    e = np.array(sorted({(min(a, b), max(a, b)) for a, b in edges if a != b}), dtype=int)
    return np.array(nodes, float), e, room_node, sorted(set(junctions))
