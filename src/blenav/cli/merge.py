"""``blenav merge OUT JOB [JOB ...]``: the jobs of a fan-out over methods as the one evaluation they split.

A fan-out runs each method (or group of methods) of an experiment as its own job, on any Hydra launcher::

    blenav eval -m experiment=NAME data=DIR runs=N only=A,B,C 'out=FAN/${hydra:job.num}' hydra/launcher=joblib

(``hydra/launcher=submitit_slurm`` on a cluster); ``blenav merge OUT FAN`` then writes ``OUT/results.json`` with every
job's methods (the serial run's numbers: a method's runs depend on the seed and the session only),
the trajectories and ``OUT/report.html`` (:func:`blenav.eval.merge.merge_runs`). ``JOB``: a job's output folder, or
a folder whose sub-folders are the jobs.
"""

from __future__ import annotations

import sys
from pathlib import Path

from .args import ArgumentParser
from .common import run_main, write_page

PROG = "blenav-merge"


def _main(argv: list[str] | None) -> int:
    p = ArgumentParser(PROG, description=__doc__.splitlines()[0])
    p.add_argument("out", type=Path, help="the merged evaluation's folder (new)")
    p.add_argument("jobs", type=Path, nargs="+", help="the jobs' output folders (or their parent)")
    args = p.parse_args(argv)

    from blenav.eval.merge import merge_runs
    from blenav.eval.metrics import rmse_mean

    merged = merge_runs(args.jobs, args.out)
    width = max(map(len, merged["methods"]), default=0)
    for name, m in merged["methods"].items():
        r = rmse_mean(m)
        print(f"{name:<{width}}  RMSE {r:.2f} m" if r is not None else f"{name:<{width}}  skipped")
    print(f"wrote {args.out}/results.json ({len(merged['methods'])} methods from {len(merged['merged_from'])} jobs)")
    page = write_page(PROG, args.out)
    if page:
        print(f"wrote {args.out}/report.html ({page})")
    return 0


def main(argv: list[str] | None = None) -> int:
    """``blenav merge``: errors the user can fix print one line and exit 1 (``--debug``: with the traceback)."""
    return run_main(PROG, _main, argv)


if __name__ == "__main__":
    sys.exit(main())
