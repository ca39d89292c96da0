"""The beacon map corrected by every walk of a building before the back-end (issue 32): the closed loop of 000 on
each walk, but on a map that pools the RSSI of every scored walk, each placed by another row's estimate (its
front-end on the wrong map, no ground truth).

One walk's ranges cannot move a 3 m wrong map's beacons much (``benchmarks/beacon_bound.py``: a few per cent even on
the true track); a building's walks together can (``benchmarks/pooled_map.py``: 20-28 %). So, in batch:

1. the labels row (``pool.labels``, e.g. F-end, the closed-loop filter on the given map) runs on every scored walk;
2. for each building (and run, when every run has a map of its own), ``blenav map``'s RSSI-domain estimator
   (:func:`blenav.backend.mapping.map_beacons`) takes every walk of the building placed along that row's estimate,
   each beacon's prior centred on the given map with ``pool.prior_sigma_m`` per axis; a beacon it does not place
   keeps the given position;
3. each walk runs the closed loop (:class:`~blenav.backend.localizer.BackendLocalizer`) on that map, each beacon's
   prior the back-end's own (``priors.beacon_sigma_m``, or the estimator's std_m with ``pool.stated_std``); its
   ``outputs['beacon_map']`` is the back-end's final map, scored against the truth as usual (``beacon_error_m``'s
   prior stays the map the evaluation gave).

Measured (docs/results-000-002.md, ``make backend-robust``): with 6-7 walks the beacons end 19-20 % closer to the truth
(the back-end alone: 2 %), but the trajectories are no better, and with two walks worse: the pooled beacons inherit
the errors of the tracks that placed them, which the next filter then follows (the same map pooled on the true
tracks makes B-end better).

Transductive (:class:`~blenav.localizers.base.Transductive`): a walk's estimate depends on the other walks scored
with it, never on their ground truth. The runs' maps: under ``beacon_map.noise_m > 0`` the evaluation calls each
run alone on its own map (``inputs.run`` = r) and the pool takes run r of the labels row, which was computed on the
same draw when ``beacon_map.per_walk: false`` (one deployed map: what ``experiment=mapnoise_pooled`` gives). With
``per_walk: true`` the other walks' estimates were made on other draws, whose errors do not share this walk's map
error: the pool is then optimistic (the method cannot tell; mapnoise_pooled sets ``per_walk: false``).
"""

from __future__ import annotations

from dataclasses import replace
from typing import Any

import numpy as np
import pandas as pd

from blenav.data.session import Session
from blenav.localizers.base import Estimate, RunInputs, Transductive, batch_settings

from .localizer import BackendLocalizer, map_fingerprint
from .mapping import map_beacons

__all__ = ["along_track", "PooledMapBackend"]


def along_track(session: Session, t: np.ndarray, xy: np.ndarray, z: float | np.ndarray) -> Session:
    """``session`` whose ground truth is the track ``t`` (T,) s, ``xy`` (T, 2) world m at height ``z`` m (one value or
    (T,); NaN orientation): what :func:`~blenav.backend.mapping.map_beacons` reads as the walk's poses. Its other
    streams are the session's (read once on ``session`` and shared); its own ground truth is not read here."""
    session.rssi  # noqa: B018  (read and cached on the session itself: the view shares it)
    track = pd.DataFrame({"t": np.asarray(t, float), "x": xy[:, 0], "y": xy[:, 1],
                          "z": np.broadcast_to(np.asarray(z, float), (len(t),)),
                          "qw": np.nan, "qx": np.nan, "qy": np.nan, "qz": np.nan})
    view = replace(session, meta={**session.meta, "labelled": True})
    view.__dict__["_streams"] = {**session.__dict__.get("_streams", {}), "groundtruth": track}
    view.__dict__["_home"] = session.__dict__.get("_home", session.building)
    return view


class PooledMapBackend(BackendLocalizer, Transductive):
    """:class:`BackendLocalizer` on the map pooled from every scored walk of the building (module doc). ``pool``:
    ``labels`` (the row whose estimates place the walks, run before this one), ``prior_sigma_m`` (m per axis, > 0:
    each beacon's prior around the given map), ``stated_std`` (the pooled beacons' std_m into the back-end's prior).
    Every other setting is :class:`BackendLocalizer`'s."""

    def __init__(self, name: str, shared=None, pool: Any = None, **settings):
        super().__init__(name, shared, **settings)
        pool, self.batch_labels = batch_settings(name, "pool", pool, {"prior_sigma_m", "stated_std"}, "F-end")
        self.prior_sigma_m = float(pool.get("prior_sigma_m", 3.0))
        if not (np.isfinite(self.prior_sigma_m) and self.prior_sigma_m > 0):
            raise ValueError(f"method {name!r}: pool.prior_sigma_m must be a positive number of metres, got "
                             f"{pool.get('prior_sigma_m')!r}")
        self.stated_std = bool(pool.get("stated_std", False))
        # not shared with F-end / B-end
        self._settings += repr(("pool", self.batch_labels, self.prior_sigma_m, self.stated_std))
        self._walks: dict[str, list[tuple[Session, np.ndarray, np.ndarray]]] = {}
        self._prepared = False

    def prepare_batch(self, sessions: list, estimates: dict, inputs: RunInputs | None = None) -> dict:
        """Keep, per building, every walk of ``sessions`` that the labels row's ``estimates`` place (finite positions
        at two times or more): the session, its times (T,) s and positions (R, T, 2) m. Returns walks per building."""
        self._walks, self._prepared = {}, True
        for s in sessions:
            est = estimates.get(s.id)
            if est is None or len(est.t) < 2:
                continue
            pos = np.asarray(est.position, float)
            self._walks.setdefault(s.building.id, []).append((s, np.asarray(est.t, float), pos))
        return {"labels": self.batch_labels, "prior_sigma_m": self.prior_sigma_m,
                "buildings": {b: {"walks": len(w)} for b, w in self._walks.items()}}

    def pooled_map(self, building, run: int | None, cache: dict) -> tuple[pd.DataFrame, str]:
        """(anchors.csv rows of ``building`` with the placed BLE beacons moved to the pooled estimate, with its std_m
        when ``stated_std``, a note); ``run``: the labels row's run whose tracks place the walks (None: their runs'
        mean); computed once per building, given map and run (``cache``)."""
        anchors = building.anchors
        key = ("pooled-map", building.id, map_fingerprint(building), run, self.batch_labels, self.prior_sigma_m,
               self.stated_std)
        if key in cache:
            return cache[key]
        walks = self._walks.get(building.id, [])
        views = []
        for s, t, pos in walks:
            xy = pos[run] if run is not None and run < len(pos) else pos.mean(axis=0)  # that run's track, or the mean
            ok = np.isfinite(xy).all(axis=1)
            if ok.sum() >= 2 and s.has("rssi"):
                views.append(along_track(s.with_building(building), t[ok], xy[ok], self.cfg.range.device_z))
        if not views:
            cache[key] = anchors, f"pooled map: no walk of building {building.id} placed by {self.batch_labels}"
            return cache[key]
        mcfg = replace(self.cfg.mapping, use_map_prior=True, prior_sigma_m=self.prior_sigma_m,
                       device_z=self.cfg.range.device_z)
        res = map_beacons(views, anchors, mcfg)
        placed = res.placed.set_index(res.placed["anchor_id"].astype(str))
        out = anchors.copy()
        ids = out["anchor_id"].astype(str)
        hit = ids.isin(placed.index).to_numpy() & (out["kind"] == "ble").to_numpy()
        out.loc[hit, ["x", "y"]] = placed.loc[ids[hit], ["x", "y"]].to_numpy(float)
        if self.stated_std:
            out.loc[hit, "std_m"] = placed.loc[ids[hit], "std_m"].to_numpy(float)
        note = (f"pooled map: {int(hit.sum())} of {int((out['kind'] == 'ble').sum())} BLE beacons placed from "
                f"{len(views)} walks along {self.batch_labels}'s estimates ({res.wall_s:.1f} s)")
        cache[key] = out, note
        return cache[key]

    def run(self, session, n_runs: int, seed: int, inputs: RunInputs | None = None) -> Estimate:
        """The closed loop on ``session`` with its building's pooled map (:meth:`pooled_map`)."""
        if not self._prepared:
            raise ValueError(f"method {self.name!r} pools the scored walks placed by {self.batch_labels!r}: prepare it "
                             f"(prepare_batch) with that row's estimates first")
        self.check_session(session)  # what the closed loop needs, before any pooling
        inputs = inputs or RunInputs()
        b = session.building
        anchors, note = self.pooled_map(b, inputs.run, inputs.cache)
        est = super().run(session.with_building(replace(b, anchors=anchors)), n_runs, seed, inputs)
        est.notes.insert(0, note)
        return est
