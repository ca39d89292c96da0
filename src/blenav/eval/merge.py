"""Merge several evaluations' results.json into one per-session table (RMSE mean over runs, m).

``python -m blenav.eval.merge OUT.md TITLE RUN[:PREFIX] [RUN[:PREFIX] ...]``: RUN is an output folder of
blenav-eval (its results.json); PREFIX, when given, is put before that run's method names (e.g. the
reference runs of another calibration). Writes a markdown table: one row per session, one column per
(prefixed) method, plus the mean over sessions; sessions a method did not run on are blank.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path


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


def main(argv: list[str] | None = None) -> int:
    args = sys.argv[1:] if argv is None else argv
    if len(args) < 3:
        print(__doc__.splitlines()[2].strip(), file=sys.stderr)
        return 2
    out, title, specs = Path(args[0]), args[1], args[2:]
    runs = [(Path(s.split(":", 1)[0]), s.split(":", 1)[1] if ":" in s else "") for s in specs]
    cols, sessions = load_columns(runs)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(markdown(title, cols, sessions, [str(r) for r, _ in runs]), encoding="utf-8")
    print(out)
    return 0


if __name__ == "__main__":
    sys.exit(main())
