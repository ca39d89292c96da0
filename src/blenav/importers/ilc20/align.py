"""How the walks of an ILC 2.0 floor sit on its plan, and how the floors of a site relate (building.yaml
``alignment`` and ``floor_frames``)."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import shapely

from blenav.data import FREE, OCCUPIED

from .. import ImportReport
from .._common import grid_lookup
from .plan import RESOLUTION_M, Plan


@dataclass
class FloorAcc:
    """What the sessions of one floor contribute to its building."""

    waypoints: list = field(default_factory=list)           # (n, 2) arrays
    walks: int = 0
    site_name: str = ""
    site_id: str = ""
    floor_id: str = ""


def floor_frame(plan: Plan, ref: Plan) -> dict:
    """building.yaml ``floor_frames`` entry of a floor: its outline's lon/lat bounding box, size (m), the shift
    (m) of its origin in the frame of the site's first floor ``ref``, and floor_info / geodesic size ratios."""
    lon0, lat0, lon1, lat1 = plan.lonlat_box
    r0 = ref.lonlat_box
    shift = ((lon0 - r0[0]) / (r0[2] - r0[0]) * ref.width, (lat0 - r0[1]) / (r0[3] - r0[1]) * ref.height)
    return {"lonlat_bbox": [lon0, lat0, lon1, lat1], "size_m": [plan.width, plan.height],
            "origin_shift_m": [round(shift[0], 3), round(shift[1], 3)],
            "scale_vs_geodesic": [round(plan.scale_ratio[0], 4), round(plan.scale_ratio[1], 4)]}


def floor_alignment(plan: Plan, fa: FloorAcc, name: str, report: ImportReport) -> dict:
    """building.yaml ``alignment`` entry of floor ``name`` (SITE/FLOOR): how its walks' waypoints (m) sit on the
    plan (shares inside the outline, on walkable cells, inside a unit; walks mostly off walkable cells), also
    written as a report note."""
    wps = np.vstack(fa.waypoints) if fa.waypoints else np.empty((0, 2))
    n = len(wps)
    in_outline = float(shapely.contains_xy(plan.outline, wps[:, 0], wps[:, 1]).mean()) if n else float("nan")
    on_free = float((grid_lookup(plan.occupancy, (0.0, 0.0), wps, RESOLUTION_M, OCCUPIED) == FREE).mean()) \
        if n else float("nan")
    if n and plan.units:
        u = shapely.union_all([g for _, _, g in plan.units])
        in_unit = float(shapely.contains_xy(u, wps[:, 0], wps[:, 1]).mean())
    else:
        in_unit = float("nan") if not n else 0.0
    # walks whose waypoints lie mostly off walkable cells (inside shops, or a misaligned plan)
    off = sum(float(np.mean(grid_lookup(plan.occupancy, (0.0, 0.0), w_, RESOLUTION_M, OCCUPIED) != FREE)) > 0.5
              for w_ in fa.waypoints)
    report.notes.append(
        f"floor {name}: {fa.walks} walks, {n} waypoints: {in_outline:.1%} inside the outline, "
        f"{on_free:.1%} on walkable cells, {in_unit:.1%} inside a unit ({off} walks with most waypoints off "
        f"walkable cells); plan {plan.width:.1f} x "
        f"{plan.height:.1f} m, floor_info / geodesic size x {plan.scale_ratio[0]:.3f}, "
        f"y {plan.scale_ratio[1]:.3f}; {len(plan.units)} units")
    return {"waypoints": n, "walks": fa.walks, "inside_outline": round(in_outline, 4),
            "on_walkable": round(on_free, 4), "inside_unit": round(in_unit, 4),
            "walks_mostly_off_walkable": int(off),
            "free_share_of_plan": round(float((plan.occupancy == FREE).mean()), 4)}
