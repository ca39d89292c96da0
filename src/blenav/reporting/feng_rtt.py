"""The Feng et al. real-RTT page (issue 15 sec. 3): ``docs/results/feng_rtt.md`` from the results.json of
``blenav-eval experiment=crf_004_feng`` plus the range errors of the imported dataset
(:func:`blenav.eval.feng_rtt.range_errors`).

    python -m blenav.cli.tables feng RESULTS.json OUT.md [COMMAND]     (``make feng-tables`` runs all of it)

Two tables: (1) localization error per environment (test points) and method (``SOLVER/CALIBRATION`` and
``/no-65dBm``: without the -65 dBm rule), with the share of scans localized (a scan with fewer than 3 usable
ranges has none); (2) the absolute range error |range - true 3-D distance| of every RTT reading at the test
points, uncalibrated and with the offline per-AP offsets of the train points, with and without the -65 dBm rule
(004 Fig. 9's comparison). Numbers only from the files; no plotting.
"""

from __future__ import annotations

import json
import re
from pathlib import Path

import numpy as np

from blenav.eval.common import write_text
from blenav.eval.feng_rtt import ENVS, range_errors, scan_counts

from . import num

__all__ = ["findings", "render", "write_page"]


def _mean(methods: dict, name: str, env: str):
    ps = methods.get(name, {}).get("per_session", {}).get(f"{env}_test")
    return None if ps is None else ps["error_m"]["mean"]


def _fmt(v) -> str:
    return "skipped" if v is None else f"{v:.2f}"


def findings(methods: dict, ranges: list[dict] | None) -> list[str]:
    """Bullet lines comparing calibration and the -65 dBm rule, from the numbers above."""
    out = []
    for solver in ("grid-L2", "grid-L1", "SRLS"):
        if f"{solver}/none/no-65dBm" not in methods:
            continue
        cal = ", ".join(f"{e} {_fmt(_mean(methods, f'{solver}/none/no-65dBm', e))} -> "
                        f"{_fmt(_mean(methods, f'{solver}/offline/no-65dBm', e))}" for e in ENVS)
        rule = ", ".join(f"{e} {_fmt(_mean(methods, f'{solver}/offline/no-65dBm', e))} -> "
                         f"{_fmt(_mean(methods, f'{solver}/offline', e))}" for e in ENVS)
        out.append(f"- {solver}, offline calibration (no rule), mean error none -> offline [m]: {cal}.")
        out.append(f"- {solver}, the -65 dBm rule (offline), mean error without -> with [m]: {rule}.")
    clamped = [f"{k} {m['confined']['bbox']} of {m['confined']['estimates']}" for k, m in methods.items()
               if m.get("confined", {}).get("bbox")]
    if clamped:
        out.append("- Estimates the evaluation clamped to the floor plan's bounding box (SRLS is not confined to the "
                   "grid; the grid methods never leave it): " + "; ".join(clamped) + ".")
    if ranges:
        for r in ranges:
            if r["rule"] == "none" and r["none"] and r["offline"]:
                out.append(f"- Range error, {r['env']} (all readings): median {r['none'][0]:.2f} -> {r['offline'][0]:.2f} m "
                           f"with the offline offsets, p90 {r['none'][2]:.2f} -> {r['offline'][2]:.2f} m.")
        for env in ENVS:
            a = next((r for r in ranges if r["env"] == env and r["rule"] == "none"), None)
            b = next((r for r in ranges if r["env"] == env and r["rule"] != "none"), None)
            if a and b and a["none"] and b["none"]:
                out.append(f"- The -65 dBm rule keeps {b['n']} of {a['n']} {env} readings; their uncalibrated p90 range "
                           f"error is {b['none'][2]:.2f} m (all readings: {a['none'][2]:.2f} m).")
    return out


def render(results: dict, ranges: list[dict] | None = None, command: str = "", scans: dict | None = None) -> str:
    """The page's markdown (``scans``: test session -> number of scans, the denominator of the share localized)."""
    methods = results["methods"]
    out = ["# Real WiFi RTT: the Feng et al. test points (issue 15 sec. 3)", ""]
    if command:
        out += ["Reproduce (imports ../shared/data/raw/feng_wifi_rtt, evaluates, writes this page):", "",
                "```bash", command, "```", ""]
    out += ["Data: Feng, Nguyen, Luo, *WiFi RSS & RTT dataset with different LOS conditions* (Zenodo 10.5281/zenodo."
            "11558792), imported by `blenav-import feng_wifi_rtt` (`rtt.csv` carries the scan's AP RSS as `rssi`). "
            "Static scans, 60 per reference point, one per synthetic second; the train points calibrate, the test "
            "points are scored. Lecture theatre: 5 APs, line of sight; office: 5 APs, mixed; corridor: 4 APs, all "
            "NLOS. AP and phone heights are unknown (both assumed 1.2 m).",
            "",
            "Methods: the range baselines of 004 sec. VI-E (`blenav.localizers.ranging`), RTT ranges only, one 1 s "
            "window per scan: grid-L2 (range least squares over the free 0.5 m cells; it is also the argmax of the "
            "CRF's RTT feature, eq. 6, with one sigma for every AP), grid-L1 (absolute residuals), SRLS (exact "
            "squared-range least squares, Beck et al. 2008; not confined to the grid; when the APs left in a scan are "
            "collinear its two mirror solutions are equally good and, the imported floor having no walls, it keeps the "
            "left one). Calibration `none` or "
            "`offline` (a range offset per AP: the median of measured minus true range over the environment's "
            "train points); `/no-65dBm`: the -65 dBm rule of 004 sec. V-A off (every range kept). A scan with "
            "fewer than 3 usable ranges gets no estimate; `scans` is the share localized.",
            "", "## Localization error at the test points (m)", "",
            "| method | " + " | ".join(f"{e} mean | median | p90 | scans" for e in ENVS) + " |",
            "|---|" + "---|" * (4 * len(ENVS))]
    for name, m in methods.items():
        cov = {}
        for n in m.get("map_notes", []):
            g = re.match(r"(\w+): (\d+) of (\d+) windows localized", n)
            if g:
                cov[g.group(1)] = (int(g.group(2)), int(g.group(3)))
        cells = []
        for env in ENVS:
            sid = f"{env}_test"
            ps = m.get("per_session", {}).get(sid)
            if ps is None:
                why = m.get("skipped", {}).get(sid, "")
                cells.append(f"skipped | | | 0/{(scans or {}).get(sid, '')}" if "3 or more" in why else "skipped | | |")
                continue
            e = ps["error_m"]
            c = cov.get(sid)
            total = (scans or {}).get(sid, c[1] if c else None)
            cells.append(f"{num(e['mean'])} | {num(e['median'])} | {num(e['p90'])} | "
                         + (f"{c[0]}/{total}" if c else ""))
        out.append(f"| {name} | " + " | ".join(cells) + " |")
    out.append("")
    skipped = sorted({(k, s, w) for k, m in methods.items() for s, w in m.get("skipped", {}).items()})
    if skipped:
        out += ["Skipped: " + "; ".join(sorted({f"{s}: {w.split(': ', 1)[-1]}" for _, s, w in skipped})), ""]
    lines = findings(methods, ranges)
    if lines:
        out += ["## What the numbers say", ""] + lines + [""]
    if ranges:
        out += ["## RTT range error at the test points (m): |range - true 3-D distance|", "",
                "| environment | -65 dBm rule | readings | none: median | mean | p90 | offline: median | mean | p90 | "
                "offline offsets per AP (m) |", "|---|---|---|---|---|---|---|---|---|---|"]
        for r in ranges:
            def f(v):
                return " | ".join(f"{x:.2f}" for x in v) if v else "- | - | -"
            offs = ", ".join(f"{a} {o:+.2f}" if np.isfinite(o) else f"{a} -" for a, o in r["offsets"].items())
            out.append(f"| {r['env']} | {r['rule']} | {r['n']} | {f(r['none'])} | {f(r['offline'])} | {offs} |")
        out.append("")
    return "\n".join(out)


def write_page(results_json: Path, out_md: Path, command: str = "") -> Path:
    """OUT.md (:func:`render`) from the results.json of ``experiment=crf_004_feng`` and the range errors and scan
    counts of its dataset (``results["dataset"]``), written atomically; ``command``: the reproducing command shown."""
    results = json.loads(Path(results_json).read_text(encoding="utf-8"))
    ranges = range_errors(Path(results["dataset"]))
    text = render(results, ranges, command, scan_counts(Path(results["dataset"])))
    return write_text(Path(out_md), text + "\n")
