"""``blenav-plot DATASET``: draw overview figures of a dataset as PNG files.

Writes ``<out>/<building>_overview.png`` for each building (floors, anchors, rooms, routes, ground-truth
tracks) and ``<out>/radio.png`` (RSSI against distance with a path-loss fit, RSSI per receiver), and prints
their paths. Exit 1 with a message when the dataset breaks a rule of the format.
"""

from __future__ import annotations

import sys
from pathlib import Path

from .args import ArgumentParser
from .common import run_main


def _main(argv: list[str] | None) -> int:
    p = ArgumentParser(prog="blenav-plot", description=__doc__.splitlines()[0])
    p.add_argument("dataset", type=Path, help="dataset folder (contains dataset.yaml)")
    p.add_argument("-s", "--sessions", "--session", dest="sessions", metavar="S", action="extend", nargs="+",
                   help="session id(s) to draw: A,B or A B (repeatable; default: all sessions)")
    p.add_argument("-o", "--out", type=Path, default=None, help="output folder (default: DATASET/plots)")
    args = p.parse_args(argv)
    if args.sessions:
        args.sessions = [x for s in args.sessions for x in s.split(",") if x]

    from blenav import plotting
    from blenav.data import Dataset
    from blenav.errors import DatasetError

    out = args.out if args.out is not None else args.dataset / "plots"
    try:
        ds = Dataset.open(args.dataset)
        ids = list(dict.fromkeys(args.sessions)) if args.sessions else ds.session_ids
        unknown = [s for s in ids if s not in ds.session_ids]
        if unknown:
            print(f"blenav-plot: no session(s) {', '.join(unknown)} in {args.dataset}; sessions are "
                  f"{', '.join(ds.session_ids) or '(none)'}", file=sys.stderr)
            return 1
        sessions = [ds.session(s) for s in ids]
        # with --session: only the buildings of those sessions; else every building
        buildings = sorted({s.building.id for s in sessions}) if args.sessions else ds.building_ids
        for b in buildings:
            path = plotting.save_figure(plotting.figure_overview(ds, ids, building_id=b), out / f"{b}_overview.png")
            print(path)
        print(plotting.save_figure(plotting.figure_radio(sessions), out / "radio.png"))
    except DatasetError as exc:
        print(f"blenav-plot: {args.dataset} is not a valid blenav/1 dataset:\n{exc}", file=sys.stderr)
        return 1
    return 0


def main(argv: list[str] | None = None) -> int:
    """``blenav-plot``: errors the user can fix print one line and exit 1 (``--debug``: with the traceback)."""
    return run_main("blenav-plot", _main, argv)


if __name__ == "__main__":
    sys.exit(main())
