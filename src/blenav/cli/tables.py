"""``python -m blenav.cli.tables merge | leaderboard | crf | feng ...``: the results pages of docs/ written from
evaluations' results.json (:mod:`blenav.reporting`); the real-walk tables, which compose their experiment, are
``python -m blenav.cli.realwalks tables | priors``.

    merge OUT.md TITLE RUN[:PREFIX] [RUN[:PREFIX] ...]   one row per session, one column per (prefixed) method
                                                         (make selfcal-tables; blenav.reporting.merge.write_merge)
    leaderboard OUT.md TITLE RUN [RUN ...]               the leaderboard over a fleet, OUT.md and OUT.json; RUN is an
                                                         output folder or a multirun's FLEET (make leaderboard)
    crf TABLE1_OUT FIG12_OUT OUT.md                      the CRF experiments' Table I / Fig. 12 (make crf-tables)
    feng RESULTS.json OUT.md [COMMAND]                   the Feng et al. real-RTT page (make feng-tables)

Prints the file written (``crf``: its text). Errors the user can fix (a folder without results.json, a bad file)
print one line ``python -m blenav.cli.tables: error: ...`` and exit 1 (``--debug``: with the traceback); wrong
arguments print the usage and exit 2.
"""

from __future__ import annotations

import sys
from pathlib import Path

from .common import display_prog, guarded, pop_debug, subcommand_args

PROG = "python -m blenav.cli.tables"
USAGE = (f"usage: {PROG} merge OUT.md TITLE RUN[:PREFIX] [RUN[:PREFIX] ...] | leaderboard OUT.md TITLE RUN [RUN ...] "
         f"| crf TABLE1_OUT FIG12_OUT OUT.md | feng RESULTS.json OUT.md [COMMAND] "
         f"| backend [--made-by CMD] OUT.md TITLE LABEL=TRUE_RUN[,NOISE_RUN] [...]")


def _main(argv: list[str]) -> int:
    cmd, args = (argv[0], argv[1:]) if argv else ("", [])
    if cmd == "merge" and len(args) >= 3:
        from blenav.reporting.merge import write_merge

        print(write_merge(Path(args[0]), args[1], args[2:]))
    elif cmd == "leaderboard" and len(args) >= 3:
        from blenav.reporting.merge import write_leaderboard

        print(write_leaderboard(Path(args[0]), args[1], [Path(a) for a in args[2:]]))
    elif cmd == "crf" and len(args) == 3:
        from blenav.reporting.crf_tables import write

        print(write(Path(args[0]), Path(args[1]), Path(args[2])))
    elif cmd == "feng" and len(args) in (2, 3):
        from blenav.reporting.feng_rtt import write_page

        write_page(Path(args[0]), Path(args[1]), args[2] if len(args) > 2 else "")
        print(f"wrote {args[1]}")
    elif cmd == "backend" and len(args) >= 3 + 2 * (args[0] == "--made-by"):
        from blenav.reporting.backend_robust import write_backend_table

        made_by = "make backend-robust"  # the command the page says made it
        if args[0] == "--made-by":
            made_by, args = args[1], args[2:]
        print(write_backend_table(Path(args[0]), args[1], args[2:], command=made_by))
    else:
        print(USAGE.replace(PROG, display_prog(PROG)), file=sys.stderr)
        return 2
    return 0


def _checked(argv: list[str]) -> int:
    try:
        return _main(argv)
    except KeyError as exc:  # a results.json of another kind: a known error, said as such
        raise ValueError(f"a results.json lacks the key {exc} (not an output of blenav-eval?)") from exc


def main(argv: list[str] | None = None) -> int:
    debug, argv = pop_debug(sys.argv[1:] if argv is None else list(argv))
    argv = subcommand_args(PROG, USAGE, argv)
    return 0 if argv is None else guarded(PROG, lambda: _checked(argv), debug)


if __name__ == "__main__":
    sys.exit(main())
