"""Bounds on every size a file or a config can set, checked before the work that size would cost.

Settings from files (a bundle's settings.json, an experiment's YAML, a localizer's metadata) choose particle
counts, runs, rates, window lengths and grid cells; archives declare member sizes. A value outside its
documented range, or work whose memory estimate exceeds the limit, is refused with one line naming the file
or config and the field (:class:`LimitError`, a ``ValueError``: the CLIs' known-error channel), never a
``MemoryError`` traceback half way through.

* :data:`RANGES`: the named ranges (inclusive); :func:`check_range` checks one value against one.
* :func:`check_memory`: refuse an allocation estimate above :func:`max_memory_bytes` (environment variable
  ``BLENAV_MAX_MEMORY_GB``, default :data:`DEFAULT_MAX_MEMORY_GB` GiB: a third of a 24 GB machine, so the
  estimate's slack and the rest of the process fit).
* Archives (:mod:`blenav.importers._common`): :func:`max_member_bytes` (``BLENAV_MAX_ARCHIVE_MEMBER_MB``, default
  :data:`DEFAULT_MAX_MEMBER_MB` MiB; the largest ILC 2.0 path file is 4.1 MB) and :func:`max_archive_ratio`
  (``BLENAV_MAX_ARCHIVE_RATIO``, default :data:`DEFAULT_MAX_ARCHIVE_RATIO`: the members read may expand to at
  most that many times the archive's size, plus :data:`ARCHIVE_RATIO_FREE_MB` MiB; the ILC archives expand
  5.1-5.6 times: tests/test_limits.py measures them).
* Files read whole: :func:`read_json` (a bundle's or an export's metadata, ``BLENAV_MAX_JSON_MB``, default
  :data:`DEFAULT_MAX_JSON_MB` MiB; the read itself stops past the limit) and ONNX graphs (:func:`max_model_bytes`,
  ``BLENAV_MAX_MODEL_MB``, default :data:`DEFAULT_MAX_MODEL_MB` MiB, checked by :func:`blenav.onnx_io.session`),
  their size checked before reading.

Standard library and numpy only: every layer may import it.
"""

from __future__ import annotations

import math
import numbers
import os
from dataclasses import dataclass

import numpy as np

DEFAULT_MAX_MEMORY_GB = 8.0
DEFAULT_MAX_MEMBER_MB = 256.0
DEFAULT_MAX_ARCHIVE_RATIO = 200.0
#: largest metadata JSON file (a bundle's manifest, settings, building signature, an export's meta.json) read
#: whole: ``BLENAV_MAX_JSON_MB`` MiB; blenav writes them at a few kB to a few hundred kB (a building signature
#: lists the beacons)
DEFAULT_MAX_JSON_MB = 16.0
#: largest ONNX graph handed to onnxruntime: ``BLENAV_MAX_MODEL_MB`` MiB (blenav's networks export at 0.1-20 MB)
DEFAULT_MAX_MODEL_MB = 512.0
#: expansion any archive may have regardless of its ratio (a 2 kB zip of a 100 kB text file is no bomb)
ARCHIVE_RATIO_FREE_MB = 64.0

GIB = float(1 << 30)
MIB = float(1 << 20)


class LimitError(ValueError):
    """A setting outside its documented range, or work above a size limit; the message is one line naming the
    file or config and the field."""


class MemoryLimitError(LimitError):
    """The memory a setting implies exceeds :func:`max_memory_bytes`."""


@dataclass(frozen=True)
class Range:
    """Inclusive bounds of one setting; ``integer``: the value must be a whole number."""

    lo: float
    hi: float
    unit: str
    what: str
    integer: bool = False

    def describe(self) -> str:
        return f"[{_num(self.lo)}, {_num(self.hi)}]" + (f" {self.unit}" if self.unit else "")


def _num(x: float) -> str:
    """1000000 -> '1,000,000'; 0.001 -> '0.001'."""
    return f"{int(x):,}" if float(x).is_integer() and abs(x) < 1e15 else f"{x:g}"


#: The documented ranges, by name (docs/security.md). A setting's field is checked against the range of its
#: name; a config may name the field differently (``filter.n_particles`` uses ``n_particles``).
RANGES: dict[str, Range] = {
    "n_particles": Range(1, 10_000_000, "", "particles per run", integer=True),
    "runs": Range(1, 100_000, "", "independent runs of a filter per session", integer=True),
    "rate_hz": Range(1e-3, 1000.0, "Hz", "filter steps per second"),
    "step_hz": Range(1e-2, 1000.0, "Hz", "window steps per second"),
    "window_s": Range(1e-3, 3600.0, "s", "a time window"),
    "history": Range(1, 10_000, "", "steps per window", integer=True),
    "heading_bins": Range(1, 3600, "", "heading hypotheses of the map prior", integer=True),
    "cell_m": Range(0.01, 100.0, "m", "a grid cell's side"),
    "max_step_m": Range(0.0, 1000.0, "m", "a transition's longest step"),
}


def check_range(value, name: str, where: str, field: str | None = None, rng: Range | None = None):
    """``value`` as a float (an int for integer ranges) if it lies in ``RANGES[name]`` (or ``rng``), else
    :class:`LimitError`: ``"<where>: <field> = <value> is outside [lo, hi] unit (<what>)"``; ``field`` defaults to
    ``name``. Booleans, text and non-finite numbers are refused the same way."""
    r = rng if rng is not None else RANGES[name]
    field = field or name
    ok_type = isinstance(value, numbers.Real) and not isinstance(value, (bool, np.bool_))
    v = float(value) if ok_type else math.nan
    if not ok_type:
        raise LimitError(f"{where}: {field} = {value!r} is not a number (expected {r.describe()}, {r.what})")
    if not (r.lo <= v <= r.hi):
        raise LimitError(f"{where}: {field} = {value!r} is outside {r.describe()} ({r.what})")
    if r.integer:
        if v != round(v):
            raise LimitError(f"{where}: {field} = {value!r} is not a whole number ({r.what}, {r.describe()})")
        return int(v)
    return v


def _env_float(var: str, default: float) -> float:
    raw = os.environ.get(var)
    if raw is None or raw.strip() == "":
        return default
    try:
        v = float(raw)
    except ValueError:
        v = math.nan
    if not (math.isfinite(v) and v > 0):
        raise LimitError(f"environment variable {var}={raw!r}: expected a positive number (default {default:g})")
    return v


def max_memory_bytes() -> float:
    """The memory one piece of work may claim: ``BLENAV_MAX_MEMORY_GB`` GiB (default 8)."""
    return _env_float("BLENAV_MAX_MEMORY_GB", DEFAULT_MAX_MEMORY_GB) * GIB


def check_memory(nbytes: float, what: str, where: str) -> None:
    """Refuse (:class:`MemoryLimitError`) an estimate of ``nbytes`` above :func:`max_memory_bytes`; ``what`` says
    what needs it (e.g. ``"1000000000 particles x 1 run(s) x 5 state values"``)."""
    limit = max_memory_bytes()
    if nbytes > limit:
        raise MemoryLimitError(f"{where}: {what} needs about {nbytes / GIB:.3g} GiB, above the limit of "
                               f"{limit / GIB:g} GiB (set BLENAV_MAX_MEMORY_GB to allow more)")


def max_member_bytes() -> float:
    """Largest archive member read into memory: ``BLENAV_MAX_ARCHIVE_MEMBER_MB`` MiB (default 256)."""
    return _env_float("BLENAV_MAX_ARCHIVE_MEMBER_MB", DEFAULT_MAX_MEMBER_MB) * MIB


def check_file_size(path, what: str, limit: float, var: str) -> None:
    """Refuse (:class:`LimitError`) a file of more than ``limit`` bytes before it is read; ``var``: the
    environment variable that raises the limit."""
    _check_size(path, os.stat(path).st_size, what, limit, var)


def _check_size(path, size: int, what: str, limit: float, var: str) -> None:
    if size > limit:
        raise LimitError(f"{path}: {what} file of {size:,} bytes, above the limit of {int(limit):,} bytes "
                         f"(set {var}, in MiB, to allow more)")


def max_model_bytes() -> float:
    """Largest ONNX model file: ``BLENAV_MAX_MODEL_MB`` MiB (default 512)."""
    return _env_float("BLENAV_MAX_MODEL_MB", DEFAULT_MAX_MODEL_MB) * MIB


def read_bounded(path, what: str, limit: float, var: str) -> bytes:
    """The bytes of ``path`` (a file from a stranger), at most ``limit``: the size of the file opened is checked and
    the read itself bounded, so a file that grows after the check, or one whose size says nothing (/dev/zero, a
    FIFO), stops there (:class:`LimitError` naming ``var``, the environment variable that raises the limit)."""
    with open(path, "rb") as f:
        size = os.fstat(f.fileno()).st_size
        data = f.read(int(limit) + 1) if size <= limit else b""
    _check_size(path, max(size, len(data)), what, limit, var)
    return data


def read_json(path, what: str = "metadata"):
    """The JSON document of ``path`` (a file from a stranger: a bundle's or an export's metadata), its size
    checked before it is read (``BLENAV_MAX_JSON_MB``, default :data:`DEFAULT_MAX_JSON_MB`) and its syntax
    refused in one line naming the file (:class:`LimitError` / ``ValueError``)."""
    import json
    from pathlib import Path

    path = Path(path)
    data = read_bounded(path, what, _env_float("BLENAV_MAX_JSON_MB", DEFAULT_MAX_JSON_MB) * MIB, "BLENAV_MAX_JSON_MB")
    try:
        return json.loads(data.decode("utf-8"))
    except UnicodeDecodeError as exc:
        raise ValueError(f"{path}: not UTF-8 text ({exc.reason} at byte {exc.start})") from None
    except json.JSONDecodeError as exc:
        raise ValueError(f"{path}: not JSON ({exc.msg}: line {exc.lineno} column {exc.colno})") from None
    except RecursionError:
        raise ValueError(f"{path}: nested too deeply to read") from None
    except ValueError as exc:  # an integer of more than 4,300 digits (int's conversion limit)
        raise ValueError(f"{path}: not readable JSON ({' '.join(str(exc).split())[:160]})") from None


def max_archive_ratio() -> float:
    """Most the members read may expand relative to the archive's size: ``BLENAV_MAX_ARCHIVE_RATIO`` (default
    200), beyond :data:`ARCHIVE_RATIO_FREE_MB`."""
    return _env_float("BLENAV_MAX_ARCHIVE_RATIO", DEFAULT_MAX_ARCHIVE_RATIO)
