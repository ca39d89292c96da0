"""Several evaluations' results.json as one: per session and method (:func:`load_columns`), and the leaderboard over
a fleet of datasets (:func:`merge_leaderboard`: per method its RMSE on each dataset and pooled over every session of
every dataset it ran on; the best method's distance to the PCRLB per simulated dataset).

The tables are written by :mod:`blenav.reporting.merge` (``python -m blenav.cli.tables merge | leaderboard ...``).
"""

from __future__ import annotations

from pathlib import Path

from blenav.limits import read_json

from .metrics import best_against_bound, finite_number, rmse_mean

__all__ = ["load_columns", "result_folders", "merge_leaderboard", "merge_runs"]


def _read_methods(path: Path) -> dict:
    """``path``'s results (results.json of blenav eval); ValueError naming the file when it has no ``methods`` table or
    a method that is not one."""
    res = read_json(path, "results.json")
    if not isinstance(res, dict) or not isinstance(res.get("methods"), dict):
        raise ValueError(f"{path}: no 'methods' table (not written by blenav eval?)")
    for name, m in res["methods"].items():
        if not isinstance(m, dict):
            raise ValueError(f"{path}: methods.{name} is not a table")
    return res


def _rmse(m, path: Path, where: str) -> float:
    """A row's ``rmse_m.mean`` (:func:`rmse_mean`); ValueError naming the file and the field when it is not a finite
    number."""
    v = rmse_mean(m)
    if v is None:
        raise ValueError(f"{path}: {where}.rmse_m.mean is missing or not a finite number")
    return v


def _number(d: dict, key: str, path: Path, where: str) -> float:
    v = finite_number(d.get(key))
    if v is None:
        raise ValueError(f"{path}: {where}.{key} is missing or not a finite number")
    return v


def _per_session(m, path: Path, where: str) -> dict:
    ps = m.get("per_session")
    if ps is not None and not isinstance(ps, dict):
        raise ValueError(f"{path}: {where}.per_session is not a table")
    return ps or {}


def load_columns(runs: list[tuple[Path, str]]) -> tuple[dict[str, dict[str, float]], list[str]]:
    """{column: {session: RMSE mean}} and the sessions in first-seen order."""
    cols: dict[str, dict[str, float]] = {}
    sessions: list[str] = []
    for folder, prefix in runs:
        path = Path(folder) / "results.json"
        for name, m in _read_methods(path)["methods"].items():
            for sid, v in _per_session(m, path, f"methods.{name}").items():
                cols.setdefault(prefix + name, {})[sid] = _rmse(v, path, f"methods.{name}.per_session.{sid}")
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
        path = Path(f) / "results.json"
        res = _read_methods(path)
        base = Path(str(res.get("dataset", f))).name or str(f)
        names[base] = names.get(base, 0) + 1
        name = base if names[base] == 1 else f"{base} ({names[base]})"
        datasets.append({"name": name, "dataset": res.get("dataset"), "folder": str(f), "sessions": res.get("sessions", []),
                         "runs": res.get("runs")})
        for m_name, m in res["methods"].items():
            row = methods.setdefault(m_name, {"family": str(m.get("family", "-")), "rmse_m": {}, "_per_session": [],
                                              "skipped": {}})
            if "rmse_m" in m:
                where = f"methods.{m_name}"
                row["rmse_m"][name] = _rmse(m, path, where)
                row["_per_session"] += [_rmse(v, path, f"{where}.per_session.{sid}")
                                        for sid, v in _per_session(m, path, where).items()]
            elif "skipped" in m:
                why = m["skipped"]
                row["skipped"][name] = "; ".join(sorted(set(map(str, why.values() if isinstance(why, dict) else [why]))))
        b = res["methods"].get("PCRLB", {}).get("best")
        if b:
            where = "methods.PCRLB.best"
            if not isinstance(b, dict):
                raise ValueError(f"{path}: {where} is not a table")
            best[name] = {"method": str(b.get("method")), "rmse_m": _number(b, "rmse_m", path, where),
                          "bound_m": _rmse(res["methods"]["PCRLB"], path, "methods.PCRLB"),
                          "ratio": _number(b, "ratio", path, where)}
    for row in methods.values():
        ps = row.pop("_per_session")
        row["pooled_rmse_m"] = float(sum(ps) / len(ps)) if ps else None
        row["sessions"], row["datasets"] = len(ps), len(row["rmse_m"])
    return {"datasets": datasets, "methods": methods, "best": best}


#: what the jobs of one fan-out share; results of jobs that differ in any of them are not one evaluation
SAME_KEYS = ("experiment", "dataset", "runs", "sessions", "init_s", "seed", "split")


def _is_bound(m) -> bool:
    return isinstance(m, dict) and m.get("kind") == "bound"


def merge_results(folders: list[Path], results: list[dict]) -> dict:
    """The results.json of the jobs (``results[i]`` read from ``folders[i]``) as one: every job's methods in the jobs'
    order; the rows every job computes alike (the leaderboard's PCRLB bounds, ``kind: bound``) once, their
    ``best`` recomputed over the merged methods; the other top-level keys from the first job, dictionaries joined
    over the jobs (``fixes``, ``model``: what each job's methods used) and ``calibration`` from the job that
    fitted one (a job whose methods fit none has None). ValueError when a key of :data:`SAME_KEYS` or a fitted
    calibration differs, or a method comes from two jobs."""
    first = results[0]
    for key in SAME_KEYS:
        for f, r in zip(folders[1:], results[1:]):
            if r.get(key) != first.get(key):
                raise ValueError(f"{key} differs: {first.get(key)!r} in {folders[0]}, {r.get(key)!r} in {f}: these "
                                 "are not jobs of one evaluation")
    cals = [(f, r.get("calibration")) for f, r in zip(folders, results) if r.get("calibration") is not None]
    for f, c in cals[1:]:
        if c != cals[0][1]:
            raise ValueError(f"calibration differs: {cals[0][1]!r} in {cals[0][0]}, {c!r} in {f}: these are not "
                             "jobs of one evaluation")
    merged = dict(first)
    for r in results[1:]:
        merged = _join(merged, {k: v for k, v in r.items() if k != "methods" and k not in SAME_KEYS})
    merged["calibration"] = cals[0][1] if cals else None
    merged["methods"] = {}
    owner: dict[str, Path] = {}
    for f, r in zip(folders, results):
        for name, m in r["methods"].items():
            if name in merged["methods"]:
                if _is_bound(m) and _is_bound(merged["methods"][name]):
                    continue  # a bound does not depend on the methods: every job computed the same
                raise ValueError(f"method {name} is in {owner[name]} and in {f}: each job of a fan-out over methods "
                                 "runs its own (only=...)")
            merged["methods"][name], owner[name] = m, f
    ran = {n: rmse_mean(m) for n, m in merged["methods"].items() if not _is_bound(m) and rmse_mean(m) is not None}
    for m in merged["methods"].values():  # how far the best of the merged methods is from each bound
        if _is_bound(m) and rmse_mean(m) is not None and ran:
            m["best"] = best_against_bound(ran, rmse_mean(m))
    merged["merged_from"] = [str(f) for f in folders]
    return merged


def _join(a: dict, b: dict) -> dict:
    """``a`` with what ``b`` adds: keys only ``b`` has, dictionaries under one key joined the same way."""
    out = dict(a)
    for k, v in b.items():
        if isinstance(v, dict) and isinstance(out.get(k), dict):
            out[k] = _join(out[k], v)
        elif k not in out or out[k] is None:
            out[k] = v
    return out


def merge_runs(folders: list[Path], out: Path) -> dict:
    """The jobs of a fan-out over methods (``blenav eval -m only=A,B ... 'out=FAN/${hydra:job.num}'``) as the one
    evaluation they split (:func:`merge_results`), written to ``out``: ``results.json``, each session's TUM
    trajectories (``out/<session>/trajectories``; the jobs' ground truth must agree) and nothing else; the
    caller adds the page. ``out`` must not exist: it is written beside itself and renamed at the end (an error
    leaves nothing). Returns the merged results."""
    import filecmp
    import os
    import shutil

    from .common import check_output_names, write_json

    folders = result_folders(folders)
    out = Path(out)
    if out.exists():
        raise ValueError(f"{out} exists: merge into a new folder")
    results = [_read_methods(f / "results.json") for f in folders]
    merged = merge_results(folders, results)
    check_output_names(merged["methods"], "method")
    tmp = out.with_name(f".{out.name}.tmp-{os.getpid()}")
    shutil.rmtree(tmp, ignore_errors=True)
    try:
        for f in folders:
            for traj in sorted(f.glob("*/trajectories")):
                dest = tmp / traj.parent.name / "trajectories"
                dest.mkdir(parents=True, exist_ok=True)
                for tum in traj.glob("*.tum"):
                    if not (dest / tum.name).exists():
                        shutil.copyfile(tum, dest / tum.name)
                    elif tum.name == "groundtruth.tum" and not filecmp.cmp(tum, dest / tum.name, shallow=False):
                        raise ValueError(f"{tum} differs from another job's ground truth of session "
                                         f"{traj.parent.name}: these are not jobs of one evaluation")
        tmp.mkdir(parents=True, exist_ok=True)
        write_json(tmp / "results.json", merged)
        os.replace(tmp, out)
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    return merged
