"""The radio-inertial smoothing back-end of Ghaffari Jadidi et al. (000, sec. IV-D) on GTSAM, and beacon maps
from labelled walks (issue 14).

* :mod:`blenav.backend.config`: settings (:class:`BackendConfig`, ``conf/backend/default.yaml``);
* :mod:`blenav.backend.graph`: the factor graph and its solvers (:func:`smooth`);
* :mod:`blenav.backend.inputs`: a session and a front-end estimate -> the graph's inputs;
* :mod:`blenav.backend.mapping`: beacon positions and RSSI at 1 m from walks with known poses (``blenav-map``);
* :mod:`blenav.backend.localizer`: :class:`BackendLocalizer`, a particle-filter front-end then the smoother, as a
  localizer (``conf/localizer/backend.yaml``).

GTSAM is imported when a graph is built, not when this package is.
"""

from .config import BackendConfig, load_backend_config
from .graph import (BackendFailure, BackendResult, BeaconPriors, ImuSamples, Keyframes, RangeObs, describe_key,
                    smooth)

__all__ = ["BackendConfig", "BackendFailure", "BackendResult", "BeaconPriors", "ImuSamples", "Keyframes", "RangeObs",
           "describe_key", "load_backend_config", "smooth"]
