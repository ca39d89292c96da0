"""Scenario 2 training speed on this CPU: TransNet+LocNet with the losses of eq. 3.6 on about 50k windows.

The issue's budget: scenario 2 training (50 epochs, batch 256, Adam lr 1e-4, Roy section 3.1.4) on 50k
windows in under 15 min on the 2-core CPU. The benchmark simulates a campus_floor dataset of the six
labelled phones (skipped when ``--data`` exists), times ``--epochs`` epochs of the real ``train(cfg)``
(``experiment=crossphone_s2``, receiver augmentation on as configured) and projects 50 epochs as the
first epoch plus 49 times the mean of the later ones (every epoch is the same work: same windows, same
batches; the first also warms up). References in the same run: LocNet alone (baseline 2) on the same
windows (what TransNet and the SSL term cost), TransNet+LocNet without the receiver augmentation (what it
costs), and scenario 2 with torch's default threads (all cores) against the configured ``threads=1``.
The 1-min load average before timing is printed: on a shared machine the figures change a lot.

    .venv/bin/python benchmarks/crossphone_train.py [--data data/bench_crossphone] [--epochs 3]
"""

from __future__ import annotations

import argparse
import os
import tempfile
import time
from pathlib import Path

import lightning as L
import torch

from blenav.cli.sim import run as sim_run
from blenav.configs import compose
from blenav.learn.train import train

BUDGET_S = 15 * 60
PHONES = "[iphone-7,iphone-8,iphone-xr,galaxy-s10,galaxy-note9,galaxy-a50]"


class EpochTimer(L.Callback):
    def __init__(self):
        self.times: list[float] = []

    def on_train_epoch_start(self, trainer, module):
        self._t0 = time.perf_counter()

    def on_train_epoch_end(self, trainer, module):
        self.times.append(time.perf_counter() - self._t0)


def timed(experiment: str, data: Path, epochs: int, *extra: str) -> tuple[int, list[float]]:
    timer = EpochTimer()
    with tempfile.TemporaryDirectory() as out:
        cfg = compose("train", f"experiment={experiment}", f"data={data}", f"out={out}", f"trainer.max_epochs={epochs}",
                      "trainer.enable_progress_bar=false", "data.holdout=0", *extra)
        _, objs = train(cfg, callbacks=[timer])
    return len(objs["datamodule"].sets["train"]), timer.times


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", default="data/bench_crossphone")
    ap.add_argument("--sessions", type=int, default=105, help="10-min walks to simulate (105: about 50k windows)")
    ap.add_argument("--epochs", type=int, default=3)
    ap.add_argument("--no-threads-reference", action="store_true", help="skip the all-core-threads reference run")
    args = ap.parse_args()
    data = Path(args.data)
    if not (data / "dataset.yaml").exists():
        print(f"simulating {args.sessions} x 600 s on campus_floor with the six labelled phones into {data} ...")
        sim_run(compose("sim", "sim=campus_floor", "seed=21", f"out={data}", "duration_s=600",
                        f"sessions={args.sessions}", "progress=false", "sim.carriers=[pedestrian]",
                        f"sim.receivers={PHONES}", "sim.unlabelled_every=0", "overwrite=true"))
    print(f"cores: {torch.get_num_threads()} (torch default threads)")
    rows = {}
    default_threads = torch.get_num_threads()
    print(f"load average (1 min) before timing: {os.getloadavg()[0]:.2f} on {os.cpu_count()} cores")
    runs = [("TransNet+LocNet (scenario 2)", "crossphone_s2", args.epochs, ()),
            ("LocNet (baseline 2, reference)", "crossphone_s2", args.epochs, ("model=locnet",)),
            ("TransNet+LocNet, no receiver aug", "crossphone_s2", args.epochs,
             ("model.augment.offset_db_std=0", "model.augment.gain_std=0", "model.augment.dropout_max=0"))]
    if not args.no_threads_reference:
        runs.append(("TransNet+LocNet, all-core threads", "crossphone_s2", 2, ("threads=null",)))
    for name, exp, epochs, extra in runs:
        torch.set_num_threads(default_threads)  # train(threads=1) changed it for the whole process
        n, times = timed(exp, data, epochs, *extra)
        steady = times[1:] or times
        per = sum(steady) / len(steady)
        total = times[0] + 49 * per  # the first epoch (warm-up included) as measured, 49 steady ones
        rows[name] = (per, total)
        print(f"{name:32s} {n:,} training windows; epochs {', '.join(f'{t:.1f}' for t in times)} s; "
              f"50 epochs projected {total / 60:.1f} min")
    s2, total = rows["TransNet+LocNet (scenario 2)"]
    print(f"ratio TransNet+LocNet / LocNet per epoch: {s2 / rows['LocNet (baseline 2, reference)'][0]:.2f}x")
    print(f"ratio with / without receiver augmentation per epoch: "
          f"{s2 / rows['TransNet+LocNet, no receiver aug'][0]:.2f}x")
    if "TransNet+LocNet, all-core threads" in rows:
        print(f"all-core threads / threads=1: {rows['TransNet+LocNet, all-core threads'][0] / s2:.2f}x")
    verdict = "MEETS" if total <= BUDGET_S else "MISSES"
    print(f"verdict: {verdict} the 15 min budget: 50 epochs of scenario 2 projected {total / 60:.1f} min "
          f"({total / BUDGET_S:.2f}x the budget)")


if __name__ == "__main__":
    main()
