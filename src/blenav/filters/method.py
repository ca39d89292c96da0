"""What one localization method is, as the runners build it: :class:`Method` (the filter's settings, motion and
measurement models, :class:`MapSpec`, AHRS and step-detector settings, the BLE anchors it may use) and the modes
of its ``map`` node.

:func:`blenav.filters.runner.run_session` runs a method on a recorded session (R runs batched),
:class:`blenav.filters.online.OnlineLocalizer` sample by sample; both give the same numbers for the same seed.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from enum import StrEnum
from typing import Optional

from blenav.errors import MissingStream

from .attitude import AttitudeConfig
from .engine import FilterConfig
from .steps import StepDetectorConfig

__all__ = ["InitMode", "HeadingMode", "MapIndex", "INIT_MODES", "HEADING_MODES", "MapSpec", "Method",
           "require_models"]


class InitMode(StrEnum):
    """``map.init``: where particles start (see :class:`MapSpec`)."""

    uniform = "uniform"
    map = "map"
    fix = "fix"
    groundtruth = "groundtruth"


class HeadingMode(StrEnum):
    """``map.heading``: the odometry frame angle at the start (see :class:`MapSpec`)."""

    motion = "motion"
    groundtruth = "groundtruth"


class MapIndex(StrEnum):
    """``map.index``: the spatial index of the map conditioning (:mod:`blenav.filters.map.index`)."""

    grid = "grid"
    strtree = "strtree"


INIT_MODES = tuple(m.value for m in InitMode)
HEADING_MODES = tuple(m.value for m in HeadingMode)


@dataclass
class MapSpec:
    """How a method uses the floor plan.

    init: 'uniform' (global localization over free space, 000), 'map' (Patel et al. eq. 3:
    beta on navigation edges with sigma_nav, the rest in rooms with sigma_rm), 'fix' (Roy section 3.2:
    N(start, init_sigma_m^2 I) around the first position fix of ``init_fix_source``, by default the source
    of the method's first fix likelihood; Roy starts "around the true starting location obtained from the
    BLE localization model" with sigma = 0.01 m) or 'groundtruth' (the same around the ground-truth
    position at the session's start: an oracle start for methods without any absolute measurement, e.g.
    odometry alone, as inertial-odometry evaluations do); condition: project resampled particles onto
    edges / shrunk rooms (eqs. 4-5) with jitter ``sigma``; walls: penalise steps through obstacles (weight
    factor exp(filter.wall_log_penalty)).

    heading: 'motion' (the motion model's own initial frame angle: uniform in [-pi, pi) for
    :class:`~blenav.filters.motion.OdometryIncrement`, whose odometry frame is arbitrary) or 'groundtruth'
    (oracle: the rotation from the odometry frame to the world that best maps the odometry displacements
    onto the ground-truth ones over the first ``align_s`` seconds (least squares, 2 Hz samples; the whole
    session when the walker moved less than 1 m by then), plus N(0, init_heading_sigma^2); only for
    motion models with a frame-angle column, others ignore it).
    """

    init: InitMode = InitMode.uniform
    beta: float = 0.8
    sigma_nav: float = 2.0
    sigma_rm: float = 1.0
    condition: bool = False
    sigma: float = 0.3
    max_edge_dist: float = 3.0
    shrink: float = 1.0
    walls: bool = False
    index: MapIndex = MapIndex.grid
    init_sigma_m: float = 0.01
    init_fix_source: Optional[str] = None
    heading: HeadingMode = HeadingMode.motion
    align_s: float = 10.0
    init_heading_sigma: float = 0.0


@dataclass
class Method:
    name: str
    filter: FilterConfig
    motion: object
    measurements: list
    map: MapSpec = field(default_factory=MapSpec)
    attitude: AttitudeConfig = field(default_factory=AttitudeConfig)
    steps: StepDetectorConfig = field(default_factory=StepDetectorConfig)
    #: BLE anchor ids the measurement models may use (None: every BLE anchor of the building); packets of
    #: other anchors are dropped, as if those beacons were absent (the sparse-beacon rows of Roy, Table 3.7)
    beacons: Optional[tuple] = None

    @property
    def needs_imu(self) -> bool:
        return any(n in self.motion.needs for n in ("acc_w", "heading", "steps"))

    @property
    def needs_odometry(self) -> bool:
        return "odo" in self.motion.needs or bool(self.measurements_needing("odo"))

    def measurements_needing(self, stream: str) -> list:
        """The measurement models that read ``stream`` ('rssi', 'fixes')."""
        return [m for m in self.measurements if stream in m.needs]


def require_models(method: Method) -> None:
    """Raise :class:`MissingStream` when a component of ``method`` is unavailable (e.g. a learned map prior
    that was not given): models say so by ``missing_reason() -> str | None``."""
    for m in method.measurements:
        reason = m.missing_reason()
        if reason:
            raise MissingStream(f"{method.name}: {reason}")
