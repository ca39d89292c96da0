"""The back-end on buildings and channels it was not tuned to (issue 32): one row per simulated building, the IMU
filter, the closed-loop filter (F-end) and the smoother (B-end) with the true beacon map (``experiment=backend_000``)
and with every beacon moved by N(0, 3^2) m (``experiment=mapnoise_000``), from the two evaluations' results.json.

    blenav tables backend OUT.md LABEL=TRUE_RUN[,NOISE_RUN] [...]     (make backend-robust)

Columns: RMSE mean over runs (m); B-end / best filter: B-end over the better of IMU and F-end (the issue's aim: at
most 0.95); with the perturbed map: B-end and its change against the true map (aim: within 20 %), the beacons'
error given -> optimized and how much closer (aim: 25 %); where the perturbed run has the pooled rows
(``B-end+pool``, :mod:`blenav.backend.pooled`), their B-end and beacons too. A second table: the same beacon errors
by how often a beacon was heard (rssi.csv rows per session, ``beacon_error_m.by_heard``), where the runs have it.
"""

from __future__ import annotations

from pathlib import Path

from blenav.eval.beacon_map import checked_by_heard, heard_bins
from blenav.eval.common import write_text
from blenav.eval.metrics import rmse_mean
from blenav.limits import read_json

__all__ = ["backend_rows", "markdown", "write_backend_table"]


def _rmse(res: dict, name: str) -> float | None:
    return rmse_mean(res["methods"].get(name))


def backend_rows(specs: list[str]) -> list[dict]:
    """One dict per ``LABEL=TRUE_RUN[,NOISE_RUN]``: the numbers of the table (None where a run lacks them)."""
    rows = []
    for spec in specs:
        label, _, runs = spec.partition("=")
        if not runs:
            raise ValueError(f"{spec!r}: expected LABEL=TRUE_RUN[,NOISE_RUN]")
        true_dir, _, noise_dir = runs.partition(",")
        t = read_json(Path(true_dir) / "results.json", "results.json")
        row = {"label": label, "runs": t.get("runs"), "IMU": _rmse(t, "IMU"), "F-end": _rmse(t, "F-end"),
               "B-end": _rmse(t, "B-end"), "source": true_dir}
        best = min(v for v in (row["IMU"], row["F-end"]) if v is not None) if (row["IMU"] or row["F-end"]) else None
        row["ratio"] = row["B-end"] / best if row["B-end"] is not None and best else None
        if noise_dir:
            n = read_json(Path(noise_dir) / "results.json", "results.json")
            row["noise_B-end"] = _rmse(n, "B-end")
            row["noise_F-end"] = _rmse(n, "F-end")
            be = (n["methods"].get("B-end") or {}).get("beacon_error_m") or {}
            row["beacons"] = (be.get("prior"), be.get("optimized"))
            row["by_heard"] = be.get("by_heard") or []
            pool = n["methods"].get("B-end+pool")
            if pool:
                row["pool_B-end"] = _rmse(n, "B-end+pool")
                pb = pool.get("beacon_error_m") or {}
                row["pool_beacons"] = (pb.get("prior"), pb.get("optimized"))
        rows.append(row)
    return rows


def _f(v, fmt="{:.2f}") -> str:
    return "-" if v is None else fmt.format(v)


def _vs_true(r: dict, key: str) -> str:
    """``key``'s RMSE and its change against the true map's B-end."""
    v = r.get(key)
    ch = 100.0 * (v / r["B-end"] - 1.0) if v is not None and r["B-end"] else None
    return f"{_f(v)} ({_f(ch, '{:+.0f} %')})"


def _closer(b) -> str:
    b = b or (None, None)
    closer = 100.0 * (1.0 - b[1] / b[0]) if b[0] and b[1] is not None else None
    return f"{_f(b[0])} -> {_f(b[1])} ({_f(closer, '{:.0f} %')})"


def markdown(title: str, rows: list[dict], command: str = "") -> str:
    pooled = any("pool_B-end" in r for r in rows)
    head = ("| building, channel | IMU | F-end | B-end | B-end / best filter | 3 m map: F-end "
            "| 3 m map: B-end (vs true map) | beacons given -> optimized (closer) |")
    if pooled:
        head += " 3 m map, pooled walks: B-end+pool (vs true map) | beacons given -> pooled, optimized (closer) |"
    lines = [f"# {title}", "", f"RMSE mean over runs (m); made by `{command or 'blenav tables backend'}`.", "",
             head, "|---" * head.count(" | ") + "|---|"]
    for r in rows:
        ratio = _f(r["ratio"]) + (" ok" if r["ratio"] is not None and r["ratio"] <= 0.95 else "")
        line = (f"| {r['label']} | {_f(r['IMU'])} | {_f(r['F-end'])} | {_f(r['B-end'])} | {ratio} | "
                f"{_f(r.get('noise_F-end'))} | {_vs_true(r, 'noise_B-end')} | {_closer(r.get('beacons'))} |")
        if pooled:
            line += f" {_vs_true(r, 'pool_B-end')} | {_closer(r.get('pool_beacons'))} |"
        lines.append(line)
    heard = [r for r in rows if r.get("by_heard")]
    if heard:
        cells = [checked_by_heard(r["by_heard"]) for r in heard]
        names = [label for _, _, label in heard_bins() if any(label in c for c in cells)]
        lines += ["", "3 m map, beacons by how often they were heard (rssi.csv rows per session; pooled over sessions "
                  "and runs): error given -> optimized (m), beacons in brackets", "",
                  "| building, channel | " + " | ".join(names) + " |", "|---|" + "---|" * len(names)]
        for r, cell in zip(heard, cells):
            lines.append(f"| {r['label']} | " + " | ".join(
                f"{_f(cell[k]['given_m'])} -> {_f(cell[k]['optimized_m'])} ({cell[k]['beacons']})" if k in cell else "-"
                for k in names) + " |")
    return "\n".join(lines) + "\n"


def write_backend_table(out: Path, title: str, specs: list[str], command: str = "") -> Path:
    out = Path(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    return write_text(out, markdown(title, backend_rows(specs), command))
