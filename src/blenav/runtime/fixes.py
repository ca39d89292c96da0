"""Position fixes from an exported localizer, written to ``fixes.csv`` for other consumers.

:func:`session_fixes` runs an :class:`OnnxLocalizer` over every window of a session (window ends at
``1 / step_hz`` steps, the windowing of :func:`blenav.learn.windows.session_windows`) and returns the
fixes (t s, x y m world) of the windows in which at least one beacon was heard; :func:`write_model_fixes`
does so for sessions of a dataset and merges them into each session's ``fixes.csv`` under one
``source`` (rows of other sources are kept; see :func:`blenav.data.writer.write_fixes`). The particle
filter reads them with :class:`blenav.filters.measurement.FixLikelihood` (eq. 3.9, Roy).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from blenav.learn.windows import WindowConfig, session_windows

from .onnx_localizer import OnnxLocalizer


def session_fixes(model: OnnxLocalizer, session) -> tuple[np.ndarray, np.ndarray, int]:
    """(t (F,), xy (F, 2), number of windows without any beacon heard) for one session."""
    w = model.meta["window"]
    wcfg = WindowConfig(history=int(w["history"]), step_hz=float(w["step_hz"]), offset_db=float(w["offset_db"]),
                        floor_u=float(w["floor_u"]), beacon_subset=model.beacon_subset)
    win = session_windows(session, model.beacons, wcfg)
    xy = model.predict(win.S)
    ok = np.isfinite(xy).all(axis=1)
    return win.t[ok], xy[ok], int((~ok).sum())


def write_model_fixes(dataset, model_path: str | Path, source: str, session_ids=None) -> dict[str, dict]:
    """Write fixes for the chosen sessions (default: all) of ``dataset``; returns per session
    {"fixes": count, "no_beacon_windows": count, "path": fixes.csv}. The model must match the building."""
    from blenav.data.writer import write_fixes

    report = {}
    models: dict[str, OnnxLocalizer] = {}
    for s in dataset.sessions(session_ids):
        if s.building.id not in models:
            models[s.building.id] = OnnxLocalizer(model_path, building=s.building)
        t, xy, silent = session_fixes(models[s.building.id], s)
        if len(t) == 0:
            report[s.id] = {"fixes": 0, "no_beacon_windows": silent, "path": None}
            continue
        path = write_fixes(s.root, t, xy, source=source)
        report[s.id] = {"fixes": int(len(t)), "no_beacon_windows": silent, "path": str(path)}
    return report
