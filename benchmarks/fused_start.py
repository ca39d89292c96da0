"""What the unknown start costs the fused rows (issue 30): ``fused-online`` / ``fused-offline`` of
``experiment=realwalks`` on a floor's test walks beside the same rows started at each walk's first surveyed
waypoint (``start.source: first_waypoint``, std 1 m: **reads the scored walk's ground truth**, a bound, not a
method: the PDR rows of the realwalks tables start the same way), and where the difference comes from: the walks
whose fixes are far off (their fingerprint row's mean error at the walk's waypoints above ``--far`` m) against the
others, and how far each group's surveyed waypoints lie from the train walks (the survey: their positions between
waypoints on the fused rows' walkable grid, :func:`blenav.localizers.survey.survey_distance`, as their off-survey
model).

    .venv/bin/python benchmarks/fused_start.py FLOOR_DATA [--out OUT] [--far 10]

It runs ``blenav-eval experiment=realwalks data=FLOOR_DATA runs=1 out=OUT`` with the rows ``KNN-WiFi+BLE``,
``fused-online``, ``fused-offline`` and the two known-start rows (the command is printed), then reads OUT's
results.json. About 1 min a floor.
"""

from __future__ import annotations

import argparse
import json
import shlex
import tempfile
from pathlib import Path

import numpy as np
from omegaconf import OmegaConf

from blenav.cli.eval import main as eval_main
from blenav.cli.realwalks import experiment_config
from blenav.crf.grid import build_grid
from blenav.eval.config import parse_eval_config
from blenav.eval.sessions import open_dataset, scored_sessions, train_test
from blenav.localizers.survey import survey_distance

FIX_ROW = "KNN-WiFi+BLE"  # the fused rows' fixes (role both)
ROWS = ("fused-online", "fused-offline")


#: the settings of the realwalks rows the known-start twins copy (the rest is conf/localizer/fused_walk.yaml's, as
#: the rows' own)
COPIED = ("mode", "estimate", "fix_roles", "novelty", "fix_std_scale")


def eval_args(data: str, out: Path) -> list[str]:
    """The blenav-eval overrides of the run: the realwalks rows and their known-start twins (label ``ROW@start``), each
    twin with its row's :data:`COPIED` settings as the experiment composes them."""
    methods = experiment_config(f"data={data}").methods
    args = ["experiment=realwalks", f"data={data}", "runs=1", f"out={out}", "overwrite=true", "progress=false"]
    only = [FIX_ROW, *ROWS]
    for row, mode in zip(ROWS, ("online", "offline")):
        key, node = f"fused_{mode}_start", methods[f"fused_{mode}"]
        only.append(f"{row}@start")
        args += [f"+localizer@methods.{key}=fused_walk", f"methods.{key}.label={row}@start",
                 f"methods.{key}.start.source=first_waypoint"]
        own = OmegaConf.to_container(node, resolve=True)
        args += [f"methods.{key}.{k}={v}" for k, v in _leaves({k: own[k] for k in COPIED})]
    return args + [f"only=[{','.join(only)}]"]


def _leaves(node, prefix: str = "") -> list[tuple[str, str]]:
    """(dotted key, Hydra value) of every leaf of ``node`` (dicts descended into, lists written [a,b])."""
    out = []
    for k, v in node.items():
        if isinstance(v, dict):
            out += _leaves(v, f"{prefix}{k}.")
        else:
            out.append((f"{prefix}{k}", f"[{','.join(map(str, v))}]" if isinstance(v, list) else str(v)))
    return out


def summarise(results: dict, far_m: float) -> list[str]:
    """The table's lines: per row the mean / median / p90 error at the test waypoints and the share of walks within
    5 m; then each row's mean over the walks whose fixes are far (> far_m) and the others."""
    m = results["methods"]
    lines = ["| row | mean | median | p90 | walks within 5 m | mean, walks with fixes > far | mean, the other walks |",
             "|---|---|---|---|---|---|---|"]
    fix = {s: v["error_m"]["mean"] for s, v in m[FIX_ROW]["per_session"].items()}
    far = {s for s, e in fix.items() if e > far_m}
    for row in (FIX_ROW, *ROWS, *(f"{r}@start" for r in ROWS)):
        if row not in m:
            continue
        per = m[row]["per_session"]
        a = [per[s]["error_m"]["mean"] for s in per if s in far]
        b = [per[s]["error_m"]["mean"] for s in per if s not in far]
        e = m[row]["error_m"]
        lines.append(f"| {row} | {e['mean']:.2f} | {e['median']:.2f} | {e['p90']:.2f} | "
                     f"{100 * m[row]['walks_within_m']['5']:.0f} % | {np.mean(a) if a else float('nan'):.2f} "
                     f"({len(a)} walks) | {np.mean(b) if b else float('nan'):.2f} ({len(b)} walks) |")
    return lines


def off_survey(data: str, results: dict, far_m: float) -> list[str]:
    """Per group of test walks (fixes far / the others): the mean distance (m) of their surveyed waypoints to the
    train walks' positions and the share of those waypoints more than 5 m from them."""
    composed = experiment_config(f"data={data}")
    cell, step = (float(composed.methods.fused_offline.grid[k]) for k in ("cell_m", "max_step_m"))  # the rows' grid
    cfg = parse_eval_config(composed)
    ds = open_dataset(cfg)
    train, test = train_test(cfg, ds, scored_sessions(cfg, ds))
    fix = results["methods"][FIX_ROW]["per_session"]
    groups: dict[str, list] = {"far": [], "other": []}
    dist: dict = {}
    for s in test:
        if s.id not in fix:
            continue
        floor = (s.building.id, str(s.meta.get("floor")))
        if floor not in dist:
            grid = build_grid(s.floor, cell_m=cell, max_step_m=step)
            same = [w for w in train if w.labelled and (w.building.id, str(w.meta.get("floor"))) == floor]
            dist[floor] = (grid, survey_distance(grid, same)[0])
        grid, d = dist[floor]
        groups["far" if fix[s.id]["error_m"]["mean"] > far_m else "other"].append(
            d[grid.cell_of(s.groundtruth[["x", "y"]].to_numpy(float))])
    return [f"walks with fixes {name}: {len(g)}; their waypoints {np.concatenate(g).mean():.1f} m from the survey on "
            f"average, {100 * np.mean(np.concatenate(g) > 5.0):.0f} % more than 5 m" for name, g in groups.items() if g]


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("data")
    p.add_argument("--out", type=Path, help="the evaluation's output folder (default: a temporary one)")
    p.add_argument("--far", type=float, default=10.0,
                   help="a walk's fixes are far when their mean error exceeds it (m)")
    args = p.parse_args()
    out = args.out or Path(tempfile.mkdtemp(prefix="fused_start_"))
    argv = eval_args(args.data, out)
    print("blenav-eval " + " ".join(shlex.quote(a) for a in argv), flush=True)
    eval_main(argv)
    results = json.loads((out / "results.json").read_text())
    n = len(results["methods"][FIX_ROW]["per_session"])
    print(f"\n{args.data}: {n} test walks; error at the test waypoints, m; "
          f"'@start': started at the first surveyed waypoint (ground truth, a bound)")
    print("\n".join(summarise(results, args.far)))
    print("\n".join(off_survey(args.data, results, args.far)))


if __name__ == "__main__":
    main()
