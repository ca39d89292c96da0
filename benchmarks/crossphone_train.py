"""Time to converge of the cross-phone training on this CPU: TransNet+LocNet (scenario 2, the losses of eq. 3.6,
receiver augmentation on) under the default step budget (conf/trainer/cpu.yaml ``budget``) on a small survey
(about 2k training windows), a medium one (about 10k) and a large one (about 50k), against the issue's budgets of
5 minutes (2k) and 15 minutes (10k and 50k: the issue names none for 10k; 15 min is the larger survey's).

Each size is a campus_floor dataset of the six labelled phones simulated here (skipped when ``--data-*``
exists): ``--small`` walks of 240 s (default 12: about 2,300 training windows after the 20 % validation split)
``--medium`` walks of 600 s (default 21: about 10k) and ``--large`` walks of 600 s (default 105: about 50k). The real ``train(cfg)`` (``experiment=crossphone_s2``,
``data.holdout=0``) runs to its end: early stopping or the step budget. Printed per size: training windows,
steps, stop reason, wall time (the whole fit: validation checks, checkpoints and the report included), the
best validation error beside KNN's on the same windows, and the verdict against the budget. The step
budget is the default ``auto`` one (:func:`blenav.learn.common.budget.budget_steps`: about 6,500 steps of batch 128 at
2.3k windows -- ``data.batch_size: auto`` picks 128 under 2,560 windows and doubles the steps -- about 6,700 of
batch 256 at 10k, 15,000 at 50k). The 1-min load average before and after each run is printed, and the process' CPU
time beside the wall time: on a shared machine the times change a lot. ``--threads 0`` (the default here) is
torch's default, all cores of the machine (both on this one); ``--threads 1`` is ``train.py``'s default
``threads: 1``, which suits a machine shared with other jobs (with one thread, the CPU time is about the wall
time the run would take alone on a core).

    nice -n 10 .venv/bin/python benchmarks/crossphone_train.py [--sizes small,medium,large] [--data-small DIR] ...
"""

from __future__ import annotations

import argparse
import os
import tempfile
import time
from pathlib import Path

import torch

from blenav.cli.sim import run as sim_run
from blenav.configs import compose
from blenav.learn.train import train

PHONES = "[iphone-7,iphone-8,iphone-xr,galaxy-s10,galaxy-note9,galaxy-a50]"
BUDGET_S = {"small": 5 * 60, "medium": 15 * 60, "large": 15 * 60}
WALK_S = {"small": 240.0, "medium": 600.0, "large": 600.0}


def simulate(data: Path, sessions: int, duration_s: float) -> None:
    if (data / "dataset.yaml").exists():
        return
    print(f"simulating {sessions} x {duration_s:.0f} s on campus_floor with the six labelled phones into {data} ...")
    sim_run(compose("sim", "sim=campus_floor", "seed=21", f"out={data}", f"duration_s={duration_s}",
                    f"sessions={sessions}", "progress=false", "sim.carriers=[pedestrian]",
                    f"sim.receivers={PHONES}", "sim.unlabelled_every=0", "overwrite=true"))


def converge(data: Path, threads: int | None, *extra: str, keep: Path | None = None) -> dict:
    with tempfile.TemporaryDirectory() as tmp:
        out = keep if keep is not None else tmp
        over = ["experiment=crossphone_s2", f"data={data}", f"out={out}", "trainer.enable_progress_bar=false",
                "data.holdout=0", f"plots={keep is not None}", f"threads={threads if threads else 'null'}", *extra]
        t0, c0 = time.perf_counter(), time.process_time()
        _, objs = train(compose("train", *over))
        wall, cpu = time.perf_counter() - t0, time.process_time() - c0
    info = objs["training"]
    return {"windows": len(objs["datamodule"].sets["train"]), "wall_s": wall, "cpu_s": cpu, **info}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sizes", default="small,medium,large")
    ap.add_argument("--data-small", default="data/bench_crossphone_2k")
    ap.add_argument("--data-medium", default="data/bench_crossphone_10k")
    ap.add_argument("--data-large", default="data/bench_crossphone")
    ap.add_argument("--small", type=int, default=12, help="240 s walks of the small survey")
    ap.add_argument("--medium", type=int, default=21, help="600 s walks of the medium survey (about 10k windows)")
    ap.add_argument("--large", type=int, default=105, help="600 s walks of the large survey (105: about 50k windows)")
    ap.add_argument("--threads", type=int, default=0, help="torch threads (0: torch's default, all cores)")
    ap.add_argument("--out", default=None, help="keep each size's run (training.json with the learning curve, "
                    "learning_curves.png, last.ckpt) in OUT/SIZE instead of a temporary folder; an existing run is "
                    "resumed, so give a new folder to time one")
    ap.add_argument("extra", nargs="*", help="more train.py overrides, e.g. model=locnet")
    args = ap.parse_args()
    default_threads = torch.get_num_threads()
    for size in [s.strip() for s in args.sizes.split(",") if s.strip()]:
        if size not in BUDGET_S:
            raise SystemExit(f"--sizes: {size!r} is not one of {sorted(BUDGET_S)}")
        data = Path(getattr(args, f"data_{size}"))
        simulate(data, getattr(args, size), WALK_S[size])
        torch.set_num_threads(default_threads)  # train(threads=1) changed it for the whole process
        print(f"load average (1 min) before {size}: {os.getloadavg()[0]:.2f} on {os.cpu_count()} cores", flush=True)
        keep = Path(args.out) / size if args.out else None
        r = converge(data, args.threads or None, *args.extra, keep=keep)
        budget = BUDGET_S[size]
        verdict = "MEETS" if r["wall_s"] <= budget else "MISSES"
        print(f"{size}: {r['windows']:,} training windows; {r['steps']} of {r['budget_steps']} budget steps, stop reason {r['stop_reason']} "
              f"(converged: {r['converged']}); {r['wall_s'] / 60:.1f} min wall, {r['cpu_s'] / 60:.1f} min of CPU time; best validation error "
              f"{r['best_val_error_m']:.2f} m at step {r['best_step']}, KNN {r['knn_val_error_m']:.2f} m; "
              f"verdict: {verdict} the {budget // 60} min budget ({r['wall_s'] / budget:.2f}x); "
              f"load average (1 min) after: {os.getloadavg()[0]:.2f}", flush=True)


if __name__ == "__main__":
    main()
