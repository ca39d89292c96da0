"""ILC 2.0 import speed: one floor (site1/F1: 106 walks, 172 MB of path files) from its archive, validation included.

Budget (issue 17, sec. 1): one floor of about 100 walks / 150 MB imports in under 60 s. Prints the wall time with
its ratio to the budget (< 1: within it), the CPU time of the process (less sensitive to other processes on a
shared machine than the wall time, which is what the budget is for), the load average, and the peak memory
(maximum resident set size of this process, Python and its libraries included: their size before the import is
printed too). Skips with the reason when ../shared/data/raw/ilc20 is absent.

    .venv/bin/python benchmarks/ilc20_import.py [--src ../shared/data/raw/ilc20/site1_F1.tar.gz] [--floors site1/F1]
"""

from __future__ import annotations

import argparse
import os
import resource
import sys
import tempfile
import time
from pathlib import Path

from blenav.importers import run_import

BUDGET_S = 60.0
DEFAULT_SRC = Path(__file__).resolve().parents[2] / "shared" / "data" / "raw" / "ilc20" / "site1_F1.tar.gz"


def _rss_mb() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0  # Linux: kB


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--src", type=Path, default=DEFAULT_SRC, help="floor/site folder or archive")
    ap.add_argument("--floors", default=None, help="SITE/FLOOR,... (default: every floor in --src)")
    args = ap.parse_args()
    if not args.src.exists():
        print(f"skipped: {args.src} is absent (../shared/data/raw/ilc20 not available)")
        return
    size = args.src.stat().st_size if args.src.is_file() else sum(p.stat().st_size for p in args.src.rglob("*"))
    before = _rss_mb()
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp) / "ilc20"
        t0, c0 = time.perf_counter(), time.process_time()
        rep = run_import("ilc20", args.src, out, **({"floors": args.floors} if args.floors else {}))
        wall, cpu = time.perf_counter() - t0, time.process_time() - c0
        written = sum(p.stat().st_size for p in out.rglob("*") if p.is_file())
    peak = _rss_mb()
    print(f"source: {args.src} ({size / 1e6:.1f} MB); {rep.sessions} walks -> {written / 1e6:.1f} MB written "
          "(import + validation)")
    print(f"{'wall [s]':>9s} {'/ budget':>9s} {'CPU [s]':>8s} {'load avg':>9s} {'peak RSS [MB]':>14s} "
          f"{'RSS before [MB]':>16s}")
    print(f"{wall:9.2f} {wall / BUDGET_S:9.2f} {cpu:8.2f} {os.getloadavg()[0]:9.2f} {peak:14.0f} {before:16.0f}")
    for line in str(rep).splitlines():
        if line.startswith(("floor ", "site ")):
            print(line)
    sys.stdout.flush()


if __name__ == "__main__":
    main()
