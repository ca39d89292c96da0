"""The fixes of one role scored as a trajectory: the BLE-only rows of Roy's Table 3.7 ("Dense BLE",
"Sparse BLE"), whose estimate is the BLE localizer's output itself.

Config node::

    _target_: blenav.localizers.FixTrackLocalizer
    role: dense          # a role of the experiment's fixes block (blenav.eval.fixes)
"""

from __future__ import annotations

import time

import numpy as np

from blenav.errors import MissingStream

from .base import Estimate, FixConsumer, Localizer
from .inputs import RunInputs


class FixTrackLocalizer(Localizer, FixConsumer):
    """The ``role``'s fixes as R identical runs (no covariance). ``wall_s`` is the time the BLE localizer took
    to compute them (when computed, also if read from the evaluation's cache) times R, else the time to read
    them."""

    uses_floor_plan = False  # the fixes as they are

    def __init__(self, name: str, shared=None, role: str = "dense"):
        super().__init__(name, shared)
        self.role = str(role)

    def fix_roles(self) -> list[str]:
        return [self.role]

    def run(self, session, n_runs: int, seed: int, inputs: RunInputs | None = None) -> Estimate:
        if inputs is None or inputs.fixes is None:
            raise ValueError(f"method {self.name} scores {self.role} fixes but the experiment has no fixes block")
        t0 = time.perf_counter()
        f = inputs.fixes[self.role]  # MissingStream when the session has none
        t, xy = f.t, f.xy
        if not len(t):
            raise MissingStream(f"no {self.role} fixes for session {session.id}")
        pos = np.broadcast_to(xy, (n_runs,) + xy.shape).copy()
        wall = f.wall_s if f.wall_s is not None else time.perf_counter() - t0
        return Estimate(self.name, session.id, t, pos, None, [], {}, n_runs * wall, [])
