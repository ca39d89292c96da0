"""The tables of the real phone walks (issue 17, the ILC 2.0 recordings; ``experiment=realwalks``, ``make
realwalks-tables``): docs/results/ilc20_<floor>.md per floor, the summary block of docs/results-ilc20.md and the
README's table, from the floors' results.json.

The rows are the experiment's own (:func:`table_rows` of its composed ``methods`` node, which the entry point
``python -m blenav.cli.realwalks tables ...`` composes); the verdicts compare their mean errors
(:data:`OUTCOMES`). Only numbers of the results are written.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from blenav.eval.common import write_text

from .splice import splice

__all__ = ["OUTCOMES", "TAG", "table_rows", "floor_table", "fused_table", "verdicts", "summary_table", "floor_markdown",
           "write_tables"]

TAG = "realwalks-table"  # the markers <!-- TAG --> / <!-- /TAG --> of the summary page and the README


def table_rows(methods: dict) -> dict[str, tuple[str, ...]]:
    """The labels of an experiment's rows, in its order, from its composed ``methods`` node (a dict:
    ``OmegaConf.to_container(cfg.methods, resolve=False)``; the entry point composes it, so a renamed label is
    renamed in the tables too): ``all``; ``fingerprint`` (fingerprint localizers); ``fused`` (rows with a fix
    likelihood of a ``fixes`` role, or a ``fix_roles`` list: the global fusion rows)."""
    rows = {"all": [], "fingerprint": [], "fused": []}
    for key, node in methods.items():
        if node is None:
            continue
        label = str(node.get("label", key))
        rows["all"].append(label)
        if str(node.get("_target_", "")).endswith("FingerprintLocalizer"):
            rows["fingerprint"].append(label)
        meas = node.get("measurements") or {}
        if node.get("fix_roles") or any(isinstance(m, dict) and m.get("role")
                                        for m in (meas.values() if isinstance(meas, dict) else meas)):
            rows["fused"].append(label)
    return {k: tuple(v) for k, v in rows.items()}


#: the map-prior outcomes of issue 17 (left open by the map-prior issue): (question, row a, row b); a beats b
#: when its mean error is lower (labels of conf/experiment/realwalks.yaml; tests/eval/test_realwalks.py checks them)
OUTCOMES = (("sparse BLE + odometry + learned map vs dense BLE (WiFi+BLE fixes)", "BLE+PDR+learned-map", "KNN-WiFi+BLE"),
            ("sparse BLE + odometry + learned map vs odometry + learned map", "BLE+PDR+learned-map", "PDR+learned-map"),
            ("sparse BLE + odometry + learned map vs sparse BLE + odometry", "BLE+PDR+learned-map", "BLE+PDR"),
            ("learned map prior vs heuristic map PF (PDR odometry)", "PDR+learned-map", "PDR+map"),
            ("learned map prior vs heuristic map PF (BLE fixes + PDR)", "BLE+PDR+learned-map", "BLE+PDR+map"),
            ("learned map prior vs heuristic map PF (WiFi fixes + PDR)", "WiFi+PDR+learned-map", "WiFi+PDR+map"))


def _mean(results: dict, row: str) -> float | None:
    m = results["methods"].get(row) or {}
    e = m.get("error_m") or {}
    v = e.get("mean")
    return float(v) if v is not None and np.isfinite(v) else None


def _fmt(v, pct: bool = False) -> str:
    if v is None:
        return "--"
    return f"{100 * v:.0f} %" if pct else f"{v:.2f}"


def floor_table(results: dict, rows: dict) -> str:
    """Markdown: one row per method of a realwalks results.json (error_m over the test walks' waypoints, m;
    share of walks within 2 m / 5 m; the mean displacement error per waypoint segment, m), in the order of ``rows`` (:func:`table_rows`), skipped methods with the first
    reason."""
    lines = ["| method | mean | median | p90 | walks within 2 m | within 5 m | walks | segment error |",
             "|---|---|---|---|---|---|---|---|"]
    order = rows["all"]
    names = [r for r in order if r in results["methods"]] + [r for r in results["methods"] if r not in order]
    for name in names:
        m = results["methods"][name]
        e = m.get("error_m")
        if not e:
            reason = next(iter((m.get("skipped") or {}).values()), "not run")
            lines.append(f"| {name} | skipped: {str(reason)[:110]} | | | | | | |")
            continue
        w = m.get("walks_within_m") or {}
        n = len(m.get("per_session") or {})
        seg = (m.get("segment_error_m") or {}).get("mean")  # displacement error per waypoint segment (issue 31)
        lines.append(f"| {name} | {_fmt(e.get('mean'))} | {_fmt(e.get('median'))} | {_fmt(e.get('p90'))} | "
                     f"{_fmt(w.get('2'), True)} | {_fmt(w.get('5'), True)} | {n} | {_fmt(seg)} |")
    return "\n".join(lines)


def verdicts(results: dict, rows: dict) -> list[str]:
    """Markdown bullets: whether the best fused row beats the best fingerprint row and PDR+map (the rows of
    :func:`table_rows`), and the map-prior outcomes (mean errors, m)."""
    out = []
    best = lambda rows: min(((_mean(results, r), r) for r in rows if _mean(results, r) is not None), default=None)
    bf, bp = best(rows["fused"]), best(rows["fingerprint"])
    pm = _mean(results, "PDR+map")
    if bf and bp:
        out.append(f"best fused {bf[1]} {bf[0]:.2f} m vs best fingerprint {bp[1]} {bp[0]:.2f} m: "
                   f"{'fusion better' if bf[0] < bp[0] else 'fusion NOT better'}")
    if bf and pm is not None:
        out.append(f"best fused {bf[1]} {bf[0]:.2f} m vs PDR+map {pm:.2f} m: "
                   f"{'fusion better' if bf[0] < pm else 'fusion NOT better'}")
    for q, a, b in OUTCOMES:
        va, vb = _mean(results, a), _mean(results, b)
        if va is None or vb is None:
            out.append(f"{q}: not measured ({a if va is None else b} did not run)")
        else:
            out.append(f"{q}: {a} {va:.2f} m vs {b} {vb:.2f} m -> {a if va < vb else b} better")
    return out


def summary_table(results_by_floor: dict, rows: dict) -> str:
    """Markdown: mean error (m) per method (the rows of :func:`table_rows`) and floor (columns: the floors)."""
    floors = list(results_by_floor)
    lines = ["| method | " + " | ".join(f"{f} mean / p90" for f in floors) + " |",
             "|---|" + "---|" * len(floors)]
    for row in rows["all"]:
        cells = []
        for f in floors:
            m = results_by_floor[f]["methods"].get(row) or {}
            e = m.get("error_m")
            cells.append(f"{_fmt(e.get('mean'))} / {_fmt(e.get('p90'))}" if e else "skipped" if m else "--")
        if any(c not in ("--",) for c in cells):
            lines.append(f"| {row} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def fused_table(results_by_floor: dict, rows: dict) -> str | None:
    """Markdown: per floor and fused row with fixes (per role) and fingerprint row with a stated std (its ``own``
    fixes), the share of the test waypoints inside the fixes' stated 1-sigma / 2-sigma regions (a 2-D Gaussian holds
    39 % / 86 %) and the time until the track stays within 5 m
    (median over the walks that settle, and their share); None when no row reports them."""
    lines = ["| floor | method | fixes | inside 1 sigma | inside 2 sigma | settles within 5 m | after (median) |",
             "|---|---|---|---|---|---|---|"]
    n = 0
    for floor, r in results_by_floor.items():
        for row in dict.fromkeys(rows["fused"] + rows["fingerprint"]):  # in order, each once
            m = r["methods"].get(row) or {}
            for role, c in (m.get("fix_coverage") or {}).items():
                conv = m.get("convergence") or {}
                med = conv.get("median_s")
                lines.append(f"| {floor} | {row} | {role} | {_fmt(c['1sigma'], True)} | {_fmt(c['2sigma'], True)} | "
                             f"{_fmt(conv.get('settled'), True)} | {'--' if med is None else f'{med:.0f} s'} |")
                n += 1
    return "\n".join(lines) if n else None


def floor_markdown(results: dict, floor: str, command: str, rows: dict) -> str:
    """docs/results/ilc20_<floor>.md: the floor's table, the verdicts (``rows``: :func:`table_rows`), the split and
    what was trained."""
    m = results["methods"]
    step = next((v["training"]["step_length"] for v in m.values() if (v.get("training") or {}).get("step_length")), None)
    lines = [f"# Real walks, ILC 2.0 site1 {floor}: every method on the same test walks", "",
             f"Generated by `{command}` ([summary](../results-ilc20.md)). {len(results['sessions'])} test walks, "
             f"{len(results.get('split', {}).get('train', []))} train walks (split {results.get('split', {}).get('train_fraction')}, "
             f"seed {results.get('split', {}).get('seed')}), {results['runs']} run(s) per walk and method; errors in metres at "
             f"the test walks' surveyed waypoints (the estimate interpolated at the waypoint times), pooled over the "
             f"waypoints; 'walks within' = share of (walk, run) pairs whose mean waypoint error is within 2 m / 5 m.",
             ""]
    if step:
        lines += [f"PDR step length fitted on the train walks: {step['step_length_m']:.3f} m ({step['steps']} steps over "
                  f"{step['path_m']:.0f} m of surveyed path between waypoints, {step['walks']} walks).", ""]
    if results.get("model"):
        lines += [f"Map prior: `{results['model'].get('path')}`; unavailable for: "
                  f"{', '.join(results['model'].get('unavailable', {})) or 'none'}.", ""]
    lines += [floor_table(results, rows), ""]
    fused = fused_table({floor: results}, rows)
    if fused:
        lines += ["## Fused rows: the fixes' stated uncertainty and the time to converge", "",
                  "No fused row is told where a walk starts. 'inside 1 / 2 sigma': share of the test waypoints whose "
                  "error of the fix (interpolated at the waypoint time) is within 1 / 2 of its stated std (a 2-D "
                  "Gaussian: 39 % / 86 %); 'settles': share of the walks whose error stays within 5 m from some "
                  "waypoint on, and the median time from the walk's first waypoint to that one. Rows 'own': a "
                  "fingerprint row's own fixes and their stated std.", "", fused, ""]
    lines += ["## Verdicts (mean error)", ""] + [f"- {v}" for v in verdicts(results, rows)]
    return "\n".join(lines) + "\n"


def write_tables(out_root: str, summary_md: str, rows: dict, command: str = "make realwalks-tables",
                 floors_dir: str | None = None, readme: str | None = None) -> str:
    """Per floor (``out_root/<floor>/results.json``): docs/results/ilc20_<floor>.md beside ``summary_md``; then the
    summary (``summary_md``) and, with ``readme``, the table between the README's realwalks markers. ``rows``: the
    experiment's rows (:func:`table_rows`; ``python -m blenav.cli.realwalks tables ...`` composes them)."""
    root, summary = Path(out_root), Path(summary_md)
    by_floor = {}
    for d in sorted(p for p in root.iterdir() if (p / "results.json").is_file() and p.name != "floors"):
        r = json.loads((d / "results.json").read_text())
        by_floor[d.name] = r
        (summary.parent / "results").mkdir(parents=True, exist_ok=True)
        write_text(summary.parent / "results" / f"ilc20_{d.name}.md", floor_markdown(r, d.name, command, rows))
    table = summary_table(by_floor, rows)
    fa = None
    if floors_dir and (Path(floors_dir) / "results.json").is_file():
        fa = json.loads((Path(floors_dir) / "results.json").read_text()).get("floor_accuracy")
    parts = [f"Mean / p90 error (m) at the test walks' waypoints, per floor (`{command}`):", "", table, ""]
    fused = fused_table(by_floor, rows)
    if fused:
        parts += ["The fused rows' fixes (and, 'own', every fingerprint row's): share of the test waypoints inside their "
                  "stated 1 / 2 sigma (39 % / 86 % for a calibrated 2-D Gaussian), and how long the fused rows take to "
                  "stay within 5 m (no start given):", "",
                  fused, ""]
    if fa is not None:
        parts += [f"Floor classifier (which floor a test walk is on, from its scans; all three floors in one dataset): "
                  f"`floor_accuracy` = {json.dumps(fa)}", ""]
    for f, r in by_floor.items():
        parts += [f"{f}:"] + [f"- {v}" for v in verdicts(r, rows)] + [""]
    body = "\n".join(parts)
    splice(summary, body, TAG, append=True)
    if readme:
        splice(readme, table, TAG)
    return body

