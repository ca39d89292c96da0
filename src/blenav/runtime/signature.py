"""What a runtime bundle knows of the building it was made for, and the check that refuses another one.

A *building signature* (:func:`building_signature`) is a JSON-able dict:

- ``building``: the building id (informative: a renamed copy of the same building passes);
- ``beacons``: the BLE anchor ids, sorted (the row order of a cross-phone model, :func:`beacon_order`);
- ``beacon_xy``: {id: [x, y, floor]} world metres of each BLE anchor (a moved beacon changes what its RSSI
  means, so it counts as a difference);
- ``floors``: {floor id: sha256 hex of the floor plan} (:func:`floor_plan_hash`), ``plan_sha256``: the sha256
  of all of them (sorted by floor id);
- ``floor_facts``: {floor id: shape (H, W) px, resolution (m/px), origin (m), free and occupied pixel counts}
  (:func:`floor_facts`), so that a refusal can say *how* a plan differs, not only that its hash does (optional:
  bundles written before it have none, and their refusals name the hashes only).

:func:`compare` lists what differs between the bundle's signature and a building's (missing and extra beacon
ids, beacons moved by more than ``tol_m``, floors missing, extra or with another plan hash -- and then what changed
in it: size, resolution, origin, or which pixels are free or occupied);
:func:`check_building` raises :class:`BuildingMismatch` (a ValueError) with all of it in one message.

A floor plan's hash covers what the filter and the map prior read: the occupancy grid (FREE / OCCUPIED /
UNKNOWN codes, :meth:`blenav.data.Floor.occupancy`), its shape, resolution and origin. The PNG's bytes are not
hashed: a re-encoded image of the same plan passes. numpy only (no torch, lightning, hydra).
"""

from __future__ import annotations

import hashlib

import numpy as np

from blenav.data import FREE, OCCUPIED
from blenav.features.windows import beacon_order

TOL_M = 0.01  # a beacon moved by more than this (m) counts as a difference


class BuildingMismatch(ValueError):
    """The building (or session) is not the one a bundle was made for; the message says what differs."""


def floor_plan_hash(floor) -> str:
    """sha256 hex of a floor plan: occupancy codes (int8, row-major), shape, resolution (m/px) and origin (m)."""
    occ = np.ascontiguousarray(np.asarray(floor.occupancy, dtype=np.int8))
    h = hashlib.sha256()
    h.update(f"{occ.shape}|{float(floor.resolution):.9g}|{float(floor.origin[0]):.9g}|"
             f"{float(floor.origin[1]):.9g}|".encode())
    h.update(occ.tobytes())
    return h.hexdigest()


def floor_facts(floor) -> dict:
    """What a refusal says about a floor plan: ``shape`` [H, W] px, ``resolution`` m/px, ``origin`` [x, y] m, and the
    numbers of ``free`` and ``occupied`` pixels."""
    occ = np.asarray(floor.occupancy, dtype=np.int8)
    return {"shape": [int(v) for v in occ.shape], "resolution": float(floor.resolution),
            "origin": [float(floor.origin[0]), float(floor.origin[1])], "free": int(np.count_nonzero(occ == FREE)),
            "occupied": int(np.count_nonzero(occ == OCCUPIED))}


def plan_change(want: dict | None, have: dict | None) -> str:
    """How the building's floor plan ``have`` differs from the bundle's ``want`` (:func:`floor_facts`); empty when
    either is unknown."""
    if not want or not have:
        return ""
    out = []
    if want["shape"] != have["shape"]:
        out.append(f"{want['shape'][1]} x {want['shape'][0]} px -> {have['shape'][1]} x {have['shape'][0]} px")
    if not np.isclose(want["resolution"], have["resolution"], rtol=0, atol=1e-9):
        out.append(f"resolution {want['resolution']:g} -> {have['resolution']:g} m/px")
    if not np.allclose(want["origin"], have["origin"], rtol=0, atol=1e-6):
        out.append(f"origin ({want['origin'][0]:g}, {want['origin'][1]:g}) -> ({have['origin'][0]:g}, "
                   f"{have['origin'][1]:g}) m")
    if out:
        return "; ".join(out)
    d_occ, d_free = have["occupied"] - want["occupied"], have["free"] - want["free"]
    counts = ", ".join(f"{abs(d)} px {'more' if d > 0 else 'fewer'} {what}" for d, what in
                       ((d_occ, "occupied"), (d_free, "free")) if d) or "as many free and occupied pixels, elsewhere"
    return f"same size, resolution and origin; {counts}"


def building_signature(building) -> dict:
    """The signature (see the module docstring) of a :class:`blenav.data.Building`."""
    ids = beacon_order(building)
    a = building.anchors
    ble = a[a["kind"] == "ble"] if len(a) else a
    xy = {}
    for row in ble.itertuples(index=False):
        fl = getattr(row, "floor", None)
        xy[str(row.anchor_id)] = [round(float(row.x), 4), round(float(row.y), 4),
                                  None if fl is None or (isinstance(fl, float) and np.isnan(fl)) else str(fl)]
    floors = {str(fid): floor_plan_hash(f) for fid, f in sorted(building.floors.items(), key=lambda kv: str(kv[0]))}
    total = hashlib.sha256("|".join(f"{k}:{v}" for k, v in floors.items()).encode()).hexdigest()
    facts = {str(fid): floor_facts(f) for fid, f in sorted(building.floors.items(), key=lambda kv: str(kv[0]))}
    return {"building": str(building.id), "beacons": ids, "beacon_xy": xy, "floors": floors, "plan_sha256": total,
            "floor_facts": facts}


def _few(ids, n: int = 8) -> str:
    ids = list(ids)
    return ", ".join(ids[:n]) + (f", ... ({len(ids) - n} more)" if len(ids) > n else "")


def compare(want: dict, have: dict, tol_m: float = TOL_M) -> list[str]:
    """What differs between the bundle's signature ``want`` and a building's ``have`` (empty: they match)."""
    out = []
    wb, hb = set(want.get("beacons") or []), set(have.get("beacons") or [])
    missing, extra = sorted(wb - hb), sorted(hb - wb)
    if missing:
        out.append(f"{len(missing)} beacon(s) of the bundle missing from the building: {_few(missing)}")
    if extra:
        out.append(f"{len(extra)} beacon(s) the bundle does not know: {_few(extra)}")
    moved = []
    wxy, hxy = want.get("beacon_xy") or {}, have.get("beacon_xy") or {}
    for b in sorted(wb & hb):
        if b in wxy and b in hxy:
            d = float(np.hypot(wxy[b][0] - hxy[b][0], wxy[b][1] - hxy[b][1]))
            if d > tol_m or wxy[b][2] != hxy[b][2]:
                moved.append(f"{b} ({d:.2f} m)" if wxy[b][2] == hxy[b][2] else f"{b} (floor {wxy[b][2]} -> {hxy[b][2]})")
    if moved:
        out.append(f"{len(moved)} beacon(s) moved: {_few(moved)}")
    wf, hf = want.get("floors") or {}, have.get("floors") or {}
    if wf or hf:
        gone = sorted(set(wf) - set(hf))
        new = sorted(set(hf) - set(wf))
        changed = [f for f in sorted(set(wf) & set(hf)) if wf[f] != hf[f]]
        if gone:
            out.append(f"floor(s) {_few(gone)} of the bundle missing from the building")
        if new:
            out.append(f"floor(s) {_few(new)} the bundle does not know")
        wfacts, hfacts = want.get("floor_facts") or {}, have.get("floor_facts") or {}
        for f in changed:
            how = plan_change(wfacts.get(f), hfacts.get(f))
            out.append(f"floor {f}: another floor plan (plan hash {hf[f][:12]}..., bundle's {wf[f][:12]}...)"
                       + (f": {how}" if how else ""))
    return out


def check_building(want: dict, building, what: str = "bundle", tol_m: float = TOL_M) -> None:
    """Raise :class:`BuildingMismatch` when ``building`` is not the one of the signature ``want``."""
    have = building_signature(building)
    diff = compare(want, have, tol_m)
    if diff:
        raise BuildingMismatch(f"{what} was made for building {want.get('building')!r} ({len(want.get('beacons') or [])} "
                               f"beacons, plan hash {str(want.get('plan_sha256'))[:12]}...); building "
                               f"{have['building']!r} differs: {'; '.join(diff)}. Export a bundle for this building "
                               f"(python export.py bundle=true ckpt=RUN/last.ckpt out=BUNDLE, trained on its data)")
