"""What every entry point shares: known errors become one line ``PROG: error: ...`` and exit code 1.

A known error is one the user can act on: a bad dataset or file (``ValueError`` and its subclasses
``DatasetError``, ``EvalError``, ``ConfigError``; ``OSError`` such as a missing file). Anything else is a
bug in blenav and keeps its traceback. ``--debug`` on the command line (or ``BLENAV_DEBUG=1``) shows the
traceback of known errors too.

Hydra entry points (:func:`run_hydra`) also check the overrides before Hydra runs
(:func:`blenav.configs.check_overrides`): an unknown key, with or without ``+``, fails with the nearest
known key, instead of being added silently or explained in a traceback.
"""

from __future__ import annotations

import os
import sys
from typing import Callable

KNOWN_ERRORS = (ValueError, OSError)


def pop_debug(args: list[str]) -> tuple[bool, list[str]]:
    """(debug wanted, the arguments without ``--debug``)."""
    debug = "--debug" in args or os.environ.get("BLENAV_DEBUG", "") not in ("", "0")
    return debug, [a for a in args if a != "--debug"]


def fail(prog: str, exc: BaseException | str) -> None:
    """Print ``PROG: error: MESSAGE`` (one line) to stderr and exit 1."""
    msg = " ".join(str(exc).split()) or type(exc).__name__
    sys.stdout.flush()
    print(f"{prog}: error: {msg}", file=sys.stderr, flush=True)
    sys.exit(1)


def guarded(prog: str, body: Callable[[], int | None], debug: bool) -> int:
    """Run ``body``; a known error becomes one line and exit code 1 (unless ``debug``)."""
    try:
        return int(body() or 0)
    except KNOWN_ERRORS as exc:
        if debug:
            raise
        fail(prog, exc)
    return 1


def run_hydra(prog: str, config_name: str, task: Callable, args: list[str], convert=None) -> None:
    """Run ``task(cfg)`` as a Hydra app on ``args`` (``sys.argv[1:]``) with one-line errors.

    ``convert``: the entry point's command-line conveniences (:func:`blenav.configs.cli_overrides`).
    The overrides are checked first (one composition) unless Hydra is asked for a sweep (``-m``) or help."""
    import hydra

    from blenav.configs import check_overrides, register_configs
    from blenav.errors import ConfigError
    from blenav.paths import conf_dir

    debug, args = pop_debug(args)
    if convert is not None:
        args = convert(args)
    register_configs()
    flags = [a for a in args if a.startswith("-")]
    if not flags:
        try:
            check_overrides(config_name, args)
        except ConfigError as exc:
            if debug:
                raise
            fail(prog, exc)

    @hydra.main(config_path=str(conf_dir()), config_name=config_name, version_base="1.3")
    def _app(cfg) -> float | None:
        value: list = []  # a float the task returns is the sweep's objective (Hydra's Optuna sweeper reads it)
        guarded(prog, lambda: value.append(task(cfg)), debug)
        return value[0] if value and isinstance(value[0], float) else None

    sys.argv = [sys.argv[0]] + args
    _app()
