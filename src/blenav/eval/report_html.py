"""``OUT/report.html``: one self-contained page of an evaluation (issue 33, section 3), written at the end of every
``blenav eval`` (unless ``report=false``) and by ``blenav report OUT``.

What the page shows comes from the evaluation's own files, read back as a stranger's (sizes bounded):
``results.json`` (the leaderboard, the skipped methods and why), the per-session TUM trajectories
``OUT/<session>/trajectories/<method>.tum`` (run 0 of each method, and ``groundtruth.tum``) and the dataset's floor
plan (``results.json``'s ``dataset``, when it is still there). The page itself is drawn by
:func:`blenav.plotting.html.render_report` (plotly, inlined: it works offline).

Errors for the CDFs are those of run 0 against the ground truth interpolated at each estimate's time (the same
definition as :func:`blenav.eval.metrics.errors_vs_groundtruth`), over every session; the tables are results.json's.
"""

from __future__ import annotations

import io
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from blenav.limits import check_memory, max_member_bytes, read_bounded, read_json

from .common import output_name, write_text
from .metrics import errors_at_waypoints, errors_vs_groundtruth

#: the most sessions drawn as trajectory panels (the tables cover every session)
MAX_SESSIONS = 12
#: the floor plan is drawn at most this many cells along its longer side
MAX_PLAN_CELLS = 400


@dataclass
class SessionView:
    """One session's tracks: ``tracks[method] = (t (K,), xy (K, 2))`` of run 0; ``gt`` the ground truth; ``plan``:
    (occupied (H, W) bool, row 0 at the top, extent (x0, x1, y0, y1) in m) or None."""

    id: str
    gt: tuple[np.ndarray, np.ndarray] | None
    tracks: dict[str, tuple[np.ndarray, np.ndarray]]
    plan: tuple[np.ndarray, tuple[float, float, float, float]] | None = None


@dataclass
class ReportData:
    title: str
    experiment: str
    results: dict
    sessions: list[SessionView] = field(default_factory=list)
    errors: dict[str, np.ndarray] = field(default_factory=dict)  #: method -> errors of run 0 over all sessions (m)
    skipped: dict[str, dict[str, str]] = field(default_factory=dict)  #: method -> session -> why
    notes: list[str] = field(default_factory=list)
    versus: list[str] = field(default_factory=list)  #: each learned row beside its simplest baseline (one sentence)


def read_tum(path: Path) -> tuple[np.ndarray, np.ndarray]:
    """(t (K,), xy (K, 2)) of a TUM file (``t x y z qx qy qz qw``), its size bounded (``BLENAV_MAX_ARCHIVE_MEMBER_MB``);
    ValueError naming the file when it is not numeric or has fewer than 3 columns; rows with a non-finite value
    dropped."""
    data = read_bounded(path, "trajectory", max_member_bytes(), "BLENAV_MAX_ARCHIVE_MEMBER_MB")
    try:
        a = np.loadtxt(io.BytesIO(data), dtype=float, ndmin=2, comments="#")
    except ValueError as exc:
        raise ValueError(f"{path}: not a TUM trajectory (t x y z qx qy qz qw): {exc}") from None
    if a.size == 0:
        return np.zeros(0), np.zeros((0, 2))
    if a.shape[1] < 3:
        raise ValueError(f"{path}: {a.shape[1]} column(s); a TUM trajectory has t x y z qx qy qz qw")
    a = a[np.isfinite(a[:, :3]).all(axis=1)]
    order = np.argsort(a[:, 0], kind="stable")
    return a[order, 0], a[order, 1:3]


def track_errors(t: np.ndarray, xy: np.ndarray, gt_t: np.ndarray, gt_xy: np.ndarray, sparse: bool) -> np.ndarray:
    """Errors (m) of a track against the ground truth: dense ground truth interpolated at the estimate times
    (:func:`blenav.eval.metrics.errors_vs_groundtruth`); sparse surveyed waypoints: the estimate interpolated at
    every waypoint time, held at its ends (:func:`blenav.eval.metrics.errors_at_waypoints` with ``hold_ends``, as the
    experiments on waypoint walks score them, ``scoring.hold_ends: true``)."""
    if not sparse:
        return errors_vs_groundtruth(t, xy[None], gt_t, gt_xy)[0][0]
    return errors_at_waypoints(t, xy[None], gt_t, gt_xy, hold_ends=True)[0][0]


def _plan(session) -> tuple[np.ndarray, tuple[float, float, float, float]] | None:
    """The session's floor as occupied cells, subsampled to at most :data:`MAX_PLAN_CELLS` along its longer side."""
    try:
        fl = session.floor
        occ = fl.occupancy
    except Exception:  # noqa: BLE001 -- a plan that cannot be read: the page draws the tracks without it
        return None
    step = max(1, int(np.ceil(max(occ.shape) / MAX_PLAN_CELLS)))
    return occ[::step, ::step] == 1, fl.extent


def report_data(out: Path, title: str | None = None, data: str | None = None) -> ReportData:
    """Everything the page draws, read from the evaluation folder ``out`` (see the module docstring). ``data``: the
    dataset whose floor plans are drawn (default: results.json's ``dataset``; ``""``: none). The trajectory files
    read are bounded each (``BLENAV_MAX_ARCHIVE_MEMBER_MB``) and together (``BLENAV_MAX_MEMORY_GB``)."""
    out = Path(out)
    if not (out / "results.json").is_file():
        raise FileNotFoundError(f"{out} has no results.json: not the output folder of an evaluation (blenav eval)")
    res = read_json(out / "results.json", "results.json")
    if not isinstance(res, dict) or not isinstance(res.get("methods"), dict):
        raise ValueError(f"{out / 'results.json'}: no 'methods' table (not written by blenav eval?)")
    page = ReportData(title=title or str(res.get("title") or res.get("experiment") or out.name),
                      experiment=str(res.get("experiment", "")), results=res)
    for name, m in res["methods"].items():
        if isinstance(m, dict) and m.get("skipped"):
            page.skipped[name] = {str(k): str(v) for k, v in m["skipped"].items()}
    dataset, where = None, res.get("dataset") if data is None else data
    if where:
        try:
            from blenav.data import Dataset

            dataset = Dataset.open(where)
        except Exception as exc:  # noqa: BLE001 -- moved or deleted since: tracks without the plan
            page.notes.append(f"floor plans not drawn: the dataset {where} cannot be opened "
                              f"({' '.join(str(exc).split())[:160]})")
    errs: dict[str, list[np.ndarray]] = {}
    total = 0
    ids = [str(s) for s in res.get("sessions", [])] or sorted(p.name for p in out.iterdir() if (p / "trajectories").is_dir())
    for sid in ids:
        d = out / output_name(sid) / "trajectories"
        if not d.is_dir():
            continue
        gt_path = d / "groundtruth.tum"
        files = [gt_path, *(d / f"{output_name(n)}.tum" for n in res["methods"])]
        total += sum(f.stat().st_size for f in files if f.is_file())
        check_memory(3 * total, f"the trajectory files read so far ({total:,} bytes of text)", str(out))
        gt = read_tum(gt_path) if gt_path.is_file() else None
        session = dataset.session(sid) if dataset is not None and sid in dataset.session_ids else None
        # waypoint walks: results.json says so (the evaluation scored them at their waypoints), the dataset or not
        sparse = any("waypoints" in (((m.get("per_session") or {}).get(sid)) or {}) for m in res["methods"].values()
                     if isinstance(m, dict) and isinstance(m.get("per_session"), dict)) \
            or bool(getattr(session, "groundtruth_sparse", False))
        tracks = {}
        for name in res["methods"]:
            p = d / f"{output_name(name)}.tum"
            if p.is_file():
                t, xy = read_tum(p)
                if len(t):
                    tracks[name] = (t, xy)
                    if gt is not None and len(gt[0]) > 1:
                        errs.setdefault(name, []).append(track_errors(t, xy, gt[0], gt[1], sparse))
        if len(page.sessions) < MAX_SESSIONS and (tracks or gt is not None):
            page.sessions.append(SessionView(sid, gt, tracks, _plan(session) if session is not None else None))
    if len(ids) > MAX_SESSIONS:
        page.notes.append(f"trajectories of the first {MAX_SESSIONS} of {len(ids)} sessions drawn")
    page.errors = {k: np.concatenate(v) for k, v in errs.items()}
    page.versus = learned_vs_baseline(res["methods"])
    return page


def _score(m) -> tuple[str, float] | None:
    """(what, value) a row is ranked by: its RMSE, else its mean error (waypoint walks)."""
    for key in ("rmse_m", "error_m"):
        v = m.get(key) if isinstance(m, dict) else None
        if isinstance(v, dict) and isinstance(v.get("mean"), (int, float)) and np.isfinite(v["mean"]):
            return ("RMSE" if key == "rmse_m" else "mean error"), float(v["mean"])
    return None


def _is_learned(name: str, m: dict) -> bool:
    return (m.get("family") == "learned" or name.startswith(("LocNet", "TransNet", "LIO", "Net-"))
            or (m.get("family") == "fingerprint" and not name.startswith("KNN")))


def _is_baseline(name: str) -> bool:
    return name.startswith(("KNN", "PDR")) and "learned" not in name


def _training_note(m: dict) -> str:
    """What a learned row's results.json says of its training (steps, why it stopped, validation vs KNN)."""
    tr = m.get("training")
    runs = [f.get("training") for f in (tr.get("floors") or {}).values()] if isinstance(tr, dict) else []
    runs = [r for r in runs if isinstance(r, dict)]
    if not runs:
        return ""
    r = runs[0]
    bits = [f"{r.get('steps')} steps (stopped: {r.get('stop_reason')}, "
            f"{'converged' if r.get('converged') else 'not converged'})"]
    if r.get("best_val_error_m") is not None and r.get("knn_val_error_m") is not None:
        bits.append(f"validation {r['best_val_error_m']:.2f} m vs KNN {r['knn_val_error_m']:.2f} m")
    more = f" (and {len(runs) - 1} more floor(s))" if len(runs) > 1 else ""
    return "; its training: " + ", ".join(bits) + more


def learned_vs_baseline(methods: dict) -> list[str]:
    """One sentence per learned row that ran: its error beside its simplest baseline's on the same walks (the KNN of
    the same features, ``LocNet-BLE`` -> ``KNN-BLE``; else the best KNN / PDR row), whether it is ahead or behind,
    and what its training report says (a model that trails says why, as far as results.json knows)."""
    rows = {n: m for n, m in methods.items() if isinstance(m, dict) and _score(m) is not None}
    base = {n: _score(m) for n, m in rows.items() if _is_baseline(n)}
    out = []
    for name, m in rows.items():
        if not _is_learned(name, m) or not base:
            continue
        if name.startswith("LIO"):  # learned odometry: beside PDR (with the same map where there is one)
            pool = {b: v for b, v in base.items() if b.startswith("PDR")}
            same = [b for b in pool if b == name.replace("LIO", "PDR", 1)]
        else:
            pool = base
            suffix = name.split("-", 1)[1] if "-" in name else None
            same = [b for b in base if suffix and b.endswith("-" + suffix)]
        if not pool:
            continue
        ref = same[0] if same else min(pool, key=lambda b: pool[b][1])
        what, v = _score(m)
        _, bv = base[ref]
        verdict = "ahead of" if v < bv else "behind"
        out.append(f"{name} {v:.2f} m ({what}) is {verdict} {ref} {bv:.2f} m on these walks{_training_note(m)}.")
    return out


def write_report(out: Path, page: Path | None = None, title: str | None = None, data: str | None = None) -> Path:
    """Write the page of the evaluation folder ``out`` to ``page`` (default ``out/report.html``), atomically;
    ``data``: see :func:`report_data`."""
    from blenav.plotting.html import render_report

    page = Path(page) if page is not None else Path(out) / "report.html"
    return write_text(page, render_report(report_data(out, title, data)))
