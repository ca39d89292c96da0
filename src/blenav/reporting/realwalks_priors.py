"""The learned map prior on real walks with two priors (issue 17 section 2): trained on the simulator's
procedural buildings vs trained on the other floors of the mall, beside the heuristic map PF.

Reads, per floor, ``MAIN/<floor>/results.json`` (``blenav-eval experiment=realwalks ... model=SIM_PRIOR``: the
heuristic-map rows and the learned-map rows with the procedural prior) and ``OTHER/<floor>/results.json``
(``blenav-eval experiment=mapprior_ilc_rows ... model=FLOOR_PRIOR``: the learned-map rows, labelled ``... (other
floors)``, with a prior trained on the other floors' train walks), and the priors' ``meta.json`` (what each was
trained on). Writes the table and the verdicts between ``<!-- realwalks-priors-table -->`` markers of a markdown
page (and the table alone into the README's), through :func:`blenav.reporting.splice.splice`. Only numbers of those
files are written; nothing is computed but the comparisons.

    python -m blenav.cli.realwalks priors MAIN OTHER PRIOR_PATTERN PAGE.md [README.md]

``PRIOR_PATTERN``: the floor priors' directory with ``{floor}`` for the tested floor, e.g.
``data/runs/realwalks_prior_not_{floor}_onnx``.
"""

from __future__ import annotations

import json
from pathlib import Path

from . import num
from .splice import splice

__all__ = ["ROWS", "priors_table", "priors_verdicts", "write_priors"]

OTHER = " (other floors)"
#: (row label in the table, results key, which run: "main" or "other")
ROWS = (
    ("PDR+map (heuristic map PF)", "PDR+map", "main"),
    ("PDR+learned-map, procedural prior", "PDR+learned-map", "main"),
    ("PDR+learned-map, other-floors prior", "PDR+learned-map" + OTHER, "other"),
    ("WiFi+PDR+map", "WiFi+PDR+map", "main"),
    ("WiFi+PDR+learned-map, procedural prior", "WiFi+PDR+learned-map", "main"),
    ("WiFi+PDR+learned-map, other-floors prior", "WiFi+PDR+learned-map" + OTHER, "other"),
    ("BLE+PDR+map", "BLE+PDR+map", "main"),
    ("BLE+PDR+learned-map, procedural prior", "BLE+PDR+learned-map", "main"),
    ("BLE+PDR+learned-map, other-floors prior", "BLE+PDR+learned-map" + OTHER, "other"),
    ("WiFi+BLE+PDR+learned-map, procedural prior", "WiFi+BLE+PDR+learned-map", "main"),
    ("WiFi+BLE+PDR+learned-map, other-floors prior", "WiFi+BLE+PDR+learned-map" + OTHER, "other"),
)
#: (odometry/fixes, heuristic row, procedural-prior row, other-floors row)
GROUPS = (("PDR odometry", "PDR+map", "PDR+learned-map"),
          ("WiFi fixes + PDR", "WiFi+PDR+map", "WiFi+PDR+learned-map"),
          ("BLE fixes + PDR", "BLE+PDR+map", "BLE+PDR+learned-map"))
TAG = "realwalks-priors-table"  # the markers <!-- TAG --> / <!-- /TAG --> of the page and the README


def _err(results: dict, key: str) -> dict | None:
    e = ((results or {}).get("methods", {}).get(key) or {}).get("error_m")
    return e if e and e.get("mean") is not None else None


def _cell(e: dict | None) -> str:
    return f"{num(e['mean'])} / {num(e['p90'])}" if e else "-"


def priors_table(main: dict[str, dict], other: dict[str, dict]) -> str:
    """Markdown table: rows :data:`ROWS`, a column per floor (``main`` / ``other``: floor -> results.json)."""
    floors = sorted(main)
    lines = ["| method | " + " | ".join(f"{f} mean / p90" for f in floors) + " |",
             "|---|" + "---|" * len(floors)]
    for label, key, run in ROWS:
        src = main if run == "main" else other
        lines.append(f"| {label} | " + " | ".join(_cell(_err(src.get(f), key)) for f in floors) + " |")
    return "\n".join(lines)


def priors_verdicts(floor: str, main: dict, other: dict) -> list[str]:
    """Per odometry/fix group: the other-floors prior vs the heuristic map PF and vs the procedural prior (mean error
    at the test waypoints; lower wins)."""
    out = []
    for what, heur, learned in GROUPS:
        h, s, o = _err(main, heur), _err(main, learned), _err(other, learned + OTHER)
        if not (h and s and o):
            out.append(f"{floor}, {what}: not all three rows ran")
            continue
        scored = [(v, k) for v, k in ((h["mean"], "heuristic map PF"), (s["mean"], "procedural prior"),
                                      (o["mean"], "other-floors prior")) if v is not None]
        best = min(scored)[1] if scored else "none scored"
        out.append(f"{floor}, {what}: heuristic map PF {num(h['mean'])} m, procedural prior {num(s['mean'])} m, "
                   f"other-floors prior {num(o['mean'])} m -> {best} best")
    return out


def _prior_note(pattern: str, floor: str) -> str:
    p = Path(pattern.format(floor=floor)) / "meta.json"
    if not p.is_file():
        return f"- {floor}: no prior meta at {p}"
    m = json.loads(p.read_text())
    wp = m.get("waypoint_sessions") or {}
    read = (f"{len(m['sessions'])} walks read" if m.get("sessions") is not None else
            f"the train walks of split {m['train_split']}" if m.get("train_split") else "every labelled walk")
    return (f"- tested on {floor}: prior `{p.parent}` trained on {', '.join(m.get('floors') or m.get('buildings') or [])} "
            f"(datasets {', '.join(m.get('datasets') or [])}; {read}; {wp.get('sessions', '?')} walks with waypoint "
            f"ground truth, {wp.get('positions', '?')})")


def write_priors(main_root: str, other_root: str, prior_pattern: str, page: str, readme: str | None = None,
                 command: str = "make realwalks-tables") -> str:
    """Read the results, write the table + notes + verdicts into ``page`` (and the table into ``readme``) between
    the markers (appended to ``page`` when it has none); returns the page's block."""
    load = lambda d: {p.name: json.loads((p / "results.json").read_text()) for p in sorted(Path(d).iterdir())
                      if (p / "results.json").is_file() and p.name != "floors"}
    main, other = load(main_root), load(other_root)
    main = {f: r for f, r in main.items() if f in other}
    if not main:
        raise ValueError(f"no floor has results in both {main_root} and {other_root}")
    table = priors_table(main, other)
    parts = [f"Mean / p90 error (m) at the test walks' waypoints, learned-map rows with both priors (`{command}`):", "",
             table, "", "Priors trained on the other floors (leave one floor out):"]
    parts += [_prior_note(prior_pattern, f) for f in sorted(main)] + [""]
    parts += [f"- {v}" for f in sorted(main) for v in priors_verdicts(f, main[f], other[f])]
    body = "\n".join(parts)
    splice(page, body, TAG, append=True)
    if readme:  # the README gets the table only where its markers are
        splice(readme, table, TAG)
    return body

