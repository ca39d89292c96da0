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
    MAX_LABELLED_ANCHORS,
    MAX_LABELLED_ROOMS,
    MAX_LEGEND_SESSIONS,
    OCCUPIED_GREY,
    ROOM_COLOR,
    ROUTE_COLOR,
    UNKNOWN_GREY,
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


def plot_floor(ax: Axes, building: Building, floor_id, *, anchor_labels: bool | None = None,
               room_labels: bool | None = None) -> Axes:
    """Draw one floor in world metres: occupancy grid, rooms, navigation graph and radio anchors.

    Anchors: BLE beacons as triangles, WiFi RTT access points as squares, at their prior (map) positions;
    where the anchors carry ``x_true, y_true`` a thin line joins the prior to the true position (small x).
    ``anchor_labels``: write anchor ids next to them (default: when the floor has at most
    :data:`MAX_LABELLED_ANCHORS`); ``room_labels``: write room ids inside them (default: at most
    :data:`MAX_LABELLED_ROOMS` rooms: a mall's hundreds of shop ids would cover the plan). Anchors without a position
    are neither drawn nor counted in the legend.
    """
    fl = building.floor(floor_id)
    occ = fl.occupancy
    grey = np.full(occ.shape, UNKNOWN_GREY, dtype=float)
    grey[occ == FREE] = FREE_GREY
    grey[occ == OCCUPIED] = OCCUPIED_GREY
    # row 0 of the image is its top (largest y): origin="upper" with the world extent
    ax.imshow(grey, cmap="gray", vmin=0.0, vmax=1.0, extent=fl.extent, origin="upper",
              interpolation="nearest", zorder=0)

    rooms = list(building.rooms_on(fl.id))
    if room_labels is None:
        room_labels = len(rooms) <= MAX_LABELLED_ROOMS
    for k, room in enumerate(rooms):
        rings = [ring for poly in _polygons(room.geometry) for ring in (poly.exterior, *poly.interiors)]
        for j, ring in enumerate(rings):
            x, y = ring.xy
            ax.plot(x, y, color=ROOM_COLOR, lw=0.8, alpha=0.6, zorder=1, label="room" if k == j == 0 else None)
        if room_labels:
            p = room.geometry.representative_point()
            ax.text(p.x, p.y, room.id, fontsize=7, color=ROOM_COLOR, alpha=0.55, ha="center", va="center", zorder=1)

    segments = [np.asarray(line.coords)[:, :2] for r in building.routes_on(fl.id) for line in _lines(r.geometry)]
    if segments:
        ax.add_collection(LineCollection(segments, colors=ROUTE_COLOR, linewidths=1.0, linestyles="--",
                                         alpha=0.8, zorder=2, label="navigation graph"))

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
                                             zorder=3))
            ax.scatter(true[:, 0], true[:, 1], marker="x", s=14, linewidths=0.8, color="0.25", zorder=3,
                       label="true anchor position")
    for kind, style in ANCHOR_STYLE.items():
        sub = anchors[anchors["kind"] == kind]
        if len(sub):
            ax.scatter(sub["x"], sub["y"], marker=style["marker"], s=40, color=style["color"], edgecolors="k",
                       linewidths=0.5, zorder=4, label=f"{style['label']} ({len(sub)})")
    if anchor_labels is None:
        anchor_labels = len(anchors) <= MAX_LABELLED_ANCHORS
    if anchor_labels:
        for aid, x, y in zip(anchors["anchor_id"], anchors["x"], anchors["y"]):
            ax.annotate(str(aid), (x, y), xytext=(3, 3), textcoords="offset points", fontsize=6, zorder=5)

    x0, x1, y0, y1 = fl.extent
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
    dataset). One panel per floor; legends sit to the right of each panel.
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
    legend_w = 3.2
    fig = new_figure(ncols * (panel_w + legend_w), nrows * panel_h + 0.5)
    axes = np.atleast_1d(fig.subplots(nrows, ncols, squeeze=False)).ravel()
    for ax, fid in zip(axes, floors):
        plot_floor(ax, b, fid)
        plot_tracks(ax, [s for s in sessions if str(s.meta.get("floor")) == str(fid)])
    for ax in axes[len(floors):]:
        ax.set_visible(False)
    n_tracks = sum(1 for s in sessions if s.labelled)
    fig.suptitle(f"{dataset.name}: {b.name} ({b.id}), {len(sessions)} session(s), {n_tracks} with ground truth",
                 fontsize=11)
    return fig
