"""The front-end + back-end of 000 (Fig. 2) as one :class:`~blenav.localizers.base.Localizer`: a particle filter
front-end (:class:`~blenav.localizers.ParticleFilterLocalizer` built from the node ``front_end``), whose position
and velocity estimates and AHRS attitude initialise the radio-inertial smoother (:func:`blenav.backend.graph.smooth`,
settings ``backend`` over ``conf/backend/default.yaml``); the smoothed trajectory is the estimate.

Config node (``conf/localizer/backend.yaml``)::

    _target_: blenav.backend.localizer.BackendLocalizer
    front_end: {motion: ..., measurements: ..., map: ...}   # a ParticleFilterLocalizer node (no _target_ needed)
    backend: {solver: {method: lm}, priors: {beacon_sigma_m: 3.0}}   # overrides of BackendConfig
    per_run: true       # smooth every front-end run (false: one back-end on the runs' mean, copied to all runs)
    range_from_front_end: true  # the back-end's path loss = the front-end's PathLossRange (after any fit)

``outputs``: ``beacon_map`` (DataFrame anchor_id, x, y, z, std_m, n_ranges, status: the mean over runs of the
optimized beacons; std_m the root mean variance), ``smoothed`` (R, K, 2) (= position), ``front_end`` (R, K, 2)
the particle filter's own estimate (the F.-end of 000 Fig. 3, open loop), ``bias`` (R, K, 6) accelerometer m/s^2
and gyroscope rad/s, ``attitude`` (the front-end's AHRS), ``backend_s`` (R,) seconds of back-end per run,
``backend_failures`` (list of str). Back-end failures never stop a run: that run keeps the front-end's estimate
where the back-end had none (see :class:`~blenav.backend.graph.BackendResult`).

The closed loop of 000 (the optimized map and bias fed back to the front-end) is not part of this class.
"""

from __future__ import annotations

import time
from dataclasses import replace
from typing import Any

import numpy as np
import pandas as pd
from omegaconf import DictConfig, OmegaConf

from blenav.filters.measurement import PathLossRange
from blenav.localizers.base import Estimate, Localizer, MissingStream, PathLossCalibrated, RunContext

from .config import load_backend_config
from .graph import smooth
from .inputs import beacon_priors, keyframes_from_front_end, path_loss_model, session_attitude, session_imu, session_ranges


class BackendLocalizer(Localizer, PathLossCalibrated):
    """Particle-filter front-end, then the smoothing back-end of 000 (sec. IV-D) on every run."""

    def __init__(self, name: str, shared=None, front_end: Any = None, backend: Any = None, per_run: bool = True,
                 range_from_front_end: bool = True):
        super().__init__(name, shared)
        from blenav.localizers import ParticleFilterLocalizer

        if front_end is None:
            raise ValueError(f"method {name!r}: the back-end needs a front_end node (a particle filter's settings)")
        node = OmegaConf.to_container(front_end, resolve=True) if isinstance(front_end, DictConfig) else dict(front_end)
        node.pop("_target_", None)
        node.pop("label", None)
        self.front = ParticleFilterLocalizer(name, shared, **node)
        try:
            over = OmegaConf.to_container(backend, resolve=True) if isinstance(backend, DictConfig) else backend
            self.cfg = load_backend_config(node=over or {})
        except ValueError as exc:
            raise ValueError(f"method {name!r}, backend: {exc}") from exc
        self.per_run = bool(per_run)
        self.range_from_front_end = bool(range_from_front_end)

    @property
    def uses_floor_plan(self) -> bool:
        return self.front.uses_floor_plan

    # ------------------------------------------------------------------ capabilities
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
                    return replace(m, sigma_n=rc.sigma_n, max_range_m=rc.max_range_m, anchors=None)
        return path_loss_model(self.cfg)

    # ------------------------------------------------------------------ run
    def run(self, session, n_runs: int, seed: int, ctx: RunContext | None = None) -> Estimate:
        t0 = time.perf_counter()
        ctx = ctx or RunContext()
        if not session.has("imu"):
            raise MissingStream("no IMU data, which the back-end's preintegrated IMU factors need")
        if not session.has("rssi"):
            raise MissingStream("no BLE readings (rssi.csv absent or empty) for the back-end's range factors")
        front = self.front.run(session, n_runs, seed, ctx)
        att = front.outputs.get("attitude")
        if att is None:
            key = ("backend-ahrs", session.id, repr(self.front.method.attitude))
            if key not in ctx.cache:
                ctx.cache[key] = session_attitude(session, self.front.method.attitude)
            q_t, q = ctx.cache[key]
        else:
            q_t, q = att["t"], att["q"]
        anchors = session.building.anchors_of("ble")
        if not len(anchors):
            raise MissingStream(f"building {session.building.id} has no BLE anchors for the back-end")
        beacons = beacon_priors(anchors, self.cfg.priors.beacon_sigma_m, self.cfg.priors.beacon_sigma_z_m)
        ranges = session_ranges(session, beacons, self._range_model(), anchors)
        imu = session_imu(session)
        R, K = front.position.shape[:2]
        runs = range(R) if self.per_run else [None]
        pos = front.position.copy()
        bias = np.zeros((R, K, 6))
        maps, secs, fails, notes = [], [], [], []
        for r in runs:
            xy = front.position if r is None else front.position[r]
            kf, kf_notes = keyframes_from_front_end(front.t, xy, q_t, q, self.cfg)
            res = smooth(self.cfg, kf, imu, ranges, beacons)
            sm = _to_front_times(front.t, kf.t, res.position[:, :2])
            sb = _to_front_times(front.t, kf.t, res.bias)
            target = slice(None) if r is None else r
            pos[target] = sm
            bias[target] = sb
            maps.append(res.beacon_map)
            secs.append(res.wall_s)
            fails += [f"run {r if r is not None else 'mean'}: {f}" for f in res.failures]
            if r in (0, None):
                notes += [f"back-end: {n}" for n in kf_notes + res.notes]
        outputs = dict(front.outputs)
        outputs.update({"smoothed": pos, "front_end": front.position, "bias": bias, "beacon_map": _mean_map(maps),
                        "backend_s": np.asarray(secs), "backend_failures": fails})
        notes = list(front.notes) + notes + [f"back-end failure: {f}" for f in fails[:5]]
        return Estimate(self.name, session.id, front.t, pos, None, front.events, outputs, time.perf_counter() - t0,
                        notes)


def _to_front_times(t: np.ndarray, kf_t: np.ndarray, values: np.ndarray) -> np.ndarray:
    """Keyframe values (Kk, D) at the front-end's step times t (K,) (linear interpolation; identical when every
    step is a keyframe)."""
    if len(kf_t) == len(t) and np.array_equal(kf_t, t):
        return values
    return np.stack([np.interp(t, kf_t, values[:, i]) for i in range(values.shape[1])], axis=-1)


def _mean_map(maps: list[pd.DataFrame]) -> pd.DataFrame:
    """Mean over runs of the beacon maps (x, y, z; std_m as the root mean variance; n_ranges summed; the
    status of run 0)."""
    if len(maps) == 1:
        return maps[0]
    cat = pd.concat(maps, keys=range(len(maps)), names=["run", "row"])
    g = cat.groupby("anchor_id", sort=False)
    out = g[["x", "y", "z"]].mean()
    out["std_m"] = np.sqrt(g["std_m"].apply(lambda s: float(np.nanmean(s.to_numpy(float) ** 2))
                                             if s.notna().any() else np.nan))
    out["n_ranges"] = g["n_ranges"].sum()
    out["status"] = maps[0].set_index("anchor_id")["status"]
    return out.reset_index()
