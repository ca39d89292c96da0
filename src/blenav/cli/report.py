"""``blenav report OUT [--out FILE.html] [--title TEXT] [--data DIR | --no-plan]``: the HTML page of an evaluation's output folder.

One self-contained file that works offline (plotly inlined): the leaderboard as a sortable table, the error CDFs,
per session the trajectories on the floor plan with a toggle per method and a time slider, and the skipped methods
with their reasons (:mod:`blenav.eval.report_html`). ``blenav eval`` writes it as ``OUT/report.html`` at the end
of every evaluation (unless ``report=false``); this command draws it again, e.g. for an OUT written before it existed.
"""

from __future__ import annotations

import sys
from pathlib import Path

from .args import ArgumentParser
from .common import run_main

PROG = "blenav-report"


def _main(argv: list[str] | None) -> int:
    p = ArgumentParser(PROG, description=__doc__.splitlines()[0])
    p.add_argument("evaluation", type=Path, help="an output folder of blenav eval (it holds results.json)")
    p.add_argument("--out", type=Path, default=None, help="the page to write (default: EVALUATION/report.html)")
    p.add_argument("--title", default=None, help="the page's title (default: the experiment's)")
    p.add_argument("--data", default=None, help="the dataset whose floor plans are drawn (default: the one "
                   "results.json names)")
    p.add_argument("--no-plan", action="store_true", help="draw no floor plan (open no dataset)")
    args = p.parse_args(argv)

    from blenav.eval.report_html import write_report

    if args.out is not None and args.out.is_dir():
        raise ValueError(f"--out {args.out} is a folder; give the .html file to write")
    page = write_report(args.evaluation, args.out, args.title, "" if args.no_plan else args.data)
    print(f"wrote {page} ({page.stat().st_size:,} bytes; open it in a browser, it needs no network)")
    return 0


def main(argv: list[str] | None = None) -> int:
    """``blenav report``: errors the user can fix print one line and exit 1 (``--debug``: with the traceback)."""
    return run_main(PROG, _main, argv)


if __name__ == "__main__":
    sys.exit(main())
