"""An output folder that appears whole or not at all (``blenav-eval``'s OUT).

The command writes into a fresh temporary folder beside OUT (same parent, so the final rename is atomic:
``.OUT.tmp-<pid>``) and swaps it in when it has finished: a failed, interrupted (Ctrl-C, SIGTERM) or killed run
never leaves a half-written OUT, nor mixes its files with an earlier run's. An existing OUT is refused unless
``overwrite``; then it is replaced whole (renamed aside, the new one renamed in, the old one deleted), and only
when it is an evaluation's output (``results.json``, or ``runs/`` of an evaluation that trained and then failed)
or empty, and holds none of the run's inputs (the dataset, the model): ``out=.`` cannot delete a working tree.

Reusable artefacts of the old OUT (:data:`REUSABLE`: ``runs/``, the cross-phone experiment's training runs,
reused when complete; ``fixes/``, the computed BLE fixes cached by :mod:`blenav.eval.fixes`) are copied into the
temporary folder first, so a rerun with ``overwrite=true`` reuses them as a run in place did, while the old OUT
stays untouched until the swap. Paths the run recorded in its ``.json`` / ``.md`` files, and in its error
messages, name OUT, not the temporary folder.
"""

from __future__ import annotations

import json
import logging
import os
import shutil
from contextlib import contextmanager
from pathlib import Path
from typing import Iterator

from blenav.paths import inside

from .common import interrupt_behind, signals_held

#: sub-folders of an earlier OUT that a rerun reuses (copied into the new output when ``overwrite``)
REUSABLE = ("runs", "fixes")
#: what marks a folder as an evaluation's output (``overwrite`` replaces only those, or empty folders)
MARKERS = ("results.json", "runs")


def temp_beside(out: Path, tag: str = "tmp") -> Path:
    """``PARENT/.NAME.TAG-<pid>``: a hidden sibling of ``out`` (same file system: renames are atomic)."""
    return out.parent / f".{out.name}.{tag}-{os.getpid()}"


def check_replaceable(out: Path, overwrite: bool, inputs=(), shown: str | None = None) -> bool:
    """Whether ``out`` exists (as a folder that may be replaced); raises ``ValueError`` saying why not: it is a
    file, a non-empty folder without ``overwrite``, a folder that is not an evaluation's output, or one that holds
    an input of the run (``inputs``: paths). ``shown``: ``out`` as the user wrote it, for the messages."""
    shown = shown or str(out)
    if not out.name or out.name in (".", ".."):
        raise ValueError(f"out={shown}: name a folder of its own for the output")
    within = [str(p) for p in inputs if p and Path(p).is_dir() and inside(out, p)]
    if within:  # out=DATA/sessions/x would become a session of the dataset, out=BUNDLE/x an unlisted file of it
        raise ValueError(f"out={shown} lies inside {', '.join(within)}, an input of this run: the output would "
                         "change it; choose another out=")
    if not out.exists():
        return False
    if not out.is_dir():
        raise ValueError(f"out={shown} is a file, not a folder")
    if not any(out.iterdir()):
        return True
    if not overwrite:
        raise ValueError(f"output folder {shown} exists; pass overwrite=true to replace it, or choose another out=")
    if not any((out / m).exists() for m in MARKERS):
        raise ValueError(f"output folder {shown} holds no results.json: not an evaluation's output, so overwrite=true "
                         "does not replace it; choose another out=")
    held = [str(p) for p in inputs if p and inside(p, out)]
    if held:
        raise ValueError(f"output folder {shown} holds {', '.join(held)}, an input of this run: overwrite=true would "
                         "delete it; choose another out=")
    return True


def relocate(folder: Path, old: str, new: str, suffixes=(".json", ".md"), max_bytes: int = 64 << 20) -> None:
    """Rewrite the path ``old`` as ``new`` in the ``.json`` / ``.md`` files under ``folder`` (as written, and as JSON
    escapes it), each file atomically."""
    from blenav.eval.common import write_text

    pairs = [(old, new), (json.dumps(old)[1:-1], json.dumps(new)[1:-1])]
    for p in folder.rglob("*"):
        if p.suffix not in suffixes or not p.is_file() or p.is_symlink() or p.stat().st_size > max_bytes:
            continue
        text = p.read_text(encoding="utf-8", errors="surrogateescape")
        if any(a in text for a, _ in pairs):
            for a, b in pairs:
                text = text.replace(a, b)
            write_text(p, text)


def _swap(tmp: Path, out: Path, existed: bool) -> None:
    """``tmp`` becomes ``out``; an existing ``out`` is renamed aside first and deleted after (put back on failure)."""
    if not existed:
        os.replace(tmp, out)
        return
    old = temp_beside(out, "old")
    os.replace(out, old)
    try:
        os.replace(tmp, out)
    except BaseException:
        os.replace(old, out)
        raise
    shutil.rmtree(old, ignore_errors=True)


class _NameOut(logging.Filter):
    """Log lines name ``out``, not the temporary folder that becomes it (a training report's 'RUN: worse than KNN'
    named ``.OUT.tmp-<pid>/runs/KEY``, a folder gone once the run ends)."""

    def __init__(self, tmp: Path, shown: str):
        super().__init__()
        self.tmp, self.shown = str(tmp), shown

    def filter(self, record: logging.LogRecord) -> bool:
        msg = record.getMessage()
        if self.tmp in msg:
            record.msg, record.args = msg.replace(self.tmp, self.shown), ()
        return True


@contextmanager
def _log_names_out(tmp: Path, shown: str) -> Iterator[None]:
    handlers = logging.getLogger().handlers  # where every blenav logger's records end (propagation)
    f = _NameOut(tmp, shown)
    for h in handlers:
        h.addFilter(f)
    try:
        yield
    finally:
        for h in handlers:
            h.removeFilter(f)


@contextmanager
def fresh_output(out, overwrite: bool = False, inputs=()) -> Iterator[Path]:
    """Yield the temporary folder to write into (not created: the command creates it); swap it in as ``out`` when
    the block ends normally (:func:`check_replaceable` first, before any work). On an error or an interruption the
    temporary folder is removed, ``out`` is left as it was, and an interruption carries the note ``removed partial
    output TMP`` (printed by :func:`blenav.cli.common.interrupted`); an error whose message names the temporary
    folder names ``out`` instead, and so do the log lines written meanwhile."""
    shown = str(out)
    out = Path(os.path.abspath(out))
    existed = check_replaceable(out, overwrite, inputs, shown)
    tmp = temp_beside(out)
    shutil.rmtree(tmp, ignore_errors=True)  # a folder of a killed run that had this pid
    try:
        if existed:
            for name in REUSABLE:
                if (out / name).is_dir():
                    shutil.copytree(out / name, tmp / name, symlinks=True)
        with _log_names_out(tmp, shown):
            yield tmp
        if not tmp.is_dir():
            raise ValueError(f"the run wrote nothing to {shown}")
        relocate(tmp, str(tmp), shown)
        with signals_held():
            _swap(tmp, out, existed)
    except BaseException as exc:
        _remove(tmp)
        if isinstance(exc, (ValueError, OSError)) and str(tmp) in str(exc):
            raise ValueError(str(exc).replace(str(tmp), shown)) from exc
        # KeyboardInterrupt, Terminated (or one behind the SystemError of C code it interrupted): say what was cleaned up
        sig = exc if not isinstance(exc, (Exception, SystemExit)) else interrupt_behind(exc)
        if sig is not None:
            sig.add_note(f"removed partial output {temp_beside(Path(shown))}"
                         + (f"; {shown} left as it was" if existed else ""))
        raise


def _remove(tmp: Path) -> None:
    with signals_held():  # a second Ctrl-C does not leave half a folder behind
        shutil.rmtree(tmp, ignore_errors=True)
