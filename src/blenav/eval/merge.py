"""Several evaluations' results.json as one: per session and method (:func:`load_columns`), and the leaderboard over
a fleet of datasets (:func:`merge_leaderboard`: per method its RMSE on each dataset and pooled over every session of
every dataset it ran on; the best method's distance to the PCRLB per simulated dataset).

The tables are written by :mod:`blenav.reporting.merge` (``python -m blenav.cli.tables merge | leaderboard ...``).
"""

from __future__ import annotations

import json
from pathlib import Path

__all__ = ["load_columns", "result_folders", "merge_leaderboard"]


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
