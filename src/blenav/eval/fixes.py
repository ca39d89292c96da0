"""BLE position fixes for Roy's fusion experiments (Table 3.7): named ``fixes.csv`` sources, or computed.

The fused filters of Roy (section 3.2) weigh particles by the output of a BLE localizer (eq. 3.9), and
the "Dense BLE" / "Sparse BLE" rows of Table 3.7 are that localizer's output itself. An experiment
names, per role (``dense``, ``sparse``), a ``fixes.csv`` source (``fixes.dense=SOURCE``); a session that
has no fixes of that source (or every session, when the role is ``null``) gets *simple BLE fixes
computed from its rssi.csv*:

* the BLE-only localizer is PF-PS of Patel et al. (RSSI-domain likelihood ``ps_002`` with the random-walk
  motion, uniform start over free space; settings in the experiment's ``fixes.compute``), calibrated
  like the experiment's other path-loss models, run once (one run, a seed fixed per session and role);
* ``dense`` uses every BLE anchor of the building; ``sparse`` a subset of ``fixes.sparse_beacons``
  anchors: an integer k picks k anchors that cover the floor (:func:`spread_beacons`: greedy k-median
  over the floor's free space, each round adding the anchor that most reduces the mean distance from the
  walkable area to its nearest chosen anchor; ties by anchor id, so the choice is deterministic and the
  same for every session of a building), a list names them;
* the filter's estimates are taken at ``fixes.rate_hz`` (1 Hz: at t_start + 1 s, + 2 s, ...), source names
  ``ps-dense`` and ``ps-sparse<k>``.

Other roles and other fix localizers. A role may have any name (e.g. ``wifi``); only ``sparse`` means a beacon
subset. ``fixes.compute`` is one localizer config node for every role, or a mapping role -> node. Roles whose
nodes are equal share ONE localizer (built once; trained once by the harness when it is
:class:`~blenav.localizers.Trained`), and a node equal to one of the experiment's ``methods`` rows is that row's
own localizer (e.g. ``compute: {wifi: ${methods.knn_wifi}}``: the KNN-WiFi row's KNN, trained once, gives the
``wifi`` fixes). A localizer that is not a BLE particle filter (e.g. a trained
:class:`~blenav.localizers.fingerprint.FingerprintLocalizer`) gives its estimates of one run at its own times
(fingerprinting: one per scan, nothing added before the first or after the last), with their standard
deviation (``std``: the root of the mean of the covariance's diagonal, which a fix likelihood with
``use_std: true`` uses), source ``fix-<role>``; for ``sparse`` it hears only the chosen beacons (its
``beacons`` attribute, set per session; a localizer without one cannot give sparse fixes). These fixes are kept
in memory (a trained model is not a cache key).

Computed fixes are cached in the evaluation's output folder (``OUT/fixes/<session>/<source>.csv`` with
a key of the session's rssi.csv, the building's anchors and plan (:func:`building_key`), the beacons, the localizer's
settings and the seed), never written into the dataset unless ``fixes.write: true`` (then with
:func:`blenav.data.writer.write_fixes`, which replaces only the rows of that source).
"""

from __future__ import annotations

import hashlib
import json
import logging
import time
import zlib
from pathlib import Path

import numpy as np
import pandas as pd

from blenav.errors import MissingStream
from blenav.filters.method import Method
from blenav.filters.runner import run_session
from blenav.features.windows import spread_beacons
from blenav.localizers import ParticleFilterLocalizer
from blenav.localizers.inputs import Fixes, RoleFixes

from .common import output_name

log = logging.getLogger("blenav.eval.fixes")


def ble_fixes(method: Method, session, seed: int, rate_hz: float = 1.0) -> tuple[np.ndarray, np.ndarray]:
    """Fixes (t (F,) s, xy (F, 2) world m) of a BLE-only filter ``method`` (one run) at ``rate_hz``.

    The filter runs at its own rate; its estimates at t_start + j / rate_hz (j >= 1) are kept (every
    ``round(filter rate / rate_hz)``-th step). Raises :class:`MissingStream` without usable BLE data."""
    res = run_session(method, session, n_runs=1, seed=seed)
    stride = max(1, int(round(method.filter.rate_hz / rate_hz)))
    keep = slice(stride - 1, None, stride)
    return res.t[keep].copy(), res.position[0, keep].copy()


def building_key(session) -> str:
    """A digest of what a BLE filter reads of ``session``'s building: the anchors as the run sees them (anchors.csv,
    or the map ``beacon_map`` gave) and the floor's occupancy grid, resolution and origin (a wrong plan of
    ``plan_error``). Part of the key of cached fixes, so that a rerun into the same OUT (``overwrite=true`` reuses
    ``fixes/``) after anchors.csv or the plan changed computes them again."""
    fl = session.floor
    h = hashlib.sha256(session.building.anchors.to_csv(index=False).encode())
    h.update(np.ascontiguousarray(fl.occupancy).tobytes())
    h.update(repr((fl.occupancy.shape, float(fl.resolution), tuple(map(float, fl.origin)))).encode())
    return h.hexdigest()[:16]


class FixProvider:
    """Per session and role, the fixes an experiment uses (named source, or computed and cached).

    ``roles``: role -> named ``fixes.csv`` source or None; ``localizers``: role -> the localizer that computes
    the role's fixes (several roles may share one instance): a BLE-only
    :class:`~blenav.localizers.ParticleFilterLocalizer` (the ``beacons`` of its method are set per building for
    ``sparse``) or any other localizer (module doc);
    ``sparse_beacons``: k or a list of anchor ids; ``out``: the evaluation folder (cache)."""

    def __init__(self, roles: dict, localizers: dict, sparse_beacons, out: Path, seed: int = 0,
                 rate_hz: float = 1.0, write: bool = False):
        missing = set(localizers) - set(roles)
        if missing:
            raise ValueError(f"fixes.compute names role(s) {sorted(missing)} that the fixes block does not define")
        self.roles = {r: (None if v is None else str(v).strip()) for r, v in roles.items()}
        self.localizers = localizers
        self.sparse_beacons = sparse_beacons
        self.out = Path(out)
        self.seed = int(seed)
        self.rate_hz = float(rate_hz)
        self.write = bool(write)
        self._mem: dict = {}
        self._computed: set = set()  # (role, session id) whose fixes were computed (added in memory)
        self.compute_s: dict = {}  # (role, session id) -> seconds the localizer took (one run)
        self.beacon_ids: dict[str, list[str]] = {}  # building id -> sparse beacons chosen
        self.used: dict[str, dict[str, str]] = {r: {} for r in self.roles}  # role -> session -> what was used

    @property
    def methods(self) -> dict:
        """The distinct localizers, each once, keyed by the computed source name of the first role that uses it (for
        the harness's path-loss calibration and training)."""
        out: dict = {}
        for r, m in self.localizers.items():
            if all(m is not o for o in out.values()):
                out[self.computed_source(r)] = m
        return out

    def computed_source(self, role: str) -> str:
        prefix = "ps" if self._ble_filter(role) else "fix"
        if role == "sparse":
            k = len(self.sparse_beacons) if not isinstance(self.sparse_beacons, int) else int(self.sparse_beacons)
            return f"{prefix}-sparse{k}"
        return f"{prefix}-{role}"

    def beacons_for(self, role: str, session) -> tuple | None:
        if role != "sparse":
            return None
        if isinstance(self.sparse_beacons, int):
            return tuple(spread_beacons(session.building.anchors, self.sparse_beacons, session.meta.get("floor"),
                                        session.floor))
        return tuple(str(b) for b in self.sparse_beacons)

    # ------------------------------------------------------------------ the fixes of one role
    def fixes_for(self, role: str, session) -> tuple[np.ndarray, np.ndarray, str]:
        """(t (F,), xy (F, 2), source) of ``role`` for ``session``: the named source's rows when the session
        has them, else computed from rssi.csv (cached); :class:`MissingStream` when neither is possible."""
        t, xy, _, src, _ = self._fixes(role, session)
        return t, xy, src

    def _fixes(self, role: str, session) -> tuple:
        """:meth:`fixes_for` with the fixes' std (F,) m (NaN where the source gives none) and their off-survey log
        ratios (F,) (None where the source states none: :attr:`RoleFixes.off_log_ratio`): (t, xy, std, source,
        off_log_ratio)."""
        if role not in self.roles:
            raise ValueError(f"unknown fixes role {role!r}; the experiment defines {sorted(self.roles)}")
        key = (role, session.id)
        if key in self._mem:
            return self._mem[key]
        named = self.roles[role]
        fx = session.fixes
        if named is not None and len(fx):
            sel = fx["source"].fillna("").astype(str).str.strip() == named
            if sel.any():
                rows = fx[sel]
                self.used[role][session.id] = f"fixes.csv source {named!r}"
                self._mem[key] = (rows["t"].to_numpy(float), rows[["x", "y"]].to_numpy(float),
                                  rows["std"].to_numpy(float), named, None)
                return self._mem[key]
        if role not in self.localizers:
            raise MissingStream(f"session {session.id} has no fixes of source {named!r} and no localizer is "
                                f"configured to compute {role} fixes")
        why = "fixes.%s is null" % role if named is None else f"no fixes of source {named!r} in fixes.csv"
        pf = self._ble_filter(role)
        if pf and not len(session.rssi):  # other localizers check their own streams
            raise MissingStream(f"session {session.id}: {why} and no rssi.csv to compute {role} BLE fixes from")
        if pf:
            t, xy = self._compute(role, session)
            sd, off = np.full(len(t), np.nan), None
        else:
            t, xy, sd, off = self._compute_any(role, session)
        src = self.computed_source(role)
        self._computed.add(key)
        by = "from rssi.csv" if pf else f"by {self.localizers[role].name}"
        self.used[role][session.id] = f"computed {by} as {src!r} ({why})"
        self._mem[key] = (t, xy, sd, src, off)
        return self._mem[key]

    def _ble_filter(self, role: str) -> bool:
        """Whether ``role``'s localizer is a BLE particle filter (fixes at ``rate_hz`` from rssi.csv, cached on disk);
        any other localizer (e.g. fingerprinting) gives its own estimates (:meth:`_compute_any`)."""
        return isinstance(self.localizers[role], ParticleFilterLocalizer)

    def _compute(self, role: str, session) -> tuple[np.ndarray, np.ndarray]:
        """The BLE filter's fixes with its ``beacons`` set for ``role`` (the sparse subset or all), restored after:
        the filter may be shared with other roles or be a scored row itself."""
        m = self.localizers[role].method
        old, m.beacons = m.beacons, self.beacons_for(role, session)
        try:
            return self._compute_ble(role, session, m)
        finally:
            m.beacons = old

    def _compute_ble(self, role: str, session, m: Method) -> tuple[np.ndarray, np.ndarray]:
        if m.beacons is not None:
            self.beacon_ids[str(session.building.id)] = list(m.beacons)
        seed = self.seed * 1_000_003 + zlib.crc32(f"{session.id}/{role}".encode())
        src = self.computed_source(role)
        rssi_file = Path(session.root) / "rssi.csv"
        st = rssi_file.stat() if rssi_file.is_file() else None
        key = hashlib.sha256(json.dumps({
            "session": str(Path(session.root).resolve()), "rssi": [st.st_size, st.st_mtime_ns] if st else None,
            "beacons": m.beacons, "filter": repr(m.filter), "motion": repr(m.motion), "map": repr(m.map),
            "measurements": [repr(x) for x in m.measurements], "seed": seed, "rate_hz": self.rate_hz,
            "building": building_key(session),
        }, sort_keys=True).encode()).hexdigest()[:16]
        path = self.out / "fixes" / output_name(session.id) / f"{src}.csv"
        meta = path.with_suffix(".json")
        if path.is_file() and meta.is_file():
            info = json.loads(meta.read_text())
            if info.get("key") == key:
                self.compute_s[(role, session.id)] = float(info.get("wall_s", 0.0))
                df = pd.read_csv(path)
                return df["t"].to_numpy(float), df[["x", "y"]].to_numpy(float)
        t0 = time.perf_counter()
        t, xy = ble_fixes(m, session, seed, self.rate_hz)
        self.compute_s[(role, session.id)] = time.perf_counter() - t0
        path.parent.mkdir(parents=True, exist_ok=True)
        pd.DataFrame({"t": t, "x": xy[:, 0], "y": xy[:, 1]}).to_csv(path, index=False, float_format="%.4f")
        meta.write_text(json.dumps({"key": key, "source": src, "beacons": m.beacons, "seed": seed,
                                    "localizer": m.name, "wall_s": self.compute_s[(role, session.id)]}, indent=1))
        # read back what was written, so a cached and a fresh run use the very same (rounded) numbers
        df = pd.read_csv(path)
        t, xy = df["t"].to_numpy(float), df[["x", "y"]].to_numpy(float)
        if self.write:
            from blenav.data.writer import write_fixes

            write_fixes(session.root, t, xy, source=src)
            log.warning("wrote %d %s fixes into %s/fixes.csv (fixes.write = true)", len(t), src, session.root)
        return t, xy

    def _compute_any(self, role: str, session) -> tuple:
        """Fixes (t (F,) s, xy (F, 2) m, std (F,) m, off-survey log ratios (F,) or None: the estimate's output
        ``off_survey_log_ratio``) of a localizer that is not a BLE particle filter (e.g. a trained
        :class:`~blenav.localizers.fingerprint.FingerprintLocalizer`): its finite estimates of one run, at its own
        times (fingerprinting: one per scan), not resampled to ``rate_hz``; std from its covariance (NaN without
        one). ``sparse``: the localizer hears only :meth:`beacons_for` (its ``beacons`` attribute, restored after).
        One run per (localizer, beacons, session), shared by the roles that ask the same; kept in memory only."""
        loc = self.localizers[role]
        beacons = self.beacons_for(role, session)
        if beacons is not None and not hasattr(loc, "beacons"):
            raise ValueError(f"fixes.{role}: {loc.name} cannot be limited to the sparse beacon subset (no 'beacons')")
        key = ("run", id(loc), beacons, session.id)
        if key not in self._mem:
            seed = self.seed * 1_000_003 + zlib.crc32(f"{session.id}/{loc.name}".encode())
            t0 = time.perf_counter()
            if beacons is not None:
                self.beacon_ids[str(session.building.id)] = list(beacons)
                old, loc.beacons = loc.beacons, beacons
            try:
                est = loc.run(session, 1, seed)
            finally:
                if beacons is not None:
                    loc.beacons = old
            self.compute_s[(role, session.id)] = time.perf_counter() - t0
            xy = est.position[0]
            sd = est.std[0] if est.cov is not None else np.full(len(est.t), np.nan)
            ok = np.isfinite(xy).all(axis=1)
            if not ok.any():
                raise MissingStream(f"{loc.name} gave no position on session {session.id} for the {role} fixes")
            lr = est.outputs.get("off_survey_log_ratio")
            self._mem[key] = (est.t[ok].copy(), xy[ok].copy(), sd[ok].copy(),
                              None if lr is None else np.asarray(lr, float)[ok].copy())
        return self._mem[key]

    # ------------------------------------------------------------------ per method and session
    def resolve(self, roles, session) -> Fixes:
        """The fixes of ``roles`` (in the order the method reads them) on ``session``, as the typed
        :class:`~blenav.localizers.inputs.Fixes` a localizer's run receives. The first role that has none
        (:class:`MissingStream`) ends the resolution: it and the roles after it carry that reason (the method is
        skipped on the session, and fixes it would not read are not computed)."""
        got, missing = {}, {}
        for role in roles:
            if missing:
                missing[role] = next(iter(missing.values()))
                continue
            try:
                t, xy, sd, src, off = self._fixes(role, session)
            except MissingStream as exc:
                missing[role] = str(exc)
                continue
            key = (role, session.id)
            got[role] = RoleFixes(t, xy, sd, src, computed=key in self._computed, wall_s=self.compute_s.get(key),
                                  off_log_ratio=off)
        return Fixes(got, missing)

    def resolve_first(self, roles, session) -> Fixes:
        """The fixes of the first of ``roles`` that ``session`` has (alternatives, e.g. WiFi + BLE fixes, else BLE
        ones): the roles before it carry their reasons; none found: every role its own reason."""
        missing = {}
        for role in roles:
            fx = self.resolve([role], session)
            if role in fx.roles:
                return Fixes({role: fx.roles[role]}, missing)
            missing.update(fx.missing)
        return Fixes({}, missing)

    def describe(self) -> dict:
        """For results.json: role -> {session: what was used}, plus the sparse beacons chosen per building."""
        sb = self.sparse_beacons
        return {"roles": dict(self.roles), "used": self.used,
                "localizers": {r: m.name for r, m in self.localizers.items()},
                "sparse_beacons": f"{sb} covering the floor (greedy k-median)" if isinstance(sb, int) else list(sb),
                "sparse_beacon_ids": self.beacon_ids}
