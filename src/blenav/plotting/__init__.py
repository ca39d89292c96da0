"""Figures of blenav: floor plans with anchors, rooms, routes and tracks; RSSI statistics; evaluation and
leaderboard figures.

The only package of :mod:`blenav` that imports matplotlib. Figures are built with the object-oriented API
on an explicit Agg canvas (``matplotlib.figure.Figure`` + ``FigureCanvasAgg``), never through pyplot: this
renders headless without touching the process-wide backend (``matplotlib.use``), so importing this package
does not change plotting in a notebook or GUI that uses it, and figures are freed with their last reference.

World coordinates throughout: metres, x east, y north (docs/dataset-format.md). Computations (distance
pairing, path-loss fit) live in :mod:`blenav.radio_stats`; this package only draws.

Modules: :mod:`~blenav.plotting.common` (canvas, saving, legends, colours and styles),
:mod:`~blenav.plotting.floor` (floor plans, tracks, the overview), :mod:`~blenav.plotting.radio` (RSSI
statistics), :mod:`~blenav.plotting.evaluation` (an evaluation's and the leaderboard's figures). The names
below are the package's interface (``from blenav import plotting; plotting.figure_radio(...)``).
"""

from .common import DPI, new_figure, save_figure
from .evaluation import (
    figure_bound_over_time,
    figure_error_cdf,
    figure_error_over_time,
    figure_leaderboard_cdf,
    figure_learning_curves,
    figure_per_device,
    figure_rmse_box,
    figure_trajectories,
)
from .floor import figure_overview, plot_floor, plot_tracks
from .radio import figure_radio, figure_rssi_vs_distance

__all__ = ["DPI", "new_figure", "save_figure", "plot_floor", "plot_tracks", "figure_overview", "figure_radio",
           "figure_rssi_vs_distance", "figure_error_cdf", "figure_per_device", "figure_rmse_box",
           "figure_error_over_time", "figure_trajectories", "figure_learning_curves", "figure_leaderboard_cdf",
           "figure_bound_over_time"]
