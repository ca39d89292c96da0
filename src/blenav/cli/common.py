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
runs first and may say what it did with ``exc.add_note(...)``. A signal that arrives while numba compiles a kernel
is raised when the compile is over (:func:`_on_signal`).

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

from .hydra_help import _HYDRA_OPTS, _INFO_CHOICES, _PRINT_ONLY, _VALUED, flags_to_overrides, hydra_help

KNOWN_ERRORS = (ValueError, OSError, MemoryError, ImportError)

#: the name the running command was called by (``blenav eval``), set by the ``blenav`` dispatcher
#: (:mod:`blenav.cli.main`); None: the entry point's own name (``blenav-eval``)
_CALLED_AS: list[str] = []


def display_prog(prog: str) -> str:
    """``prog`` as the user called it: ``blenav eval`` under the ``blenav`` command, else ``prog`` itself."""
    return _CALLED_AS[-1] if _CALLED_AS else prog


@contextmanager
def called_as(name: str):
    """Within the block, :func:`display_prog` (error lines, usage lines) says ``name``."""
    _CALLED_AS.append(name)
    try:
        yield
    finally:
        _CALLED_AS.pop()


class Terminated(BaseException):
    """SIGTERM, raised in the main thread as SIGINT raises ``KeyboardInterrupt`` (a ``BaseException``: the same
    ``except Exception`` blocks let it through, the same cleanup runs)."""


#: exit code of an interrupted command: 128 + the signal's number
INTERRUPT_EXIT = {KeyboardInterrupt: 128 + signal.SIGINT, Terminated: 128 + signal.SIGTERM}


def _numba_compile_lock():
    """numba's global compiler lock (held while a kernel compiles or loads from its cache), or None before numba
    is imported (nothing to wait for then; importing it here would cost every command half a second)."""
    mod = sys.modules.get("numba.core.compiler_lock")
    return None if mod is None else mod.global_compiler_lock


def _raise_when_compiled(signum: int) -> None:
    """In a helper thread: wait until numba's compile in the main thread is over, then send ``signum`` again."""
    with _numba_compile_lock():
        pass
    signal.raise_signal(signum)


def _on_signal(signum, frame) -> None:
    """SIGINT raises ``KeyboardInterrupt``, SIGTERM :class:`Terminated`, except while numba compiles in the main
    thread: LLVM calls back into Python from C then (its object cache), an exception raised in such a callback is
    swallowed ("Exception ignored on calling ctypes callback function") and leaves the compile half-done, and the
    process segfaults instead of cleaning up. The signal is then sent again once the compile lock is free."""
    lock = _numba_compile_lock()
    if lock is not None and lock.is_locked():
        threading.Thread(target=_raise_when_compiled, args=(signum,), daemon=True).start()
        return
    if signum == signal.SIGINT:
        raise KeyboardInterrupt()
    raise Terminated(f"signal {signum}")


def install_signal_handlers() -> None:
    """SIGINT and SIGTERM raise ``KeyboardInterrupt`` / :class:`Terminated` (:func:`_on_signal`); only in the main
    thread, where Python runs signal handlers."""
    if threading.current_thread() is threading.main_thread():
        for s in (signal.SIGINT, signal.SIGTERM):
            signal.signal(s, _on_signal)


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
        from blenav.errors import missing_extra

        extra = missing_extra(exc)
        hint = f" (this needs blenav's '{extra}' extra: pip install 'blenav[{extra}]')" if extra else ""
        return (f"{type(exc).__name__}: {msg}" if msg else type(exc).__name__) + hint
    return msg or type(exc).__name__


def fail(prog: str, exc: BaseException | str) -> None:
    """Print ``PROG: error: MESSAGE`` (one line, :func:`error_message`) to stderr and exit 1."""
    sys.stdout.flush()
    print(f"{display_prog(prog)}: error: {error_message(exc)}", file=sys.stderr, flush=True)
    sys.exit(1)


def interrupted(prog: str, exc: BaseException, debug: bool = False) -> None:
    """Print ``PROG: interrupted[; NOTE; ...]`` (one line; the notes the cleanup added) and exit 130 / 143;
    ``debug``: the traceback first."""
    if debug:
        import traceback

        traceback.print_exception(exc)
    notes = [" ".join(str(n).split()) for n in getattr(exc, "__notes__", [])]
    sys.stdout.flush()
    print("; ".join([f"{display_prog(prog)}: interrupted", *notes]), file=sys.stderr, flush=True)
    sys.exit(INTERRUPT_EXIT.get(type(exc), 130))


def guarded(prog: str, body: Callable[[], int | None], debug: bool) -> int:
    """Run ``body``; a known error becomes one line and exit code 1 (unless ``debug``), Ctrl-C or SIGTERM one
    line and exit code 130 / 143 (:func:`interrupted`)."""
    install_signal_handlers()
    try:
        return int(body() or 0)
    except (KeyboardInterrupt, Terminated) as exc:
        interrupted(prog, exc, debug)
    except Exception as exc:
        sig = interrupt_behind(exc)
        if sig is not None:  # the signal came while C code ran and became its error (a SystemError): still a signal
            for note in getattr(exc, "__notes__", []):  # what a cleanup did, noted on the exception it saw
                if note not in getattr(sig, "__notes__", []):
                    sig.add_note(note)
            interrupted(prog, sig, debug)
        if not isinstance(exc, KNOWN_ERRORS) or debug:
            raise
        fail(prog, exc)
    return 1


def subcommand_args(prog: str, usage: str, argv: list[str]) -> list[str] | None:
    """The words of a command with sub-commands and positional paths (``tables``, ``realwalks``) in blenav's
    dialect: ``-h`` / ``--help`` prints ``usage`` (as the command was called) and gives None (exit 0);
    ``data=DIR`` / ``out=OUT`` name a positional path as the word itself."""
    if any(a in ("-h", "--help") for a in argv):
        print(usage.replace(prog, display_prog(prog)))
        return None
    return [a.split("=", 1)[1] if a.startswith(("data=", "out=")) else a for a in argv]


def write_page(prog: str, out) -> str | None:
    """Write OUT/report.html (:func:`blenav.eval.report_html.write_report`) and say its size; a page that cannot be
    drawn costs the command nothing: a warning names why, the results stand (None)."""
    from blenav.eval.report_html import write_report

    try:
        return f"{write_report(out).stat().st_size:,} bytes, opens offline"
    except Exception as exc:  # noqa: BLE001 -- the results are written; the page is a view of them
        print(f"{display_prog(prog)}: warning: report.html not written: {type(exc).__name__}: "
              f"{error_message(exc)[:300]}", file=sys.stderr)
        return None


def run_main(prog: str, body: Callable[[list[str]], int | None], argv: list[str] | None) -> int:
    """An argparse command's ``main(argv)``: ``body(args)`` on ``argv`` (default ``sys.argv[1:]``) without ``--debug``,
    :func:`guarded`."""
    debug, args = pop_debug(sys.argv[1:] if argv is None else list(argv))
    return guarded(prog, lambda: body(args), debug)


def interrupt_behind(exc: BaseException) -> BaseException | None:
    """The ``KeyboardInterrupt`` or :class:`Terminated` that ``exc`` was raised from or while handling, if any. A
    signal handler raises between two bytecodes; when those run inside a C function that calls back into Python (a
    compiled kernel, a sort key), the function may return with the exception set, which Python reports as a
    ``SystemError`` whose context is the interrupt."""
    seen: set[int] = set()
    e: BaseException | None = exc
    while e is not None and id(e) not in seen:
        if isinstance(e, (KeyboardInterrupt, Terminated)):
            return e
        seen.add(id(e))
        e = e.__cause__ or e.__context__
    return None


def run_hydra(prog: str, config_name: str, task: Callable, args: list[str], convert=None) -> None:
    """Run ``task(cfg)`` as a Hydra app on ``args`` (``sys.argv[1:]``) with one-line errors.

    ``convert``: the entry point's command-line conveniences (:func:`blenav.configs.cli_overrides`).
    The overrides are checked first (one composition, ``--config-dir`` and ``--config-name`` followed) unless
    Hydra is asked for a sweep (``-m``) or only prints (help, ``--cfg``, ``--info``). Every ``_target_`` of the
    composed config must be one of blenav's classes (:func:`blenav.trust.check_targets`), and the ``hydra`` node may
    make Hydra build only its own launchers and sweepers (:func:`blenav.trust.check_hydra_node`): checked before
    Hydra starts, and again on the config each job gets, before the task runs. ``--experimental-rerun`` (Hydra
    unpickles a file) is refused."""
    install_signal_handlers()
    import hydra

    from pathlib import Path

    from blenav.configs import check_overrides, register_configs
    from blenav.paths import conf_dir
    from blenav.trust import check_targets

    prog = display_prog(prog)
    debug, args = pop_debug(args)
    args = flags_to_overrides(args, _HYDRA_OPTS)  # --data DIR -> data=DIR, --no-progress -> progress=false
    if convert is not None:
        args = convert(args)
    register_configs()
    overrides, opts = _hydra_args(args)
    if "--help" in opts:  # a usage line, what the command accepts and the keys a user changes (not a config dump)
        doc = sys.modules.get(getattr(task, "__module__", ""), None)
        print(hydra_help(prog, opts.get("--config-name") or config_name, overrides, getattr(doc, "__doc__", None)))
        return
    try:
        if "--experimental-rerun" in opts:
            raise ValueError("--experimental-rerun is refused: Hydra would unpickle that file, and unpickling runs "
                             "whatever code the file names; run the job again from its overrides instead")
        if "--config-path" in opts:  # Hydra would then find neither blenav's configs nor its checks' compositions
            raise ValueError("--config-path replaces blenav's own configs (conf/), which every command needs; add a "
                             "folder of your own configs (e.g. experiment/NAME.yaml) with --config-dir DIR instead")
        if not opts.keys() & _PRINT_ONLY:
            name = opts.get("--config-name") or config_name
            if "--config-dir" in opts:  # the same search path as Hydra's, for the checks' compositions
                d = str(Path(opts["--config-dir"]).resolve()).replace("\\", "\\\\").replace("'", "\\'")
                overrides = overrides + [f"hydra.searchpath=['file://{d}']"]
            sweep = "--multirun" in opts
            if sweep:
                _check_composed(name, overrides, sweep=True)
            elif any(o.startswith(("+", "~")) for o in overrides):  # keys added or deleted: checked on the base
                check_overrides(name, overrides)
                _check_composed(name, overrides, sweep=False)
            elif not _check_composed(name, overrides, sweep=False):
                # no key added or deleted: check_overrides (two compositions) can only fail where this composition
                # failed, so it runs only then, for its one-line message naming the nearest key
                check_overrides(name, overrides)
    except ValueError as exc:  # ConfigError, UntrustedTargetError
        if debug:
            raise
        fail(prog, exc)

    def checked(cfg):
        check_targets(cfg, "the config (command line and config files)")
        return task(cfg)

    @hydra.main(config_path=str(conf_dir()), config_name=config_name, version_base="1.3")
    def _app(cfg) -> float | None:
        value: list = []  # a float the task returns is the sweep's objective (Hydra's Optuna sweeper reads it)
        guarded(prog, lambda: value.append(checked(cfg)), debug)
        return value[0] if value and isinstance(value[0], float) else None

    sys.argv = [sys.argv[0]] + args
    try:
        _app()
    except (KeyboardInterrupt, Terminated) as exc:  # outside the task (Hydra starting): one line too
        interrupted(prog, exc, debug)




def _hydra_args(args: list[str]) -> tuple[list[str], dict[str, str | None]]:
    """(overrides, {long option: value or None}) of a Hydra command line, read as Hydra's argparse reads it: short
    and long spellings, ``--opt=value``, unambiguous prefixes of long options (``--config-d``). An unknown option
    is kept as itself (Hydra refuses it)."""
    short = {v: k for k, v in _HYDRA_OPTS.items() if v}
    overrides: list[str] = []
    opts: dict[str, str | None] = {}
    i = 0
    while i < len(args):
        a = args[i]
        i += 1
        if not a.startswith("-") or a == "-":
            overrides.append(a)
            continue
        name, eq, value = a.partition("=")
        if name in short:
            name = short[name]
        elif name.startswith("--") and name not in _HYDRA_OPTS:
            hits = [o for o in _HYDRA_OPTS if o.startswith(name)]
            name = hits[0] if len(hits) == 1 else name
        if not eq and name in _VALUED and i < len(args):
            value, i = args[i], i + 1
        elif not eq and name == "--info" and i < len(args) and args[i] in _INFO_CHOICES:
            value, i = args[i], i + 1
        opts[name] = value if (eq or name in _VALUED or value) else None
    return overrides, opts


def _check_composed(config_name: str, overrides: list[str], sweep: bool) -> bool:
    """Compose the config as Hydra will (with its ``hydra`` node; for a sweep without the swept overrides) and
    check what it names (:func:`blenav.trust.check_targets`, as written, and :func:`blenav.trust.check_hydra_node`)
    before Hydra builds its launcher, sweeper, callbacks and logging from it. Returns whether it composed: a
    composition that fails is left to :func:`blenav.configs.check_overrides` and Hydra, which fail on it before
    anything is built."""
    from hydra import compose, initialize_config_dir
    from hydra.core.override_parser.overrides_parser import OverridesParser
    from omegaconf import OmegaConf

    from blenav.paths import conf_dir
    from blenav.trust import check_hydra_node, check_targets

    try:
        if sweep:
            parsed = OverridesParser.create().parse_overrides(overrides)
            overrides = [o.input_line for o in parsed if not o.is_sweep_override()]
        with initialize_config_dir(config_dir=str(conf_dir()), version_base="1.3"):
            cfg = compose(config_name=config_name, overrides=overrides, return_hydra_config=True)
    except Exception:  # noqa: BLE001 -- Hydra's and omegaconf's many error types: Hydra reports them itself
        return False
    where = "the config (command line and config files)"
    job = OmegaConf.masked_copy(cfg, [k for k in cfg.keys() if k != "hydra"])
    check_targets(job, where, resolve=False)
    check_hydra_node(cfg.get("hydra"), where)
    return True
