"""Floor plans in world metres: occupancy grid, rooms, navigation graph and radio anchors
(:func:`plot_floor`), ground-truth tracks (:func:`plot_tracks`) and a building's overview figure
(:func:`figure_overview`).
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Sequence

import numpy as np
import pandas as pd
from matplotlib.axes import Axes
from matplotlib.collections import LineCollection
from matplotlib.figure import Figure
from matplotlib.lines import Line2D
from shapely.geometry import LineString, MultiLineString, MultiPolygon, Polygon

from blenav.data import FREE, OCCUPIED, Building, Dataset, Session
from blenav.data.schema import ANCHOR_TRUE_COLUMNS

from .common import (
    ANCHOR_STYLE,
    FREE_GREY,
    LABEL_SPACING,
    MAX_LABELLED_ANCHORS,
    MAX_LABELLED_ROOMS,
    MAX_LEGEND_SESSIONS,
    OCCUPIED_GREY,
    ROOM_COLOR,
    ROUTE_COLOR,
    UNKNOWN_GREY,
    keep_apart,
    new_figure,
    session_colors,
    survey_points,
)

def _polygons(g) -> list[Polygon]:
    if isinstance(g, Polygon):
        return [g]
    if isinstance(g, MultiPolygon):
        return list(g.geoms)
    return []


def _lines(g) -> list[LineString]:
    if isinstance(g, LineString):
        return [g]
    if isinstance(g, MultiLineString):
        return list(g.geoms)
    return []


#: the floor plan's image is drawn at most this many pixels on its longer side (a finer occupancy grid is reduced
#: by whole blocks, each the darkest of its cells, so a wall one cell thick stays): a mall floor's 0.1 m grid is
#: 3,200 cells across, and mapping and resampling it costs about half a second in every panel it is drawn in
MAX_PLAN_PX = 1600


def plan_image(occ: np.ndarray) -> np.ndarray:
    """The occupancy grid ``occ`` (H, W) as the plan's RGB image (h, w, 3) uint8: free white, unknown light grey,
    occupied black (:data:`FREE_GREY` ...); reduced by an integer factor f to at most :data:`MAX_PLAN_PX` on its
    longer side, each pixel the darkest of its block. The far edges are padded with their own cells to whole blocks,
    so the image drawn in the plan's extent is stretched by at most f - 1 cells over the plan: under a pixel of the
    at most MAX_PLAN_PX drawn."""
    grey = np.full(occ.shape, UNKNOWN_GREY, dtype=float)
    grey[occ == FREE] = FREE_GREY
    grey[occ == OCCUPIED] = OCCUPIED_GREY
    f = max(1, math.ceil(max(grey.shape) / MAX_PLAN_PX))
    if f > 1:
        h, w = -(-grey.shape[0] // f) * f, -(-grey.shape[1] // f) * f
        padded = np.pad(grey, ((0, h - grey.shape[0]), (0, w - grey.shape[1])), mode="edge")
        grey = padded.reshape(h // f, f, w // f, f).min(axis=(1, 3))
    return np.repeat(np.round(grey * 255).astype(np.uint8)[:, :, None], 3, axis=2)


#: how a faint floor (``plot_floor(faint=True)``) draws its rooms, routes and anchors: behind the tracks of a panel
FAINT_ALPHA = 0.35


def plot_floor(ax: Axes, building: Building, floor_id, *, anchor_labels: bool | None = None,
               room_labels: bool | None = None, faint: bool = False) -> Axes:
    """Draw one floor in world metres: occupancy grid, rooms, navigation graph and radio anchors.

    Anchors: BLE beacons as triangles, WiFi RTT access points as squares, at their prior (map) positions;
    where the anchors carry ``x_true, y_true`` a thin line joins the prior to the true position (small x).
    ``anchor_labels``: write anchor ids next to them (default: when the floor has at most
    :data:`MAX_LABELLED_ANCHORS`); ``room_labels``: write room ids inside them (default: at most
    :data:`MAX_LABELLED_ROOMS` rooms: a mall's hundreds of shop ids would cover the plan). Anchors without a position
    are neither drawn nor counted in the legend. Labels never overprint one another: anchor ids first, then room ids,
    a label whose point is within :data:`LABEL_SPACING` of the floor's larger side of one already written is left
    out (:func:`~blenav.plotting.common.keep_apart`); an anchor id sits on a light box (readable over walls), to the
    left of anchors in the floor's right tenth and below those in its top tenth. ``faint``: rooms, routes and anchors
    drawn small and pale, without labels (the background of a panel of tracks).
    """
    fl = building.floor(floor_id)
    # row 0 of the image is its top (largest y): origin="upper" with the world extent
    ax.imshow(plan_image(fl.occupancy), extent=fl.extent, origin="upper", interpolation="nearest", zorder=0)
    a = FAINT_ALPHA if faint else 1.0
    if faint:
        anchor_labels = room_labels = False

    rooms = list(building.rooms_on(fl.id))
    if room_labels is None:
        room_labels = len(rooms) <= MAX_LABELLED_ROOMS
    rings = [np.asarray(ring.coords)[:, :2] for room in rooms for poly in _polygons(room.geometry)
             for ring in (poly.exterior, *poly.interiors)]
    if rings:  # one collection: a mall's hundreds of outlines as one artist each cost seconds a panel
        ax.add_collection(LineCollection(rings, colors=ROOM_COLOR, linewidths=0.8, alpha=0.6 * a, zorder=1,
                                         label="room"))

    segments = [np.asarray(line.coords)[:, :2] for r in building.routes_on(fl.id) for line in _lines(r.geometry)]
    if segments:
        ax.add_collection(LineCollection(segments, colors=ROUTE_COLOR, linewidths=1.0, linestyles="--",
                                         alpha=0.8 * a, zorder=2, label="navigation graph"))

    anchors = building.anchors_of(floor=fl.id)
    anchors = anchors[np.isfinite(anchors["x"].astype(float)) & np.isfinite(anchors["y"].astype(float))]  # placed
    has_true = all(c in anchors.columns for c in ANCHOR_TRUE_COLUMNS[:2])
    if has_true and len(anchors):
        xt = pd.to_numeric(anchors["x_true"], errors="coerce").to_numpy(dtype=float)
        yt = pd.to_numeric(anchors["y_true"], errors="coerce").to_numpy(dtype=float)
        known = np.isfinite(xt) & np.isfinite(yt)
        if known.any():
            prior = anchors[["x", "y"]].to_numpy(dtype=float)[known]
            true = np.column_stack([xt[known], yt[known]])
            ax.add_collection(LineCollection(np.stack([prior, true], axis=1), colors="0.25", linewidths=0.6,
                                             alpha=a, zorder=3))
            ax.scatter(true[:, 0], true[:, 1], marker="x", s=14 * a, linewidths=0.8, color="0.25", alpha=a, zorder=3,
                       label="true anchor position")
    for kind, style in ANCHOR_STYLE.items():
        sub = anchors[anchors["kind"] == kind]
        if len(sub):
            ax.scatter(sub["x"], sub["y"], marker=style["marker"], s=16 if faint else 40, color=style["color"],
                       edgecolors="k", linewidths=0.5 * a, alpha=a, zorder=4, label=f"{style['label']} ({len(sub)})")

    x0, x1, y0, y1 = fl.extent
    if anchor_labels is None:
        anchor_labels = len(anchors) <= MAX_LABELLED_ANCHORS
    ids = [str(i) for i in anchors["anchor_id"]] if anchor_labels else []
    axy = anchors[["x", "y"]].to_numpy(dtype=float) if anchor_labels else np.zeros((0, 2))
    rids = [r.id for r in rooms] if room_labels else []
    rpts = [r.geometry.representative_point() for r in rooms] if rids else []
    rxy = np.array([[p.x, p.y] for p in rpts]).reshape(-1, 2)
    keep = keep_apart(np.vstack([axy, rxy]), LABEL_SPACING * max(x1 - x0, y1 - y0))
    for aid, (x, y), k in zip(ids, axy, keep[:len(ids)]):
        if not k:
            continue
        right, top = x > x1 - 0.1 * (x1 - x0), y > y1 - 0.1 * (y1 - y0)
        ax.annotate(aid, (x, y), xytext=(-3 if right else 3, -3 if top else 3), textcoords="offset points",
                    ha="right" if right else "left", va="top" if top else "bottom", fontsize=6, zorder=5,
                    bbox={"boxstyle": "square,pad=0.1", "fc": "white", "ec": "none", "alpha": 0.7})
    for rid, (x, y), k in zip(rids, rxy, keep[len(ids):]):
        if k:
            ax.text(x, y, rid, fontsize=7, color=ROOM_COLOR, alpha=0.55, ha="center", va="center", zorder=1)

    ax.set_xlim(x0, x1)
    ax.set_ylim(y0, y1)
    ax.set_aspect("equal")
    ax.set_xlabel("x (east) [m]")
    ax.set_ylabel("y (north) [m]")
    ax.set_title(f"{building.name}: floor {fl.id}", fontsize=10)
    return ax


def plot_tracks(ax: Axes, sessions: Iterable[Session], *, legend: bool = True) -> Axes:
    """Draw the ground-truth (x, y) track of every labelled session, one colour each (start: a dot).

    Sessions without ground truth are skipped. With ``legend`` a legend of everything labelled on ``ax``
    (tracks, and anchors/rooms drawn by :func:`plot_floor`) is placed outside the axes, on the right.
    """
    tracks = [(s, s.groundtruth) for s in sessions if s.labelled]
    tracks = [(s, gt) for s, gt in tracks if len(gt)]
    colors = session_colors(len(tracks))
    for k, ((s, gt), c) in enumerate(zip(tracks, colors)):
        x, y = gt["x"].to_numpy(), gt["y"].to_numpy()
        label = f"{s.id} ({s.device_model}, {s.carrier})" if k < MAX_LEGEND_SESSIONS else None
        if s.carrier == "static":  # a survey jumps between points: its points, not a line through walls
            ax.scatter(*survey_points(x, y), s=12, marker="s", color=c, zorder=6, label=label)
            continue
        ax.plot(x, y, color=c, lw=1.2, alpha=0.9, zorder=6, label=label)
        ax.plot(x[:1], y[:1], marker="o", ms=4, color=c, zorder=7)
    if legend:
        handles, labels = ax.get_legend_handles_labels()
        if len(tracks) > MAX_LEGEND_SESSIONS:
            handles.append(Line2D([], [], color="none"))
            labels.append(f"+ {len(tracks) - MAX_LEGEND_SESSIONS} more sessions")
        if handles:
            ax.legend(handles, labels, loc="upper left", bbox_to_anchor=(1.02, 1.0), fontsize=7,
                      frameon=False, borderaxespad=0.0)
    return ax


def _building_of(dataset: Dataset, sessions: Sequence[Session], building_id: str | None) -> str:
    if building_id is not None:
        return building_id
    ids = sorted({s.building.id for s in sessions})
    if len(ids) == 1:
        return ids[0]
    if not ids and len(dataset.building_ids) == 1:
        return dataset.building_ids[0]
    raise ValueError(f"sessions are in buildings {ids or dataset.building_ids}: pass building_id")


def figure_overview(dataset: Dataset, session_ids: Sequence[str] | None = None,
                    building_id: str | None = None) -> Figure:
    """One building: every floor (occupancy, rooms, routes, anchors) with the tracks of its sessions.

    ``session_ids``: the sessions whose ground truth is drawn (default all); only those in the building
    are used. ``building_id``: which building (default: the one building of the sessions, or of the
    dataset). One panel per floor; one legend for the figure (each entry once) in a column of its own right of the
    panels, so that it covers no anchor or label; anchor and room labels as :func:`plot_floor` writes them (none
    overprints another).
    """
    sessions = [dataset.session(i) for i in (dataset.session_ids if session_ids is None else session_ids)]
    b = dataset.building(_building_of(dataset, sessions, building_id))
    sessions = [s for s in sessions if s.building.id == b.id]
    floors = list(b.floors)
    ncols = 1 if len(floors) <= 2 else 2
    nrows = math.ceil(len(floors) / ncols)
    x0, x1, y0, y1 = b.floor(floors[0]).extent
    panel_w = 6.5
    panel_h = float(np.clip(panel_w * (y1 - y0) / max(x1 - x0, 1e-9), 3.0, 9.0))
    labelled = [s for s in sessions if s.labelled]
    longest = max([len(f"{s.id} ({s.device_model}, {s.carrier})") for s in labelled[:MAX_LEGEND_SESSIONS]] + [24])
    legend_w = float(np.clip(0.065 * longest + 0.6, 2.6, 6.0))  # fontsize 7: ~0.065 in per character
    fig = new_figure(ncols * panel_w + legend_w, nrows * panel_h + 0.9)
    gs = fig.add_gridspec(nrows, ncols + 1, width_ratios=[panel_w] * ncols + [legend_w])
    axes = np.array([fig.add_subplot(gs[r, c]) for r in range(nrows) for c in range(ncols)])
    leg_ax = fig.add_subplot(gs[:, ncols])  # the legend's own column: beside the panels, under the title
    leg_ax.axis("off")
    entries: dict[str, object] = {}
    unnamed = 0  # tracks plot_tracks leaves out of the legend (beyond MAX_LEGEND_SESSIONS on a floor)
    for ax, fid in zip(axes, floors):
        plot_floor(ax, b, fid)
        on_floor = [s for s in sessions if str(s.meta.get("floor")) == str(fid)]
        plot_tracks(ax, on_floor, legend=False)
        unnamed += max(0, sum(1 for s in on_floor if s.labelled and len(s.groundtruth)) - MAX_LEGEND_SESSIONS)
        for h, lab in zip(*ax.get_legend_handles_labels()):
            entries.setdefault(lab, h)
    for ax in axes[len(floors):]:
        ax.set_visible(False)
    handles, labels = list(entries.values()), list(entries)
    if unnamed:
        handles.append(Line2D([], [], color="none"))
        labels.append(f"+ {unnamed} more sessions")
    if handles:
        leg_ax.legend(handles, labels, loc="upper left", fontsize=7, frameon=False, borderaxespad=0.0,
                      ncols=max(1, math.ceil(len(handles) / 40)))
    n_gt = sum(1 for s in sessions if s.labelled)
    fig.suptitle(f"{dataset.name}: {b.name} ({b.id}), {len(sessions)} session(s), {n_gt} with ground truth",
                 fontsize=11)
    return fig
