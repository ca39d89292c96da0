"""What Lightning's ``self.log`` costs a training step on this CPU, and what skipping the steps no logger keeps
(:func:`blenav.learn.common.trainer.logs_this_step`, as :class:`blenav.learn.crossphone.module.CrossPhoneModule`
does) wins back.

A tiny model (a linear layer, batch 64) trained for ``--steps`` steps three ways: no ``self.log`` call (the
reference), ``--keys`` calls every step, and the same calls only on the steps :func:`logs_this_step` allows
(``log_every_n_steps`` 10, conf/trainer/cpu.yaml's). Printed: seconds per 1,000 steps, milliseconds per call
((every step - reference) / calls), and each variant's ratio to the reference (median of ``--repeat`` fits).

    .venv/bin/python benchmarks/lightning_log.py [--steps 1000] [--keys 4] [--repeat 3]
"""

from __future__ import annotations

import argparse
import statistics
import time
import warnings

import lightning as L
import torch
from torch.utils.data import DataLoader, TensorDataset

from blenav.learn.common.trainer import StepBudget, logs_this_step


class _Tiny(L.LightningModule):
    def __init__(self, keys: int, skip: bool):
        super().__init__()
        self.lin, self.keys, self.skip = torch.nn.Linear(8, 2), keys, skip

    def training_step(self, batch, batch_idx):
        loss = ((self.lin(batch[0]) - batch[1]) ** 2).mean()
        if self.keys and (not self.skip or logs_this_step(self._trainer)):
            for k in range(self.keys):
                self.log(f"train/k{k}", loss.detach(), batch_size=64)
        return loss

    def configure_optimizers(self):
        return torch.optim.Adam(self.parameters())


def _fit_s(steps: int, keys: int, skip: bool) -> float:
    g = torch.Generator().manual_seed(0)
    data = TensorDataset(torch.randn(64 * 17, 8, generator=g), torch.randn(64 * 17, 2, generator=g))
    trainer = L.Trainer(max_epochs=-1, callbacks=[StepBudget(steps)], logger=False, log_every_n_steps=10,
                        enable_checkpointing=False, enable_progress_bar=False, enable_model_summary=False,
                        accelerator="cpu")
    t0 = time.perf_counter()
    trainer.fit(_Tiny(keys, skip), DataLoader(data, batch_size=64))
    return time.perf_counter() - t0


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--steps", type=int, default=1000)
    ap.add_argument("--keys", type=int, default=4, help="self.log calls per step")
    ap.add_argument("--repeat", type=int, default=3)
    args = ap.parse_args()
    torch.set_num_threads(1)
    warnings.filterwarnings("ignore")
    runs = {"no self.log (reference)": (0, False), f"{args.keys} keys every step": (args.keys, False),
            f"{args.keys} keys, logs_this_step": (args.keys, True)}
    med = {name: statistics.median(_fit_s(args.steps, *how) for _ in range(args.repeat)) for name, how in runs.items()}
    ref = med["no self.log (reference)"]
    for name, s in med.items():
        print(f"{name:32s} {1000 * s / args.steps:6.2f} s per 1,000 steps  ratio {s / ref:5.2f}")
    every = med[f"{args.keys} keys every step"]
    print(f"one self.log call: {1000 * (every - ref) / (args.steps * args.keys):.2f} ms")


if __name__ == "__main__":
    main()
