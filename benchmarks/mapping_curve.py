"""Beacon-map error against walking time (issue 14, sec. 3) on a simulated dataset: the labelled walks cut to
their first T minutes in total, mapped with blenav-map's settings, the placed beacons compared with the true
positions (:mod:`blenav.backend.mapping_curve`). Writes a markdown table with the command that made it.

    .venv/bin/python benchmarks/mapping_curve.py DATASET --minutes 2,4,8,16,32 --out FILE.md \
        [--sessions ID,ID] [--set min_readings=50]

Sessions (default: every labelled one of the dataset's first building, in id order) are walked in the order
given; all must be in one building.
"""

from __future__ import annotations

import argparse
import os
import shlex
import sys
from pathlib import Path

from blenav.backend.config import load_backend_config
from blenav.backend.mapping_curve import error_vs_time, markdown_table
from blenav.data import Dataset


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else list(argv)
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("dataset")
    p.add_argument("--minutes", default="2,4,8,16,32", help="comma-separated walking times (min)")
    p.add_argument("--sessions", default=None, help="comma-separated labelled session ids, walked in this order")
    p.add_argument("--out", default=None, help="markdown file to write (default: print only)")
    p.add_argument("--set", action="append", default=[], metavar="KEY=VALUE", help="a mapping setting (repeatable)")
    args = p.parse_args(argv)
    minutes = [float(m) for m in args.minutes.split(",") if m.strip()]
    cfg = load_backend_config(overrides=[s if s.startswith("mapping.") else f"mapping.{s}" for s in args.set]).mapping
    ds = Dataset.open(args.dataset)
    ids = [s.strip() for s in args.sessions.split(",") if s.strip()] if args.sessions else None
    sessions = list(ds.sessions(ids, labelled=None if ids else True))
    if not sessions:
        raise SystemExit(f"{args.dataset}: no labelled session")
    bid = sessions[0].building.id
    if ids and any(s.building.id != bid for s in sessions):
        raise SystemExit(f"sessions {ids} are in more than one building; give sessions of one")
    sessions = [s for s in sessions if s.building.id == bid]
    df = error_vs_time(sessions, ds.building(bid).anchors, cfg, minutes)
    table = markdown_table(df)
    cmd = " ".join(shlex.quote(a) for a in [".venv/bin/python", "benchmarks/mapping_curve.py", *argv])
    load = os.getloadavg()
    text = (f"# Beacon-map error against walking time\n\n"
            f"Dataset `{args.dataset}`, building `{bid}`, sessions walked in order: "
            f"{', '.join(f'`{s.id}`' for s in sessions)}.\n"
            f"Beacons placed at every T (the 'common' column): {len(df.attrs['common_beacons'])}. "
            f"Load average during the run: {load[0]:.1f}.\n\n{table}\n"
            f"Command:\n\n    {cmd}\n")
    print(text)
    if args.out:
        Path(args.out).parent.mkdir(parents=True, exist_ok=True)
        Path(args.out).write_text(text, encoding="utf-8")
        print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
