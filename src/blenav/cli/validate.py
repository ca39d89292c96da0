"""``blenav-validate DATASET``: check a dataset against format v1.

Exit 0 when there is no violation (warnings are printed), 1 with one line per violation.
"""

from __future__ import annotations

import sys

from .args import ArgumentParser
from .common import run_main


def _main(argv: list[str] | None) -> int:
    p = ArgumentParser(prog="blenav-validate", description=__doc__.splitlines()[0])
    p.add_argument("dataset", help="dataset folder (contains dataset.yaml)")
    p.add_argument("-q", "--quiet", action="store_true", help="print violations only, not warnings")
    args = p.parse_args(argv)

    from blenav.data import validate

    issues = validate(args.dataset)
    errors = [i for i in issues if i.is_error]
    warnings = [i for i in issues if not i.is_error]
    if not args.quiet:
        for w in warnings:
            print(w)
    for e in errors:
        print(e)
    status = "INVALID" if errors else "OK"
    print(f"{status}: {args.dataset}: {len(errors)} violation(s), {len(warnings)} warning(s)", file=sys.stderr)
    return 1 if errors else 0


def main(argv: list[str] | None = None) -> int:
    """``blenav-validate``: errors the user can fix print one line and exit 1 (``--debug``: with the traceback)."""
    return run_main("blenav-validate", _main, argv)


if __name__ == "__main__":
    sys.exit(main())
