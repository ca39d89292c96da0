"""Where a cross-phone training step's time goes on this CPU: TransNet+LocNet (scenario 2, the losses of eq. 3.6, the
receiver augmentation on) on one batch of the 2k benchmark survey (``benchmarks/crossphone_train.py``; 50 beacons,
H = 5), each part against the code it replaced. The batch is the run's: ``data.batch_size: auto`` gives 128 on
the 2k survey and 256 on the 50k one; a batch of a given size costs the same whatever the survey, so
``data.batch_size=256`` and ``=128`` on one survey compare the two (the auto batch's step cost).

Printed, median of ``--repeat`` calls after one warm-up:
- fetching a batch: ``WindowTensors.__getitems__`` (one indexing per tensor) against one tuple per window stacked
  again (the same rows through a ``ConcatDataset``, which has no batched fetch);
- the eq. 3.2-3.4 SSL loss, forward and forward + backward: the compiled loop (``losses._ssl_kernel``) against the
  chunked tensor form (``_SSLDense`` with ``chunk``, what other devices run);
- the two-layer LSTM over the windows and their previous windows, forward + backward;
- a whole step outside Lightning (forward, backward, Adam) with either SSL form.

    .venv/bin/python benchmarks/crossphone_step.py [--data data/bench_crossphone_2k] [--repeat 30] [OVERRIDE ...]
"""

from __future__ import annotations

import argparse
import statistics
import tempfile
import time
from pathlib import Path

import torch
from torch.utils.data import ConcatDataset, DataLoader

from blenav.configs import compose
from blenav.learn.crossphone import losses
from blenav.learn.crossphone.data import WindowDataModule, _collate
from blenav.learn.crossphone.train import build_module, data_config


def median_ms(fn, repeat: int) -> float:
    fn()
    times = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return 1e3 * statistics.median(times)


def forever(loader):
    """Batches of ``loader``, epoch after epoch."""
    while True:
        yield from loader


def overrides(data: str, out: str, *extra: str) -> list[str]:
    return ["experiment=crossphone_s2", f"data={data}", f"out={out}", "data.holdout=0", "plots=false",
            "threads=null", "trainer.enable_progress_bar=false", *extra]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", default="data/bench_crossphone_2k", help="a survey of benchmarks/crossphone_train.py")
    ap.add_argument("--repeat", type=int, default=30)
    ap.add_argument("extra", nargs="*", help="more train.py overrides, e.g. data.batch_size=128")
    args = ap.parse_args()
    if not (Path(args.data) / "dataset.yaml").is_file():
        raise SystemExit(f"{args.data}: no dataset; `python benchmarks/crossphone_train.py --sizes small` simulates it")
    r = args.repeat
    with tempfile.TemporaryDirectory() as out:
        cfg = compose("train", *overrides(args.data, out, *args.extra))
    dm = WindowDataModule(data_config(cfg))
    dm.setup()
    m = build_module(cfg, dm)
    print(f"{len(dm.beacons)} beacons, batch {dm.batch_size}, torch threads {torch.get_num_threads()}; "
          f"median ms of {r} calls", flush=True)
    bs, tr = dm.batch_size, dm.sets["train"]
    batched = forever(DataLoader(tr, batch_size=bs, shuffle=True, collate_fn=_collate))
    rows = forever(DataLoader(ConcatDataset([tr]), batch_size=bs, shuffle=True, collate_fn=_collate))
    a, b = median_ms(lambda: next(batched), r), median_ms(lambda: next(rows), r)
    print(f"fetch a batch: {a:.2f} (one indexing per tensor) vs {b:.2f} (rows stacked): {b / a:.1f}x")

    batch = next(iter(dm.train_dataloader()))
    batch = {**batch, **dict(zip(("S", "S_prev"), m.augment([batch["S"], batch["S_prev"]], m.aug_generator)))}
    S = batch["S"]
    chunk = max(1, (1 << 22) // (S.shape[1] ** 2 * S.shape[2]))
    apply = losses._SSLDense.apply
    chunked = lambda g, w, M: apply(g, w, M, chunk)  # noqa: E731

    g0 = m.transnet(S).detach()  # the translated windows: the loss alone is timed

    def ssl(backward: bool):
        g = g0.clone().requires_grad_(backward)
        L_ = losses.ssl_loss(g, S, m.M)
        if backward:
            L_.backward()

    def step(opt):
        opt.zero_grad()
        m.model_step(batch)["loss"].backward()
        opt.step()

    opt = torch.optim.Adam(m.parameters(), 1e-4)
    for what, fn in (("SSL loss forward", lambda: ssl(False)), ("SSL loss forward + backward", lambda: ssl(True)),
                     ("step outside Lightning (fwd, bwd, Adam)", lambda: step(opt))):
        compiled = median_ms(fn, r)
        losses._SSLDense.apply = chunked
        try:
            tensor = median_ms(fn, r)
        finally:
            losses._SSLDense.apply = apply
        print(f"{what}: {compiled:.2f} (compiled loop) vs {tensor:.2f} (chunked tensors): {tensor / compiled:.1f}x")

    both = torch.cat([S, batch["S_prev"]])

    def lstm():
        m.zero_grad()
        m.locnet(both).sum().backward()

    print(f"LSTM over the windows and their previous windows ({len(both)} sequences), fwd + bwd: "
          f"{median_ms(lstm, r):.2f}")


if __name__ == "__main__":
    main()
