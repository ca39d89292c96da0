"""Position fixes from an exported localizer, written to ``fixes.csv`` for other consumers.

:func:`session_fixes` runs an :class:`OnnxLocalizer` over every window of a session (window ends at
``1 / step_hz`` steps, the windowing of :func:`blenav.features.windows.session_windows`) and returns the
fixes (t s, x y m world) of the windows in which at least one beacon was heard; :func:`write_model_fixes`
does so for sessions of a dataset and merges them into each session's ``fixes.csv`` under one
``source``, with the model's own std per fix in the ``std`` column when the graph states one (``std_m``: a LocNet with a
std head, calibrated on its validation walks; empty otherwise) (rows of other sources are kept; see :func:`blenav.data.writer.write_fixes`). The particle
filter reads them with :class:`blenav.filters.measurement.FixLikelihood` (eq. 3.9, Roy).

:func:`calibrate_model_fixes` measures, on labelled sessions, how much a fix is worth as a measurement:
eq. 3.9 takes every fix as an independent N(x, sigma^2 I) draw with sigma = 3 m. A learned localizer's errors
are neither 3 m nor independent: neighbouring windows share 4 of their 5 steps, and a phone standing in a
bad spot gives the same error for tens of seconds. :func:`fix_error_stats` gives the per-axis RMS error
sigma, the integrated autocorrelation time tau (in fixes) and sigma_eff = sigma sqrt(tau): n fixes with
correlation time tau carry the information of n / tau independent ones, so weighting each by sigma_eff
gives the filter the right total confidence (our calibration, not part of Roy's method).
"""

from __future__ import annotations

import logging
from pathlib import Path

import numpy as np

from blenav.features.windows import WindowConfig, session_windows

from .calibration import coverage, std_scale_fit
from .onnx_localizer import OnnxLocalizer

log = logging.getLogger("blenav.runtime.fixes")


def _predict_windows(model: OnnxLocalizer, session):
    """(the session's windows with the model's window settings, predicted xy (W, 2), std (W,) m or None; NaN rows:
    nothing heard)."""
    w = model.meta["window"]
    wcfg = WindowConfig(history=int(w["history"]), step_hz=float(w["step_hz"]), offset_db=float(w["offset_db"]),
                        floor_u=float(w["floor_u"]), beacon_subset=model.beacon_subset)
    win = session_windows(session, model.beacons, wcfg)
    return (win, *model.predict_std(win.S))


def _fixes(model: OnnxLocalizer, session):
    """(t (F,), xy (F, 2), std (F,) m or None, number of windows without any beacon heard) for one session; a std
    the graph gave as no finite positive number (a float32 overflow) is unknown (NaN,
    :meth:`~blenav.runtime.onnx_localizer.LocalizerSession.predict_windows_std`), counted in the log."""
    win, xy, std = _predict_windows(model, session)
    ok = np.isfinite(xy).all(axis=1)
    if std is not None:
        std = std[ok]
        bad = ~np.isfinite(std)
        if bad.any():
            log.warning("session %s: %d of %d fixes have no finite positive std from %s; written as unknown",
                        session.id, int(bad.sum()), len(std), model.path)
    return win.t[ok], xy[ok], std, int((~ok).sum())


def session_fixes(model: OnnxLocalizer, session) -> tuple[np.ndarray, np.ndarray, int]:
    """(t (F,), xy (F, 2), number of windows without any beacon heard) for one session."""
    t, xy, _, silent = _fixes(model, session)
    return t, xy, silent


def fix_error_stats(errors: list[np.ndarray], rho_stop: float = 0.05, max_lag: int = 600) -> dict:
    """Error statistics of fixes against ground truth, pooled over sessions.

    ``errors``: per session (F_i, 2) fix errors (fix - truth, m) at consecutive fix times (one per step).
    sigma: sqrt(mean e^2) per axis (m); rho(k) = sum e_t e_(t+k) / sum e_t^2 pooled over sessions and both
    axes (uncentred: a persistent bias is correlated error too); tau = 1 + 2 sum_(k=1..K) rho(k) with K the
    last lag before rho drops below ``rho_stop`` (at most ``max_lag``); sigma_eff = sigma sqrt(tau)."""
    errs = [np.asarray(e, float) for e in errors if len(e)]
    if not errs:
        raise ValueError("no fixes with ground truth to calibrate on")
    if any(not np.isfinite(e).all() for e in errs):
        raise ValueError("fix errors contain NaN or inf")
    sq = sum(float((e * e).sum()) for e in errs)
    n = sum(e.shape[0] for e in errs)
    sigma = float(np.sqrt(sq / (2 * n)))
    tau, lag = 1.0, 0
    for k in range(1, min(max_lag, max(e.shape[0] for e in errs))):  # lags, vectorised over fixes
        rho = sum(float((e[k:] * e[:-k]).sum()) for e in errs if e.shape[0] > k) / sq
        if rho < rho_stop:
            break
        tau += 2.0 * rho
        lag = k
    return {"sigma_m": sigma, "tau_fixes": tau, "sigma_eff_m": sigma * float(np.sqrt(tau)), "last_lag": lag,
            "fixes": int(n), "rmse_m": float(np.sqrt(sq / n))}


def _sessions_with_model(dataset, model_path: str | Path, session_ids=None):
    """(session, the model loaded and checked once per building) for the chosen sessions of ``dataset``."""
    models: dict[str, OnnxLocalizer] = {}
    for s in dataset.sessions(session_ids):
        if s.building.id not in models:
            models[s.building.id] = OnnxLocalizer(model_path, building=s.building)
        yield s, models[s.building.id]


def calibrate_model_fixes(dataset, model_path: str | Path, session_ids=None) -> dict:
    """:func:`fix_error_stats` of an exported localizer's fixes on labelled sessions of ``dataset`` (every
    window end with a fix and ground truth); adds ``sessions`` (the ids used) and ``trained_on`` (those of
    them whose windows the model saw in training, by its ``train_sessions`` metadata: their errors
    understate what unseen walks give; None when the model does not record its sessions) and, for a model that
    states a std per fix (``std_m``), ``stated_std``: the share of those fixes within 1 / 2 of their stated std (a
    2-D Gaussian: 39 / 86 %), the maximum-likelihood scale that would calibrate it on these walks (1: calibrated) and
    its rank correlation with the error (:func:`blenav.runtime.calibration.std_scale_fit`)."""
    errors, stds, used, trained = [], [], [], None
    for s, model in _sessions_with_model(dataset, model_path, session_ids):
        if trained is None:
            seen = model.meta.get("train_sessions")
            trained = set(seen) if seen is not None else None
        if not s.labelled:
            continue
        win, xy, std = _predict_windows(model, s)
        ok = np.isfinite(xy).all(axis=1) & np.isfinite(win.xy).all(axis=1)
        errors.append(xy[ok] - win.xy[ok])
        if std is not None:
            stds.append(std[ok])
        used.append(s.id)
    if not used:
        raise ValueError("no labelled session (ground truth) among the chosen sessions: calibration needs truth")
    overlap = sorted(set(used) & trained) if trained is not None else None
    if overlap:
        log.warning("sessions %s trained the model: their fix errors understate what unseen walks give", overlap)
    out = {**fix_error_stats(errors), "sessions": used, "trained_on": overlap}
    if stds:
        err, sd = np.linalg.norm(np.concatenate(errors), axis=1), np.concatenate(stds)
        fine = np.isfinite(sd)  # predict_windows_std: a std is unknown (NaN) or at least MIN_FIX_STD_M
        scale, fit = std_scale_fit(err, sd)
        out["stated_std"] = {"fixes": int(fine.sum()), **coverage(err[fine], sd[fine]),
                             "ml_scale": scale if "uncalibrated" not in fit else None,
                             "rank_correlation": fit.get("rank_correlation")} if fine.any() else None
    return out


def write_model_fixes(dataset, model_path: str | Path, source: str, session_ids=None) -> dict[str, dict]:
    """Write fixes for the chosen sessions (default: all) of ``dataset``; returns per session
    {"fixes": count, "no_beacon_windows": count, "path": fixes.csv, "std": whether the rows carry the model's std}.
    The model must match the building."""
    from blenav.data.writer import write_fixes

    report = {}
    for s, model in _sessions_with_model(dataset, model_path, session_ids):
        t, xy, std, silent = _fixes(model, s)
        if len(t) == 0:
            report[s.id] = {"fixes": 0, "no_beacon_windows": silent, "path": None, "std": std is not None}
            continue
        path = write_fixes(s.root, t, xy, std, source=source)
        report[s.id] = {"fixes": int(len(t)), "no_beacon_windows": silent, "path": str(path), "std": std is not None}
    return report
