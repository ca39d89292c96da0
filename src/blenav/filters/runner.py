"""Run one localization method on one session for R independent runs (the batch API).

A :class:`~blenav.filters.method.Method` bundles the components a run builds: the algorithm settings
(:class:`~blenav.filters.engine.FilterConfig`), a motion model, measurement models, the map spec
(initialisation, resampling conditioning, wall crossing) and the AHRS settings. :func:`run_session`
returns every run's estimates at every step (:class:`~blenav.filters.estimate.Estimate`); :class:`BatchRun`
is the same run in pieces; :class:`blenav.filters.online.OnlineLocalizer` is the streaming API that gives
the same answer for the same seed. This module also builds the filter of a method on a session
(:func:`build_filter`: anchors, map geometry, initializer, conditioning, obstacle rules) for both.
"""

from __future__ import annotations

import time
from dataclasses import replace

import numpy as np

from blenav.data import Session
from blenav.errors import MissingStream

from .attitude import AttitudeConfig, attitude_states, estimate_hard_iron, resumable, to_world
from .constraints import ObstacleRules
from .engine import Initializer, ParticleFilter
from .estimate import Estimate
from .map import MapGeometry, WallCrossing
from .measurement import AnchorTable
from .method import HEADING_MODES, INIT_MODES, MapSpec, Method, require_models
from .steps import SessionArrays, StepDetectorConfig, detect_steps, imu_features, session_steps


class _Initializer(Initializer):
    """Adapter: the filter's initializer from a map geometry and a :class:`MapSpec`.

    For ``init`` 'fix' / 'groundtruth' the start position ``start_xy`` (2,) world m (and, for ``heading:
    groundtruth``, the frame angle ``start_theta`` rad) must be set before the filter is initialised
    (:func:`run_session` does it from the session, see :func:`initial_pose`)."""

    def __init__(self, geom: MapGeometry, spec: MapSpec, motion=None):
        if spec.init not in INIT_MODES:
            raise ValueError(f"map.init must be one of {INIT_MODES}, got {spec.init!r}")
        if spec.heading not in HEADING_MODES:
            raise ValueError(f"map.heading must be one of {HEADING_MODES}, got {spec.heading!r}")
        self.geom, self.spec, self.motion = geom, spec, motion
        self.start_xy: np.ndarray | None = None
        self.start_theta: float | None = None

    def sample(self, rng, R, N):
        if self.spec.init == "map":
            return self.geom.sample_initial(rng, R, N, beta=self.spec.beta, sigma_nav=self.spec.sigma_nav,
                                            sigma_rm=self.spec.sigma_rm)
        if self.spec.init == "uniform":
            return self.geom.sample_uniform_free(rng, R, N)
        if self.start_xy is None:
            raise ValueError(f"map.init = {self.spec.init!r} needs a start position (run_session sets it; an "
                             f"OnlineLocalizer takes start_xy)")
        return np.asarray(self.start_xy, float) + self.spec.init_sigma_m * rng.standard_normal((R, N, 2))

    def adjust_state(self, x, rng):
        """Set the odometry frame angle (state column ``motion.frame_angle_col``) to the known start angle."""
        col = self.motion.frame_angle_col if self.motion is not None else None
        if self.spec.heading != "groundtruth" or col is None:
            return x
        if self.start_theta is None:
            raise ValueError("map.heading = 'groundtruth' needs the start frame angle (run_session sets it; an "
                             "OnlineLocalizer takes start_theta)")
        x = x.copy()
        x[..., col] = self.start_theta
        if self.spec.init_heading_sigma > 0:
            x[..., col] += self.spec.init_heading_sigma * rng.standard_normal(x.shape[:-1])
        return x

    def sample_within(self, rng, centres, N, radius):
        return self.geom.sample_free_within(rng, centres, N, radius)

    def snap_free(self, xy):
        return self.geom.snap_free(xy)


class _Conditioner:
    def __init__(self, geom: MapGeometry, spec: MapSpec):
        self.geom, self.spec = geom, spec

    def condition(self, xy, rng, mask=None):
        return self.geom.condition(xy, rng, sigma=self.spec.sigma, max_edge_dist=self.spec.max_edge_dist,
                                   shrink=self.spec.shrink, mask=mask)


def method_anchors(method: Method, session: Session) -> AnchorTable:
    """The BLE anchors of the session's building that ``method`` may use (all, or ``method.beacons``)."""
    frame = session.building.anchors
    if method.beacons is not None:
        want = [str(b) for b in method.beacons]
        have = set(frame.loc[frame["kind"] == "ble", "anchor_id"].astype(str)) if len(frame) else set()
        unknown = [b for b in want if b not in have]
        if unknown:
            raise MissingStream(f"building {session.building.id} has no BLE anchor(s) {unknown}, which {method.name} "
                                f"is restricted to")
        frame = frame[frame["anchor_id"].astype(str).isin(want)]
    if len(frame):  # beacons whose position is unknown (an imported survey; blenav-map estimates them) are unusable
        frame = frame[np.isfinite(frame[["x", "y", "z"]].to_numpy(float)).all(axis=1) | (frame["kind"] != "ble")]
    return AnchorTable.from_frame(frame, "ble")


def build_filter(method: Method, session: Session, n_runs: int, rng: np.random.Generator,
                 geom: MapGeometry | None = None) -> tuple[ParticleFilter, AnchorTable, MapGeometry]:
    """The filter of ``method`` for ``session``: binds the measurement models to the building's anchors
    (``bind``), floor (``bind_floor``, for models that use the floor plan, e.g. a map prior) and motion model
    (``bind_motion``, for models that read the motion's state columns); builds a
    wall test when the method penalises wall crossings (``map.walls``) or uses the obstacle
    re-initialisation (``filter.reinit_fraction``; walls then do not change the weights unless ``map.walls``)."""
    floor_id = session.meta.get("floor")
    geom = geom or MapGeometry.from_building(session.building, floor_id, derive_missing=True,
                                             index=method.map.index)
    anchors = method_anchors(method, session)
    for m in method.measurements:
        m.bind(anchors)
        m.bind_floor(session.floor)
        m.bind_motion(method.motion)
    cond = _Conditioner(geom, method.map) if method.map.condition else None
    pf = ParticleFilter(method.filter, method.motion, method.measurements, _Initializer(geom, method.map, method.motion),
                        rng, n_runs=n_runs, conditioner=cond, constraints=obstacle_rules(method, session))
    return pf, anchors, geom


def obstacle_rules(method: Method, session: Session) -> list[ObstacleRules]:
    """The method's obstacle rules on the session's floor: the wall-crossing penalty (``map.walls``,
    ``filter.wall_log_penalty``) and Roy's re-initialisation (``filter.reinit_fraction``,
    ``filter.reinit_radius_m``); none when it asks for neither."""
    f = method.filter
    if not method.map.walls and f.reinit_fraction is None:
        return []
    return [ObstacleRules(WallCrossing.from_floor(session.floor), penalty=f.wall_log_penalty, penalise=method.map.walls,
                          reinit_fraction=f.reinit_fraction, reinit_radius_m=f.reinit_radius_m)]


def align_heading(odo_t: np.ndarray, odo: np.ndarray, gt_t: np.ndarray, gt_xy: np.ndarray, t0: float,
                  align_s: float = 10.0, min_path_m: float = 1.0) -> float:
    """Rotation (rad) from the odometry frame to the world that best maps odometry displacements onto
    ground-truth displacements (2-D least squares: theta = atan2(sum do x dg, sum do . dg)) over
    [t0, t0 + align_s] sampled at 2 Hz; over the whole overlap when the ground truth moves less than
    ``min_path_m`` in that window. 0 when nothing moves."""
    t1 = min(float(odo_t[-1]), float(gt_t[-1]))
    for end in (t0 + align_s, t1):
        tt = np.arange(max(t0, float(odo_t[0]), float(gt_t[0])), min(end, t1) + 1e-9, 0.5)
        if len(tt) < 2:
            continue
        o = np.stack([np.interp(tt, odo_t, odo[:, 0]), np.interp(tt, odo_t, odo[:, 1])], -1)
        g = np.stack([np.interp(tt, gt_t, gt_xy[:, 0]), np.interp(tt, gt_t, gt_xy[:, 1])], -1)
        do, dg = np.diff(o, axis=0), np.diff(g, axis=0)
        if np.hypot(dg[:, 0], dg[:, 1]).sum() >= min_path_m or end == t1:
            cross = np.sum(do[:, 0] * dg[:, 1] - do[:, 1] * dg[:, 0])
            dot = np.sum(do * dg)
            return float(np.arctan2(cross, dot)) if (cross or dot) else 0.0
    return 0.0


def initial_pose(method: Method, session: Session, arrays: SessionArrays) -> tuple[np.ndarray | None, float | None]:
    """Start position (2,) world m and odometry frame angle (rad) that ``method.map`` asks for (None when
    not needed); raises :class:`MissingStream` when the session lacks what they come from."""
    spec = method.map
    xy = theta = None
    needs_gt = spec.init == "groundtruth" or (spec.heading == "groundtruth"
                                               and method.motion.frame_angle_col is not None)
    gt = session.groundtruth if needs_gt else None
    if needs_gt and not len(gt):
        raise MissingStream(f"session {session.id} has no ground truth, which the oracle start (map.init / map.heading "
                            f"= 'groundtruth') of {method.name} needs")
    if spec.init == "fix":
        src = spec.init_fix_source
        if src is None:
            fl = method.measurements_needing("fixes")
            src = fl[0].source if fl else None
        sel = np.ones(len(arrays.fix_t), bool) if src is None else arrays.fix_source == str(src).strip()
        if not sel.any():
            raise MissingStream(f"session {session.id} has no position fix of source {src!r} to start {method.name} "
                                f"at (map.init = 'fix')")
        xy = arrays.fix_xy[np.flatnonzero(sel)[0]].copy()
    elif spec.init == "groundtruth":
        gt_t = gt["t"].to_numpy(float)
        xy = np.array([np.interp(arrays.t_start, gt_t, gt["x"].to_numpy(float)),
                       np.interp(arrays.t_start, gt_t, gt["y"].to_numpy(float))])
    if needs_gt and spec.heading == "groundtruth":
        if not len(arrays.odo_t):
            raise MissingStream(f"session {session.id} has no odometry to align with the ground truth "
                                f"(map.heading = 'groundtruth') for {method.name}")
        theta = align_heading(arrays.odo_t, arrays.odo, gt["t"].to_numpy(float), gt[["x", "y"]].to_numpy(float),
                              arrays.t_start, spec.align_s)
    return xy, theta


def run_session(method: Method, session: Session, n_runs: int, seed: int,
                geom: MapGeometry | None = None, cache: dict | None = None, fixes=None, odometry=None) -> Estimate:
    """All R runs of ``method`` on ``session`` (batched), seeded by ``seed``: the :class:`Estimate` of
    :meth:`BatchRun.result`.

    ``cache``: a dict shared by calls on the same sessions (the evaluation harness passes one), so
    that the floor's map geometry and the session's AHRS and step detection, which do not depend on
    the method's filter, are computed once rather than once per method.

    ``fixes``: extra position fixes (DataFrame t, x, y, std, source) added in memory to the session's
    ``fixes.csv`` rows (see :class:`~blenav.filters.steps.SessionArrays`). ``odometry``: an odometry track
    (DataFrame t, x, y) used in place of the session's ``odometry.csv`` (e.g. PDR odometry from the IMU).
    """
    run = BatchRun(method, session, n_runs, seed, geom, cache, fixes, odometry)
    run.advance()
    return run.result()


class BatchRun:
    """:func:`run_session` in pieces: the filter built and initialised, then :meth:`advance` through the
    session's steps up to a time, so that a caller (the closed loop of :mod:`blenav.backend.loop`) can change
    the filter between pieces: :meth:`rebind_anchors` (a corrected beacon map), :meth:`correct_imu` (IMU
    biases, from then on). Without changes, pieces give exactly the numbers of one :func:`run_session`."""

    def __init__(self, method: Method, session: Session, n_runs: int, seed: int,
                 geom: MapGeometry | None = None, cache: dict | None = None, fixes=None, odometry=None):
        self.t0 = time.perf_counter()
        require_models(method)
        self.method, self.session, self.cache = method, session, cache
        for m in method.measurements:  # a receiver offset of an earlier run (closed loop) does not carry over
            m.set_receiver_offset(0.0)
        rng = np.random.default_rng(seed)
        if cache is not None and geom is None:
            gkey = ("geom", session.building.id, str(session.meta.get("floor")), method.map.index)
            if gkey not in cache:
                cache[gkey] = MapGeometry.from_building(session.building, session.meta.get("floor"),
                                                        derive_missing=True, index=method.map.index)
            geom = cache[gkey]
        self.pf, self.anchors, self.geom = pf, anchors, geom = build_filter(method, session, n_runs, rng, geom)
        radio = method.measurements_needing("rssi")
        self.notes = list(geom.notes)
        if radio:
            known, total = len(anchors.ids), int((session.building.anchors_of("ble")["anchor_id"]).nunique())
            if not known:
                raise MissingStream(f"building {session.building.id} has no BLE anchors with a position for the "
                                    f"measurement models of {method.name}"
                                    + ("; estimate them first (blenav-map)" if total else ""))
            if known < total and method.beacons is None:
                self.notes.append(f"{total - known} of {total} BLE anchors have no position and are not used")
        self.arrays = arrays = SessionArrays.from_session(session, anchors, extra_fixes=fixes, odometry=odometry)
        if radio and len(arrays.rssi_t) == 0:
            raise MissingStream("no usable BLE readings (rssi.csv absent or empty, or every row names an anchor "
                                "that is not a BLE anchor of the building)")
        for m in method.measurements_needing("fixes"):
            check_fixes(m, arrays.fix_source, session.id, method.name)
        if method.needs_imu and len(arrays.imu_t) == 0:
            raise MissingStream(f"no IMU data, which the {type(method.motion).__name__} motion model of {method.name} "
                                f"needs")
        if method.needs_odometry and len(arrays.odo_t) == 0:
            raise MissingStream(f"no inertial odometry (odometry.csv absent or empty), which {method.name} needs")
        pf.initializer.start_xy, pf.initializer.start_theta = initial_pose(method, session, arrays)
        self.mag_offset = magnetometer_offset(arrays, method)
        imu = session_imu(session.id, arrays, method.attitude, method.steps, cache) if method.needs_imu else None
        self.steps, self.q = session_steps(arrays, method.filter.rate_hz, method.attitude, method.steps,
                                           method.needs_imu, self.mag_offset, imu)
        if not self.steps:
            raise ValueError(f"session {session.id} is shorter than one filter step "
                             f"({1 / method.filter.rate_hz:.2f} s)")
        pf.initialize(arrays.t_start)
        K = len(self.steps)
        self.ts = np.array([t for t, _, _ in self.steps])
        self.pos = np.empty((n_runs, K, 2))
        self.cov = np.empty((n_runs, K, 2, 2))
        self.neff = np.empty((n_runs, K))
        self.k = 0  # steps done
        self._att_states: np.ndarray | None = None  # the AHRS in its filter frame since the last correct_imu
        self._flags: np.ndarray | None = None  # the step flags of the corrected IMU
        self._stale: int | None = None  # the first step to make again from the corrected IMU (None: none is)

    @property
    def done(self) -> bool:
        return self.k >= len(self.steps)

    def advance(self, t_end: float = np.inf) -> int:
        """Run the steps at times <= ``t_end``; returns the number of steps done so far."""
        self._refresh(int(np.searchsorted(self.ts, t_end, side="right")))
        pf, steps = self.pf, self.steps
        while self.k < len(steps) and steps[self.k][0] <= t_end:
            t, ctrl, obs = steps[self.k]
            res = pf.step(t, ctrl, obs)
            self.pos[:, self.k], self.cov[:, self.k], self.neff[:, self.k] = res.position, res.cov, res.n_eff
            self.k += 1
        return self.k

    def rebind_anchors(self, frame) -> None:
        """Bind the measurement models to a new beacon map (DataFrame anchor_id, kind, x, y, z, ...; the
        anchors of :attr:`anchors`, same ids in the same order) for the remaining steps."""
        table = AnchorTable.from_frame(frame, "ble")
        if list(table.ids) != list(self.anchors.ids):
            raise ValueError("rebind_anchors: the new map must hold the same BLE anchors in the same order")
        for m in self.method.measurements:
            m.bind(table)
        self.anchors = table

    def set_receiver_offset(self, delta_db: float) -> None:
        """The receiver reads ``delta_db`` dB above the path-loss model: every path-loss measurement model adds it
        to its a_X for the remaining steps (the back-end's estimate, issue 14 sec. 4)."""
        for m in self.method.measurements:
            m.set_receiver_offset(delta_db)

    def correct_imu(self, t_from: float, accel_bias: np.ndarray, gyro_bias: np.ndarray) -> None:
        """Subtract constant biases (device frame: m/s^2, rad/s) from the IMU samples after ``t_from`` and
        recompute the AHRS, step detection and the controls of the steps not yet done (the AHRS resumes where the
        correction starts, :func:`blenav.filters.attitude.attitude_states`, after one whole run at the first
        correction: its values before ``t_from`` do not change; the numbers of a whole run, to the bit); the steps
        are made again as :meth:`advance` reaches them."""
        if not self.method.needs_imu or not len(self.arrays.imu_t):
            return
        if self.k and t_from < self.ts[self.k - 1]:  # the steps done keep their controls: nothing before them moves
            raise ValueError(f"correct_imu: t_from {t_from} s is before the last step done ({self.ts[self.k - 1]} s)")
        a = self.arrays
        after = a.imu_t > t_from
        acc, gyr = a.acc.copy(), a.gyr.copy()
        acc[after] -= np.asarray(accel_bias, float)
        gyr[after] -= np.asarray(gyro_bias, float)
        self.arrays = a = replace(a, acc=np.ascontiguousarray(acc), gyr=np.ascontiguousarray(gyr))
        m = self.method
        # the AHRS resumes at the first corrected sample from the states of the last correction (the first one runs
        # it whole): causal, so the states before are the same; the steps done keep their controls
        i0 = int(np.searchsorted(a.imu_t, t_from, side="right"))
        resume = self._att_states is not None and i0 > 0 and resumable(m.attitude)
        self._att_states = attitude_states(a.imu_t, a.acc, a.gyr, a.mag_t, a.mag, m.attitude,
                                           mag_offset=self.mag_offset, start=i0 if resume else 0,
                                           prev=self._att_states if resume else None)
        self.q = to_world(self._att_states, m.attitude)
        self._flags = detect_steps(a.imu_t, a.acc, m.steps)
        self._stale = self.k  # the steps from here on: made again from the corrected IMU as advance reaches them

    def _refresh(self, k_end: int) -> None:
        """Make the stale steps before ``k_end`` again (after :meth:`correct_imu`), in order, each from the heading
        of the one before: the numbers of making them all at once."""
        lo = self._stale
        if lo is None or k_end <= lo:
            return
        m = self.method
        heading = self.steps[lo - 1][1]["heading"] if lo else 0.0
        steps, _ = session_steps(self.arrays, m.filter.rate_hz, m.attitude, m.steps, True, self.mag_offset,
                                 (self.q, self._flags), start=lo, stop=k_end, heading=heading)
        self.steps[lo:k_end] = steps
        self._stale = k_end if k_end < len(self.steps) else None

    def result(self) -> Estimate:
        """The estimates of the steps done so far: ``outputs`` ``n_eff`` (R, K) and, when the motion model runs an
        AHRS, ``attitude`` (its orientation {t (T,), q (T, 4)}); ``notes``: what the map was derived from."""
        k, m, a = self.k, self.method, self.arrays
        outputs = {"n_eff": self.neff[:, :k]}
        if self.q is not None:
            outputs["attitude"] = {"t": a.imu_t, "q": self.q}
        return Estimate(m.name, self.session.id, self.ts[:k], self.pos[:, :k], self.cov[:, :k], self.pf.events,
                        outputs, time.perf_counter() - self.t0, list(self.notes))


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
    return hard_iron_offset(arrays, method.attitude) if method.needs_imu else None


def hard_iron_offset(arrays: SessionArrays, att: AttitudeConfig) -> np.ndarray | None:
    """:func:`magnetometer_offset` for an AHRS of settings ``att``: None without magnetometer use or data, or with
    ``att.hard_iron`` false (a magnetometer the device already calibrates)."""
    if arrays.mag is None or not att.use_mag or not att.hard_iron or len(arrays.mag) < 50:
        return None
    return estimate_hard_iron(arrays.mag)


def session_imu(session_id: str, arrays: SessionArrays, att: AttitudeConfig, steps: StepDetectorConfig,
                cache: dict | None = None) -> tuple[np.ndarray | None, np.ndarray]:
    """The session's AHRS quaternions (T, 4) and step flags (T,) (:func:`~blenav.filters.steps.imu_features`, the
    magnetometer's hard-iron offset removed: :func:`hard_iron_offset`), computed once per ``cache`` under the key
    ``("imu", session id, attitude, steps)`` that every filter of an evaluation shares."""
    key = ("imu", session_id, repr(att), repr(steps))
    imu = cache.get(key) if cache is not None else None
    if imu is None:
        imu = imu_features(arrays, att, steps, hard_iron_offset(arrays, att))
        if cache is not None:
            cache[key] = imu
    return imu
