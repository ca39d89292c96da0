"""What every evaluation shares: JSON of numpy values, output names and atomic file writing."""

from __future__ import annotations

import json
import os
from pathlib import Path

import numpy as np

from blenav.errors import EvalError


def json_default(o):
    """JSON for numpy scalars and arrays (``json.dumps(..., default=json_default)``)."""
    if isinstance(o, (np.floating, np.integer)):
        return o.item()
    if isinstance(o, np.ndarray):
        return o.tolist()
    raise TypeError(f"not JSON serialisable: {type(o)}")


def output_name(name: str) -> str:
    """A session id or method label as a file or folder name in OUT ('RTT+BLE/online' -> 'RTT+BLE_online'): every
    character but letters, digits and ``+-_.=`` becomes ``_``. The one mapping every per-session / per-method output
    uses, so :func:`check_output_names` can refuse names that would share a file."""
    return "".join(c if c.isalnum() or c in "+-_.=" else "_" for c in str(name))


def check_output_names(names, what: str = "session") -> None:
    """Refuse ``names`` (session ids, method labels) of which two map to one :func:`output_name`: the later's files
    would overwrite the earlier's (``s 000`` and ``s_000`` both write ``OUT/s_000``). Raises :class:`EvalError`
    naming both, before any work."""
    seen: dict[str, str] = {}
    for n in map(str, names):
        o = output_name(n)
        if o in seen and seen[o] != n:
            raise EvalError(f"{what}s {seen[o]!r} and {n!r} would both be written to the output folder {o!r} "
                            f"(characters other than letters, digits and +-_.= become _): rename one of them")
        seen[o] = n


def write_text(path: Path, text: str) -> Path:
    """Write ``text`` (UTF-8) to ``path`` atomically: into a temporary file in the same folder, then
    ``os.replace`` -- a reader (or a run cut short by an error, Ctrl-C or a full disk) sees the old file or the
    new one, never half of one; the temporary file is removed on failure."""
    path = Path(path)
    tmp = path.with_name(f".{path.name}.tmp-{os.getpid()}")
    try:
        with open(tmp, "w", encoding="utf-8") as f:
            f.write(text)
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, path)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise
    return path


def finite_json(obj):
    """``obj`` with every NaN or infinite number (Python or numpy, in dicts, lists, tuples and arrays) as None: what
    strict JSON can hold (``NaN`` is not JSON; other readers refuse it). Other values as they are."""
    if isinstance(obj, dict):
        return {k: finite_json(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [finite_json(v) for v in obj]
    if isinstance(obj, np.ndarray):
        return finite_json(obj.tolist())
    if isinstance(obj, np.generic):  # numpy bool / int / float scalars as Python values
        obj = obj.item()
    if isinstance(obj, float) and not np.isfinite(obj):
        return None
    return obj


def write_json(path: Path, obj) -> Path:
    """``obj`` as indented, strict JSON (numpy values converted, :func:`json_default`; a non-finite number written as
    null, :func:`finite_json`), written atomically (:func:`write_text`)."""
    return write_text(path, json.dumps(finite_json(obj), indent=1, default=json_default, allow_nan=False))
