"""Real phone walks (issue 17, the ILC 2.0 recordings): Roy's odometry filters on PDR odometry, fused with
the fixes of a fingerprint localizer trained on the dataset's own train walks.

:class:`RealWalkPF` is a :class:`~blenav.localizers.ParticleFilterLocalizer` (the same config node: ``motion``,
``measurements``, ``map``, ``filter``, ...) with one addition for walks that have no ``odometry.csv``:

``odometry`` (optional)
    ``{source: pdr | lio, heading: orientation | ahrs | auto, step_length: 0.7 | null, attitude: null}``: ``source:
    lio`` runs the filter on the learned inertial odometry of ``io_model=IO_DIR`` (issue 31,
    :func:`blenav.filters.inertial_odometry.lio_odometry`: the network's velocities integrated, in the frame of
    ``attitude`` (null: the source the network was trained in, usually ``auto``: the rotation vector where the walk
    has one, else the AHRS); skipped with the reason when no
    io_model was given). ``source: pdr`` (the default) runs the filter on a PDR odometry track
    (:func:`blenav.filters.pdr_odometry.pdr_odometry`: detected steps along the phone's heading, world-aligned
    because the heading is magnetic-north referenced and the floor frame is east/north), handed to
    :func:`~blenav.filters.runner.run_session` as ``odometry=`` in place of ``odometry.csv``, so that Roy's
    odometry increment (eq. 3.7) and the learned map prior (eq. 3.8), which read odometry, run on a phone walk.
    ``heading: orientation`` uses the phone's rotation vector (``orientation.csv``; the walk is skipped with the
    reason when it has none), ``ahrs`` blenav's Madgwick AHRS with magnetometer (the same AHRS, hard-iron offset
    and cache entry as the filters' PDR motion model: :func:`blenav.filters.runner.session_imu`). ``step_length:
    null`` fits one step length on the train walks (:meth:`fit`, :func:`blenav.filters.pdr_odometry.fit_step_length`:
    the surveyed path length between their first and last waypoints over the steps detected there; 0.7 m until
    fitted / without train walks).

Fixes come through the experiment's ``fixes`` block like every other fused filter (:mod:`blenav.eval.fixes`: a role
per fix set, its ``compute`` node, e.g. ``${methods.knn_wifi}``, the KNN-WiFi row's own trained localizer; a fix
likelihood with ``role:`` reads it; ``use_std: true`` weighs each fix by the localizer's own std). With ``map.init:
fix`` the filter starts around the first fix (no ground truth used). Estimates are the filter's own (no padding to
the session's ends); waypoints outside them are scored with the experiment's ``scoring.hold_ends``
(:func:`blenav.eval.metrics.waypoint_metrics`).

Everything else is the particle filter's: ``map.init: groundtruth`` starts at the first surveyed waypoint
(the ground truth interpolated at the session start, i.e. the first waypoint when the walk starts there).
"""

from __future__ import annotations

import pandas as pd

from blenav.errors import MissingStream
from blenav.filters.pdr_odometry import DEFAULT_STEP_M, HEADING_SOURCES, fitted_step_length, pdr_odometry
from blenav.filters.yaw_hold import check_yaw
from blenav.localizers.base import NO_IO_MODEL, Estimate, InertialModelConsumer, Trained, attach_inertial
from blenav.localizers.inputs import RunInputs
from blenav.localizers.particle import ParticleFilterLocalizer

__all__ = ["RealWalkPF"]


ODOMETRY_SOURCES = ("pdr", "lio")


class RealWalkPF(ParticleFilterLocalizer, Trained, InertialModelConsumer):
    """A particle filter on real walks: PDR or learned odometry computed from the IMU (module doc)."""

    def __init__(self, name: str, shared=None, odometry=None, **pf):
        super().__init__(name, shared, **pf)
        odo = dict(odometry or {})
        unknown = set(odo) - {"source", "heading", "step_length", "attitude", "yaw"}
        if unknown:
            raise ValueError(f"method {name!r}, odometry: unknown key(s) {sorted(unknown)}; known: source, heading, "
                             f"step_length, attitude, yaw")
        check_yaw(odo.get("yaw", "attitude"), f"method {name!r}: odometry.yaw")
        self.odometry = odo if odometry is not None else None
        if self.odometry is not None and self.odometry.get("heading", "orientation") not in HEADING_SOURCES:
            raise ValueError(f"method {name!r}: odometry.heading must be one of {HEADING_SOURCES}, got "
                             f"{self.odometry['heading']!r}")
        self.source = str(odo.get("source", "pdr"))
        if self.source not in ODOMETRY_SOURCES:
            raise ValueError(f"method {name!r}: odometry.source must be one of {ODOMETRY_SOURCES}, got {self.source!r}")
        self.step_length = odo.get("step_length", DEFAULT_STEP_M)
        self.fitted_step: float | None = None
        self.io_model, self.io_reason = None, NO_IO_MODEL

    def attach_io_model(self, path: str | None, load) -> str | None:
        if self.odometry is None or self.source != "lio":
            return None
        self.io_model, self.io_reason = attach_inertial(path, load)
        return self.io_reason

    def fit(self, sessions: list, inputs: RunInputs) -> dict | None:
        if self.odometry is None or self.source != "pdr" or self.step_length is not None:
            return None
        fit = fitted_step_length(sessions, self.method.steps, inputs.cache)  # once per walks and detector
        self.fitted_step = float(fit["step_length_m"])
        return {"step_length": fit}

    def _step(self) -> float:
        if self.step_length is not None:
            return float(self.step_length)
        return self.fitted_step if self.fitted_step is not None else DEFAULT_STEP_M

    def odometry_for(self, session, inputs: RunInputs) -> pd.DataFrame | None:
        """The PDR or learned odometry the filter runs on (None without ``odometry``: the session's odometry.csv)."""
        if self.odometry is None:
            return None
        if self.source == "lio":
            if self.io_model is None:
                raise MissingStream(self.io_reason)
            return self.io_model.odometry(session, self.odometry.get("attitude"), cache=inputs.cache)
        return pdr_odometry(session, self.odometry.get("heading", "orientation"), self._step(), self.method.attitude,
                            self.method.steps, inputs.cache, self.odometry.get("yaw", "attitude"))

    def run(self, session, n_runs: int, seed: int, inputs: RunInputs | None = None) -> Estimate:
        est = super().run(session, n_runs, seed, inputs)
        if self.odometry is not None and self.source == "lio":
            est.notes.append(f"learned inertial odometry ({self.io_model.root}), frame "
                             f"{self.odometry.get('attitude') or self.io_model.attitude}")
        elif self.odometry is not None:
            est.notes.append(f"PDR odometry: heading from {self.odometry.get('heading', 'orientation')}, step "
                             f"{self._step():.3f} m")
        return est
