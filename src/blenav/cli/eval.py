"""``blenav-eval experiment=NAME data=DIR runs=N out=OUT [sessions=ID,ID] [model_path=PATH]``: compare localization
methods (``model_path``: a trained model the experiment evaluates; ``model=PATH`` is its deprecated spelling)."""

from __future__ import annotations

import sys

import hydra
from omegaconf import DictConfig

from blenav.configs import cli_overrides, register_configs
from blenav.paths import conf_dir


register_configs()


@hydra.main(config_path=str(conf_dir()), config_name="eval", version_base="1.3")
def _main(cfg: DictConfig) -> None:
    from omegaconf import OmegaConf

    from blenav.eval.harness import EvalError, evaluate

    if OmegaConf.is_missing(cfg.data, "path"):
        print("blenav-eval: error: name the dataset to evaluate on: data=DIR (a format-v1 dataset folder)",
              file=sys.stderr)
        sys.exit(1)
    try:
        res = evaluate(cfg)
    except EvalError as exc:
        print(f"blenav-eval: error: {exc}", file=sys.stderr)
        sys.exit(1)
    for name, m in res["methods"].items():
        if "rmse_m" not in m:
            print(f"{name:12s} skipped on {len(m['skipped'])} session(s): {next(iter(m['skipped'].values()))}")
            continue
        if "per_device" in m:  # a window-level comparison (crossphone): absolute error per window
            e = m["error_m"]
            print(f"{name:22s} error mean {e['mean']:.2f} m  median {e['median']:.2f}  p90 {e['p90']:.2f}  "
                  f"max {e['max']:.2f}  ({m['n_windows']} windows)")
            continue
        r = m["rmse_m"]
        print(f"{name:12s} RMSE {r['mean']:.2f} +- {r['stderr']:.2f} m  p75 {m['error_m']['p75']:.2f} m  "
              f"({m['realtime_factor']:.0f}x real time)")
    print(f"wrote {cfg.out}/results.json")


def main() -> None:
    sys.argv = [sys.argv[0]] + cli_overrides(sys.argv[1:], deprecated_model_path=True)
    _main()


if __name__ == "__main__":
    main()
