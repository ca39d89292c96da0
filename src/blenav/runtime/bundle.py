"""A runtime bundle: one folder an app embeds, run without PyTorch (onnxruntime + numpy).

Layout (``python export.py bundle=true ckpt=RUN/last.ckpt out=BUNDLE [mapprior=RUN2/last.ckpt]``)::

    BUNDLE/manifest.json          format, versions, sha256 and size of every file, variants with their size,
                                  latency and accuracy change against the float models
    BUNDLE/settings.json          the filter, motion, fix and map-prior settings of the pipeline
    BUNDLE/building.json          the building's signature: beacon order and positions, floor-plan hashes
    BUNDLE/localizer.onnx         the cross-phone localizer (TransNet + LocNet, metadata as blenav.learn.crossphone.export)
    BUNDLE/localizer.ort          ... in ONNX Runtime's ORT format (mobile builds)
    BUNDLE/localizer.int8.onnx    ... dynamically quantised to int8 weights (onnxruntime.quantization)
    BUNDLE/localizer.int8.ort     ... both
    BUNDLE/map_prior/             optional: map_encoder.*, trajectory_encoder.* (same four variants), meta.json

The pipeline (Roy, section 3.2): per filter step (``settings.filter.rate_hz``) a particle filter with the odometry
increment motion model (eq. 3.7), weighted by the localizer's BLE fix (eq. 3.9, N(||x - z||; 0, sigma)) and, when
the bundle has one, by the learned map prior's score (eq. 3.8). The localizer sees RSSI windows built live with the
recipe of :func:`blenav.features.windows.session_windows` (steps of ``1 / step_hz`` s from the first packet, mean of
u = max(rssi + offset_db, floor_u) per step and beacon, H steps per window); a window's fix is made at the end of its
newest step, as soon as a sample at or after that time arrives, and enters the filter's step that holds that time.

Push API (:class:`BundleLocalizer`, ``Bundle.open(dir).localizer(building)``): ``push_rssi``, ``push_odometry``,
``push_imu``, ``push_mag``, ``close`` in time order; each returns the track points (:class:`TrackPoint`: t, x, y, std) of
the filter steps the sample closed. With ``map.init: fix`` the filter starts around the first fix: samples before
it are kept and replayed then, so the first estimates come H steps after the first packet (as the batch filter,
which starts at the session's first sample). :meth:`Bundle.run_session` replays a recorded session through it and
gives exactly what :func:`blenav.filters.runner.run_session` gives with the same fixes and seed.

A bundle refuses a building (or a session's building) whose BLE beacons or floor plans are not its own
(:mod:`blenav.runtime.signature`), a folder whose files are not exactly the ones its manifest records (sha256; an
empty manifest, a missing, changed or unlisted file), and settings that name a class other than blenav's
(:data:`blenav.trust.TARGETS`; the motion model one of :data:`MOTION_TARGETS`), checked by name before any import.

Imports numpy, pandas (through blenav.data) and onnxruntime; never torch, lightning or hydra.
"""

from __future__ import annotations

import hashlib
import importlib
import json
import math
import platform
import shutil
import time
from collections import deque
from dataclasses import dataclass, fields
from pathlib import Path
from types import SimpleNamespace
from typing import Callable, Iterable, NamedTuple

import numpy as np

from blenav.features.mapgrid import pad_to_multiple
from blenav.limits import LimitError, check_range, read_json
from blenav.onnx_io import blenav_version, check_weights, read_metadata, session
from blenav.trust import TARGETS, UntrustedTargetError, check_targets

from .map_prior import OnnxBackend
from .onnx_localizer import LocalizerSession
from .signature import BuildingMismatch, building_signature, check_building

FORMAT = "blenav-bundle/1"
MANIFEST = "manifest.json"
SETTINGS = "settings.json"
BUILDING = "building.json"
LOCALIZER = "localizer"
MAP_DIR = "map_prior"
MAP_GRAPHS = ("map_encoder", "trajectory_encoder")
VARIANTS = ("float", "ort", "int8", "int8_ort")
FIX_SOURCE = "bundle"
#: the pipeline of Roy's Table 3.7 (sparse-BLE+IO+map) as a live app runs it: no ground truth, heading from the fixes
DEFAULT_SETTINGS = {
    "filter": {"n_particles": 1000, "rate_hz": 1.0, "resampling": "low_variance", "ess_threshold": 1.0,
               "estimate": "median", "divergence_sigma": float("inf"), "reinit_fraction": 0.9, "reinit_radius_m": 5.0},
    "motion": {"_target_": "blenav.filters.motion.OdometryIncrement", "sigma2_per_s": 0.1, "sigma_theta": 0.01},
    "fix": {"sigma_m": 3.0},
    "prior": {"heading_bins": 36, "window_dt_s": None},
    "map": {"init": "fix", "heading": "motion", "init_sigma_m": 0.01},
    "attitude": {},
    "steps": {},
}


def variant_name(base: str, variant: str) -> str:
    """File name of graph ``base`` in ``variant`` (float: BASE.onnx, ort: BASE.ort, int8: BASE.int8.onnx, ...)."""
    if variant not in VARIANTS:
        raise ValueError(f"bundle variant must be one of {VARIANTS}, got {variant!r}")
    return base + {"float": ".onnx", "ort": ".ort", "int8": ".int8.onnx", "int8_ort": ".int8.ort"}[variant]


def sha256_file(path: Path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for chunk in iter(lambda: f.read(1 << 20), b""):
            h.update(chunk)
    return h.hexdigest()


class TrackPoint(NamedTuple):
    """One filter step of the live track (one run): t (s, the session's clock), x, y (m, the building's world frame),
    std (m): the RMS of the per-axis standard deviations of the particle cloud, sqrt((var_x + var_y) / 2). Offline,
    R runs of K steps are one :class:`blenav.filters.estimate.Estimate`."""

    t: float
    x: float
    y: float
    std: float


# --- the method --------------------------------------------------------------------------------------------

#: the motion models a bundle's settings may name (``motion._target_``): blenav's, by their dotted names
MOTION_TARGETS = frozenset(t for t in TARGETS if t.startswith("blenav.filters.motion."))


def check_targets_of(settings: dict, where: str) -> None:
    """A bundle's settings name no class but blenav's (:func:`blenav.trust.check_targets`), and ``motion._target_``
    one of :data:`MOTION_TARGETS`: a one-line :class:`blenav.trust.UntrustedTargetError` naming ``where`` (the
    settings file) and the field, before anything is imported."""
    motion = settings.get("motion") if isinstance(settings, dict) else None
    if not isinstance(motion, dict):
        raise ValueError(f"{where}: motion must be an object with a _target_ (a motion model), got "
                         f"{type(motion).__name__}")
    target = motion.get("_target_")
    if not isinstance(target, str) or target not in MOTION_TARGETS:
        raise UntrustedTargetError(f"{where}: motion._target_ = {str(target)[:120]!r} is not one of blenav's motion "
                                   f"models ({', '.join(sorted(MOTION_TARGETS))})")
    check_targets(settings, where)


def _instantiate(node: dict, where: str = SETTINGS):
    """An object of ``node['_target_']`` (one of :data:`MOTION_TARGETS`, checked by name before anything is
    imported: :func:`check_targets_of`) with the other keys as arguments; ``where``: the settings file, named in a
    refusal (ValueError also for arguments the class does not take)."""
    check_targets_of({"motion": node}, where)
    node = dict(node)
    target = node.pop("_target_")
    mod, _, name = target.rpartition(".")
    try:
        return getattr(importlib.import_module(mod), name)(**node)
    except TypeError as exc:  # an argument the class does not take
        raise ValueError(f"{where}: motion ({name}): {exc}") from None


def _dataclass(cls, node: dict | None, where: str):
    node = dict(node or {})
    known = {f.name for f in fields(cls)}
    unknown = sorted(set(node) - known)
    if unknown:
        raise ValueError(f"bundle settings: {where} has unknown key(s) {unknown} (known: {sorted(known)})")
    return cls(**node)


def check_settings(settings: dict, where: str) -> None:
    """Every size the settings set lies in its documented range (:data:`blenav.limits.RANGES`), and the particle
    filter they ask for fits the memory limit (one run, as the push API runs it), before anything is built:
    :class:`blenav.limits.LimitError` naming ``where`` (the settings.json) and the field."""
    from blenav.filters.engine import FilterConfig, check_size

    if not isinstance(settings, dict):
        raise LimitError(f"{where}: expected a JSON object, got {type(settings).__name__}")
    f = settings.get("filter") if isinstance(settings.get("filter"), dict) else {}
    if "rate_hz" in f:
        check_range(f["rate_hz"], "rate_hz", where, field="filter.rate_hz")
    n = f.get("n_particles", FilterConfig.n_particles)
    check_range(n, "n_particles", where, field="filter.n_particles")
    prior = settings.get("prior") if isinstance(settings.get("prior"), dict) else {}
    if prior.get("heading_bins") is not None:
        check_range(prior["heading_bins"], "heading_bins", where, field="prior.heading_bins")
    if prior.get("window_dt_s") is not None:
        check_range(prior["window_dt_s"], "window_s", where, field="prior.window_dt_s")
    try:
        dim = int(_instantiate(settings["motion"]).state_dim)
    except Exception:  # a bad motion node is refused where the method is built, with its own message
        return
    check_size(1, n, dim, where, field="filter.n_particles")


def build_method(settings: dict, prior=None, where: str = SETTINGS):
    """The :class:`blenav.filters.method.Method` of a bundle's settings; ``prior``: a map prior (or None);
    ``where``: the settings file, named in errors. Every ``_target_`` of the settings must be blenav's
    (:func:`blenav.trust.check_targets`), the motion model's one of :data:`MOTION_TARGETS`."""
    from blenav.filters.attitude import AttitudeConfig
    from blenav.filters.engine import EstimateMode, FilterConfig, Resampling
    from blenav.filters.map_prior import MapPriorLikelihood
    from blenav.filters.measurement import FixLikelihood
    from blenav.filters.method import HeadingMode, InitMode, MapSpec, Method
    from blenav.filters.steps import StepDetectorConfig

    check_targets_of(settings, where)
    f = _dataclass(FilterConfig, settings.get("filter"), "filter")
    f.resampling, f.estimate = Resampling(f.resampling), EstimateMode(f.estimate)
    f.divergence_sigma = float(f.divergence_sigma)
    spec = _dataclass(MapSpec, settings.get("map"), "map")
    spec.init, spec.heading = InitMode(spec.init), HeadingMode(spec.heading)
    meas = [FixLikelihood(source=FIX_SOURCE, **dict(settings.get("fix") or {}))]
    if prior is not None and settings.get("prior") is not None:
        meas.append(MapPriorLikelihood(prior=prior, **dict(settings["prior"])))
    return Method("bundle", f, _instantiate(settings.get("motion"), where), meas, spec,
                  _dataclass(AttitudeConfig, settings.get("attitude"), "attitude"),
                  _dataclass(StepDetectorConfig, settings.get("steps"), "steps"))


# --- graphs ------------------------------------------------------------------------------------------------

class LocalizerGraph(LocalizerSession):
    """The cross-phone localizer of a bundle in one variant: (K, B, H) windows on the thesis scale -> (K, 2) m,
    each from a zero LSTM state (the export's ``lstm_state`` contract); NaN rows where nothing was heard. ``meta``:
    the float graph's metadata (the ORT variants may not keep it); ``sess``: an open session of ``path``."""

    def __init__(self, path: Path, meta: dict, threads: int = 1, sess=None):
        super().__init__(path, meta, sess if sess is not None else session(Path(path), threads))

    #: unchecked (the live path builds the windows itself)
    predict = LocalizerSession.predict_windows


class _MapBackend(OnnxBackend):
    """A bundle's map prior graphs (one variant) as a :class:`blenav.runtime.map_prior.MapPrior` backend: an
    :class:`~blenav.runtime.map_prior.OnnxBackend` (its encoders) over the bundle's file names and manifest."""

    def __init__(self, root: Path, variant: str, threads: int, digest: str):
        self.meta = read_json(root / "meta.json")
        self.map_sess = session(root / variant_name(MAP_GRAPHS[0], variant), threads)
        self.traj_sess = session(root / variant_name(MAP_GRAPHS[1], variant), threads)
        self.weights_hash = f"bundle-{variant}:{digest[:16]}"
        self.resolution_m = float(self.meta["resolution_m"])



# --- live windows ------------------------------------------------------------------------------------------

class WindowFixer:
    """RSSI packets -> the localizer's fixes, live, with the windowing of
    :func:`blenav.features.windows.session_windows` (``steps: time``): step k = floor((t - t0) step_hz) from the
    first packet t0; per step and beacon the mean of u; the window of the last H steps ends at t0 + (k + 1) / step_hz.

    :meth:`advance` (t) closes the steps that end at or before ``t`` and returns their fixes (t, x, y) (windows with
    nothing heard give none); :meth:`add` a packet; :meth:`flush` closes the open step at the end of the data."""

    def __init__(self, graph: LocalizerGraph):
        w = graph.meta["window"]
        if str(w.get("steps", "time")) != "time":
            raise ValueError("the bundle's localizer was trained on scan windows (a fingerprint survey): it cannot "
                             "localize a stream")
        where = f"{graph.path} metadata"  # the localizer's window, bounded before H steps are kept
        self.graph = graph
        self.hz = check_range(w["step_hz"], "step_hz", where, field="window.step_hz")
        self.H = check_range(w["history"], "history", where, field="window.history")
        self.offset, self.floor_u = float(w["offset_db"]), float(w["floor_u"])
        self.col = {b: i for i, b in enumerate(graph.beacons)}
        B = len(self.col)
        self.t0: float | None = None
        self.k = 0
        self.sums, self.counts = [0.0] * B, [0.0] * B  # the open step, per beacon (Python floats: cheap per packet)
        self.steps: list[np.ndarray] = []
        self.unknown: dict[str, int] = {}
        self.windows = 0

    def _close(self) -> tuple | None:
        sums, counts = np.array(self.sums), np.array(self.counts)
        self.steps.append(np.divide(sums, counts, out=np.zeros_like(sums), where=counts > 0))
        self.sums, self.counts = [0.0] * len(self.col), [0.0] * len(self.col)
        k, self.k = self.k, self.k + 1
        if len(self.steps) > self.H:
            self.steps.pop(0)
        if len(self.steps) < self.H:
            return None
        self.windows += 1
        S = np.stack(self.steps, axis=1)[None].astype(np.float32)  # (1, B, H), oldest step first
        xy = self.graph.predict(S)[0]
        if not np.isfinite(xy).all():
            return None
        return (self.t0 + (k + 1) / self.hz, float(xy[0]), float(xy[1]))

    def advance(self, t: float) -> list[tuple]:
        if self.t0 is None:
            return []
        kk = int(math.floor((t - self.t0) * self.hz))
        out = []
        while self.k < kk:
            fix = self._close()
            if fix is not None:
                out.append(fix)
        return out

    def add(self, t: float, anchor_id: str, rssi: float) -> None:
        if self.t0 is None:
            self.t0, self.k = float(t), 0
        j = self.col.get(str(anchor_id))
        if j is None:
            self.unknown[str(anchor_id)] = self.unknown.get(str(anchor_id), 0) + 1
            return
        u = float(rssi) + self.offset  # rssi_to_u, in Python floats (the same IEEE result, NaN stays NaN)
        self.sums[j] += self.floor_u if u < self.floor_u else u
        self.counts[j] += 1.0

    def flush(self) -> list[tuple]:
        """Close the open step (the last, partial one: offline windowing keeps it too)."""
        if self.t0 is None:
            return []
        fix = self._close()
        return [fix] if fix is not None else []


# --- the push API ------------------------------------------------------------------------------------------

class BundleLocalizer:
    """Live localization with a bundle: push samples in time order, get :class:`TrackPoint` rows as steps close.

    ``building``: a :class:`blenav.data.Building` (checked against the bundle); ``floor``: its floor id (default:
    the first); ``seed``: the filter's random generator; ``start_xy`` / ``start_theta``: a known start for
    ``map.init: groundtruth`` / ``map.heading: groundtruth`` settings; ``t_start``: the clock time the filter
    starts at (default: the first IMU, RSSI or odometry sample pushed); ``mag_offset``: the magnetometer's
    hard-iron offset (uT) for settings whose motion model runs an AHRS; ``keep_fixes``: how many of the latest
    fixes :attr:`fixes` holds, (t, x, y) each (None: every fix, as :meth:`Bundle.run_session` keeps for parity; a
    live app keeps memory flat with the default, benchmarks/soak.py)."""

    def __init__(self, bundle: "Bundle", building, floor=None, seed: int = 0, start_xy=None, start_theta=None,
                 t_start: float | None = None, mag_offset=None, keep_fixes: int | None = 1000):
        bundle.check_building(building)
        fid = floor if floor is not None else next(iter(building.floors))
        self._ctx = SimpleNamespace(id="live", building=building, meta={"floor": fid}, floor=building.floor(fid))
        self.bundle, self.seed = bundle, int(seed)
        self.method = bundle.method()
        self.fixer = WindowFixer(bundle.graph)
        self.fixes: deque[tuple] = deque(maxlen=keep_fixes)
        self._online = None
        self._pending: list[tuple] = []
        self._t_start = t_start
        self._start_xy = None if start_xy is None else np.asarray(start_xy, float)
        self._start_theta, self._mag_offset = start_theta, mag_offset
        self._init = str(self.method.map.init)
        self._rssi_models = bool(self.method.measurements_needing("rssi"))
        if self._init == "groundtruth" and self._start_xy is None:
            raise ValueError("the bundle's settings start at a known position (map.init: groundtruth): pass start_xy")

    @property
    def started(self) -> bool:
        return self._online is not None

    def _start(self) -> list[TrackPoint]:
        from blenav.filters.online import OnlineLocalizer

        self._online = OnlineLocalizer(self.method, self._ctx, 1, self.seed, t_start=float(self._t_start),
                                       mag_offset=self._mag_offset, start_xy=self._start_xy,
                                       start_theta=self._start_theta)
        out: list[TrackPoint] = []
        pending, self._pending = self._pending, []
        for ev in pending:
            out += self._rows(self._online.push_event(ev))
        return out

    @staticmethod
    def _rows(results) -> list[TrackPoint]:
        out = []
        for r in results:
            c = r.cov[0]
            out.append(TrackPoint(float(r.t), float(r.position[0, 0]), float(r.position[0, 1]),
                                float(np.sqrt(max(0.0, (c[0, 0] + c[1, 1]) / 2.0)))))
        return out

    def _feed(self, ev: tuple) -> list[TrackPoint]:
        if ev[0] == "rssi" and not self._rssi_models:
            return []  # the filter weighs the bundle's fixes, not packets: they only feed the localizer's windows
        if self._online is not None:
            return self._rows(self._online.push_event(ev))
        self._pending.append(ev)
        if self._init == "fix" and ev[0] == "fix":
            self._start_xy = np.array([ev[2], ev[3]], float)
        if self._init != "fix" or self._start_xy is not None:
            return self._start()
        return []

    def _push(self, ev: tuple) -> list[TrackPoint]:
        t = float(ev[1])
        if ev[0] != "mag" and self._t_start is None:
            self._t_start = t
        out = []
        for tf, x, y in self.fixer.advance(t):
            self.fixes.append((tf, x, y))
            out += self._feed(("fix", tf, x, y, None, FIX_SOURCE))
        if ev[0] == "rssi":
            self.fixer.add(t, ev[2], ev[3])
        return out + self._feed(ev)

    def push_rssi(self, t: float, anchor_id: str, rssi: float) -> list[TrackPoint]:
        """One BLE packet: time (s), anchor id, RSSI (dBm)."""
        return self._push(("rssi", float(t), str(anchor_id), float(rssi)))

    def push_odometry(self, t: float, xy) -> list[TrackPoint]:
        """Inertial odometry position (m, the odometry's own frame, as odometry.csv)."""
        return self._push(("odo", float(t), np.asarray(xy, float)))

    def push_imu(self, t: float, acc, gyr) -> list[TrackPoint]:
        """Accelerometer (m/s^2) and gyroscope (rad/s), phone frame (used by settings with an IMU motion model)."""
        return self._push(("imu", float(t), np.asarray(acc, float), np.asarray(gyr, float)))

    def push_mag(self, t: float, mag) -> list[TrackPoint]:
        """Magnetometer (uT), phone frame."""
        return self._push(("mag", float(t), np.asarray(mag, float)))

    def push_event(self, ev: tuple) -> list[TrackPoint]:
        """One event of :func:`blenav.filters.online.replay` (fix events are not taken: the bundle makes its own)."""
        if ev[0] == "fix":
            return []
        return self._push(ev)

    def close(self, t_end: float) -> list[TrackPoint]:
        """End of the data at ``t_end``: the last fix, then every step that ends by then (or by that fix)."""
        out = []
        for tf, x, y in self.fixer.flush():
            self.fixes.append((tf, x, y))
            out += self._feed(("fix", tf, x, y, None, FIX_SOURCE))
            t_end = max(t_end, tf)
        if self._online is None:
            if not self._pending:
                return out
            if self._init == "fix":
                raise ValueError("no fix was made (no window with a beacon of the bundle heard): the filter never "
                                 "started")
            out += self._start()
        return out + self._rows(self._online.close(float(t_end)))


# --- the bundle --------------------------------------------------------------------------------------------

@dataclass
class Bundle:
    """An opened bundle folder (:meth:`open`): its manifest, settings, building signature and graphs."""

    root: Path
    manifest: dict
    settings: dict
    signature: dict
    variant: str
    graph: LocalizerGraph
    prior: object | None

    @classmethod
    def open(cls, root: str | Path, variant: str = "float", threads: int = 1, verify: bool = True) -> "Bundle":
        """Open ``root``: check every file against the manifest's sha256 (``verify``), load the localizer and the map
        prior (when the bundle has one) of ``variant`` (float, ort, int8, int8_ort) with ``threads`` intra-op
        threads."""
        root = Path(root)
        mpath = root / MANIFEST
        if not mpath.is_file():
            raise FileNotFoundError(f"{root} is not a blenav bundle (no {MANIFEST}); write one with `python export.py "
                                    "bundle=true ckpt=RUN/last.ckpt out=BUNDLE`")
        manifest = read_json(mpath, "manifest")
        if not isinstance(manifest, dict):
            raise ValueError(f"{mpath}: not a manifest (a JSON object), a {type(manifest).__name__}")
        if manifest.get("format") != FORMAT:
            raise ValueError(f"{mpath}: format {manifest.get('format')!r}, this blenav reads {FORMAT!r}")
        if verify:
            verify_files(root, manifest)
        have = manifest.get("variants_available") or ["float"]
        if variant not in have:
            raise ValueError(f"bundle {root} has no {variant!r} variant (has {have})")
        settings = read_json(root / SETTINGS, "settings")
        if not isinstance(settings, dict):
            raise ValueError(f"{root / SETTINGS}: not a settings object, a {type(settings).__name__}")
        check_settings(settings, str(root / SETTINGS))
        check_targets_of(settings, str(root / SETTINGS))  # names only blenav's classes: checked before anything is built
        signature = read_json(root / BUILDING, "building signature")
        float_path = root / variant_name(LOCALIZER, "float")
        # the metadata is read from the float graph (the ORT variants may not keep it); the float variant's graph
        # reuses that session instead of loading the file a second time
        float_sess = session(float_path, threads if variant == "float" else 1)
        meta = read_metadata(float_sess)
        if verify:
            check_weights(float_path)
        graph = LocalizerGraph(root / variant_name(LOCALIZER, variant), meta, threads,
                               sess=float_sess if variant == "float" else None)
        prior = None
        if (root / MAP_DIR / "meta.json").is_file():
            from .map_prior import MapPrior

            digest = manifest["files"].get(f"{MAP_DIR}/{variant_name(MAP_GRAPHS[0], variant)}", {}).get("sha256", "")
            backend = _MapBackend(root / MAP_DIR, variant, threads, digest)
            prior = MapPrior(root / MAP_DIR / variant_name(MAP_GRAPHS[0], variant), loader=lambda _p: backend)
        return cls(root, manifest, settings, signature, variant, graph, prior)

    @property
    def beacons(self) -> list[str]:
        return list(self.signature["beacons"])

    def check_building(self, building) -> None:
        """:class:`BuildingMismatch` unless ``building`` has the bundle's beacons (ids, positions) and floor plans."""
        check_building(self.signature, building, what=f"bundle {self.root}")

    def check_session(self, session) -> None:
        """The session's building must be the bundle's (:meth:`check_building`); the message names the session."""
        try:
            self.check_building(session.building)
        except BuildingMismatch as exc:
            raise BuildingMismatch(f"session {session.id}: {exc}") from None

    def method(self):
        """A fresh filter method of the bundle's settings (its measurement models hold per-run state)."""
        return build_method(self.settings, self.prior, str(self.root / SETTINGS))

    def localizer(self, building, floor=None, seed: int = 0, **kw) -> BundleLocalizer:
        """The push API on ``building`` (see :class:`BundleLocalizer`)."""
        return BundleLocalizer(self, building, floor=floor, seed=seed, **kw)

    def run_session(self, session, seed: int = 0, on_estimate: Callable[[TrackPoint], None] | None = None,
                    on_event: Callable[[int], None] | None = None,
                    on_total: Callable[[int], None] | None = None) -> list[TrackPoint]:
        """Replay a recorded session through :meth:`localizer` (its own fixes, fixes.csv is not read); calls
        ``on_total(n)`` once with the number of samples to replay, ``on_estimate`` with each estimate as it is made
        and ``on_event(n)`` after every n samples (progress)."""
        from blenav.filters.online import replay

        self.check_session(session)
        firsts = [float(f["t"].iloc[0]) for f in (session.imu, session.rssi, session.odometry) if len(f)]
        # the batch filter's start: the first IMU, RSSI or odometry sample (even when the motion model reads no IMU)
        loc = self.localizer(session.building, floor=session.meta.get("floor"), seed=seed,
                             t_start=min(firsts) if firsts else None, keep_fixes=None)
        need_imu = loc.method.needs_imu
        out: list[TrackPoint] = []
        t_end = None
        events = [e for e in replay(session) if e[0] != "fix" and (need_imu or e[0] not in ("imu", "mag"))]
        every = max(1, len(events) // 200)
        if on_total is not None:
            on_total(len(events))
        for i, ev in enumerate(events):
            rows = loc.push_event(ev)
            if ev[0] != "mag":
                t_end = ev[1]
            for r in rows:
                out.append(r)
                if on_estimate is not None:
                    on_estimate(r)
            if on_event is not None and (i + 1) % every == 0:
                on_event(every)
        if on_event is not None:
            on_event(len(events) % every)
        if t_end is None:
            raise ValueError(f"session {session.id} has no IMU, RSSI or odometry sample")
        for r in loc.close(float(t_end)):
            out.append(r)
            if on_estimate is not None:
                on_estimate(r)
        self.last_fixes = list(loc.fixes)
        return out


#: the files every bundle has, so every manifest lists them
REQUIRED_FILES = (SETTINGS, BUILDING, LOCALIZER + ".onnx")


def verify_files(root: Path, manifest: dict) -> None:
    """The folder holds exactly the files the manifest lists (besides the manifest itself), each with its recorded
    size and sha256. Refused with a one-line ValueError naming the bundle and what differs: a manifest without a
    ``files`` table (or an empty one, or one that lacks settings.json, building.json or localizer.onnx), an entry
    that is not a plain relative path inside the folder, a missing or changed file, a file the manifest does not
    list (a bundle is verified whole: nothing unlisted is read beside the checked files)."""
    files = manifest.get("files")
    if not isinstance(files, dict) or not files:
        what = "empty" if files == {} else "missing" if files is None else f"a {type(files).__name__}, not a table"
        raise ValueError(f"bundle {root}: {MANIFEST} lists no files ('files' is {what}); a bundle that cannot be "
                         "verified is refused: export it again")
    lacking = [f for f in REQUIRED_FILES if f not in files]
    if lacking:
        raise ValueError(f"bundle {root}: {MANIFEST} does not list {', '.join(lacking)}; export it again")
    bad = []
    for rel, info in files.items():
        if not isinstance(rel, str) or rel.startswith("/") or "\\" in rel or any(
                part in ("", ".", "..") for part in rel.split("/")):
            bad.append(f"{str(rel)[:80]!r} is not a path inside the bundle")
            continue
        p = root / rel
        want = info.get("sha256") if isinstance(info, dict) else None
        size = info.get("bytes") if isinstance(info, dict) else None
        if not p.is_file():
            bad.append(f"{rel} missing")
        elif isinstance(size, int) and p.stat().st_size != size:
            bad.append(f"{rel} changed ({p.stat().st_size} bytes, manifest {size})")
        elif (got := sha256_file(p)) != want:
            bad.append(f"{rel} changed (sha256 {got[:12]}..., manifest {str(want)[:12]}...)")
    extra = sorted(q.relative_to(root).as_posix() for q in root.rglob("*")
                   if not q.is_dir() and q.relative_to(root).as_posix() not in files and q != root / MANIFEST)
    if extra:
        shown = ", ".join(extra[:5]) + (f" and {len(extra) - 5} more" if len(extra) > 5 else "")
        bad.append(f"{len(extra)} file(s) the manifest does not list: {shown}")
    if bad:
        raise ValueError(f"bundle {root} is not the one exported: {'; '.join(bad)}; export it again")


# --- writing (the export side; onnxruntime's tools, no torch) -----------------------------------------------

def _graph_paths(root: Path, has_prior: bool) -> list[str]:
    names = [LOCALIZER] + ([f"{MAP_DIR}/{g}" for g in MAP_GRAPHS] if has_prior else [])
    return names


def make_variants(root: Path, base: str) -> dict:
    """BASE.onnx -> BASE.ort, BASE.int8.onnx (onnxruntime.quantization.quantize_dynamic, int8 weights) and
    BASE.int8.ort (onnxruntime.tools.convert_onnx_models_to_ort); returns {variant: reason} for those that failed."""
    import logging

    logging.disable(logging.WARNING)  # the tools log progress lines and a pre-processing hint (restored below)
    try:
        return _make_variants(root, base)
    finally:
        logging.disable(logging.NOTSET)


def _make_variants(root: Path, base: str) -> dict:
    import contextlib
    import io
    import tempfile

    from onnxruntime.quantization import QuantType, quantize_dynamic
    from onnxruntime.tools.convert_onnx_models_to_ort import OptimizationStyle, convert_onnx_models_to_ort

    failed = {}
    try:
        with contextlib.redirect_stdout(io.StringIO()):
            quantize_dynamic(str(root / variant_name(base, "float")), str(root / variant_name(base, "int8")),
                             weight_type=QuantType.QInt8)
    except Exception as exc:  # an op the quantiser cannot handle: keep the float model, say why
        failed["int8"] = " ".join(str(exc).split())[:200]
    for v, f in (("ort", "float"), ("int8_ort", "int8")):
        if f in failed:
            failed[v] = f"no {f} model"
            continue
        with tempfile.TemporaryDirectory() as tmp:
            tin = Path(tmp) / "in"
            tin.mkdir()
            shutil.copy(root / variant_name(base, f), tin / "m.onnx")
            try:
                with contextlib.redirect_stdout(io.StringIO()):
                    convert_onnx_models_to_ort(tin / "m.onnx", output_dir=Path(tmp) / "out",
                                               optimization_styles=[OptimizationStyle.Fixed])
                shutil.move(str(Path(tmp) / "out" / "m.ort"), str(root / variant_name(base, v)))
            except Exception as exc:
                failed[v] = " ".join(str(exc).split())[:200]
    return failed


def _latency_ms(sess, feeds: dict, reps: int) -> dict:
    sess.run(None, feeds)
    ts = []
    for _ in range(reps):
        t0 = time.perf_counter()
        sess.run(None, feeds)
        ts.append((time.perf_counter() - t0) * 1e3)
    return {"median": float(np.median(ts)), "p90": float(np.percentile(ts, 90)), "reps": reps}


def _feeds(base: str, sess, meta_prior: dict | None, mask: np.ndarray | None, seed: int = 0) -> dict:
    rng = np.random.default_rng(seed)
    ins = sess.get_inputs()
    if base == LOCALIZER:
        B, H = int(ins[0].shape[1]), int(ins[0].shape[2])
        L, Hd = int(ins[1].shape[0]), int(ins[1].shape[2])
        S = (rng.uniform(0, 70, (1, B, H)) * (rng.uniform(size=(1, B, H)) < 0.7)).astype(np.float32)
        z = np.zeros((L, 1, Hd), np.float32)
        return {"S": S, "h0": z, "c0": z}
    if base.endswith(MAP_GRAPHS[0]):
        m = mask if mask is not None else np.ones((64, 64), np.float32)
        return {"mask": pad_to_multiple(m.astype(np.float32), int(meta_prior["size_multiple"]))[None, None]}
    n = int(meta_prior["window"]["n_points"])
    steps = rng.normal(0, 0.7, (36, n, 2)).cumsum(axis=1)
    return {"odometry": (steps - steps[:, :1]).astype(np.float32)}


def measure_variants(root: Path, has_prior: bool, dataset_sessions: list | None = None, reps: int = 200,
                     seed: int = 0) -> dict:
    """Per graph and variant: file size, latency of one call on one thread (the localizer: one window; the trajectory
    encoder: 36 heading windows; the map encoder: the floor, once per building) and the largest output difference
    from the float graph on the same inputs; per variant, with ``dataset_sessions`` (labelled sessions of the
    bundle's building), the whole pipeline's RMSE against ground truth and its change from the float bundle."""
    meta_prior = json.loads((root / MAP_DIR / "meta.json").read_text()) if has_prior else None
    mask = None
    if dataset_sessions:
        fl = dataset_sessions[0].floor
        if has_prior:
            from blenav.features.mapgrid import net_grid

            mask = net_grid(fl, float(meta_prior["resolution_m"]))[1].astype(np.float32)
    out: dict = {"graphs": {}, "pipeline": {}}
    for base in _graph_paths(root, has_prior):
        ref_out = None
        per = {}
        for v in VARIANTS:
            p = root / variant_name(base, v)
            if not p.is_file():
                continue
            sess = session(p, 1)
            feeds = _feeds(base, sess, meta_prior, mask, seed)
            res = sess.run(None, feeds)
            r = {"file": p.name, "bytes": p.stat().st_size,
                 "latency_ms": _latency_ms(sess, feeds, 3 if base.endswith(MAP_GRAPHS[0]) else reps)}
            if ref_out is None:
                ref_out = res
            else:
                r["max_abs_diff_vs_float"] = float(max(np.max(np.abs(a - b)) for a, b in zip(res[:1], ref_out[:1])))
            per[v] = r
        fl = per.get("float", {})
        for v, r in per.items():
            if v != "float" and fl:
                r["size_vs_float"] = r["bytes"] / fl["bytes"]
                r["latency_vs_float"] = r["latency_ms"]["median"] / fl["latency_ms"]["median"]
        out["graphs"][base] = per
    if dataset_sessions:
        for v in VARIANTS:
            try:
                b = Bundle.open(root, variant=v, verify=False)
            except ValueError:
                continue
            errs, ferrs, steps = [], [], 0
            t0 = time.perf_counter()
            for s in dataset_sessions:
                est = b.run_session(s, seed=seed)
                t = np.array([e.t for e in est])
                xy = np.array([[e.x, e.y] for e in est])
                gt = s.groundtruth
                ok = (t >= gt["t"].iloc[0]) & (t <= gt["t"].iloc[-1])
                errs.append(np.hypot(*(xy[ok] - s.positions_at(t[ok])).T))
                fx = np.array(b.last_fixes)
                if len(fx):
                    okf = (fx[:, 0] >= gt["t"].iloc[0]) & (fx[:, 0] <= gt["t"].iloc[-1])
                    ferrs.append(np.hypot(*(fx[okf, 1:] - s.positions_at(fx[okf, 0])).T))
                steps += len(est)
            e = np.concatenate(errs)
            fe = np.concatenate(ferrs) if ferrs else np.zeros(0)
            out["pipeline"][v] = {"rmse_m": float(np.sqrt(np.mean(e ** 2))), "mean_m": float(e.mean()),
                                  "fix_rmse_m": float(np.sqrt(np.mean(fe ** 2))) if len(fe) else None,
                                  "steps": int(steps), "wall_s": time.perf_counter() - t0}
        ref = out["pipeline"].get("float")
        for v, r in out["pipeline"].items():
            if ref and v != "float":
                r["rmse_change_m"] = r["rmse_m"] - ref["rmse_m"]
        out["pipeline_sessions"] = [s.id for s in dataset_sessions]
    return out


def _versions() -> dict:
    import onnxruntime

    try:
        import onnx

        onnx_v = onnx.__version__
    except ImportError:
        onnx_v = None
    return {"blenav": blenav_version(), "onnxruntime": onnxruntime.__version__, "onnx": onnx_v,
            "numpy": np.__version__, "python": platform.python_version()}


def finish_bundle(root: str | Path, building, settings: dict | None = None, variants: bool = True,
                  sessions: Iterable | None = None, extra: dict | None = None, reps: int = 200) -> Path:
    """Complete a bundle folder that holds ``localizer.onnx`` (and ``map_prior/`` when it has a prior): the
    building's signature (``building``: a :class:`blenav.data.Building` or a signature dict), the settings (default
    :data:`DEFAULT_SETTINGS`), the ORT and int8 variants (``variants``), their measurements (on ``sessions``,
    labelled sessions of the building, when given) and the manifest. Returns the folder."""
    root = Path(root)
    has_prior = (root / MAP_DIR / "meta.json").is_file()
    if not (root / variant_name(LOCALIZER, "float")).is_file():
        raise FileNotFoundError(f"{root} has no {variant_name(LOCALIZER, 'float')}")
    sig = building if isinstance(building, dict) else building_signature(building)
    settings = json.loads(json.dumps(settings if settings is not None else DEFAULT_SETTINGS))
    (root / SETTINGS).write_text(json.dumps(settings, indent=2, sort_keys=True) + "\n", encoding="utf-8")
    (root / BUILDING).write_text(json.dumps(sig, indent=2, sort_keys=True) + "\n", encoding="utf-8")
    failed: dict = {}
    available = list(VARIANTS[:1])
    if variants:
        for base in _graph_paths(root, has_prior):
            for v, why in make_variants(root, base).items():
                failed[f"{base}:{v}"] = why
        available = [v for v in VARIANTS if not any(k.endswith(f":{v}") for k in failed)]
    files = {}
    for p in sorted(root.rglob("*")):
        if p.is_file() and p.name != MANIFEST and not p.name.startswith("dmt_"):
            files[p.relative_to(root).as_posix()] = {"sha256": sha256_file(p), "bytes": p.stat().st_size}
    manifest = {"format": FORMAT, "created_utc": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()),
                "versions": _versions(), "building": {k: sig[k] for k in ("building", "plan_sha256")},
                "beacons": sig["beacons"], "has_map_prior": has_prior, "variants_available": available,
                "variants_failed": failed, "files": files, **(extra or {})}
    (root / MANIFEST).write_text(json.dumps(manifest, indent=2, sort_keys=True) + "\n", encoding="utf-8")
    if variants:
        sessions = list(sessions or [])
        manifest["measured"] = measure_variants(root, has_prior, sessions, reps=reps)
        manifest["measured"]["note"] = ("latency: one call on one intra-op thread of this machine (the localizer: one "
                                        "window; the trajectory encoder: 36 heading windows; the map encoder: once per "
                                        "floor); pipeline: the whole bundle on pipeline_sessions, seed 0")
        (root / MANIFEST).write_text(json.dumps(manifest, indent=2, sort_keys=True) + "\n", encoding="utf-8")
    return root
