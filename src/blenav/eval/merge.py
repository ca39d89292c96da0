"""Several evaluations' results.json as one: per session and method (:func:`load_columns`), and the leaderboard over
a fleet of datasets (:func:`merge_leaderboard`: per method its RMSE on each dataset and pooled over every session of
every dataset it ran on; the best method's distance to the PCRLB per simulated dataset).

The tables are written by :mod:`blenav.reporting.merge` (``python -m blenav.cli.tables merge | leaderboard ...``).
"""

from __future__ import annotations

import json
from pathlib import Path

__all__ = ["load_columns", "result_folders", "merge_leaderboard", "merge_runs"]


def load_columns(runs: list[tuple[Path, str]]) -> tuple[dict[str, dict[str, float]], list[str]]:
    """{column: {session: RMSE mean}} and the sessions in first-seen order."""
    cols: dict[str, dict[str, float]] = {}
    sessions: list[str] = []
    for folder, prefix in runs:
        res = json.loads((Path(folder) / "results.json").read_text(encoding="utf-8"))
        for name, m in res["methods"].items():
            for sid, v in (m.get("per_session") or {}).items():
                cols.setdefault(prefix + name, {})[sid] = float(v["rmse_m"]["mean"])
                if sid not in sessions:
                    sessions.append(sid)
    return cols, sessions


def result_folders(paths: list[Path]) -> list[Path]:
    """Every folder with a results.json among ``paths`` and their direct sub-folders (a multirun's jobs,
    in numeric order when their names are numbers)."""
    out: list[Path] = []
    for p in map(Path, paths):
        if (p / "results.json").is_file():
            out.append(p)
            continue
        subs = [d for d in p.iterdir() if (d / "results.json").is_file()] if p.is_dir() else []
        if not subs:
            raise FileNotFoundError(f"{p}: no results.json there nor in its sub-folders")
        out += sorted(subs, key=lambda d: (not d.name.isdigit(), int(d.name) if d.name.isdigit() else 0, d.name))
    return out


def merge_leaderboard(folders: list[Path]) -> dict:
    """``{"datasets": [{"name", "dataset", "folder", "sessions", "runs"}], "methods": {name: {"family",
    "rmse_m": {dataset name: mean}, "pooled_rmse_m", "sessions", "datasets", "skipped": {dataset name: reason}}},
    "best": {dataset name: {"method", "rmse_m", "bound_m", "ratio"}}}``. Pooled RMSE: the mean of the per-session
    RMSEs (each the mean over runs) over every session of every dataset, as one evaluation of all of them."""
    datasets, methods, best = [], {}, {}
    names: dict[str, int] = {}
    for f in folders:
        res = json.loads((Path(f) / "results.json").read_text(encoding="utf-8"))
        base = Path(str(res.get("dataset", f))).name or str(f)
        names[base] = names.get(base, 0) + 1
        name = base if names[base] == 1 else f"{base} ({names[base]})"
        datasets.append({"name": name, "dataset": res.get("dataset"), "folder": str(f), "sessions": res.get("sessions", []),
                         "runs": res.get("runs")})
        for m_name, m in res["methods"].items():
            row = methods.setdefault(m_name, {"family": m.get("family", "-"), "rmse_m": {}, "_per_session": [],
                                              "skipped": {}})
            if "rmse_m" in m:
                row["rmse_m"][name] = float(m["rmse_m"]["mean"])
                row["_per_session"] += [float(v["rmse_m"]["mean"]) for v in (m.get("per_session") or {}).values()]
            elif "skipped" in m:
                row["skipped"][name] = "; ".join(sorted(set(map(str, m["skipped"].values()))))
        b = (res["methods"].get("PCRLB") or {}).get("best")
        if b:
            best[name] = {"method": b["method"], "rmse_m": b["rmse_m"], "bound_m": res["methods"]["PCRLB"]["rmse_m"]["mean"],
                          "ratio": b["ratio"]}
    for row in methods.values():
        ps = row.pop("_per_session")
        row["pooled_rmse_m"] = float(sum(ps) / len(ps)) if ps else None
        row["sessions"], row["datasets"] = len(ps), len(row["rmse_m"])
    return {"datasets": datasets, "methods": methods, "best": best}


#: what the jobs of one fan-out share; results of jobs that differ in any of them are not one evaluation
SAME_KEYS = ("experiment", "dataset", "runs", "sessions", "init_s", "seed", "calibration", "split")


def merge_runs(folders: list[Path], out: Path) -> dict:
    """The jobs of a fan-out over methods (``blenav eval -m only=A,B ... 'out=FAN/${hydra:job.num}'``) as the one
    evaluation they split: ``out/results.json`` with every job's methods (in the jobs' order), each session's TUM
    trajectories beside it (``out/<session>/trajectories``) and ``out/report.html``. The jobs must share
    :data:`SAME_KEYS` (ValueError naming the key and the folders) and no method may come from two jobs. Returns the
    merged results."""
    import shutil

    from blenav.limits import read_json

    from .common import write_json

    folders = result_folders(folders)
    if len(folders) < 1:
        raise ValueError("name the output folders of the jobs to merge")
    out = Path(out)
    if out.exists() and any(out.iterdir()):
        raise ValueError(f"{out} exists and is not empty: merge into a new folder")
    results = [read_json(f / "results.json", "results.json") for f in folders]
    for f, r in zip(folders, results):
        if not isinstance(r, dict) or not isinstance(r.get("methods"), dict):
            raise ValueError(f"{f / 'results.json'}: no 'methods' table (not written by blenav eval?)")
    first = results[0]
    for key in SAME_KEYS:
        for f, r in zip(folders[1:], results[1:]):
            if r.get(key) != first.get(key):
                raise ValueError(f"{key} differs: {first.get(key)!r} in {folders[0]}, {r.get(key)!r} in {f}: these "
                                 "are not jobs of one evaluation")
    merged = dict(first)
    merged["methods"] = {}
    owner: dict[str, Path] = {}
    for f, r in zip(folders, results):
        for name, m in r["methods"].items():
            if name in merged["methods"]:
                raise ValueError(f"method {name} is in {owner[name]} and in {f}: each job of a fan-out over methods "
                                 "runs its own (only=...)")
            merged["methods"][name], owner[name] = m, f
    merged["merged_from"] = [str(f) for f in folders]
    out.mkdir(parents=True, exist_ok=True)
    for f in folders:
        for traj in sorted(f.glob("*/trajectories")):
            dest = out / traj.parent.name / "trajectories"
            dest.mkdir(parents=True, exist_ok=True)
            for tum in traj.glob("*.tum"):
                if not (dest / tum.name).exists():
                    shutil.copyfile(tum, dest / tum.name)
    write_json(out / "results.json", merged)
    return merged
