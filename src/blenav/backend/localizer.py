"""The front-end + back-end of 000 (Fig. 2) as one :class:`~blenav.localizers.base.Localizer`: a particle filter
front-end (:class:`~blenav.localizers.ParticleFilterLocalizer` built from the node ``front_end``) and the
radio-inertial smoother of :mod:`blenav.backend.graph` in the closed loop of :mod:`blenav.backend.loop` (the
optimized map and the IMU bias fed back to the filter every ``backend.loop.period_s``; ``backend.loop.enabled:
false`` for the open loop), then one smoothing of the whole session.

Config node (``conf/localizer/backend.yaml``)::

    _target_: blenav.backend.localizer.BackendLocalizer
    front_end: {motion: ..., measurements: ..., map: ...}   # a ParticleFilterLocalizer node (no _target_ needed)
    backend: {solver: {method: lm}, loop: {period_s: 30}}  # overrides of BackendConfig
    estimate: smoothed  # smoothed: the back-end's trajectory (B.-end of 000 Fig. 3); front_end: the closed-loop
                        # filter's own estimates (F.-end)
    per_run: false      # true: a back-end (and loop) per run; false: one for all runs, from their mean
    range_from_front_end: true  # the back-end's path loss = the front-end's PathLossRange (after any fit)

Two methods of an experiment that differ only in ``label`` and ``estimate`` (F-end, B-end) share one computation
per session (``inputs.cache``).

``outputs``: ``beacon_map`` (DataFrame anchor_id, x, y, z, std_m, n_ranges, status: the final smoothing's map,
mean over back-ends when ``per_run``), ``smoothed`` (R, K, 2), ``front_end`` (R, K, 2) the closed-loop filter,
``bias`` (R, K, 6) accelerometer m/s^2 and gyroscope rad/s (the corrections applied + the final smoothing's
residual), ``attitude`` (the front-end's AHRS), ``backend_s`` (R or 1,) seconds of back-end, ``feedbacks`` (int),
``backend_failures`` (list of str). Back-end failures never stop a run: where the back-end has no estimate the
front-end's stands (see :class:`~blenav.backend.graph_types.BackendResult`).

Given a learned inertial odometry (``io_model=``, issue 31), every smoothing also takes its displacements between
keyframes as between-factors (``backend.odometry``); the front-end is unchanged (its IMU proposal). Without one the
back-end is 000's.
"""

from __future__ import annotations

import hashlib
import time
from dataclasses import replace
from typing import Any

import numpy as np
from omegaconf import DictConfig, OmegaConf

from blenav.errors import MissingStream
from blenav.filters.measurement import PathLossRange
from blenav.localizers.base import (Estimate, InertialModelConsumer, Localizer, PathLossCalibrated, RunInputs,
                                    attach_inertial)

from .config import load_backend_config
from .graph_types import OdometryTrack
from .inputs import beacon_priors, path_loss_model, session_attitude, session_imu, session_ranges
from .loop import run_closed_loop
from .mapping import mean_map


class BackendLocalizer(Localizer, PathLossCalibrated, InertialModelConsumer):
    """Particle-filter front-end, then the smoothing back-end of 000 (sec. IV-D) on every run."""

    def __init__(self, name: str, shared=None, front_end: Any = None, backend: Any = None, per_run: bool = False,
                 range_from_front_end: bool = True, estimate: str = "smoothed"):
        super().__init__(name, shared)
        from blenav.localizers import ParticleFilterLocalizer

        if front_end is None:
            raise ValueError(f"method {name!r}: the back-end needs a front_end node (a particle filter's settings)")
        node = OmegaConf.to_container(front_end, resolve=True) if isinstance(front_end, DictConfig) else dict(front_end)
        node.pop("_target_", None)
        node.pop("label", None)
        self.front = ParticleFilterLocalizer(name, shared, **node)
        self._settings = repr((node, shared))  # what F-end / B-end pairs must share to share the computation
        try:
            over = OmegaConf.to_container(backend, resolve=True) if isinstance(backend, DictConfig) else backend
            self.cfg = load_backend_config(node=over or {})
        except ValueError as exc:
            raise ValueError(f"method {name!r}, backend: {exc}") from exc
        self.per_run = bool(per_run)
        if estimate not in ("smoothed", "front_end"):
            raise ValueError(f"method {name!r}: estimate must be 'smoothed' (the back-end, B.-end) or 'front_end' "
                             f"(the closed-loop filter, F.-end), got {estimate!r}")
        self.estimate = estimate
        self.range_from_front_end = bool(range_from_front_end)
        self.io_model = None  # a learned inertial odometry (io_model=): its displacements as between-factors

    @property
    def uses_floor_plan(self) -> bool:
        return self.front.uses_floor_plan

    # ------------------------------------------------------------------ capabilities
    def attach_io_model(self, path: str | None, load) -> str | None:
        """The odometry of ``path`` for the between-factors (``backend.odometry``); without one, 000's back-end. A
        model given that cannot be used makes the method unavailable with the reason (never dropped in silence)."""
        if not path or not self.cfg.odometry.enabled:
            self.io_model = None
            return None
        self.io_model, why = attach_inertial(path, load)
        return why

    def _odometry(self, session, inputs: RunInputs) -> tuple[OdometryTrack | None, str | None]:
        """(the learned odometry's track of ``session`` or None, a note)."""
        if self.io_model is None:
            return None, None
        try:
            tr = self.io_model.odometry(session, cache=inputs.cache)  # in the attitude it was trained in
            track = OdometryTrack(tr["t"].to_numpy(float), tr[["x", "y"]].to_numpy(float), tr["var"].to_numpy(float))
        except (MissingStream, ValueError) as exc:
            return None, f"back-end: no learned odometry between-factors ({exc})"
        return track, (f"back-end: learned inertial odometry between keyframes ({len(track.t)} points, variance x "
                       f"{self.cfg.odometry.var_scale:g})")

    def wants_path_loss_fit(self) -> bool:
        return self.front.wants_path_loss_fit()

    def apply_path_loss_fit(self, fit) -> None:
        self.front.apply_path_loss_fit(fit)

    def _range_model(self) -> PathLossRange:
        """The back-end's RSSI -> range model: the front-end's PathLossRange (its fitted parameters included),
        or the ``backend.range`` settings."""
        if self.range_from_front_end:
            for m in self.front.method.measurements:
                if isinstance(m, PathLossRange):
                    rc = self.cfg.range
                    # rx_offset_db=0: the front-end's models may still hold the offset an earlier session's
                    # closed loop set (BatchRun resets it only when the next filter is built, after this)
                    return replace(m, sigma_n=rc.sigma_n, max_range_m=rc.max_range_m, anchors=None, rx_offset_db=0.0)
        return path_loss_model(self.cfg)

    # ------------------------------------------------------------------ run
    @staticmethod
    def check_session(session):
        """The session's BLE anchors (rows of anchors.csv); :class:`MissingStream` with the reason when the back-end
        cannot run on it (no IMU, no BLE readings, no BLE anchors or one without a position)."""
        if not session.has("imu"):
            raise MissingStream("no IMU data, which the back-end's preintegrated IMU factors need")
        if not session.has("rssi"):
            raise MissingStream("no BLE readings (rssi.csv absent or empty) for the back-end's range factors")
        anchors = session.building.anchors_of("ble")
        if not len(anchors):
            raise MissingStream(f"building {session.building.id} has no BLE anchors for the back-end")
        if not np.isfinite(anchors[["x", "y", "z"]].to_numpy(float)).all():
            raise MissingStream(f"building {session.building.id} has BLE anchors without a position; estimate them "
                                f"first (blenav-map)")
        return anchors

    def _inputs(self, session, inputs: RunInputs):
        """(imu, ranges, beacons, attitude) of the session for the back-end."""
        anchors = self.check_session(session)
        beacons = beacon_priors(anchors, self.cfg.priors.beacon_sigma_m, self.cfg.priors.beacon_sigma_z_m)
        ranges = session_ranges(session, beacons, self._range_model(), anchors)
        key = ("backend-ahrs", session.id, repr(self.front.method.attitude))
        if key not in inputs.cache:
            inputs.cache[key] = session_attitude(session, self.front.method.attitude)
        return session_imu(session), ranges, beacons, inputs.cache[key]

    def _key(self, session, n_runs: int, seed: int) -> tuple:
        """What the computation depends on: the settings (not label / estimate), the session and its map."""
        return ("closed-loop", session.id, int(n_runs), int(seed), self.per_run, self.range_from_front_end,
                self._settings, repr(self.cfg), map_fingerprint(session.building), getattr(self.io_model, "key", None))

    def run(self, session, n_runs: int, seed: int, inputs: RunInputs | None = None) -> Estimate:
        """The closed loop on ``session`` (computed once per session for F-end / B-end pairs); ``wall_s`` is the
        whole computation's."""
        inputs = inputs or RunInputs()
        key = self._key(session, n_runs, seed)
        shared = inputs.cache.get(key)
        if shared is None:
            shared = self._compute(session, n_runs, seed, inputs)
            inputs.cache[key] = shared
        t, front, smoothed, bias, outputs, events, notes, wall = shared
        pos = smoothed if self.estimate == "smoothed" else front
        outputs = {**outputs, "smoothed": smoothed, "front_end": front, "bias": bias}
        return Estimate(self.name, session.id, t, pos, None, events, outputs, wall, list(notes))

    def _compute(self, session, n_runs: int, seed: int, inputs: RunInputs) -> tuple:
        t0 = time.perf_counter()
        imu, ranges, beacons, att = self._inputs(session, inputs)
        odometry, odo_note = self._odometry(session, inputs)
        method = self.front.method
        loops = ([(n_runs, seed)] if not self.per_run
                 else [(1, int(s)) for s in np.random.SeedSequence(seed).generate_state(n_runs)])
        fronts, smooths, biases, maps, secs, fails, notes, events, offsets = [], [], [], [], [], [], [], [], []
        n_feedbacks = 0
        for i, (R, sd) in enumerate(loops):
            out = run_closed_loop(method, session, R, sd, self.cfg, imu, ranges, beacons, att, inputs.cache, odometry)
            f = out.front
            fronts.append(f.position)
            events += f.events
            if out.smoothed is not None:
                sm = _to_front_times(f.t, out.smoothed.t, out.smoothed.position[:, :2])
                sb = _to_front_times(f.t, out.smoothed.t, out.smoothed.bias) + out.bias_applied
                smooths.append(np.broadcast_to(sm, f.position.shape).copy())
                biases.append(np.broadcast_to(sb, (R,) + sb.shape).copy())
                maps.append(out.smoothed.beacon_map)
                offsets.append(out.smoothed.offset_db)
            else:  # no back-end estimate: the front-end's stands
                smooths.append(f.position.copy())
                biases.append(np.broadcast_to(out.bias_applied, (R,) + out.bias_applied.shape).copy())
            secs.append(out.backend_s)
            n_feedbacks += len(out.feedbacks)
            fails += [f"run {i}: {x}" if self.per_run else x for x in out.failures]
            if i == 0:
                notes += [f"back-end: {n}" for n in out.notes] + ([odo_note] if odo_note else [])
        front = np.concatenate(fronts)
        smoothed = np.concatenate(smooths)
        bias = np.concatenate(biases)
        outputs = {"beacon_map": mean_map(maps) if maps else None, "backend_s": np.asarray(secs),
                   "feedbacks": n_feedbacks, "backend_failures": fails}
        if self.cfg.range.estimate_offset and offsets:
            outputs["receiver_offset_db"] = float(np.nanmean(offsets)) if np.isfinite(offsets).any() else None
            notes.append(f"back-end: receiver offset {outputs['receiver_offset_db']} dB (range.estimate_offset)")
        if "attitude" in out.front.outputs:
            outputs["attitude"] = out.front.outputs["attitude"]
        notes = list(out.front.notes) + notes + [f"back-end failure: {f}" for f in fails[:5]]
        return out.front.t, front, smoothed, bias, outputs, events, notes, time.perf_counter() - t0


def map_fingerprint(building) -> str:
    """A digest of the building's BLE beacon positions (what a computation on its map depends on)."""
    a = building.anchors_of("ble")
    return hashlib.sha1(np.ascontiguousarray(a[["x", "y", "z"]].to_numpy(float)).tobytes()).hexdigest()


def _to_front_times(t: np.ndarray, kf_t: np.ndarray, values: np.ndarray) -> np.ndarray:
    """Keyframe values (Kk, D) at the front-end's step times t (K,) (linear interpolation; identical when every
    step is a keyframe)."""
    if len(kf_t) == len(t) and np.array_equal(kf_t, t):
        return values
    return np.stack([np.interp(t, kf_t, values[:, i]) for i in range(values.shape[1])], axis=-1)
