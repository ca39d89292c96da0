"""The ILC 2.0 import: one pass over the source writing a session per walk, then one building per site
(floor plans, alignment, BLE anchors) and dataset.yaml; written into a temporary folder renamed in at the end."""

from __future__ import annotations

import os
import shutil
from collections import Counter, defaultdict
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd

from blenav.data.writer import write_building, write_dataset_meta
from blenav.errors import ImportError_

from .. import ImportReport
from .._common import check_out, rssi_in_range, validate_or_raise
from .align import FloorAcc, floor_alignment, floor_frame
from .archive import classify, iter_source
from .plan import RESOLUTION_M, floor_level, read_plan
from .walks import convert_walk
from .write import PHONE_HEIGHT_M, write_groundtruth, write_streams

FLOOR_HEIGHT_M = 5.0


def _floor_list(floors) -> list[tuple[str, str]] | None:
    if floors is None:
        return None
    items = floors.split(",") if isinstance(floors, str) else list(floors)
    out = []
    for it in items:
        it = str(it).strip().strip("/")
        if not it:
            continue
        site, sep, fl = it.partition("/")
        if not sep or not site or not fl or "/" in fl:
            raise ImportError_("--floors", None, f"{it!r} is not SITE/FLOOR (e.g. site1/F1)")
        out.append((site, fl))
    return out


def import_ilc20(src: Path, out: Path, floors=None, beacon_id: str = "mac") -> ImportReport:
    """Convert the ILC 2.0 / challenge recordings at ``src`` (folder or archive) into dataset ``out``.

    ``floors``: ``"site1/F1,site1/F2"`` or a list of such names (default: every floor found). ``beacon_id``:
    ``"mac"`` (``UUID:major:minor:MAC``, default) or ``"triple"`` (``UUID:major:minor``). See the package doc,
    :mod:`blenav.importers.ilc20`.
    """
    src, out = Path(src), Path(out)
    if beacon_id not in ("mac", "triple"):
        raise ValueError(f"beacon_id must be 'mac' or 'triple', got {beacon_id!r}")
    if not src.exists():
        raise ImportError_(src, None, "source does not exist")
    check_out(out)
    selected = _floor_list(floors)
    sel = set(selected) if selected is not None else None
    seen_floors: set[tuple[str, str]] = set()

    def want(vpath: str) -> bool:
        c = classify(vpath)
        if c is None:
            return False
        seen_floors.add(c[1])
        return sel is None or c[1] in sel

    tmp = out.parent / f".{out.name}.partial-{os.getpid()}"
    if tmp.exists():
        shutil.rmtree(tmp)
    report = ImportReport(out=out)
    try:
        _import(src, tmp, want, sel, seen_floors, beacon_id, report)
        if out.exists():
            out.rmdir()  # empty (check_out refused a dataset); a non-empty folder raises OSError
        os.replace(tmp, out)
    except OSError as exc:
        shutil.rmtree(tmp, ignore_errors=True)
        raise ImportError_(out, None, f"cannot write the dataset here ({exc})") from None
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    report.out = out
    validate_or_raise(out, report)
    return report


def _import(src: Path, tmp: Path, want, sel, seen_floors, beacon_id: str, report: ImportReport) -> None:
    """Write the selected walks, one building per site and dataset.yaml into ``tmp``."""
    got = _import_walks(src, tmp, want, beacon_id, report)
    if sel is not None:
        missing = sorted(sel - set(got.acc))
        if missing:
            found = ", ".join(f"{s}/{f}" for s, f in sorted(seen_floors)) or "none"
            raise ImportError_(src, None, f"--floors names {', '.join(f'{s}/{f}' for s, f in missing)}, not found "
                               f"with walks in the source (floors found: {found})")
    if not got.acc:
        raise ImportError_(src, None, "no path files found: expected <site>/<floor>/path_data_files/*.txt or "
                           "train/<site>/<floor>/*.txt (in a folder, .tar.gz or .zip)")

    by_site: dict[str, list[str]] = defaultdict(list)
    for site, floor in sorted(got.acc):
        by_site[site].append(floor)
    for site, floor_names in by_site.items():
        _write_site(src, tmp, site, floor_names, got, report)
    report.notes.append(f"{got.labelled} of {report.sessions} sessions labelled (>= 2 waypoints)")
    report.notes += [f"{n} {what}" for what, n in sorted(got.events.items())]
    write_dataset_meta(
        tmp, "ilc20", "Indoor Location Competition 2.0 walks: IMU, magnetometer, rotation vector, WiFi and iBeacon "
        "RSSI, surveyed waypoints, floor plans (beacon and AP positions not given)", "MIT",
        "XYZ10, Inc., location-competition/indoor-location-competition-20 (data/); same format as the 2021 Indoor "
        "Location & Navigation challenge", importer="blenav.importers.ilc20", source_path=str(src),
        beacon_id="UUID:major:minor:MAC" if beacon_id == "mac" else "UUID:major:minor")


@dataclass
class _WalkPass:
    """What the pass over the source's walks gathered for the buildings."""

    meta_files: dict            # ((site, floor), "floor_info" | "geojson_map") -> (display name, bytes)
    acc: dict                   # (site, floor) -> FloorAcc, floors with at least one written session
    beacons: dict               # anchor id -> what was heard (see walks._beacon_stream)
    bssids: dict                # site -> set of BSSIDs heard
    pending_gt: dict            # (site, floor) -> [(session id, groundtruth columns)], written by _write_site
    events: Counter             # walk-level events -> count
    labelled: int               # sessions with >= 2 waypoints


def _import_walks(src: Path, tmp: Path, want, beacon_id: str, report: ImportReport) -> _WalkPass:
    """One pass over the source: every selected walk converted and written as a session into ``tmp``, the
    floors' metadata files kept for the buildings."""
    meta_files: dict[tuple[tuple[str, str], str], tuple[str, bytes]] = {}
    acc: dict[tuple[str, str], FloorAcc] = defaultdict(FloorAcc)
    beacons: dict[str, dict] = {}
    bssids: dict[str, set] = defaultdict(set)
    sessions: set[str] = set()
    pending_gt: dict[tuple[str, str], list] = defaultdict(list)
    events: Counter = Counter()
    labelled = 0
    for e in iter_source(src, want, report):
        kind, key, name = classify(e.vpath)
        if kind == "meta":
            meta_files[(key, name)] = (e.display, e.data)
            continue
        site, floor = key
        sid, meta, streams, wp_xy, header = convert_walk(e.display, e.data, site, floor, name, beacon_id, report,
                                                         events, beacons, bssids[site])
        if sid in sessions:
            raise ImportError_(e.display, None, f"a second walk with session id {sid!r} (the same path file twice?)")
        if not streams:
            events["walks without any data row (no session written)"] += 1
            continue
        sessions.add(sid)
        if "groundtruth" in streams:  # written once the floor's z is known (the GeoJSON may come later)
            pending_gt[key].append((sid, streams.pop("groundtruth")))
        write_streams(tmp, sid, meta, streams)
        report.sessions += 1
        labelled += bool(meta["labelled"])
        a = acc[key]
        a.walks += 1
        if len(wp_xy):
            a.waypoints.append(wp_xy)
        a.site_name = a.site_name or header.get("SiteName", "")
        a.site_id = a.site_id or header.get("SiteID", "")
        a.floor_id = a.floor_id or header.get("FloorId", "")
    return _WalkPass(meta_files, acc, beacons, bssids, pending_gt, events, labelled)


def _write_site(src: Path, tmp: Path, site: str, floor_names: list[str], w: _WalkPass, report: ImportReport) -> None:
    """building.yaml, floor images, rooms and anchors of one site into ``tmp``: its floors' plans (in the
    upstream floor frames; ``floor_frames`` relates them to the first floor's), the waypoints' alignment with
    each plan, and its BLE anchors (positions unknown)."""
    floors, rooms, frames, alignment = [], [], {}, {}
    ref = None
    for floor in floor_names:
        key = (site, floor)
        info = w.meta_files.get((key, "floor_info"))
        geo = w.meta_files.get((key, "geojson_map"))
        if info is None or geo is None:
            lack = " and ".join(n for n, v in (("floor_info.json", info), ("geojson_map.json", geo)) if v is None)
            raise ImportError_(src, None, f"floor {site}/{floor} has walks but no {lack} (repository layout: "
                               f"beside path_data_files/; challenge layout: metadata/{site}/{floor}/)")
        plan = read_plan(*info, *geo, floor, report)
        level = floor_level(floor, plan.floor_num)
        z = level * FLOOR_HEIGHT_M
        write_groundtruth(tmp, w.pending_gt.get(key, []), z)
        floors.append({"id": floor, "occupancy": plan.occupancy, "resolution": RESOLUTION_M, "origin": (0.0, 0.0),
                       "z": z, "filename": f"floor_{floor}.png"})
        rooms += [{"id": uid, "floor": floor, "geometry": g, "properties": {"name": nm}}
                  for uid, nm, g in plan.units]
        if ref is None:
            ref = plan
        frames[floor] = floor_frame(plan, ref)
        alignment[floor] = floor_alignment(plan, w.acc[key], f"{site}/{floor}", report)
    rows = _site_anchor_rows(w.beacons, floor_names)
    anchors = pd.DataFrame(rows) if rows else None
    a0 = w.acc[(site, floor_names[0])]
    write_building(tmp, site, a0.site_name or site, floors, anchors, rooms=rooms,
                   site_id=a0.site_id, floor_frames=frames, alignment=alignment,
                   floor_plan=(f"rasterised from geojson_map.json at {RESOLUTION_M} m/px: walkable = inside the "
                               "floor outline and outside every unit polygon; each floor in its upstream frame "
                               "(outline bounding box -> [0, width] x [0, height] m)"),
                   assumptions=[f"floor z = level x {FLOOR_HEIGHT_M} m", f"phone height {PHONE_HEIGHT_M} m",
                                "anchor positions unknown"])
    report.buildings += 1
    report.notes.append(f"site {site}: {len(rows)} BLE anchors (position unknown), {len(w.bssids[site])} WiFi "
                        "access points (BSSIDs) heard")


def _site_anchor_rows(beacons: dict, floor_names: list[str]) -> list[dict]:
    """anchors.csv rows of the iBeacons heard on the site's floors, by anchor id: position unknown (NaN),
    floor = where heard most, tx power = the median advertised (NaN when outside (-150, 0) dBm)."""
    site_b = {k: v for k, v in beacons.items() if any(f in floor_names for f in v["floors"])}
    rows = []
    for aid, b in sorted(site_b.items()):
        tx = np.asarray(b["tx"], dtype=float)
        med = float(np.median(tx)) if len(tx) else float("nan")
        fl = b["floors"].most_common(1)[0][0]
        rows.append({"anchor_id": aid, "kind": "ble", "x": np.nan, "y": np.nan, "z": np.nan, "floor": fl,
                     "tx_power_dbm": med if rssi_in_range(np.array([med]))[0] else np.nan,
                     "channel_model": "iBeacon; position unknown (not in the ILC data)",
                     "uuid": b["uuid"], "major": b["major"], "minor": b["minor"], "mac": b["mac"],
                     "n_rows": int(sum(b["floors"].values())),
                     "floors_heard": ";".join(sorted(b["floors"]))})
    return rows
