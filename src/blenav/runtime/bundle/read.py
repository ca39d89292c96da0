"""An opened bundle folder (:meth:`Bundle.open`): verified, its settings checked, its graphs loaded; the entry to the
push API (:meth:`Bundle.localizer`) and to replaying a recorded session (:meth:`Bundle.run_session`).

A bundle refuses a building (or a session's building) whose BLE beacons or floor plans are not its own
(:mod:`blenav.runtime.signature`), a folder whose files are not exactly the ones its manifest records
(:func:`blenav.runtime.bundle.verify.verify_files`), and settings that name a class other than blenav's or set a size
out of range (:mod:`blenav.runtime.bundle.settings`), all before anything is built.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

from blenav.limits import read_json
from blenav.onnx_io import check_weights, read_metadata, session

from ..signature import BuildingMismatch, check_building
from .format import BUILDING, FORMAT, INERTIAL_DIR, LOCALIZER, MANIFEST, MAP_DIR, MAP_GRAPHS, SETTINGS, variant_name
from .graphs import LocalizerGraph, MapBackend
from .live import BundleLocalizer, TrackPoint
from .settings import build_method, check_settings, check_targets_of
from .verify import verify_files


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
    inertial: object | None = None  # the learned inertial odometry (blenav.runtime.inertial.InertialModel) or None
    #: what the last :meth:`run_session` made: its fixes (t, x, y) and which odometry it read
    last_fixes: list = field(default_factory=list)
    last_odometry: str = "none"

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
            from ..map_prior import MapPrior

            digest = manifest["files"].get(f"{MAP_DIR}/{variant_name(MAP_GRAPHS[0], variant)}", {}).get("sha256", "")
            backend = MapBackend(root / MAP_DIR, variant, threads, digest)
            prior = MapPrior(root / MAP_DIR / variant_name(MAP_GRAPHS[0], variant), loader=lambda _p: backend)
        inertial = None
        if (root / INERTIAL_DIR).exists():  # its own files and hashes checked too: InertialModel names what is missing
            from ..inertial import InertialModel

            inertial = InertialModel(root / INERTIAL_DIR, threads=threads)
        return cls(root, manifest, settings, signature, variant, graph, prior, inertial)

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
        and ``on_event(n)`` after every n samples (progress). A bundle with a learned inertial odometry
        (``inertial/``) runs it on the session's IMU and replays its track as the odometry (odometry.csv is not
        read); :attr:`last_odometry` says which was used."""
        from blenav.filters.online import replay

        self.check_session(session)
        method = self.method()  # the localizer below runs this one
        uses_odo = method.needs_odometry
        odometry = self.inertial.odometry(session) if self.inertial is not None and uses_odo else None
        self.last_odometry = (f"learned inertial odometry ({INERTIAL_DIR}/, {len(odometry)} points)"
                              if odometry is not None else "the session's odometry.csv" if uses_odo else "none")
        odo = session.odometry if odometry is None else odometry
        firsts = [float(f["t"].iloc[0]) for f in (session.imu, session.rssi, odo) if len(f)]
        # the batch filter's start: the first IMU, RSSI or odometry sample (even when the motion model reads no IMU)
        loc = self.localizer(session.building, floor=session.meta.get("floor"), seed=seed,
                             t_start=min(firsts) if firsts else None, keep_fixes=None, method=method)
        need_imu = loc.method.needs_imu
        out: list[TrackPoint] = []
        t_end = None
        events = [e for e in replay(session, odometry) if e[0] != "fix" and (need_imu or e[0] not in ("imu", "mag"))]
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
