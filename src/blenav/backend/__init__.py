"""The radio-inertial smoothing back-end of Ghaffari Jadidi et al. (000, sec. IV-D) on GTSAM, and beacon maps
from labelled walks (issue 14).

* :mod:`blenav.backend.config`: settings (:class:`BackendConfig`, ``conf/backend/default.yaml``);
* :mod:`blenav.backend.graph`: the factor graph and its solvers (:func:`smooth`), with its inputs and result in
  :mod:`blenav.backend.graph_types` and the pieces of its factors in :mod:`blenav.backend.factors`;
* :mod:`blenav.backend.inputs`: a session and a front-end estimate -> the graph's inputs;
* :mod:`blenav.backend.mapping`: beacon positions and RSSI at 1 m from walks with known poses (``blenav-map``);
  its readings, RSSI factor, solve and report in ``mapping_readings``, ``mapping_factor``, ``mapping_solve``,
  ``mapping_report``;
* :mod:`blenav.backend.localizer`: :class:`BackendLocalizer`, a particle-filter front-end then the smoother, as a
  localizer (``conf/localizer/backend.yaml``).

GTSAM is imported when a graph is built, not when this package is.
"""

from .config import BackendConfig, load_backend_config
from .graph import smooth
from .graph_types import (BackendFailure, BackendResult, BeaconPriors, ImuSamples, Keyframes, RangeObs,
                          describe_key)

__all__ = ["BackendConfig", "BackendFailure", "BackendResult", "BeaconPriors", "ImuSamples", "Keyframes", "RangeObs",
           "describe_key", "load_backend_config", "smooth"]
