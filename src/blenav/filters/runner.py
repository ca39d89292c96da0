"""Run one localization method on one session for R independent runs (the batch API).

A :class:`Method` bundles the components a run builds: the algorithm settings
(:class:`~blenav.filters.engine.FilterConfig`), a motion model, measurement models, the map spec
(initialisation, resampling conditioning, wall crossing) and the AHRS settings. :func:`run_session`
returns every run's estimates at every step; :class:`OnlineLocalizer` is the streaming API that gives
the same answer for the same seed.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np

from blenav.data import Session

from .attitude import AttitudeConfig, estimate_hard_iron
from .engine import Event, FilterConfig, ParticleFilter
from .map_fusion import MapGeometry, WallCrossing
from .measurement import AnchorTable
from .steps import SessionArrays, StepDetectorConfig, StepStream, imu_features, session_steps


class MissingStream(ValueError):
    """The session lacks a stream the method needs (e.g. IMU for the IMU proposal): skip, do not fail."""


@dataclass
class MapSpec:
    """How a method uses the floor plan.

    init: 'uniform' (global localization over free space, 000) or 'map' (Patel et al. eq. 3:
    beta on navigation edges with sigma_nav, the rest in rooms with sigma_rm); condition: project
    resampled particles onto edges / shrunk rooms (eqs. 4-5) with jitter ``sigma``; walls: penalise steps
    through obstacles (weight factor exp(filter.wall_log_penalty)).
    """

    init: str = "uniform"
    beta: float = 0.8
    sigma_nav: float = 2.0
    sigma_rm: float = 1.0
    condition: bool = False
    sigma: float = 0.3
    max_edge_dist: float = 3.0
    shrink: float = 1.0
    walls: bool = False
    index: str = "grid"


@dataclass
class Method:
    name: str
    filter: FilterConfig
    motion: object
    measurements: list
    map: MapSpec = field(default_factory=MapSpec)
    attitude: AttitudeConfig = field(default_factory=AttitudeConfig)
    steps: StepDetectorConfig = field(default_factory=StepDetectorConfig)

    @property
    def needs_imu(self) -> bool:
        return any(n in getattr(self.motion, "needs", ()) for n in ("acc_w", "heading", "steps"))

    def measurements_needing(self, stream: str) -> list:
        """The measurement models that read ``stream`` ('rssi', 'fixes')."""
        return [m for m in self.measurements if stream in getattr(m, "needs", ())]


class _Initializer:
    """Adapter: the filter's initializer from a map geometry and a :class:`MapSpec`."""

    def __init__(self, geom: MapGeometry, spec: MapSpec):
        self.geom, self.spec = geom, spec

    def sample(self, rng, R, N):
        if self.spec.init == "map":
            return self.geom.sample_initial(rng, R, N, beta=self.spec.beta, sigma_nav=self.spec.sigma_nav,
                                            sigma_rm=self.spec.sigma_rm)
        if self.spec.init == "uniform":
            return self.geom.sample_uniform_free(rng, R, N)
        raise ValueError(f"map.init must be 'uniform' or 'map', got {self.spec.init!r}")

    def snap_free(self, xy):
        return self.geom.snap_free(xy)


class _Conditioner:
    def __init__(self, geom: MapGeometry, spec: MapSpec):
        self.geom, self.spec = geom, spec

    def condition(self, xy, rng, mask=None):
        return self.geom.condition(xy, rng, sigma=self.spec.sigma, max_edge_dist=self.spec.max_edge_dist,
                                   shrink=self.spec.shrink, mask=mask)


@dataclass
class RunResult:
    """Estimates of R runs on one session: t (K,) s, position (R, K, 2) m, n_eff (R, K), AHRS (T, 4)."""

    method: str
    session: str
    t: np.ndarray
    position: np.ndarray
    cov: np.ndarray
    n_eff: np.ndarray
    events: list[Event]
    q_imu: np.ndarray | None
    imu_t: np.ndarray | None
    wall_s: float
    map_notes: list[str]


def build_filter(method: Method, session: Session, n_runs: int, rng: np.random.Generator,
                 geom: MapGeometry | None = None) -> tuple[ParticleFilter, AnchorTable, MapGeometry]:
    floor_id = session.meta.get("floor")
    geom = geom or MapGeometry.from_building(session.building, floor_id, derive_missing=True,
                                             index=method.map.index)
    anchors = AnchorTable.from_frame(session.building.anchors, "ble")
    for m in method.measurements:
        m.bind(anchors)
    walls = WallCrossing.from_floor(session.floor) if method.map.walls else None
    cond = _Conditioner(geom, method.map) if method.map.condition else None
    pf = ParticleFilter(method.filter, method.motion, method.measurements, _Initializer(geom, method.map), rng,
                        n_runs=n_runs, conditioner=cond, walls=walls)
    return pf, anchors, geom


def run_session(method: Method, session: Session, n_runs: int, seed: int,
                geom: MapGeometry | None = None, cache: dict | None = None) -> RunResult:
    """All R runs of ``method`` on ``session`` (batched), seeded by ``seed``.

    ``cache``: a dict shared by calls on the same sessions (the evaluation harness passes one), so
    that the floor's map geometry and the session's AHRS and step detection, which do not depend on
    the method's filter, are computed once rather than once per method.
    """
    t0 = time.perf_counter()
    rng = np.random.default_rng(seed)
    if cache is not None and geom is None:
        gkey = ("geom", session.building.id, str(session.meta.get("floor")), method.map.index)
        if gkey not in cache:
            cache[gkey] = MapGeometry.from_building(session.building, session.meta.get("floor"), derive_missing=True,
                                                    index=method.map.index)
        geom = cache[gkey]
    pf, anchors, geom = build_filter(method, session, n_runs, rng, geom)
    radio = method.measurements_needing("rssi")
    if radio and not len(anchors.ids):
        raise MissingStream(f"building {session.building.id} has no BLE anchors for the measurement models of "
                            f"{method.name}")
    arrays = SessionArrays.from_session(session, anchors)
    if radio and len(arrays.rssi_t) == 0:
        raise MissingStream("no usable BLE readings (rssi.csv absent or empty, or every row names an anchor "
                            "that is not a BLE anchor of the building)")
    for m in method.measurements_needing("fixes"):
        check_fixes(m, arrays.fix_source, session.id, method.name)
    if method.needs_imu and len(arrays.imu_t) == 0:
        raise MissingStream(f"no IMU data, which the {type(method.motion).__name__} motion model of {method.name} needs")
    offset = magnetometer_offset(arrays, method)
    imu = None
    if method.needs_imu:
        ikey = ("imu", session.id, repr(method.attitude), repr(method.steps))
        imu = cache.get(ikey) if cache is not None else None
        if imu is None:
            imu = imu_features(arrays, method.attitude, method.steps, offset)
            if cache is not None:
                cache[ikey] = imu
    steps, q = session_steps(arrays, method.filter.rate_hz, method.attitude, method.steps, method.needs_imu, offset,
                             imu)
    if not steps:
        raise ValueError(f"session {session.id} is shorter than one filter step ({1 / method.filter.rate_hz:.2f} s)")
    pf.initialize(arrays.t_start)
    K = len(steps)
    pos = np.empty((n_runs, K, 2))
    cov = np.empty((n_runs, K, 2, 2))
    neff = np.empty((n_runs, K))
    ts = np.empty(K)
    for k, (t, ctrl, obs) in enumerate(steps):
        res = pf.step(t, ctrl, obs)
        ts[k], pos[:, k], cov[:, k], neff[:, k] = t, res.position, res.cov, res.n_eff
    return RunResult(method.name, session.id, ts, pos, cov, neff, pf.events, q,
                     arrays.imu_t if q is not None else None, time.perf_counter() - t0, list(geom.notes))


def check_fixes(model, sources: np.ndarray, session_id: str, method_name: str) -> None:
    """Raise :class:`MissingStream` when ``model`` (a fix likelihood) selects no row of the session's fixes.

    ``sources``: the session's fix sources (F,) ('' for an empty cell). The message names the session
    and the sources it has, with their row counts, so that a misspelt ``source`` is easy to see.
    """
    if model.select(sources).any():
        return
    what = type(model).__name__
    if not len(sources):
        raise MissingStream(f"session {session_id} has no position fixes (fixes.csv absent or empty), which the "
                            f"{what} of {method_name} needs; available sources: none")
    names, counts = np.unique(np.asarray(sources, dtype=str), return_counts=True)
    avail = ", ".join(f"{str(n)!r} ({c} rows)" if n else f"<empty> ({c} rows)" for n, c in zip(names, counts))
    raise MissingStream(f"session {session_id} has no fixes of source {model.source!r}, which the {what} of "
                        f"{method_name} needs; available sources in fixes.csv: {avail}")


def magnetometer_offset(arrays: SessionArrays, method: Method) -> np.ndarray | None:
    """Hard-iron offset (uT) fitted on the session's magnetometer (sphere fit), or None.

    Phones calibrate their magnetometer continuously; a raw (uncalibrated) recording, as the simulator
    writes, needs this before an AHRS can use the field. Offline it is fitted on the whole session; a
    live :class:`OnlineLocalizer` takes the device's calibration as ``mag_offset``.
    """
    if not method.needs_imu or arrays.mag is None or not method.attitude.use_mag or len(arrays.mag) < 50:
        return None
    return estimate_hard_iron(arrays.mag)


class OnlineLocalizer:
    """Streaming API: push sensor samples in time order; each closed step yields estimates.

    For a given seed it reproduces :func:`run_session` exactly when fed the same session through
    :func:`replay` (magnetometer samples before IMU samples of the same time stamp).
    """

    def __init__(self, method: Method, session_meta_building: Session, n_runs: int, seed: int,
                 t_start: float = 0.0, imu_rate_hz: float = 200.0, mag_offset: np.ndarray | None = None):
        self.method = method
        rng = np.random.default_rng(seed)
        self.pf, anchors, self.geom = build_filter(method, session_meta_building, n_runs, rng)
        self.stream = StepStream(anchors, method.filter.rate_hz, method.attitude, method.steps, t_start, imu_rate_hz,
                                 method.needs_imu, mag_offset)
        self.pf.initialize(t_start)

    def _run(self, steps):
        return [self.pf.step(t, c, o) for t, c, o in steps]

    def push_imu(self, t, acc, gyr):
        return self._run(self.stream.push_imu(t, acc, gyr))

    def push_mag(self, t, mag):
        return self._run(self.stream.push_mag(t, mag))

    def push_rssi(self, t, anchor_id, rssi):
        return self._run(self.stream.push_rssi(t, anchor_id, rssi))

    def push_odometry(self, t, xy):
        return self._run(self.stream.push_odometry(t, xy))

    def push_fix(self, t, x, y, std=None, source=None):
        """A position fix from another localizer: world x, y (m), std (m, None when unknown), source name.

        A :class:`~blenav.filters.measurement.FixLikelihood` with ``source`` set uses only fixes pushed
        with that source; with ``source=None`` it uses every fix."""
        return self._run(self.stream.push_fix(t, x, y, std, source))

    def push_event(self, e: tuple):
        """Push one event of :func:`replay` (dispatch on its kind)."""
        kind = e[0]
        if kind == "imu":
            return self.push_imu(e[1], e[2], e[3])
        if kind == "mag":
            return self.push_mag(e[1], e[2])
        if kind == "rssi":
            return self.push_rssi(e[1], e[2], e[3])
        if kind == "odo":
            return self.push_odometry(e[1], e[2])
        if kind == "fix":
            return self.push_fix(e[1], e[2], e[3], e[4], e[5])
        raise ValueError(f"unknown event kind {kind!r}")

    def close(self, t_end):
        return self._run(self.stream.close(t_end))


def replay(session: Session):
    """The session's samples as one time-ordered event list (kind, t, payload...).

    Kinds: ('mag', t, m), ('odo', t, xy), ('rssi', t, anchor_id, rssi), ('fix', t, x, y, std | None,
    source | None), ('imu', t, acc, gyr); :meth:`OnlineLocalizer.push_event` dispatches them.
    """
    ev = []
    imu, mag, r, odo, fx = session.imu, session.mag, session.rssi, session.odometry, session.fixes
    order = {"mag": 0, "odo": 1, "rssi": 2, "fix": 3, "imu": 4}
    for row in mag.itertuples(index=False):
        ev.append(("mag", row.t, np.array([row.mx, row.my, row.mz])))
    for row in odo.itertuples(index=False):
        ev.append(("odo", row.t, np.array([row.x, row.y])))
    for row in r.itertuples(index=False):
        ev.append(("rssi", row.t, str(row.anchor_id), float(row.rssi)))
    for t, x, y, std, src in zip(fx["t"].to_numpy(float), fx["x"].to_numpy(float), fx["y"].to_numpy(float),
                                 fx["std"].to_numpy(float), fx["source"].to_numpy(object)):
        ev.append(("fix", float(t), float(x), float(y), None if np.isnan(std) else float(std),
                   None if not isinstance(src, str) else src))
    for row in imu.itertuples(index=False):
        ev.append(("imu", row.t, np.array([row.ax, row.ay, row.az]), np.array([row.gx, row.gy, row.gz])))
    ev.sort(key=lambda e: (e[1], order[e[0]]))
    return ev
