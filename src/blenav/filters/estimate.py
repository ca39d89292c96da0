"""The one result of a localization run: R runs of one method on one session (:class:`Estimate`).

Every :class:`~blenav.localizers.Localizer` returns it, and so do the particle filter's batch runners
(:func:`blenav.filters.runner.run_session`, :meth:`blenav.filters.runner.BatchRun.result`: ``outputs`` ``n_eff`` and
``attitude``, ``notes`` the map's remarks). It lives in the filters' layer, the lowest that makes one, so that the
runners, the runtime, the localizers and the evaluation share one type. The live runtime's rows, one step of one
run as it is made, are :class:`blenav.runtime.bundle.TrackPoint`.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from .engine import Event

__all__ = ["Estimate", "OUTPUT_KEYS"]

#: The documented keys of :attr:`Estimate.outputs` (a method may add others; these are the ones the
#: harness and the plots read).
OUTPUT_KEYS = {
    "n_eff": "(R, K) effective sample size per run and step (particle filters)",
    "attitude": "{'t': (T,) s, 'q': (T, 4) w, x, y, z}: the AHRS orientation, device to world (for "
                "orientation RMSE against the ground truth)",
    "beacon_map": "DataFrame anchor_id, x, y, z, std_m: beacon positions a method estimated",
    "smoothed": "(R, K, 2) world m: a smoothed trajectory at the same times as position",
    "probability": "per-step probability maps over a grid (method-specific layout, documented by the method)",
    "off_survey_log_ratio": "(K,) per estimate (a KNN fix with fix_std: calibrated): the log Bayes factor its scan "
                            "gives for the walker being off the survey (blenav.localizers.knn.NoveltyModel)",
}


@dataclass
class Estimate:
    """R runs of one localizer on one session.

    t (K,) s; position (R, K, 2) world m; cov (R, K, 2, 2) m^2 or None when the method gives no
    uncertainty; events: per-run events (``Event.run`` is the run index: recoveries, re-initialisations);
    outputs: method-specific results under the keys of :data:`OUTPUT_KEYS`; wall_s: the method's
    wall-clock time on this session, all runs; notes: remarks for the report (e.g. what a map was derived
    from).
    """

    method: str
    session: str
    t: np.ndarray
    position: np.ndarray
    cov: np.ndarray | None = None
    events: list[Event] = field(default_factory=list)
    outputs: dict[str, Any] = field(default_factory=dict)
    wall_s: float = 0.0
    notes: list[str] = field(default_factory=list)

    def __post_init__(self):
        self.t = np.asarray(self.t, float)
        self.position = np.asarray(self.position, float)
        if self.position.ndim != 3 or self.position.shape[1:] != (len(self.t), 2):
            raise ValueError(f"{self.method} on {self.session}: position must be (R, K, 2) with K = len(t) = "
                             f"{len(self.t)}, got {self.position.shape}")
        if self.cov is not None and self.cov.shape != self.position.shape + (2,):
            raise ValueError(f"{self.method} on {self.session}: cov must be (R, K, 2, 2), got {self.cov.shape}")

    @property
    def n_runs(self) -> int:
        return int(self.position.shape[0])

    @property
    def std(self) -> np.ndarray | None:
        """(R, K) m: sqrt of the covariance's trace / 2 (the mean per-axis standard deviation), or None."""
        if self.cov is None:
            return None
        return np.sqrt(np.maximum(np.trace(self.cov, axis1=-2, axis2=-1), 0.0) / 2.0)
