"""Where the train walks went (issue 30), on a floor's walkable grid: the survey the fused rows' priors and their
off-survey fix model read (:mod:`blenav.localizers.fusedwalk`), and the positions the KNN's novelty model measures
the survey by (:class:`blenav.localizers.knn.NoveltyModel`): each labelled walk's positions every
:data:`SURVEY_STEP_S` s, linear between its surveyed waypoints (no position between waypoints is scored, only used as
where a walker went)."""

from __future__ import annotations

import math

import numpy as np

__all__ = ["SURVEY_STEP_S", "walk_positions", "survey_counts", "path_prior", "survey_distance", "fix_log_likelihood"]

#: seconds between the positions a labelled walk is counted by
SURVEY_STEP_S = 0.5


def walk_positions(walk, step_s: float = SURVEY_STEP_S) -> np.ndarray:
    """(P, 2) m: a labelled walk's positions every ``step_s`` s between its first and last waypoint (linear between
    them); none for a walk with fewer than two waypoints."""
    gt = walk.groundtruth
    if len(gt) < 2:
        return np.zeros((0, 2))
    t = np.arange(float(gt["t"].iloc[0]), float(gt["t"].iloc[-1]) + 1e-9, step_s)
    xy = walk.positions_at(t)[:, :2]
    return xy[np.isfinite(xy).all(axis=1)]


def survey_counts(grid, walks: list, step_s: float) -> np.ndarray:
    """(N,) count per cell of ``grid`` of the labelled ``walks``' positions (:func:`walk_positions`)."""
    cnt = np.zeros(grid.n_cells)
    for s in walks:
        xy = walk_positions(s, step_s)
        if len(xy):
            np.add.at(cnt, grid.cell_of(xy), 1.0)
    return cnt


def path_prior(grid, walks: list, blur_m: float = 1.5, step_s: float = SURVEY_STEP_S, counts: np.ndarray | None = None
               ) -> np.ndarray:
    """(N,) density (sums to 1) over ``grid``'s cells of the labelled ``walks``' positions (interpolated linearly
    between their waypoints every ``step_s`` s), blurred by a Gaussian of ``blur_m`` m over the cell raster.
    ``counts``: those positions per cell already counted (:func:`survey_counts`), in place of ``walks``."""
    from scipy.ndimage import gaussian_filter

    img = np.zeros(grid.shape)
    img[grid.cy, grid.cx] = survey_counts(grid, walks, step_s) if counts is None else counts
    img = gaussian_filter(img, blur_m / grid.cell_m)[grid.cy, grid.cx]
    tot = img.sum()
    return img / tot if tot > 0 else np.full(grid.n_cells, 1.0 / grid.n_cells)


def survey_distance(grid, walks: list, step_s: float = SURVEY_STEP_S, counts: np.ndarray | None = None
                    ) -> tuple[np.ndarray, np.ndarray]:
    """Per cell of ``grid``: (distance in m to the nearest cell the labelled ``walks`` passed (N,), that cell's index
    (N,)); zeros and the cell itself where no walk is given. (The walks' positions are counted on their cells
    (:meth:`CrfGrid.cell_of`: always a walkable one), so the nearest is a cell of the grid.) ``counts``: as
    :func:`path_prior`'s."""
    from scipy.ndimage import distance_transform_edt

    cnt = survey_counts(grid, walks, step_s) if counts is None else counts
    if not cnt.any():
        return np.zeros(grid.n_cells), np.arange(grid.n_cells)
    img = np.ones(grid.shape, bool)
    img[grid.cy[cnt > 0], grid.cx[cnt > 0]] = False
    dist, (iy, ix) = distance_transform_edt(img, return_indices=True)
    lut = np.full(grid.shape, -1, np.int64)
    lut[grid.cy, grid.cx] = np.arange(grid.n_cells)
    return dist[grid.cy, grid.cx] * grid.cell_m, lut[iy[grid.cy, grid.cx], ix[grid.cy, grid.cx]]


def fix_log_likelihood(expected: np.ndarray, extra_var: np.ndarray, fix: np.ndarray, std: float, outlier: float,
                       n_cells: int) -> np.ndarray:
    """(N,) log p(fix | walker in cell i): (1 - ``outlier``) N(fix; ``expected[i]``, (std^2 + ``extra_var[i]``) I) +
    ``outlier`` / ``n_cells``. ``expected`` (N, 2) m: where a fix of a walker in each cell lands (the cell itself, or
    off the survey the nearest surveyed cell: ``off_survey.project``); ``extra_var`` (N,) m^2 the spread a fix gains
    there (``off_survey.std_per_m`` x the cell's distance to the survey, squared); ``fix`` (2,) m, ``std`` m."""
    var = std * std + extra_var
    d2 = ((expected - fix) ** 2).sum(axis=1)
    return np.logaddexp(math.log1p(-outlier) - d2 / (2.0 * var) - np.log(2.0 * math.pi * var),
                        math.log(outlier / n_cells))
