"""``blenav-eval experiment=NAME data=DIR runs=N out=OUT [sessions=ID,ID] [model_path=PATH]``: compare localization
methods (``model_path``: a trained model the experiment evaluates; ``model=PATH`` is its deprecated spelling).

A failed evaluation leaves no output folder behind when it created it."""

from __future__ import annotations

import shutil
import sys
from functools import partial
from pathlib import Path

from omegaconf import DictConfig, OmegaConf

from blenav.configs import cli_overrides

from .common import run_hydra

PROG = "blenav-eval"


def summary_lines(res: dict) -> list[str]:
    """One console line per method: its error, or why it was skipped."""
    out = []
    for name, m in res["methods"].items():
        if "rmse_m" not in m:
            out.append(f"{name:12s} skipped on {len(m['skipped'])} session(s): {next(iter(m['skipped'].values()))}")
        elif m.get("kind") == "bound":  # the leaderboard's PCRLB (blenav.eval.pcrlb): no estimates, no timing
            out.append(f"{name:12s} RMSE {m['rmse_m']['mean']:.2f} m  (lower bound on the position error)")
        elif "per_device" in m:  # a window-level comparison (crossphone): absolute error per window
            e = m["error_m"]
            out.append(f"{name:22s} error mean {e['mean']:.2f} m  median {e['median']:.2f}  p90 {e['p90']:.2f}  "
                       f"max {e['max']:.2f}  ({m['n_windows']} windows)")
        else:
            r = m["rmse_m"]
            out.append(f"{name:12s} RMSE {r['mean']:.2f} +- {r['stderr']:.2f} m  p75 {m['error_m']['p75']:.2f} m  "
                       f"({m['realtime_factor']:.0f}x real time)")
    for sid, streams in (res.get("dropped") or {}).items():
        what = "; ".join(f"{stream}: " + ", ".join(f"{n} {why}" for why, n in reasons.items())
                         for stream, reasons in streams.items())
        out.append(f"dropped rows in {sid}: {what}")
    return out


def task(cfg: DictConfig) -> None:
    from blenav.eval.harness import evaluate

    if OmegaConf.is_missing(cfg.data, "path"):
        raise ValueError("name the dataset to evaluate on: data=DIR (a format-v1 dataset folder)")
    out = Path(cfg.out)
    existed = out.exists()
    try:
        res = evaluate(cfg)
    except BaseException:
        if not existed and out.exists():  # no half-written output folder
            shutil.rmtree(out, ignore_errors=True)
        raise
    for line in summary_lines(res):
        print(line)
    print(f"wrote {cfg.out}/results.json")


def main() -> None:
    run_hydra(PROG, "eval", task, sys.argv[1:], convert=partial(cli_overrides, deprecated_model_path=True))


if __name__ == "__main__":
    main()
