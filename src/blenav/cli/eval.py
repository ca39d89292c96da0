"""``blenav-eval experiment=NAME data=DIR runs=N out=OUT [sessions=ID,ID] [model_path=PATH] [overwrite=true]``: compare
localization methods (``model_path``: a trained model the experiment evaluates; ``model=PATH`` is its deprecated
spelling).

OUT appears whole or not at all (:mod:`blenav.cli.outdir`): the evaluation writes into ``.OUT.tmp-<pid>`` beside it
and renames that to OUT at the end. An existing OUT is refused unless ``overwrite=true``, which replaces it whole
(no stale session folder of an earlier run stays beside the new results.json) and reuses its ``runs/`` (trained
cross-phone runs) and ``fixes/`` (computed BLE fixes). A failed run leaves OUT as it was; Ctrl-C or SIGTERM prints
``blenav-eval: interrupted; removed partial output ...`` and exits 130 / 143. Session ids (and method labels) that
map to one output name (``s 000``, ``s_000``) are refused before any work."""

from __future__ import annotations

import sys
from functools import partial

from omegaconf import DictConfig, OmegaConf

from blenav.configs import cli_overrides

from .common import run_hydra
from .outdir import fresh_output

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
    inputs = [cfg.data.path, cfg.get("model_path")]  # never inside an OUT that overwrite=true deletes
    with fresh_output(cfg.out, bool(cfg.get("overwrite", False)), inputs) as tmp:
        res = evaluate(OmegaConf.merge(cfg, {"out": str(tmp)}))
    for line in summary_lines(res):
        print(line)
    print(f"wrote {cfg.out}/results.json")


def main() -> None:
    run_hydra(PROG, "eval", task, sys.argv[1:], convert=partial(cli_overrides, deprecated_model_path=True))


if __name__ == "__main__":
    main()
