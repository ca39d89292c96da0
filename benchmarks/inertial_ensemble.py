"""The learned inertial odometry averaged over turns of its input frame (issue 31;
:class:`blenav.models.inertial.YawEnsemble`), chosen on the training run's own validation walks: no test walk is read.

For each run folder (``train.py experiment=inertial ... out=RUN``): the run's data config (``RUN/config.yaml``) rebuilds
its validation walks (the same seeded held-out share of its training walks, ``data.val_fraction``), and the network of
``RUN/last.ckpt`` is scored on their waypoint segments with k = 1, 2, 4, 8 ... turns: the mean segment error
|D - g| (m) of the validation loss (:func:`blenav.learn.inertial.module.segment_loss`, the figure of
``training.json``'s ``best_val_error_m``), its median, and the seconds per 1,000 windows on this machine.

    .venv/bin/python benchmarks/inertial_ensemble.py RUN [RUN ...] [--yaws 1 2 4 8]
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np
import torch
from omegaconf import OmegaConf

from blenav.learn.inertial.checkpoint import load_inertial
from blenav.learn.inertial.data import InertialDataModule
from blenav.learn.inertial.module import segment_integral
from blenav.learn.inertial.train import inertial_data_config
from blenav.models.inertial import YawEnsemble


def val_errors(net, batches: list[dict], k: int) -> tuple[np.ndarray, float, int]:
    """(segment errors (S,) m, seconds, windows) of ``net`` averaged over ``k`` turns on the validation ``batches``."""
    ens, errs, secs, n = YawEnsemble(net, k).eval(), [], 0.0, 0
    with torch.no_grad():
        for b in batches:
            t0 = time.perf_counter()
            out = ens(b["windows"])
            secs += time.perf_counter() - t0
            n += len(b["windows"])
            D, _, _ = segment_integral(out, b["segment"], b["weight"], b["target"].shape[0], b.get("psi"))
            errs.append((D - b["target"]).norm(dim=1).numpy())
    return np.concatenate(errs), secs, n


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("runs", nargs="+", type=Path, help="run folders of train.py experiment=inertial")
    ap.add_argument("--yaws", nargs="+", type=int, default=[1, 2, 4, 8], help="turns of the frame to average")
    a = ap.parse_args(argv)
    print("| run | val walks | segments | " + " | ".join(f"k = {k}: mean / median m, s per 1k windows" for k in a.yaws)
          + " |")
    print("|---|---|---|" + "---|" * len(a.yaws))
    for run in a.runs:
        cfg = OmegaConf.load(run / "config.yaml")  # the run's own resolved config (YAML, nothing instantiated)
        dm = InertialDataModule(inertial_data_config(cfg))
        dm.setup()
        if "val" not in dm.sets:
            print(f"| {run.name} | 0 | 0 |" + " - |" * len(a.yaws))
            continue
        net, _ = load_inertial(run / "last.ckpt")
        batches = list(dm.val_dataloader())
        cells = []
        for k in a.yaws:
            e, secs, n = val_errors(net, batches, k)
            cells.append(f"{e.mean():.3f} / {np.median(e):.3f}, {1000 * secs / max(n, 1):.2f}")
        print(f"| {run.name} | {len(dm.walks['val'])} | {len(dm.segments['val'])} | " + " | ".join(cells) + " |",
              flush=True)


if __name__ == "__main__":
    main()
