"""What every figure of :mod:`blenav.plotting` shares: the figure on an explicit Agg canvas
(:func:`new_figure`, :func:`save_figure` at :data:`DPI`), legends that never get cut off, track colours and
the styles of anchors, rooms and routes.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
from matplotlib import colormaps
from matplotlib.axes import Axes
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure

#: Resolution of saved figures (pixels per inch); a figure of size (w, h) inches saves as (w*DPI, h*DPI) px.
DPI = 120

#: Grey levels drawn for occupancy values: free white, unknown light grey, occupied black.
FREE_GREY, UNKNOWN_GREY, OCCUPIED_GREY = 1.0, 0.82, 0.0

#: Tracks named one by one in a legend; further sessions are summarised as "+ k more".
MAX_LEGEND_SESSIONS = 12

#: Anchors are labelled with their id when a floor has at most this many.
MAX_LABELLED_ANCHORS = 40
#: at most this many rooms get their id written inside (plot_floor's room_labels default)
MAX_LABELLED_ROOMS = 40

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


#: labels of anchors and rooms closer than this fraction of the floor's larger side to a label already written are
#: left out (:func:`keep_apart`): no label overprints another
LABEL_SPACING = 0.045


def keep_apart(xy: np.ndarray, min_dist: float) -> np.ndarray:
    """Which of the label anchors ``xy`` (N, 2) to label: greedily in the given order, a point is kept when it is at
    least ``min_dist`` from every point kept before it (deterministic: the same input, the same labels). Non-finite
    points are never kept. Returns a boolean mask (N,)."""
    xy = np.asarray(xy, float).reshape(-1, 2)
    keep = np.zeros(len(xy), bool)
    kept: list[np.ndarray] = []
    for i, p in enumerate(xy):
        if not np.isfinite(p).all():
            continue
        if kept and np.min(np.hypot(*(np.asarray(kept) - p).T)) < min_dist:
            continue
        keep[i] = True
        kept.append(p)
    return keep


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
