"""Choosing the fused rows' settings on the train walks only (issue 30): the floor's train walks split again into a
survey and tune walks, ``--fraction`` (0.8) of them the survey, repeated for each ``--seeds`` split; the rows
``fused-online`` / ``fused-offline`` of ``experiment=realwalks`` beside variants given as ``--row NAME='YAML body'``
(FusedWalk settings, as a method's block), all scored on the tune walks. No test walk is read: the survey of each
split is train walks, and so are the walks it scores.

Why 80 / 20 and repeated: with every train walk as the survey, the test walks meet a survey twice as dense as a 50 / 50
split of the train walks leaves (the "Which smoother" protocol of docs/results-ilc20.md), so settings that weigh the
fixes chosen there were chosen for fixes further off than the test walks' are; one 80 / 20 split scores only a fifth of
the train walks (10-16 per floor), four seeded splits score most of them.

Printed: per row and floor the mean error at the tune walks' waypoints pooled over the splits (weighted by walks,
the number of splits in brackets), and pooled over the floors; then how the fixes' errors (``KNN-WiFi+BLE``, the fused
rows' fixes) hang together within a walk, on the same tune walks: the correlation of a fix's error vector with the
error of the fix ``lag`` fixes later, and the share of the error power that is each walk's mean error (its offset).

    .venv/bin/python benchmarks/fused_tuning.py FLOOR_DATA... [--seeds 1 2 3 4] [--fraction 0.8] \\
        [--row 's15=estimate: graph, novelty: {weight: 0.5}, fix_std_scale: 1.5'] [--out OUT]

About 1 min per floor and split with two variants (each variant adds a few seconds per tune walk).
"""

from __future__ import annotations

import argparse
import json
import tempfile
from collections import defaultdict
from pathlib import Path

import numpy as np

from blenav.cli.eval import main as eval_main
from blenav.cli.realwalks import train_ids_of
from blenav.eval.metrics import positions_at
from blenav.eval.report_html import read_tum

FIX_ROW = "KNN-WiFi+BLE"
ROWS = ("fused-online", "fused-offline")
LAGS = (1, 2, 3, 5, 8)


def eval_args(data: str, train_ids: list[str], seed: int, fraction: float, rows: dict[str, str], out: Path
              ) -> list[str]:
    """blenav-eval's overrides: experiment=realwalks on ``data``'s train walks ``train_ids``
    (:func:`blenav.cli.realwalks.train_ids_of`) split again (``seed``, ``fraction``), the fix row, the fused rows and
    the variants ``rows`` (name -> YAML body of a FusedWalk block)."""
    args = ["experiment=realwalks", f"data={data}", f"sessions=[{','.join(train_ids)}]",
            f"split.seed={seed}", f"split.train_fraction={fraction}", "runs=1", f"out={out}", "overwrite=true",
            "progress=false"]
    for name, body in rows.items():
        args.append(f"+methods.{name}={{_target_: blenav.localizers.fusedwalk.FusedWalk, label: {name}, {body}}}")
    return args + [f"only=[{','.join([FIX_ROW, *ROWS, *rows])}]"]


def pooled(runs: list[tuple[str, dict]]) -> dict[str, dict[str, tuple[float, int, int]]]:
    """{row: {floor: (mean error, walks, splits)}} of ``runs`` [(floor, results.json's "methods")]: each row's mean
    error at the waypoints over the walks of every split of a floor (a split's mean weighted by its walks); the key
    "pooled" over every floor's walks."""
    acc: dict = defaultdict(lambda: defaultdict(list))
    for floor, methods in runs:
        for row, m in methods.items():
            n = len(m.get("per_session") or {}) or 1
            acc[row][floor].append((float(m["error_m"]["mean"]), n))
            acc[row]["pooled"].append((float(m["error_m"]["mean"]), n))
    return {row: {f: (sum(e * n for e, n in v) / sum(n for _, n in v), sum(n for _, n in v), len(v))
                  for f, v in d.items()} for row, d in acc.items()}


def error_coherence(pairs: list[tuple[np.ndarray, np.ndarray]], lags=LAGS) -> tuple[dict[int, float], float]:
    """({lag: correlation}, offset share) of the walks' fix errors ``pairs`` [(t (F,) s, error vectors (F, 2) m) per
    walk, in time order]: the correlation of error vectors ``lag`` fixes apart (E[e_i . e_j] / sqrt(E|e_i|^2
    E|e_j|^2), pooled over walks), and the share of the error power E|e|^2 that is each walk's mean error vector."""
    corr = {}
    for lag in lags:
        a = [e[:-lag] for _, e in pairs if len(e) > lag]
        b = [e[lag:] for _, e in pairs if len(e) > lag]
        if not a:
            continue
        A, B = np.concatenate(a), np.concatenate(b)
        corr[lag] = float(np.einsum("ij,ij->i", A, B).mean()
                          / np.sqrt(np.einsum("ij,ij->i", A, A).mean() * np.einsum("ij,ij->i", B, B).mean()))
    E = [e for _, e in pairs if len(e)]
    if not E:
        return corr, float("nan")
    offsets = np.concatenate([np.broadcast_to(e.mean(axis=0), e.shape) for e in E])
    allE = np.concatenate(E)
    return corr, float((offsets ** 2).sum(axis=1).mean() / (allE ** 2).sum(axis=1).mean())


def fix_errors(out: Path, row: str = FIX_ROW) -> list[tuple[np.ndarray, np.ndarray]]:
    """[(t, error vectors)] per scored walk of the evaluation in ``out``: the row's estimates (its TUM trajectory,
    read bounded by :func:`blenav.eval.report_html.read_tum`) minus the ground truth interpolated linearly at their
    times, those inside the ground truth's span."""
    pairs = []
    for traj in sorted(out.glob(f"*/trajectories/{row}.tum")):
        gt_file = traj.parent / "groundtruth.tum"
        if not gt_file.exists():
            continue
        (t, xy), (gt, g) = read_tum(traj), read_tum(gt_file)
        if not len(gt):
            continue
        inside = (t >= gt[0]) & (t <= gt[-1])
        t = t[inside]
        pairs.append((t, xy[inside] - positions_at(gt, g[None], t)[0]))
    return pairs


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("data", nargs="+", help="imported ILC floors (blenav-import ilc20)")
    p.add_argument("--seeds", type=int, nargs="+", default=[1, 2, 3, 4])
    p.add_argument("--fraction", type=float, default=0.8, help="share of the train walks that is each split's survey")
    p.add_argument("--row", action="append", default=[], metavar="NAME=BODY",
                   help="a variant row: its label and the YAML body of its FusedWalk block (repeatable)")
    p.add_argument("--out", type=Path, help="the evaluations' parent folder (default: a temporary one)")
    args = p.parse_args()
    rows = dict(r.split("=", 1) for r in args.row)
    root = args.out or Path(tempfile.mkdtemp(prefix="fused_tuning_"))
    runs, pairs = [], defaultdict(list)
    for data in args.data:
        floor, ids = Path(data).name, train_ids_of(data)
        for seed in args.seeds:
            out = root / f"{floor}_s{seed}"
            eval_main(eval_args(data, ids, seed, args.fraction, rows, out))
            runs.append((floor, json.loads((out / "results.json").read_text())["methods"]))
            pairs[floor] += fix_errors(out)
    table = pooled(runs)
    floors = [Path(d).name for d in args.data] + ["pooled"]
    print(f"\nmean error at the tune walks' waypoints (m), train walks split {args.fraction:g} / "
          f"{1 - args.fraction:g}, seeds {' '.join(map(str, args.seeds))}; (splits)")
    print("| row | " + " | ".join(floors) + " |")
    print("|---" * (len(floors) + 1) + "|")
    for row in [FIX_ROW, *ROWS, *rows]:
        if row in table:
            print(f"| {row} | " + " | ".join(f"{table[row][f][0]:.2f} ({table[row][f][2]})" if f in table[row] else "-"
                                            for f in floors) + " |")
    print(f"\n{FIX_ROW}'s errors on the tune walks: correlation of error vectors k fixes apart; share of the error "
          "power that is each walk's own offset")
    for floor, pf in pairs.items():
        corr, share = error_coherence(pf)
        print(f"{floor} ({len(pf)} walk evaluations): " + ", ".join(f"k={k}: {c:.2f}" for k, c in corr.items())
              + f"; offsets {100 * share:.0f} %")


if __name__ == "__main__":
    main()
