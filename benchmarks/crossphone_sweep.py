"""The smallest simulated survey at which TransNet+LocNet overtakes KNN (issue 16): a sweep over survey sizes.

Each point is the issue's small-survey setting at another walk length: ``campus_floor`` simulated with six
receiver profiles, four walks of ``D`` seconds each (24 sessions), the building renamed (``sim.name``), then the
contract command ``blenav-eval experiment=crossphone_003 ... runs=1`` with three receivers labelled (three walks
each trained or validated, one tested), one unlabelled (two walks unlabelled, two tested; its semi-supervised
stage is not run here) and two never seen. Only TransNet+LocNet is trained (``--all-methods``: every method of
the experiment); the baselines (KNN, Bayesian, KRR+KF) are fitted on the same windows. Printed per seed and
walk length: training windows, TransNet+LocNet's and KNN's mean error (m) on the labelled receivers, on the
unseen ones (the unlabelled one included: no label of it was used) and overall, the training's steps and stop
reason; at the end, the smallest walk length at which TransNet+LocNet is ahead of KNN on the unseen receivers
and overall for every seed.

    .venv/bin/python benchmarks/crossphone_sweep.py [--durations 15,30,60,240] [--seeds 16,17] [--root DIR]
    make crossphone-sweep

Heavy: one TransNet+LocNet training per point (a few minutes each on this CPU); run it under ``nice -n 10``.
Simulations and runs already in ``--root`` are reused (blenav-eval reuses a complete run).
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
from pathlib import Path

from blenav.eval.report import pooled_mean

BIN = Path(sys.executable).parent
#: receiver profiles of the simulator (blenav.sim.receivers) standing in for a deployer's phones A-F; none of
#: them is in crossphone_003's default split, so every device name is given on the command line
LABELLED = ["honor-20-pro", "galaxy-a50", "iphone-7"]
UNLABELLED = ["mi-9t-pro"]
UNSEEN = ["pixel-4xl", "redmi-note8"]


def simulate(data: Path, seed: int, duration_s: float, name: str) -> None:
    if (data / "dataset.yaml").exists():
        return
    rx = ",".join(LABELLED + UNLABELLED + UNSEEN)
    subprocess.run([str(BIN / "blenav-sim"), "sim=campus_floor", f"seed={seed}", f"out={data}",
                    f"duration_s={duration_s:g}", "sessions=24", "progress=false", "sim.carriers=[pedestrian]",
                    f"sim.receivers=[{rx}]", "sim.unlabelled_every=0", f"sim.name={name}", "overwrite=true"],
                   check=True)


def evaluate(data: Path, out: Path, all_methods: bool, *extra: str) -> dict:
    if not (out / "results.json").exists():
        off = [] if all_methods else [f"experiment.learned.{k}=null" for k in ("locnet", "locnet_aug", "semi", "dlrnn")]
        cmd = [str(BIN / "blenav-eval"), "experiment=crossphone_003", f"data={data}", "runs=1", f"out={out}",
               f"data.train_devices=[{','.join(LABELLED)}]", f"data.unlabelled_devices=[{','.join(UNLABELLED)}]",
               f"data.test_devices=[{','.join(LABELLED + UNLABELLED + UNSEEN)}]", "progress=false", *off, *extra]
        print("$", " ".join(cmd[1:]), flush=True)
        subprocess.run(cmd, check=True)
    return json.loads((out / "results.json").read_text(encoding="utf-8"))


def pooled(method: dict, devices: list[str]) -> float:
    """Mean error over the windows of ``devices`` (:func:`blenav.eval.report.pooled_mean`: per-device means
    weighted by their window counts); NaN when none of them was scored."""
    v = pooled_mean(method, devices)
    return float("nan") if v is None else v


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--durations", default="15,30,60,240", help="walk lengths in s (four walks per receiver)")
    ap.add_argument("--seeds", default="16,17")
    ap.add_argument("--root", default="data/issue16/sweep")
    ap.add_argument("--all-methods", action="store_true", help="train every learned method, not only TransNet+LocNet")
    ap.add_argument("extra", nargs="*", help="more blenav-eval overrides")
    args = ap.parse_args()
    root = Path(args.root)
    durations = [float(d) for d in args.durations.split(",") if d.strip()]
    seeds = [int(s) for s in args.seeds.split(",") if s.strip()]
    rows = []
    for seed in seeds:
        for dur in durations:
            tag = f"s{seed}_d{dur:g}"
            data = root / f"sim_{tag}"
            simulate(data, seed, dur, name=f"annex_{seed}")
            print(f"load average (1 min) before {tag}: {os.getloadavg()[0]:.2f} on {os.cpu_count()} cores", flush=True)
            res = evaluate(data, root / f"out_{tag}", args.all_methods, *args.extra)
            tl, knn = res["methods"]["TransNet+LocNet"], res["methods"]["KNN"]
            tr = tl.get("training") or {}
            row = {"seed": seed, "duration_s": dur, "train_windows": tr.get("train_windows"),
                   "steps": tr.get("steps"), "stop": tr.get("stop_reason"), "train_s": tl.get("train_s")}
            for name, m in (("tl", tl), ("knn", knn)):
                row[f"{name}_lab"] = pooled(m, LABELLED)
                row[f"{name}_unseen"] = pooled(m, UNLABELLED + UNSEEN)
                row[f"{name}_all"] = m["error_m"]["mean"]
            rows.append(row)
            print(json.dumps(row), flush=True)
    print("\nseed | walk s | training windows | TL / KNN labelled | TL / KNN unseen | TL / KNN all | steps, stop | train s")
    for r in rows:
        print(f"{r['seed']} | {r['duration_s']:g} | {r['train_windows']} | {r['tl_lab']:.2f} / {r['knn_lab']:.2f} | "
              f"{r['tl_unseen']:.2f} / {r['knn_unseen']:.2f} | {r['tl_all']:.2f} / {r['knn_all']:.2f} | "
              f"{r['steps']}, {r['stop']} | {r['train_s'] if r['train_s'] is None else round(r['train_s'])}")
    for what in ("unseen", "all"):
        ahead = [d for d in durations
                 if all(r[f"tl_{what}"] < r[f"knn_{what}"] for r in rows if r["duration_s"] == d)]
        # the smallest size from which on it stays ahead at every larger size of the sweep
        smallest = next((d for d in durations if all(x in ahead for x in durations if x >= d)), None)
        print(f"TransNet+LocNet ahead of KNN ({what}) for every seed from walks of: "
              f"{'never in this sweep' if smallest is None else f'{smallest:g} s'}")
    (root / "sweep.json").write_text(json.dumps(rows, indent=1) + "\n", encoding="utf-8")


if __name__ == "__main__":
    main()
