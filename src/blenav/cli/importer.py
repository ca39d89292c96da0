"""``blenav-import KIND SRC OUT``: convert a public recording to dataset format v1."""

from __future__ import annotations

import sys

from .args import ArgumentParser
from .common import run_main


def _main(argv: list[str] | None) -> int:
    from blenav.importers import KINDS

    p = ArgumentParser(prog="blenav-import", description=__doc__.splitlines()[0])
    p.add_argument("kind", choices=KINDS, help="which public data set SRC holds")
    p.add_argument("src", help="folder of the raw data set (e.g. ../shared/data/raw/uji_ble); ilc20: a floor or "
                   "site folder, the challenge layout, or a .tar.gz/.zip of one")
    p.add_argument("out", help="output dataset folder (created)")
    p.add_argument("--floors", default=None, metavar="SITE/FLOOR,...",
                   help="ilc20 only: import only these floors (e.g. site1/F1,site1/F2); default every floor found")
    args = p.parse_args(argv)
    if args.floors is not None and args.kind != "ilc20":
        p.error("--floors applies to ilc20 only")

    from blenav.errors import DatasetError, ImportError_
    from blenav.importers import run_import

    try:
        options = {"floors": args.floors} if args.floors is not None else {}
        report = run_import(args.kind, args.src, args.out, **options)
    except (ImportError_, DatasetError) as exc:
        # one line: a DatasetError from the validator holds one error per line
        print(f"blenav-import: error: {' '.join(str(exc).split())}", file=sys.stderr)
        return 1
    print(report)
    return 0


def main(argv: list[str] | None = None) -> int:
    """``blenav-import``: errors the user can fix print one line and exit 1 (``--debug``: with the traceback)."""
    return run_main("blenav-import", _main, argv)


if __name__ == "__main__":
    sys.exit(main())
