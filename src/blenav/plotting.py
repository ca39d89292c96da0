"""Figures of a dataset: floor plans with anchors, rooms, routes and tracks; RSSI statistics.

The only module of :mod:`blenav` that imports matplotlib. Figures are built with the object-oriented API
on an explicit Agg canvas (``matplotlib.figure.Figure`` + ``FigureCanvasAgg``), never through pyplot: this
renders headless without touching the process-wide backend (``matplotlib.use``), so importing this module
does not change plotting in a notebook or GUI that uses it, and figures are freed with their last reference.

World coordinates throughout: metres, x east, y north (docs/dataset-format.md). Computations (distance
pairing, path-loss fit) live in :mod:`blenav.radio_stats`; this module only draws.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Sequence
from pathlib import Path

import numpy as np
import pandas as pd
from matplotlib import colormaps
from matplotlib.axes import Axes
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.collections import LineCollection
from matplotlib.figure import Figure
from matplotlib.lines import Line2D
from matplotlib.ticker import FuncFormatter, NullFormatter
from shapely.geometry import LineString, MultiLineString, MultiPolygon, Polygon

from blenav.data import FREE, OCCUPIED, Building, Dataset, Session
from blenav.data.schema import ANCHOR_TRUE_COLUMNS
from blenav.radio_stats import fit_path_loss, path_loss_rssi, rssi_distance_pairs

#: Resolution of saved figures (pixels per inch); a figure of size (w, h) inches saves as (w*DPI, h*DPI) px.
DPI = 120

#: Grey levels drawn for occupancy values: free white, unknown light grey, occupied black.
FREE_GREY, UNKNOWN_GREY, OCCUPIED_GREY = 1.0, 0.82, 0.0

#: Tracks named one by one in a legend; further sessions are summarised as "+ k more".
MAX_LEGEND_SESSIONS = 12

#: Anchors are labelled with their id when a floor has at most this many.
MAX_LABELLED_ANCHORS = 40

#: Points drawn per receiver in the RSSI scatter (the fit always uses all of them).
MAX_SCATTER_POINTS = 20000

ANCHOR_STYLE = {
    "ble": {"marker": "^", "color": "tab:blue", "label": "BLE beacon"},
    "wifi_rtt": {"marker": "s", "color": "tab:red", "label": "WiFi RTT AP"},
}
ROOM_COLOR = "tab:purple"
ROUTE_COLOR = "tab:green"


def legend_in_figure(fig: Figure, ax: Axes, n_entries: int, inside: str | None = None, max_inside: int = 6,
                     rows: int = 22) -> None:
    """The legend of ``ax``: inside the axes at ``inside`` when it has at most ``max_inside`` entries, else
    beside the axes in the figure's right margin (``loc='outside right upper'``, which constrained layout
    makes room for), in as many columns of at most ``rows`` entries as needed: never cut off by the figure."""
    handles, labels = ax.get_legend_handles_labels()
    if not handles:
        return
    if inside is not None and n_entries <= max_inside:
        ax.legend(handles, labels, loc=inside, fontsize=8)
        return
    fig.legend(handles, labels, loc="outside right upper", fontsize=7, ncols=max(1, math.ceil(len(handles) / rows)),
               frameon=False)


def survey_points(x: np.ndarray, y: np.ndarray, decimals: int = 2) -> tuple[np.ndarray, np.ndarray]:
    """The distinct (x, y) positions of a static survey's ground truth (rounded to ``decimals``)."""
    xy = np.unique(np.round(np.column_stack([x, y]), decimals), axis=0)
    return xy[:, 0], xy[:, 1]


def new_figure(width_in: float, height_in: float) -> Figure:
    """A figure on an Agg canvas (no pyplot, no global backend), with constrained layout."""
    fig = Figure(figsize=(width_in, height_in), dpi=DPI, layout="constrained")
    FigureCanvasAgg(fig)
    return fig


def save_figure(fig: Figure, path: str | Path) -> Path:
    """Write ``fig`` as PNG at :data:`DPI` (size exactly figsize * DPI) and return the path."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=DPI, format="png")
    return path


def session_colors(n: int) -> list:
    """``n`` distinct colours for tracks/receivers (Dark2: unlike the blue/red anchor markers)."""
    if n <= 8:
        return [colormaps["Dark2"](i) for i in range(n)]
    return [colormaps["turbo"](0.05 + 0.9 * i / (n - 1)) for i in range(n)]


# --------------------------------------------------------------------------- floor plans


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


def plot_floor(ax: Axes, building: Building, floor_id, *, anchor_labels: bool | None = None) -> Axes:
    """Draw one floor in world metres: occupancy grid, rooms, navigation graph and radio anchors.

    Anchors: BLE beacons as triangles, WiFi RTT access points as squares, at their prior (map) positions;
    where the anchors carry ``x_true, y_true`` a thin line joins the prior to the true position (small x).
    ``anchor_labels``: write anchor ids next to them (default: when the floor has at most
    :data:`MAX_LABELLED_ANCHORS`).
    """
    fl = building.floor(floor_id)
    occ = fl.occupancy
    grey = np.full(occ.shape, UNKNOWN_GREY, dtype=float)
    grey[occ == FREE] = FREE_GREY
    grey[occ == OCCUPIED] = OCCUPIED_GREY
    # row 0 of the image is its top (largest y): origin="upper" with the world extent
    ax.imshow(grey, cmap="gray", vmin=0.0, vmax=1.0, extent=fl.extent, origin="upper",
              interpolation="nearest", zorder=0)

    for k, room in enumerate(building.rooms_on(fl.id)):
        rings = [ring for poly in _polygons(room.geometry) for ring in (poly.exterior, *poly.interiors)]
        for j, ring in enumerate(rings):
            x, y = ring.xy
            ax.plot(x, y, color=ROOM_COLOR, lw=0.8, alpha=0.6, zorder=1, label="room" if k == j == 0 else None)
        p = room.geometry.representative_point()
        ax.text(p.x, p.y, room.id, fontsize=7, color=ROOM_COLOR, alpha=0.55, ha="center", va="center", zorder=1)

    segments = [np.asarray(line.coords)[:, :2] for r in building.routes_on(fl.id) for line in _lines(r.geometry)]
    if segments:
        ax.add_collection(LineCollection(segments, colors=ROUTE_COLOR, linewidths=1.0, linestyles="--",
                                         alpha=0.8, zorder=2, label="navigation graph"))

    anchors = building.anchors_of(floor=fl.id)
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


# --------------------------------------------------------------------------- radio


def figure_radio(sessions: Iterable[Session]) -> Figure:
    """RSSI statistics of ``sessions``.

    Left: RSSI against the 3-D phone-anchor distance (labelled sessions; ground truth interpolated at each
    reading, true anchor positions when known) per receiver model, with the least-squares log-distance
    path-loss line ``A - 10 n log10(d)`` over all points (``n`` and the residual std in the legend).
    Right: RSSI histograms per receiver (``device_model``), all sessions.
    """
    sessions = list(sessions)
    fig = new_figure(13.0, 5.0)
    ax_d, ax_h = fig.subplots(1, 2, width_ratios=[1.35, 1.0])

    pairs, values = [], {}
    for s in sessions:
        r = s.rssi
        if len(r):
            values.setdefault(s.device_model or "?", []).append(r["rssi"].to_numpy(dtype=float))
        p = rssi_distance_pairs(s)
        if len(p):
            pairs.append(p.assign(device_model=s.device_model or "?"))
    models = sorted(values)
    colors = dict(zip(models, session_colors(len(models))))

    if pairs:
        allp = pd.concat(pairs, ignore_index=True)
        rng = np.random.default_rng(0)
        for m, grp in allp.groupby("device_model", sort=True):
            count = len(grp)
            if count > MAX_SCATTER_POINTS:
                grp = grp.iloc[np.sort(rng.choice(count, MAX_SCATTER_POINTS, replace=False))]
            ax_d.scatter(grp["distance_m"], grp["rssi"], s=5, alpha=0.35, color=colors[m], linewidths=0,
                         label=f"{m} ({count} readings)", rasterized=True)
        d = allp["distance_m"].to_numpy()
        try:
            a_dbm, n, sd = fit_path_loss(d, allp["rssi"].to_numpy())
        except ValueError as exc:
            ax_d.text(0.5, 0.05, f"no path-loss fit: {exc}", transform=ax_d.transAxes, ha="center", fontsize=8)
        else:
            dd = np.geomspace(max(d[d > 0].min(), 0.05), d.max(), 200)
            ax_d.plot(dd, path_loss_rssi(dd, a_dbm, n), color="k", lw=2,
                      label=f"fit: A = {a_dbm:.1f} dBm at 1 m, n = {n:.2f}, residual std = {sd:.1f} dB")
        ax_d.set_xscale("log")
        ax_d.xaxis.set_major_formatter(FuncFormatter(lambda v, _: f"{v:g}"))
        span = np.log10(d.max() / max(d[d > 0].min(), 1e-9)) if (d > 0).any() else 0.0
        ax_d.xaxis.set_minor_formatter(FuncFormatter(lambda v, _: f"{v:g}") if span < 1.3 else NullFormatter())
        ax_d.legend(loc="upper right", fontsize=7, markerscale=2.5)
    else:
        ax_d.text(0.5, 0.5, "no RSSI readings with ground truth", transform=ax_d.transAxes, ha="center",
                  va="center")
    ax_d.set_xlabel("3-D distance phone - anchor [m]")
    ax_d.set_ylabel("RSSI [dBm]")
    ax_d.set_title("RSSI against distance", fontsize=10)
    ax_d.grid(True, which="both", alpha=0.3)

    if values:
        allv = np.concatenate([np.concatenate(v) for v in values.values()])
        bins = np.arange(np.floor(allv.min()) - 0.5, np.ceil(allv.max()) + 1.5, 1.0)
        if len(bins) > 121:  # wide ranges: about 120 bins
            bins = np.linspace(bins[0], bins[-1], 121)
        for m in models:
            v = np.concatenate(values[m])
            ax_h.hist(v, bins=bins, density=True, histtype="step", lw=1.4, color=colors[m],
                      label=f"{m} (N = {v.size}, median {np.median(v):.0f} dBm)")
        ax_h.legend(loc="upper left", fontsize=7)
    else:
        ax_h.text(0.5, 0.5, "no RSSI readings", transform=ax_h.transAxes, ha="center", va="center")
    ax_h.set_xlabel("RSSI [dBm]")
    ax_h.set_ylabel("density")
    ax_h.set_title("RSSI per receiver", fontsize=10)
    ax_h.grid(True, alpha=0.3)
    fig.suptitle(f"Received signal strength, {len(sessions)} session(s)", fontsize=11)
    return fig


def figure_rssi_vs_distance(panels: dict[str, pd.DataFrame]) -> Figure:
    """One panel per data set: RSSI against distance (2-D histogram) with its fitted path-loss line.

    ``panels`` maps a title to a frame with ``distance_m`` and ``rssi`` (as from
    :func:`blenav.radio_stats.rssi_distance_pairs`); shared axes so the sets compare at a glance.
    """
    n = max(len(panels), 1)
    cols = min(n, 3)
    rows = math.ceil(n / cols)
    fig = new_figure(4.6 * cols, 3.6 * rows)
    axes = np.atleast_1d(fig.subplots(rows, cols, sharex=True, sharey=True)).ravel()
    dmin = min((p["distance_m"][p["distance_m"] > 0].min() for p in panels.values() if len(p)), default=0.1)
    dmax = max((p["distance_m"].max() for p in panels.values() if len(p)), default=10.0)
    xbins = np.geomspace(max(dmin, 0.1), dmax, 50)
    ybins = np.arange(-110, -20, 2.0)
    for ax, (title, p) in zip(axes, panels.items()):
        d, r = p["distance_m"].to_numpy(float), p["rssi"].to_numpy(float)
        ax.hist2d(d, r, bins=[xbins, ybins], cmap="Greys", cmin=1, rasterized=True)
        try:
            a_dbm, nexp, sd = fit_path_loss(d, r)
            dd = np.geomspace(xbins[0], xbins[-1], 100)
            ax.plot(dd, path_loss_rssi(dd, a_dbm, nexp), color="tab:red", lw=1.8,
                    label=f"A = {a_dbm:.1f} dBm, n = {nexp:.2f}, std {sd:.1f} dB")
            ax.legend(loc="lower left", fontsize=7)
        except ValueError as exc:
            ax.text(0.5, 0.5, str(exc), transform=ax.transAxes, ha="center", fontsize=7)
        ax.set_xscale("log")
        ax.xaxis.set_major_formatter(FuncFormatter(lambda v, _: f"{v:g}"))
        ax.set_title(f"{title} ({len(p):,} readings)", fontsize=9)
        ax.grid(True, which="both", alpha=0.3)
    for ax in axes[len(panels):]:
        ax.set_visible(False)
    for ax in axes[::cols]:
        ax.set_ylabel("RSSI [dBm]")
    for ax in axes[-cols:]:
        ax.set_xlabel("distance [m]")
    return fig


# --------------------------------------------------------------------------- evaluation


def figure_error_cdf(grid: np.ndarray, cdfs: dict[str, np.ndarray], title: str = "") -> Figure:
    """Position-error CDF per method: median over runs with the 5-95 % band (``cdfs[name]`` (3, G))."""
    fig = new_figure(7.0, 4.6)
    ax = fig.subplots()
    for (name, band), c in zip(cdfs.items(), session_colors(len(cdfs))):
        ax.fill_between(grid, band[0], band[2], color=c, alpha=0.2, linewidth=0)
        ax.plot(grid, band[1], color=c, lw=1.8, label=name)
    ax.set_xlabel("position error [m]")
    ax.set_ylabel("fraction of estimates")
    ax.set_ylim(0, 1)
    ax.set_xlim(grid[0], grid[-1])
    ax.grid(True, alpha=0.3)
    legend_in_figure(fig, ax, len(cdfs), inside="lower right")
    ax.set_title(title or "error CDF (median over runs, 5-95 % band)", fontsize=9)
    return fig


def figure_per_device(means: dict[str, dict[str, float]], title: str = "") -> Figure:
    """Grouped bars: mean error (m) per test device (x) and method (colour); ``means[method][device]``."""
    devices = sorted({d for m in means.values() for d in m})
    fig = new_figure(max(6.0, 0.55 * len(devices) * max(1, len(means)) ** 0.5 + 2), 4.4)
    ax = fig.subplots()
    w = 0.8 / max(len(means), 1)
    x = np.arange(len(devices))
    for k, ((name, m), c) in enumerate(zip(means.items(), session_colors(len(means)))):
        ax.bar(x + (k - (len(means) - 1) / 2) * w, [m.get(d, np.nan) for d in devices], w, color=c, label=name)
    ax.set_xticks(x, devices, rotation=45, ha="right", fontsize=8)
    ax.set_ylabel("mean absolute error [m]")
    ax.grid(True, axis="y", alpha=0.3)
    ax.legend(fontsize=7, ncol=2)
    ax.set_title(title or "mean error per test device", fontsize=9)
    return fig


def figure_rmse_box(rmses: dict[str, np.ndarray], title: str = "") -> Figure:
    """Box plot of per-run RMSE (m) per method."""
    fig = new_figure(1.4 + 1.2 * len(rmses), 4.4)
    ax = fig.subplots()
    ax.boxplot(list(rmses.values()), tick_labels=list(rmses), showfliers=True)
    ax.set_ylabel("RMSE per run [m]")
    ax.grid(True, axis="y", alpha=0.3)
    ax.set_title(title or "RMSE per run", fontsize=9)
    return fig


def figure_error_over_time(err_t: dict[str, tuple[np.ndarray, np.ndarray]], init_s: float, session_id: str) -> Figure:
    """Error over time per method (median over runs, 5-95 % band); the global-localization period shaded."""
    fig = new_figure(9.0, 4.0)
    ax = fig.subplots()
    t0 = None
    for (name, (t, err)), c in zip(err_t.items(), session_colors(len(err_t))):
        q = np.quantile(err, [0.05, 0.5, 0.95], axis=0)
        ax.fill_between(t, q[0], q[2], color=c, alpha=0.15, linewidth=0)
        ax.plot(t, q[1], color=c, lw=1.2, label=name)
        t0 = t[0] if t0 is None else min(t0, t[0])
    if t0 is not None:
        ax.axvspan(t0, t0 + init_s, color="0.85", zorder=0, label="global localization")
    ax.set_xlabel("time [s]")
    ax.set_ylabel("position error [m]")
    ax.set_title(f"error over time, session {session_id}", fontsize=9)
    ax.grid(True, alpha=0.3)
    legend_in_figure(fig, ax, len(err_t) + 1, inside="upper right")
    return fig


def figure_trajectories(session: Session, tracks: dict[str, tuple[np.ndarray, np.ndarray]]) -> Figure:
    """Estimated trajectories (one run per method) over the floor plan with the ground truth."""
    b = session.building
    fl = session.floor
    x0, x1, y0, y1 = fl.extent
    w = 9.0
    fig = new_figure(w, max(3.5, w * (y1 - y0) / max(x1 - x0, 1e-9) * 0.85))
    ax = fig.subplots()
    plot_floor(ax, b, session.meta.get("floor"), anchor_labels=False)
    gt = session.groundtruth
    static = session.carrier == "static"  # a survey: points (the device jumps between them), not lines through walls
    if static:
        ax.scatter(*survey_points(gt["x"].to_numpy(), gt["y"].to_numpy()), s=30, marker="s", color="k",
                   label="ground truth (survey points)", zorder=6)
    else:
        ax.plot(gt["x"], gt["y"], color="k", lw=2.0, label="ground truth")
    for (name, (t, p)), c in zip(tracks.items(), session_colors(len(tracks))):
        if static:
            ax.scatter(p[:, 0], p[:, 1], s=6, color=c, alpha=0.7, label=name, zorder=5)
        else:
            ax.plot(p[:, 0], p[:, 1], color=c, lw=1.0, alpha=0.9, label=name)
    legend_in_figure(fig, ax, len(tracks) + 1)
    ax.set_anchor("W")  # the equal aspect narrows the axes: keep them (and the y label) at the left, beside the legend
    ax.set_title(f"trajectories, session {session.id} (first run)", fontsize=9)
    return fig


def figure_learning_curves(history: Sequence[dict], knn_val_err_m: float | None = None, title: str = "") -> Figure:
    """Learning curves of one training run (:class:`blenav.learn.trainer.TrainingMonitor` history): left, the
    training and validation loss per validation check against optimizer steps (log scale) and the learning
    rate (right axis); right, the validation error in metres with KNN's on the same validation windows."""
    fig = new_figure(9.0, 3.6)
    ax, ax2 = fig.subplots(1, 2)
    step = np.array([h.get("step", np.nan) for h in history], float)

    def col(key):
        return np.array([np.nan if h.get(key) is None else h[key] for h in history], float)

    ax.plot(step, col("train_loss"), label="train loss", lw=1.0)
    ax.plot(step, col("val_loss"), label="validation loss", lw=1.0)
    if np.isfinite(col("val_loss")).any() or np.isfinite(col("train_loss")).any():
        ax.set_yscale("log")
    ax.set_xlabel("optimizer step")
    ax.set_ylabel("loss")
    ax.grid(True, alpha=0.3)
    lr = col("lr")
    if np.isfinite(lr).any():
        axr = ax.twinx()
        axr.plot(step, lr, color="0.6", lw=0.8, ls=":", label="learning rate")
        axr.set_ylabel("learning rate", fontsize=8)
    ax.legend(fontsize=7)
    ax2.plot(step, col("val_err_m"), label="network, validation", lw=1.0)
    if knn_val_err_m is not None and np.isfinite(knn_val_err_m):
        ax2.axhline(knn_val_err_m, color="k", ls="--", lw=0.8, label=f"KNN, validation ({knn_val_err_m:.2f} m)")
    ax2.set_xlabel("optimizer step")
    ax2.set_ylabel("mean validation error [m]")
    ax2.grid(True, alpha=0.3)
    ax2.legend(fontsize=7)
    fig.suptitle(title or "learning curves", fontsize=9)
    return fig


# --------------------------------------------------------------------------- leaderboard

#: one colour per method family of the leaderboard (conf/experiment/leaderboard.yaml ``experiment.families``)
FAMILY_COLORS = {"PF classical": "tab:blue", "map fusion": "tab:green", "back-end": "tab:purple", "CRF": "tab:orange",
                 "learned": "tab:red", "fingerprint": "tab:brown", "bound": "black", "other": "tab:gray"}
_FAMILY_STYLES = ["-", "--", ":", "-."]


def figure_leaderboard_cdf(grid: np.ndarray, cdfs: dict[str, np.ndarray], families: dict[str, str], title: str = "",
                           rmse: dict[str, float] | None = None,
                           bounds: dict[str, tuple[float, np.ndarray]] | None = None) -> Figure:
    """The leaderboard's error CDF: one colour per method family (:data:`FAMILY_COLORS`), methods of one family
    told apart by line style; ``cdfs[name]`` (G,) the median CDF over runs, ``rmse[name]`` shown in the
    legend; ``bounds[name] = (RMSE, CDF (G,))``: a bound as the error CDF of an estimator that attains it
    (black, dashed / dotted) and its RMSE as a thin vertical line. The legend, grouped by family and sorted by
    RMSE within it, sits in the figure's right margin."""
    rmse = rmse or {}
    fig = new_figure(10.0, 5.2)
    ax = fig.subplots()
    fam_rank = {f: i for i, f in enumerate(FAMILY_COLORS)}
    seen: dict[str, int] = {}
    for name in sorted(cdfs, key=lambda n: (fam_rank.get(families.get(n, "other"), 99), rmse.get(n, np.inf))):
        fam = families.get(name, "other")
        k = seen.get(fam, 0)
        seen[fam] = k + 1
        lab = f"{name} ({rmse[name]:.2f} m)" if name in rmse else name
        ax.plot(grid, cdfs[name], color=FAMILY_COLORS.get(fam, "tab:gray"), ls=_FAMILY_STYLES[k % 4],
                lw=2.0 if k < 4 else 1.0, label=f"{fam}: {lab}")
    for k, (name, (b_rmse, b_cdf)) in enumerate((bounds or {}).items()):
        ls = "--" if k == 0 else ":"
        ax.plot(grid, b_cdf, color="black", ls=ls, lw=2.0, label=f"bound: {name} ({b_rmse:.2f} m RMSE)")
        ax.axvline(b_rmse, color="black", lw=0.7, ls=ls)
    ax.set_xlabel("position error [m]")
    ax.set_ylabel("fraction of estimates")
    ax.set_ylim(0, 1)
    ax.set_xlim(grid[0], grid[-1])
    ax.grid(True, alpha=0.3)
    legend_in_figure(fig, ax, len(cdfs) + len(bounds or {}), rows=26)
    ax.set_title(title or "leaderboard: error CDF (median over runs), one colour per family", fontsize=9)
    return fig


def figure_bound_over_time(curves: dict[str, dict], curves_ble: dict[str, dict] | None = None) -> Figure:
    """The PCRLB (sqrt of the trace of the position block of J_k^-1, m) over time per session (solid) and,
    when given, the BLE-only bound (dashed); ``curves[session] = {"t" (K,), "bound_m" (K,)}``."""
    fig = new_figure(8.0, 3.8)
    ax = fig.subplots()
    for (sid, c), col in zip(curves.items(), session_colors(len(curves))):
        ax.plot(c["t"], c["bound_m"], color=col, lw=1.2, label=f"{sid}: PCRLB")
        if curves_ble and sid in curves_ble:
            ax.plot(curves_ble[sid]["t"], curves_ble[sid]["bound_m"], color=col, lw=1.0, ls="--", label=f"{sid}: BLE only")
    ax.set_yscale("log")
    ax.set_xlabel("time [s]")
    ax.set_ylabel("PCRLB of the position error [m]")
    ax.grid(True, alpha=0.3, which="both")
    legend_in_figure(fig, ax, len(curves) + sum(sid in (curves_ble or {}) for sid in curves), inside="upper right")
    ax.set_title("posterior Cramer-Rao lower bound along the true trajectories", fontsize=9)
    return fig
