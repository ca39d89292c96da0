"""Problem-specific rules the particle filter applies after every propagation (engine ``constraints``).

:class:`ObstacleRules` holds the two rules that use the floor plan's obstacles:

* the wall-crossing penalty: a particle whose step crossed an obstacle gets ``penalty`` added to its
  log-weight (-inf: the particle dies; Patel et al. and 000 kill particles that walk through walls);
* Roy's re-initialisation (section 3.2): a run in which more than ``reinit_fraction`` (s_reinit = 0.9) of
  the particles crossed an obstacle on this step is re-initialised uniformly over the free space within
  ``reinit_radius_m`` (r_reinit = 5 m) of its last estimate (positions only: the other state columns, e.g.
  the odometry frame angle, are kept), with uniform weights, and recorded as a ``reinit-obstacles`` event;
  the step's measurements then weigh the new particles, and the new particles are not penalised.

Either rule can be used alone (``penalise=False`` keeps the walls for the re-initialisation only).
"""

from __future__ import annotations

import numpy as np

from .engine import Constraint, Event


class ObstacleRules(Constraint):
    """Wall-crossing penalty and/or obstacle re-initialisation on one floor.

    ``walls``: an object with ``crossed(xy_prev (R, N, 2), xy_new (R, N, 2)) -> bool (R, N)`` (e.g.
    :class:`~blenav.filters.map.walls.WallCrossing`); ``penalty``: log-weight added to crossing particles
    (``penalise=True``); ``reinit_fraction``: s_reinit in [0, 1), None disables the re-initialisation;
    ``reinit_radius_m``: r_reinit (m).
    """

    def __init__(self, walls, penalty: float = -np.inf, penalise: bool = True, reinit_fraction: float | None = None,
                 reinit_radius_m: float = 5.0):
        if reinit_fraction is not None and not 0.0 <= reinit_fraction < 1.0:
            raise ValueError(f"filter.reinit_fraction must be in [0, 1) or null, got {reinit_fraction!r}")
        if not reinit_radius_m > 0:
            raise ValueError(f"filter.reinit_radius_m must be > 0 m, got {reinit_radius_m!r}")
        self.walls = walls
        self.penalty = float(penalty)
        self.penalise = bool(penalise)
        self.reinit_fraction = reinit_fraction
        self.reinit_radius_m = float(reinit_radius_m)

    def after_propagate(self, pf, t: float, xy_prev: np.ndarray) -> np.ndarray | None:
        crossed = self.walls.crossed(xy_prev, pf.x[..., :2])
        if self.reinit_fraction is not None:
            crossed = self._reinit(pf, t, xy_prev, crossed)
        if not self.penalise:
            return None
        return np.where(crossed, self.penalty, 0.0)

    def _reinit(self, pf, t: float, xy_prev: np.ndarray, crossed: np.ndarray) -> np.ndarray:
        """Re-initialise the runs where more than ``reinit_fraction`` of the particles crossed an obstacle:
        N new positions uniform over the free space within ``reinit_radius_m`` of the run's last estimate
        (before the first estimate, the mean of the previous positions), uniform weights. Returns
        ``crossed`` (R, N) with those runs' rows cleared (the new particles did not move through anything)."""
        frac = crossed.mean(axis=1)
        redo = np.flatnonzero(frac > self.reinit_fraction)
        if len(redo) == 0:
            return crossed
        centre = pf.last_est[redo].copy()
        unknown = ~np.isfinite(centre[:, 0])
        if unknown.any():
            centre[unknown] = xy_prev[redo[unknown]].mean(axis=1)
        r = self.reinit_radius_m
        pf.x[redo, :, :2] = pf.initializer.sample_within(pf.rng, centre, pf.N, r)
        pf.logw[redo] = -np.log(pf.N)
        for run, f in zip(redo, frac[redo]):
            pf.events.append(Event(t, int(run), "reinit-obstacles",
                                   f"{f:.0%} of the particles crossed an obstacle (> {self.reinit_fraction:.0%}): "
                                   f"re-initialised within {r:g} m of the last estimate"))
        crossed = crossed.copy()
        crossed[redo] = False
        return crossed
