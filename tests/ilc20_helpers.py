"""Synthetic ILC 2.0 path files (a floor folder and its walks), independent of ../shared: the importer tests
(tests/importers/) and the fingerprint tests' position-coded walks (tests/localizers/test_fingerprint.py,
tests/learn/test_fingerprint.py; the ``coded`` fixture of conftest.py)."""

from __future__ import annotations

import json
from pathlib import Path

LON0, LAT0 = 120.0, 30.0
W_M, H_M = 40.0, 20.0
DLON, DLAT = 0.0004, 0.0002  # the outline's box in degrees (mapped onto W_M x H_M metres)
UUID = "9195B3AD-A9D0-4500-85FF-9FB0F65A5201"


def _ll(x, y):
    return [LON0 + x / W_M * DLON, LAT0 + y / H_M * DLAT]


def write_floor(root: Path, site="mall", floor="F1") -> Path:
    """A floor folder: a 40 x 20 m outline and one 10 x 5 m shop at (25..35, 12..17) m."""
    d = root / site / floor
    (d / "path_data_files").mkdir(parents=True)
    (d / "floor_info.json").write_text(json.dumps({"map_info": {"width": W_M, "height": H_M}}))
    outline = [[_ll(0, 0), _ll(W_M, 0), _ll(W_M, H_M), _ll(0, H_M), _ll(0, 0)]]
    shop = [[_ll(25, 12), _ll(35, 12), _ll(35, 17), _ll(25, 17), _ll(25, 12)]]
    feats = [{"type": "Feature", "properties": {"type": "floor", "name": floor, "floor_num": 1},
              "geometry": {"type": "MultiPolygon", "coordinates": [outline]}},
             {"type": "Feature", "properties": {"id": "shop1", "name": "Coffee"},
              "geometry": {"type": "Polygon", "coordinates": shop}}]
    (d / "geojson_map.json").write_text(json.dumps({"type": "FeatureCollection", "features": feats}))
    return d


def walk_lines(start=1_600_000_000_000, seconds=6.0, waypoints=((5.0, 5.0), (15.0, 6.0), (20.0, 8.0)),
               gyro_shift_ms=0, sensor_offset_ms=0, extra=()) -> list[str]:
    """Lines of a path file: 50 Hz sensors, a WiFi scan and beacon rows every second, waypoints spread out."""
    L = [f"#\tstartTime:{start}", "#\tSiteID:s1\tSiteName:Mall\tFloorId:f1\tFloorName:F1",
         "#\tBrand:ACME\tModel:X1\tAndroidName:9\tAPILevel:28\t"]
    rows = []
    n = int(seconds * 50)
    for k in range(n):
        t = start + 100 + 20 * k + sensor_offset_ms
        rows.append((t, f"{t}\tTYPE_ACCELEROMETER\t0.1\t0.2\t9.8\t3"))
        rows.append((t + gyro_shift_ms, f"{t + gyro_shift_ms}\tTYPE_GYROSCOPE\t0.01\t-0.02\t{0.001 * k:.3f}\t3"))
        rows.append((t, f"{t}\tTYPE_MAGNETIC_FIELD\t20.0\t-5.0\t-40.0\t3"))
        rows.append((t, f"{t}\tTYPE_ROTATION_VECTOR\t0.0\t0.0\t0.6\t3"))
        rows.append((t, f"{t}\tTYPE_ACCELEROMETER_UNCALIBRATED\t0.1\t0.2\t9.8\t0.0\t0.0\t0.0\t3"))
    for s in range(int(seconds)):
        t = start + 1000 * s + 500
        rows.append((t, f"{t}\tTYPE_WIFI\tshop,wifi\tAA:BB:CC:00:00:01\t-60\t2412\t{t - 300}"))
        rows.append((t, f"{t}\tTYPE_WIFI\t\taa:bb:cc:00:00:02\t-75\t5180\t{t - 2000}"))
        rows.append((t, f"{t}\tTYPE_BEACON\t{UUID}\t0\t0\t-56\t-80\t12.0\tE0:78:A3:00:00:01\t{t}"))
        rows.append((t + 5, f"{t + 5}\tTYPE_BEACON\t{UUID}\t0\t0\t-56\t-85\t15.0\tE0:78:A3:00:00:02\t{t + 5}"))
    for i, (x, y) in enumerate(waypoints):
        t = start + 10 + int(i * 1000 * (seconds - 1) / max(len(waypoints) - 1, 1))
        rows.append((t, f"{t}\tTYPE_WAYPOINT\t{x}\t{y}"))
    rows += list(extra)
    rows.sort(key=lambda r: r[0])
    end = max(r[0] for r in rows) + 20
    return L + [r[1] for r in rows] + [f"#\tendTime:{end}"]


def write_walk(floor_dir: Path, name: str, lines: list[str], newline_at_end: bool = True) -> Path:
    p = floor_dir / "path_data_files" / f"{name}.txt"
    p.write_text("\n".join(lines) + ("\n" if newline_at_end else ""), encoding="utf-8")
    return p


START = 1_600_000_000_000


def coded_walk(start: int, y: float, ap_prefix: str = "aa:00") -> list[str]:
    """A 6 s walk along x at 4 m/s from (5, y) (waypoints at 0.01, 2.51, 5.01 s: 5, 15, 25 m); at the scan of
    second s (t = s + 0.5) access point ``<prefix>:0c``, c = min(s, 4), is heard at -50 dBm besides the importer
    test's two (the last scan, after the last waypoint, repeats the code of the one before)."""
    extra = []
    for s in range(6):
        t = start + 1000 * s + 500
        extra.append((t, f"{t}\tTYPE_WIFI\tcoded\t{ap_prefix}:00:00:0{min(s, 4)}\t-50\t2412\t{t - 100}"))
    return walk_lines(start=start, waypoints=((5.0, y), (15.0, y), (25.0, y)), extra=extra)


def write_coded(root: Path):
    """walkA at y = 5 m, walkB at y = 7 m (both trained on), walkC at y = 5 m (tested), imported into
    ``root/ds``; the opened :class:`blenav.data.Dataset`."""
    from blenav.data import Dataset
    from blenav.importers import run_import

    d = write_floor(root / "raw")
    for name, y, k in (("walkA", 5.0, 0), ("walkB", 7.0, 1), ("walkC", 5.0, 2)):
        write_walk(d, name, coded_walk(START + k * 100_000, y))
    run_import("ilc20", d, root / "ds")
    return Dataset.open(root / "ds")
