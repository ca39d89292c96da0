"""Floor-plan errors: the plan the filters are given is not quite the building that was walked.

In a simulation the floor plan is exact, so a filter that gives weight 0 to every particle crossing a wall
(the heuristic map particle filter) is close to optimal there. Real plans are not exact: a door drawn
closed or missing, a partition since removed, a glass wall, a plan registered to the world with a
translation error. Roy measured the learned map prior's advantage over the heuristic on real buildings;
this module makes a wrong plan from a right one so an evaluation can test that claim
(``blenav-eval ... plan_error.barriers_per_100m2=K``, see :mod:`blenav.eval.harness`).

Two kinds of error, both seeded per building (``seed`` and the building id), so every method and every
session of a building sees the same wrong plan:

* spurious barriers: K per 100 m^2 of free space. Each is a straight wall ``thickness_m`` thick across a
  free span of at most ``max_span_m`` (default 1.5 m: doorways and narrow passages, not 2 m corridors or
  rooms), from obstacle to obstacle, at a place drawn uniformly among such spans' pixels -- a door drawn
  closed, a passage the plan blocks.
* registration offset: the whole plan shifted by ``offset_m`` = (dx, dy) m in the world.

Ground truth, anchors, rooms, navigation graph and every stream are untouched; only the occupancy grid
the filters see (wall tests, map prior) changes. The wrong plan is written as a PNG, so it can be looked
at, and the returned :class:`~blenav.data.Floor` reads it like any other plan.
"""

from __future__ import annotations

import zlib
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np
from PIL import Image


@dataclass
class PlanErrorConfig:
    """How the plan given to the filters differs from the true one (all zero: the true plan).

    ``barriers_per_100m2``: spurious barriers per 100 m^2 of free space. ``max_span_m``: widest free span
    (m) a barrier may close. ``thickness_m``: barrier thickness (m, at least one pixel). ``offset_m``:
    (dx, dy) m shift of the whole plan. ``seed``: with the building id, seeds the barrier draws.
    """

    barriers_per_100m2: float = 0.0
    max_span_m: float = 1.5
    thickness_m: float = 0.2
    offset_m: list = field(default_factory=lambda: [0.0, 0.0])
    seed: int = 0

    def __post_init__(self):
        if not self.barriers_per_100m2 >= 0:
            raise ValueError(f"plan_error.barriers_per_100m2 must be >= 0, got {self.barriers_per_100m2}")
        if not self.max_span_m > 0 or not self.thickness_m > 0:
            raise ValueError(f"plan_error.max_span_m and thickness_m must be > 0 m, got {self.max_span_m}, "
                             f"{self.thickness_m}")
        if len(self.offset_m) != 2 or not np.all(np.isfinite(np.asarray(self.offset_m, dtype=float))):
            raise ValueError(f"plan_error.offset_m must be two finite numbers (dx, dy) in m, got {self.offset_m}")

    @property
    def active(self) -> bool:
        return self.barriers_per_100m2 > 0 or any(float(v) != 0.0 for v in self.offset_m)


def building_rng(seed: int, building_id: str) -> np.random.Generator:
    """The barrier draws' generator for one building: independent of session order and of other buildings."""
    return np.random.default_rng([int(seed), zlib.crc32(str(building_id).encode())])


def run_lengths(free: np.ndarray, axis: int) -> np.ndarray:
    """(H, W) int: the length (pixels) of the run of free pixels along ``axis`` (1: the row, 0: the column)
    that each pixel lies in; 0 on non-free pixels."""
    f = np.asarray(free, dtype=bool)
    if axis == 0:
        return run_lengths(f.T, 1).T
    h, w = f.shape
    flat = np.pad(f, ((0, 0), (0, 1))).ravel()  # a blocked column after each row: runs never wrap
    start = flat & ~np.concatenate([[False], flat[:-1]])
    rid = np.cumsum(start) * flat  # run id per free pixel, 0 elsewhere
    lengths = np.bincount(rid, minlength=int(rid.max()) + 1)
    lengths[0] = 0
    return lengths[rid].reshape(h, w + 1)[:, :w]


def _run(line: np.ndarray, i: int) -> tuple[int, int]:
    """[a, b): the maximal run of True in the 1-D bool array ``line`` that contains index ``i``."""
    blocked = np.flatnonzero(~line)
    a = blocked[blocked < i]
    b = blocked[blocked > i]
    return (int(a[-1]) + 1 if len(a) else 0), (int(b[0]) if len(b) else len(line))


def draw_barriers(free: np.ndarray, resolution: float, n: int, max_span_m: float, thickness_m: float,
                  rng: np.random.Generator, max_tries: int = 50) -> tuple[np.ndarray, list[tuple[int, int, int, int]]]:
    """``n`` spurious barriers across the narrow free spans of a grid.

    ``free``: (H, W) bool, True where free; ``resolution``: m per pixel. Candidates are the free pixels whose
    horizontal or vertical free run is at most ``max_span_m`` long (doorways, narrow passages; corridors
    too when ``max_span_m`` exceeds their width); a barrier is drawn at a uniformly chosen candidate, along
    a qualifying direction (either with equal chance when both qualify), ``thickness_m`` thick, across the
    whole run; a draw that would touch an earlier barrier is drawn again. Returns the (H, W) bool mask of
    the pixels the barriers cover and the barriers as (row0, col0, row1, col1) pixel boxes (end exclusive).
    Fewer than ``n`` when the grid has fewer such places (``max_tries * n`` draws; a loop over barriers, not
    over pixels or particles).
    """
    free = np.asarray(free, dtype=bool)
    h, w = free.shape
    max_px = max_span_m / resolution
    ok_h = free & (run_lengths(free, 1) <= max_px)
    ok_v = free & (run_lengths(free, 0) <= max_px)
    cells = np.flatnonzero(ok_h | ok_v)
    mask = np.zeros_like(free)
    boxes: list[tuple[int, int, int, int]] = []
    if n <= 0 or not len(cells):
        return mask, boxes
    t = max(1, int(round(thickness_m / resolution)))
    for _ in range(max_tries * n):
        if len(boxes) == n:
            break
        r, c = divmod(int(cells[rng.integers(len(cells))]), w)
        horizontal = ok_h[r, c] if not (ok_h[r, c] and ok_v[r, c]) else rng.random() < 0.5
        if horizontal:  # spans the free run of row r through column c
            a, b = _run(free[r], c)
            box = (max(0, r - t // 2), a, min(h, r - t // 2 + t), b)
        else:  # the free run of column c through row r
            a, b = _run(free[:, c], r)
            box = (a, max(0, c - t // 2), b, min(w, c - t // 2 + t))
        if mask[max(0, box[0] - t):box[2] + t, max(0, box[1] - t):box[3] + t].any():
            continue  # one barrier per place
        mask[box[0]:box[2], box[1]:box[3]] = True
        boxes.append(box)
    return mask & free, boxes


def perturb_floor(floor, building_id: str, cfg: PlanErrorConfig, rng: np.random.Generator, out_dir: Path):
    """The wrong plan of ``floor``: a :class:`~blenav.data.Floor` reading ``out_dir/<building>_floor<id>.png``
    (the true image with the barriers drawn as occupied) at the shifted origin, and a summary dict
    (``barriers``, ``requested``, ``closed_m2``, ``offset_m``, ``image``)."""
    free = floor.free_mask
    area_m2 = float(free.sum()) * floor.resolution**2
    n = int(round(cfg.barriers_per_100m2 * area_m2 / 100.0))
    mask, boxes = draw_barriers(free, floor.resolution, n, cfg.max_span_m, cfg.thickness_m, rng)
    img = floor.image.copy()
    img[mask] = 255 if floor.negate else 0  # fully dark = occupied (the ROS map_server convention)
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    path = out_dir / f"{building_id}_floor{floor.id}.png"
    Image.fromarray(img).save(path)
    dx, dy = (float(v) for v in cfg.offset_m)
    wrong = replace(floor, image_path=path, origin=(float(floor.origin[0]) + dx, float(floor.origin[1]) + dy))
    info = {"barriers": len(boxes), "requested": n, "closed_m2": float(mask.sum()) * floor.resolution**2,
            "free_m2": area_m2, "offset_m": [dx, dy], "image": str(path)}
    return wrong, info


def perturb_building(building, cfg: PlanErrorConfig, out_dir: Path):
    """``building`` with every floor replaced by its wrong plan (:func:`perturb_floor`), and the summaries
    per floor id. Anchors, rooms and the navigation graph are kept."""
    rng = building_rng(cfg.seed, building.id)
    floors, info = {}, {}
    for key in sorted(building.floors, key=str):
        floors[key], info[str(key)] = perturb_floor(building.floors[key], building.id, cfg, rng, out_dir)
    return replace(building, floors=floors), info
