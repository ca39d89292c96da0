"""What every entry point shares: known errors become one line ``PROG: error: ...`` and exit code 1.

A known error is one the user can act on: a bad dataset or file (``ValueError`` and its subclasses
``DatasetError``, ``EvalError``, ``ConfigError``; ``OSError`` such as a missing file), a size in a setting or
file this machine cannot hold (``MemoryError``: ``PROG: error: out of memory: ...``), a name in a setting or
file that imports nothing (``ImportError``, ``ModuleNotFoundError``: ``PROG: error: ModuleNotFoundError: No
module named 'x'``). Anything else is a bug in blenav and keeps its traceback. ``--debug`` on the command
line (or ``BLENAV_DEBUG=1``) shows the traceback of known errors too.

Ctrl-C (SIGINT, ``KeyboardInterrupt``) and SIGTERM (:class:`Terminated`, raised by the handler
:func:`install_signal_handlers` installs) end as one line ``PROG: interrupted[; what was cleaned up]`` with
exit code 130 / 143 (128 + the signal's number); the cleanup (``finally`` blocks, ``except BaseException``)
runs first and may say what it did with ``exc.add_note(...)``.

Hydra entry points (:func:`run_hydra`) also check the overrides before Hydra runs
(:func:`blenav.configs.check_overrides`): an unknown key, with or without ``+``, fails with the nearest
known key, instead of being added silently or explained in a traceback.
"""

from __future__ import annotations

import os
import signal
import sys
import threading
from contextlib import contextmanager
from typing import Callable

KNOWN_ERRORS = (ValueError, OSError, MemoryError, ImportError)


class Terminated(BaseException):
    """SIGTERM, raised in the main thread as SIGINT raises ``KeyboardInterrupt`` (a ``BaseException``: the same
    ``except Exception`` blocks let it through, the same cleanup runs)."""


#: exit code of an interrupted command: 128 + the signal's number
INTERRUPT_EXIT = {KeyboardInterrupt: 128 + signal.SIGINT, Terminated: 128 + signal.SIGTERM}


def _raise_terminated(signum, frame) -> None:
    raise Terminated(f"signal {signum}")


def install_signal_handlers() -> None:
    """SIGTERM raises :class:`Terminated` (Python's own SIGINT handler raises ``KeyboardInterrupt``); only in the
    main thread, where Python runs signal handlers."""
    if threading.current_thread() is threading.main_thread():
        signal.signal(signal.SIGTERM, _raise_terminated)


@contextmanager
def signals_held():
    """SIGINT and SIGTERM deferred while the block runs (a cleanup or an output swap that must not stop halfway); one
    that arrived is raised when the block ends (not again after an exception: the block is then already cleanup)."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    pending: list[int] = []
    old = {s: signal.signal(s, lambda n, _f: pending.append(n)) for s in (signal.SIGINT, signal.SIGTERM)}
    ok = False
    try:
        yield
        ok = True
    finally:
        for s, h in old.items():
            signal.signal(s, h)
    if ok and pending:
        raise KeyboardInterrupt() if pending[0] == signal.SIGINT else Terminated(f"signal {pending[0]}")


def pop_debug(args: list[str]) -> tuple[bool, list[str]]:
    """(debug wanted, the arguments without ``--debug``)."""
    debug = "--debug" in args or os.environ.get("BLENAV_DEBUG", "") not in ("", "0")
    return debug, [a for a in args if a != "--debug"]


def error_message(exc: BaseException | str) -> str:
    """The one-line message of a known error: its text, said as what it means for a memory or import error."""
    msg = " ".join(str(exc).split())
    if isinstance(exc, MemoryError):  # numpy says how much; a bare MemoryError says nothing
        return f"out of memory{': ' + msg if msg else ''} (a size in a setting or file is too large for this machine)"
    if isinstance(exc, ImportError):
        return f"{type(exc).__name__}: {msg}" if msg else type(exc).__name__
    return msg or type(exc).__name__


def fail(prog: str, exc: BaseException | str) -> None:
    """Print ``PROG: error: MESSAGE`` (one line, :func:`error_message`) to stderr and exit 1."""
    sys.stdout.flush()
    print(f"{prog}: error: {error_message(exc)}", file=sys.stderr, flush=True)
    sys.exit(1)


def interrupted(prog: str, exc: BaseException, debug: bool = False) -> None:
    """Print ``PROG: interrupted[; NOTE; ...]`` (one line; the notes the cleanup added) and exit 130 / 143;
    ``debug``: the traceback first."""
    if debug:
        import traceback

        traceback.print_exception(exc)
    notes = [" ".join(str(n).split()) for n in getattr(exc, "__notes__", [])]
    sys.stdout.flush()
    print("; ".join([f"{prog}: interrupted", *notes]), file=sys.stderr, flush=True)
    sys.exit(INTERRUPT_EXIT.get(type(exc), 130))


def guarded(prog: str, body: Callable[[], int | None], debug: bool) -> int:
    """Run ``body``; a known error becomes one line and exit code 1 (unless ``debug``), Ctrl-C or SIGTERM one
    line and exit code 130 / 143 (:func:`interrupted`)."""
    install_signal_handlers()
    try:
        return int(body() or 0)
    except KNOWN_ERRORS as exc:
        if debug:
            raise
        fail(prog, exc)
    except (KeyboardInterrupt, Terminated) as exc:
        interrupted(prog, exc, debug)
    return 1


def run_hydra(prog: str, config_name: str, task: Callable, args: list[str], convert=None) -> None:
    """Run ``task(cfg)`` as a Hydra app on ``args`` (``sys.argv[1:]``) with one-line errors.

    ``convert``: the entry point's command-line conveniences (:func:`blenav.configs.cli_overrides`).
    The overrides are checked first (one composition) unless Hydra is asked for a sweep (``-m``) or help."""
    install_signal_handlers()
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
    try:
        _app()
    except (KeyboardInterrupt, Terminated) as exc:  # outside the task (Hydra starting): one line too
        interrupted(prog, exc, debug)
