"""Map-fusion spatial index: the paper's 1 m grid vs shapely's STRtree (Patel et al., Sec. VI.C).

Simulates the office_45x55 building (2 s, one session: only the building is used), then times
:meth:`blenav.filters.map.MapGeometry.condition` on 100 runs x 300 particles (Table I) with each
index, checks that both give the same result, and prints the times and their ratio. Also times the same
on the building's derived map (rooms and routes removed, derived from the occupancy grid).

    .venv/bin/python benchmarks/map_index.py [--runs 100] [--particles 300] [--repeat 20]
"""

from __future__ import annotations

import argparse
import shutil
import tempfile
import time
from pathlib import Path

import numpy as np
from blenav.configs import compose

from blenav.cli.sim import run  # registers the sim schema
from blenav.data import Building
from blenav.filters.map import INDEX_KINDS, MapGeometry


def simulate_office(out: Path) -> Path:
    cfg = compose("sim", *["sim=office_45x55", "seed=0", "duration_s=2", "sessions=1",
                                                f"out={out}", "progress=false"])
    run(cfg)
    return next((out / "buildings").iterdir())


def bench(m: MapGeometry, R: int, N: int, repeat: int, seed: int = 0) -> dict:
    rng = np.random.default_rng(seed)
    x = m.sample_initial(rng, R, N)  # a realistic cloud: copies of particles on the map
    out = {}
    for kind in INDEX_KINDS:
        t0 = time.perf_counter()
        ix = m.get_index(kind)
        build = time.perf_counter() - t0
        m.condition(x, np.random.default_rng(1), index=kind)  # warm-up (prepared geometries, caches)
        times = []
        for _ in range(repeat):
            g = np.random.default_rng(2)
            t0 = time.perf_counter()
            y = m.condition(x, g, index=kind)
            times.append(time.perf_counter() - t0)
        out[kind] = {"build_s": build, "median_s": float(np.median(times)), "min_s": float(np.min(times)),
                     "result": y, "stats": getattr(ix, "stats", {})}
    diff = np.abs(out["grid"]["result"] - out["strtree"]["result"]).max()
    return {"per_kind": out, "max_abs_diff": float(diff)}


def report(title: str, m: MapGeometry, res: dict, R: int, N: int) -> None:
    print(f"\n{title}: {m.n_rooms} rooms, {m.n_edges} edge segments; condition() on {R} runs x {N} particles")
    for kind, r in res["per_kind"].items():
        extra = ""
        if r["stats"]:
            s = r["stats"]
            extra = (f"  [{s['cells']} cells, edges/cell mean {s['edges_per_cell_mean']:.1f} max "
                     f"{s['edges_per_cell_max']}, rooms/cell mean {s['rooms_per_cell_mean']:.2f} max "
                     f"{s['rooms_per_cell_max']}]")
        print(f"  {kind:8s} build {r['build_s'] * 1e3:7.1f} ms   condition median {r['median_s'] * 1e3:7.2f} ms "
              f"(min {r['min_s'] * 1e3:.2f}){extra}")
    g, s = res["per_kind"]["grid"]["median_s"], res["per_kind"]["strtree"]["median_s"]
    faster = "grid" if g < s else "strtree"
    print(f"  strtree / grid = {s / g:.2f}  -> faster: {faster};  max |grid - strtree| = {res['max_abs_diff']:.2e} m")


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--runs", type=int, default=100)
    p.add_argument("--particles", type=int, default=300)
    p.add_argument("--repeat", type=int, default=20)
    args = p.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        broot = simulate_office(Path(tmp) / "office")
        m = MapGeometry.from_building(Building.load(broot), 0)
        report("office_45x55 (rooms.geojson + navgraph.geojson)", m, bench(m, args.runs, args.particles, args.repeat),
               args.runs, args.particles)
        bare = Path(tmp) / "bare" / broot.name
        shutil.copytree(broot, bare)
        (bare / "rooms.geojson").unlink()
        (bare / "navgraph.geojson").unlink()
        t0 = time.perf_counter()
        md = MapGeometry.from_building(Building.load(bare), 0)
        print(f"\nderivation from the occupancy grid: {time.perf_counter() - t0:.2f} s")
        print(md.describe())
        report("office_45x55 derived map", md, bench(md, args.runs, args.particles, args.repeat),
               args.runs, args.particles)


if __name__ == "__main__":
    main()
