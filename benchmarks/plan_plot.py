"""How long the evaluation's trajectories figure takes on a real floor plan: ``figure_trajectories`` (small multiples,
the floor drawn faint in every panel) of a dataset's first session, built and saved as PNG, with ``--panels`` methods
(the session's ground truth shifted by 0.5 m per method, each its own panel). Printed: the plan's grid, the build and
the save time (median of ``--repeat``), and their ratio to the reference: the same figure with one panel.

Run it at two commits to compare their plotting (the script uses only ``blenav.plotting``'s public figure):
``git worktree add /tmp/old COMMIT`` then ``PYTHONPATH=/tmp/old/src .venv/bin/python benchmarks/plan_plot.py DATA``.

    .venv/bin/python benchmarks/plan_plot.py DATA [--panels 3] [--repeat 3]
"""

from __future__ import annotations

import argparse
import statistics
import tempfile
import time
from pathlib import Path

from blenav import plotting
from blenav.data import Dataset


def _time(session, panels: int, out: Path) -> tuple[float, float]:
    gt = session.groundtruth
    t, xy = gt["t"].to_numpy(float), gt[["x", "y"]].to_numpy(float)
    tracks = {f"method {k}": (t, xy + 0.5 * k) for k in range(panels)}
    t0 = time.perf_counter()
    fig = plotting.figure_trajectories(session, tracks)
    t1 = time.perf_counter()
    plotting.save_figure(fig, out)
    return t1 - t0, time.perf_counter() - t1


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("data", help="a dataset with a floor plan (e.g. an imported ILC floor)")
    ap.add_argument("--panels", type=int, default=3)
    ap.add_argument("--repeat", type=int, default=3)
    args = ap.parse_args()
    ds = Dataset.open(args.data)
    s = ds.session(ds.session_ids[0])
    print(f"{args.data}: session {s.id}, occupancy grid {s.floor.occupancy.shape[0]} x {s.floor.occupancy.shape[1]}")
    with tempfile.TemporaryDirectory() as tmp:
        res = {}
        for n in (1, args.panels):
            runs = [_time(s, n, Path(tmp) / "t.png") for _ in range(args.repeat)]
            res[n] = (statistics.median(r[0] for r in runs), statistics.median(r[1] for r in runs))
    ref = sum(res[1])
    for n, (b, w) in res.items():
        print(f"{n:2d} panel(s): build {b:.2f} s, save {w:.2f} s, total {b + w:.2f} s (ratio to one panel "
              f"{(b + w) / ref:.2f})")


if __name__ == "__main__":
    main()
