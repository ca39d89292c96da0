"""Several evaluations in one markdown table (``make selfcal-tables``; the leaderboard of issue 18 sec. 2, ``make
leaderboard``).

:func:`write_merge`: one row per session, one column per (prefixed) method, the RMSE mean over runs; RUN is an output
folder of blenav-eval, PREFIX, when given, goes before that run's method names (e.g. the reference runs of another
calibration). :func:`write_leaderboard`: the leaderboard over a fleet of datasets (``blenav-eval -m
experiment=leaderboard data=A,B,... 'out=FLEET/${hydra:job.num}'``), OUT.md and OUT.json (the same numbers of
:func:`blenav.eval.merge.merge_leaderboard`). The command line: ``python -m blenav.cli.tables merge | leaderboard``.
"""

from __future__ import annotations

import json
from pathlib import Path

from blenav.eval.common import write_text
from blenav.eval.merge import load_columns, merge_leaderboard, result_folders

__all__ = ["markdown", "leaderboard_markdown", "write_merge", "write_leaderboard"]


def markdown(title: str, cols: dict[str, dict[str, float]], sessions: list[str], sources: list[str]) -> str:
    """One row per session, one column per (prefixed) method (``cols``: :func:`blenav.eval.merge.load_columns`), the
    RMSE mean over runs (m), a last row with the mean over sessions; sessions a method did not run on are blank."""
    names = list(cols)
    lines = [f"# {title}", "", "RMSE mean over runs per session (m); from " + ", ".join(f"`{s}`" for s in sources) + ".",
             "", "| session | " + " | ".join(names) + " |", "|---|" + "---|" * len(names)]
    for sid in sessions:
        lines.append(f"| {sid} | " + " | ".join(f"{cols[n][sid]:.2f}" if sid in cols[n] else "" for n in names) + " |")
    means = [sum(cols[n].values()) / len(cols[n]) if cols[n] else float("nan") for n in names]
    lines.append("| mean | " + " | ".join(f"{v:.2f}" for v in means) + " |")
    return "\n".join(lines) + "\n"


def leaderboard_markdown(title: str, merged: dict) -> str:
    """One row per method of ``merged`` (:func:`blenav.eval.merge.merge_leaderboard`): its family, its RMSE (m) on each
    dataset, pooled, on how many sessions and datasets, sorted by the pooled RMSE (the bound last); then the best
    method per simulated dataset against the PCRLB and the skipped methods with their reasons."""
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


def write_merge(out: Path, title: str, specs: list[str]) -> Path:
    """OUT.md: the table of :func:`markdown` over ``specs`` (``RUN[:PREFIX]``: an output folder of blenav-eval and
    the prefix of its method names), written atomically."""
    out = Path(out)
    runs = [(Path(s.split(":", 1)[0]), s.split(":", 1)[1] if ":" in s else "") for s in specs]
    cols, sessions = load_columns(runs)
    out.parent.mkdir(parents=True, exist_ok=True)
    return write_text(out, markdown(title, cols, sessions, [str(r) for r, _ in runs]))


def write_leaderboard(out: Path, title: str, runs: list[Path]) -> Path:
    """OUT.md (:func:`leaderboard_markdown`) and OUT.json (the merged numbers) over ``runs``: output folders, or
    folders whose sub-folders are (a multirun's FLEET: :func:`blenav.eval.merge.result_folders`)."""
    out = Path(out)
    merged = merge_leaderboard(result_folders([Path(a) for a in runs]))
    out.parent.mkdir(parents=True, exist_ok=True)
    write_text(out, leaderboard_markdown(title, merged))
    write_text(out.with_suffix(".json"), json.dumps(merged, indent=1))
    return out
