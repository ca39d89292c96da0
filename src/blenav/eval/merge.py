"""Merge several evaluations' results.json into one table.

``python -m blenav.eval.merge OUT.md TITLE RUN[:PREFIX] [RUN[:PREFIX] ...]``: RUN is an output folder of
blenav-eval (its results.json); PREFIX, when given, is put before that run's method names (e.g. the
reference runs of another calibration). Writes a markdown table: one row per session, one column per
(prefixed) method, plus the mean over sessions; sessions a method did not run on are blank.

``python -m blenav.eval.merge --leaderboard OUT.md TITLE RUN [RUN ...]``: the leaderboard over a fleet of
datasets (``blenav-eval -m experiment=leaderboard data=A,B,... 'out=FLEET/${hydra:job.num}'``). RUN is an
output folder, or a folder whose sub-folders are (the multirun's FLEET). One row per method (its family,
the RMSE on each dataset, the RMSE pooled over every session of every dataset it ran on, on how many
datasets it ran), sorted by the pooled RMSE; the PCRLB row where the data were simulated, and per dataset
the best method's distance to it. Writes OUT.md and OUT.json (the same numbers).
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

from .common import write_text


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


def markdown(title: str, cols: dict[str, dict[str, float]], sessions: list[str], sources: list[str]) -> str:
    names = list(cols)
    lines = [f"# {title}", "", "RMSE mean over runs per session (m); from " + ", ".join(f"`{s}`" for s in sources) + ".",
             "", "| session | " + " | ".join(names) + " |", "|---|" + "---|" * len(names)]
    for sid in sessions:
        lines.append(f"| {sid} | " + " | ".join(f"{cols[n][sid]:.2f}" if sid in cols[n] else "" for n in names) + " |")
    means = [sum(cols[n].values()) / len(cols[n]) if cols[n] else float("nan") for n in names]
    lines.append("| mean | " + " | ".join(f"{v:.2f}" for v in means) + " |")
    return "\n".join(lines) + "\n"


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


def leaderboard_markdown(title: str, merged: dict) -> str:
    ds = [d["name"] for d in merged["datasets"]]
    ms = merged["methods"]
    order = sorted(ms, key=lambda n: (ms[n]["family"] == "bound", ms[n]["pooled_rmse_m"] is None,
                                      ms[n]["pooled_rmse_m"] or 0.0))
    lines = [f"# {title}", "", f"{len(ds)} dataset(s): " + "; ".join(
        f"`{d['name']}` ({len(d['sessions'])} session(s), {d['runs']} run(s), from `{d['folder']}`)" for d in merged["datasets"])
        + ". RMSE (m): mean over runs and sessions per dataset; pooled: over every session of every dataset the method "
        "ran on. Sorted by the pooled RMSE; the bound last.", "",
        "| # | method | family | " + " | ".join(ds) + " | pooled | sessions | datasets |",
        "|---|---|---|" + "---|" * len(ds) + "---|---|---|"]
    for i, n in enumerate(order, 1):
        r = ms[n]
        cells = [f"{r['rmse_m'][d]:.2f}" if d in r["rmse_m"] else ("skipped" if d in r["skipped"] else "") for d in ds]
        pooled = "-" if r["pooled_rmse_m"] is None else f"{r['pooled_rmse_m']:.2f}"
        lines.append(f"| {i if r['family'] != 'bound' and r['pooled_rmse_m'] is not None else '-'} | {n} | {r['family']} | " + " | ".join(cells)
                     + f" | {pooled} | {r['sessions']} | {r['datasets']} |")
    if merged["best"]:
        lines += ["", "Best method per simulated dataset against the PCRLB:", ""]
        lines += [f"- {d}: {b['method']} {b['rmse_m']:.2f} m = {b['ratio']:.1f}x the bound ({b['bound_m']:.2f} m)"
                  for d, b in merged["best"].items()]
    skipped = {n: r["skipped"] for n, r in ms.items() if r["skipped"]}
    if skipped:
        lines += ["", "Skipped (method: dataset: reason):", ""]
        for n, sk in skipped.items():
            lines += [f"- {n}: " + "; ".join(f"{d}: {why}" for d, why in sk.items())]
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> int:
    args = sys.argv[1:] if argv is None else argv
    if args[:1] == ["--leaderboard"]:
        if len(args) < 4:
            print("python -m blenav.eval.merge --leaderboard OUT.md TITLE RUN [RUN ...]", file=sys.stderr)
            return 2
        out, title = Path(args[1]), args[2]
        try:
            merged = merge_leaderboard(result_folders([Path(a) for a in args[3:]]))
        except (FileNotFoundError, KeyError, ValueError) as exc:
            print(f"blenav.eval.merge: error: {exc}", file=sys.stderr)
            return 1
        out.parent.mkdir(parents=True, exist_ok=True)
        write_text(out, leaderboard_markdown(title, merged))
        write_text(out.with_suffix(".json"), json.dumps(merged, indent=1))
        print(out)
        return 0
    if len(args) < 3:
        print(__doc__.splitlines()[2].strip(), file=sys.stderr)
        return 2
    out, title, specs = Path(args[0]), args[1], args[2:]
    runs = [(Path(s.split(":", 1)[0]), s.split(":", 1)[1] if ":" in s else "") for s in specs]
    cols, sessions = load_columns(runs)
    out.parent.mkdir(parents=True, exist_ok=True)
    write_text(out, markdown(title, cols, sessions, [str(r) for r, _ in runs]))
    print(out)
    return 0


if __name__ == "__main__":
    sys.exit(main())
