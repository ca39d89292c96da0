"""What every evaluation shares: its error type and JSON writing."""

from __future__ import annotations

import json
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


def write_json(path: Path, obj) -> None:
    Path(path).write_text(json.dumps(obj, indent=1, default=json_default), encoding="utf-8")
