"""docs/results-inertial.md (issue 31): the learned inertial odometry beside PDR on the real mall walks, leave one floor
out, and the simulator-only model on the same walks (``make inertial-tables``; ``python -m blenav.cli.realwalks
inertial OUT_ROOT PAGE.md``).

``OUT_ROOT/<floor>/results.json``: ``experiment=realwalks_inertial`` on the floor's test walks with the model trained on
the other floors' train walks plus simulated walks; ``OUT_ROOT/sim_<floor>/results.json``: the same with the model
trained on simulated walks only. ``OUT_ROOT/runs.json`` (optional): the training runs' reports (steps, wall time,
validation error beside PDR's). Every number of the page is read from these files.
"""

from __future__ import annotations

import json
from pathlib import Path

from blenav.eval.common import write_text

from . import num

__all__ = ["inertial_markdown", "write_inertial"]

def _get(results: dict, row: str, *keys):
    m = (results or {}).get("methods", {}).get(row) or {}
    for k in keys:
        m = m.get(k) if isinstance(m, dict) else None
    return m


def _f(v, nd: int = 2) -> str:
    return num(v, nd, "--")


def inertial_markdown(floors: dict[str, dict], sim_only: dict[str, dict], runs: dict | None, command: str) -> str:
    """The page: per floor the segment error (mean / median, m) and the waypoint error (mean, m) of each row, the ratio
    LIO / PDR (rotation vector) of the segment error, and the simulator-only model's LIO row."""
    lines = ["# Learned inertial odometry on the real mall walks (issue 31)", "",
             f"Made by `{command}` from the results under its output folder; numbers are means over the test walks of "
             "each floor (the split of experiment=realwalks). Segment error: the error of a row's displacement over "
             "each waypoint segment, |(p(b) - p(a)) - (g(b) - g(a))| (the 2021 indoor challenge's measure); waypoint "
             "error: as in docs/results-ilc20.md (started at the first waypoint, heading absolute).", "",
             "Leave one floor out: the model of each floor is trained on the other two floors' train walks plus "
             "simulated walks (`python train.py experiment=inertial ...`), exported (`python export.py`), and run "
             "by `blenav-eval experiment=realwalks_inertial data=FLOOR io_model=IO_DIR`.", "",
             "| floor | PDR (rot. vector) segment mean / median | LIO segment mean / median | LIO / PDR | "
             "PDR (rot. vector) waypoint | LIO waypoint | PDR+map | LIO+map | simulator-only LIO segment / waypoint |",
             "|---|---|---|---|---|---|---|---|---|"]
    for fl in sorted(floors):
        r, s = floors[fl], sim_only.get(fl)
        ps, ls = _get(r, "PDR (rotation vector)", "segment_error_m"), _get(r, "LIO", "segment_error_m")
        ratio = ls["mean"] / ps["mean"] if ps and ls else None
        sl = _get(s, "LIO", "segment_error_m") if s else None
        lines.append(
            f"| {fl} | {_f((ps or {}).get('mean'))} / {_f((ps or {}).get('median'))} | {_f((ls or {}).get('mean'))} / "
            f"{_f((ls or {}).get('median'))} | {_f(ratio)} | {_f(_get(r, 'PDR (rotation vector)', 'error_m', 'mean'))} | "
            f"{_f(_get(r, 'LIO', 'error_m', 'mean'))} | {_f(_get(r, 'PDR+map', 'error_m', 'mean'))} | "
            f"{_f(_get(r, 'LIO+map', 'error_m', 'mean'))} | {_f((sl or {}).get('mean'))} / "
            f"{_f(_get(s, 'LIO', 'error_m', 'mean') if s else None)} |")
    lines += ["", "Where the segment error comes from (test walks; length: mean | |p(b) - p(a)| - |g(b) - g(a)| |, how much a "
              "row over- or under-shoots; heading: median angle between its displacement and the surveyed one, segments of "
              "2 m or more). PDR's heading is the phone's rotation vector (magnetic north); LIO's, for a model trained "
              "with `data.yaw: auto` (the default; the hold on these phones' calibrated gyroscopes), the gyroscope's yaw "
              "held to the rotation vector's "
              "running mean (blenav.filters.yaw_hold), which follows the turns without the magnetic field's local "
              "wander but keeps the rotation vector's offset over the walk (the gyroscope has no north).", "",
              "| floor | row | segment error | length error | heading error |", "|---|---|---|---|---|"]
    for fl in sorted(floors):
        for row in ("PDR (rotation vector)", "LIO", "LIO+map"):
            se = _get(floors[fl], row, "segment_error_m") or {}
            if se:
                lines.append(f"| {fl} | {row} | {_f(se.get('mean'))} | {_f(se.get('length_abs_mean'))} | "
                             f"{_f(se.get('heading_abs_median_deg'), 1)} deg |")
    if runs:
        lines += ["", "Training runs (validation walks are a held-out share of the training walks; PDR on the same "
                  "validation segments):", "", "| run | model | steps | stop | wall s | walks | best val. segment error | "
                  "PDR on it |", "|---|---|---|---|---|---|---|---|"]
        for name, info in sorted(runs.items()):
            d = (info.get("data") or {}).get("train") or {}
            lines.append(f"| {name} | {info.get('model', '--')} | {info.get('steps')} | {info.get('stop_reason')} | "
                         f"{_f(info.get('fit_wall_s'), 0)} | {d.get('walks')} | {_f(info.get('best_val_error_m'))} | "
                         f"{_f(info.get('baseline_val_error_m'))} |")
    return "\n".join(lines) + "\n"


def write_inertial(out_root: str | Path, page: str | Path, command: str = "make inertial-tables") -> str:
    """Read OUT_ROOT's results and write ``page``; returns a one-line summary."""
    root = Path(out_root)
    floors, sim_only = {}, {}
    for d in sorted(p for p in root.iterdir() if (p / "results.json").is_file()):
        res = json.loads((d / "results.json").read_text(encoding="utf-8"))
        (sim_only if d.name.startswith("sim_") else floors)[d.name.removeprefix("sim_")] = res
    if not floors:
        raise ValueError(f"{root} holds no <floor>/results.json (run make inertial-tables)")
    runs_file = root / "runs.json"
    runs = json.loads(runs_file.read_text(encoding="utf-8")) if runs_file.is_file() else None
    write_text(Path(page), inertial_markdown(floors, sim_only, runs, command))
    return f"wrote {page} ({len(floors)} floors, {len(sim_only)} simulator-only)"
