"""``blenav-eval experiment=NAME data=DIR runs=N out=OUT [sessions=ID,ID] [model_path=PATH] [io_model=DIR] [overwrite=true]``:
compare
localization methods (``model_path``: a trained model the experiment evaluates; ``model=PATH`` is its deprecated
spelling).

OUT appears whole or not at all (:mod:`blenav.cli.outdir`): the evaluation writes into ``.OUT.tmp-<pid>`` beside it
and renames that to OUT at the end. An existing OUT is refused unless ``overwrite=true``, which replaces it whole
(no stale session folder of an earlier run stays beside the new results.json) and reuses its ``runs/`` (trained
cross-phone runs) and ``fixes/`` (computed BLE fixes). A failed run leaves OUT as it was; Ctrl-C or SIGTERM prints
``blenav-eval: interrupted; removed partial output ...`` and exits 130 / 143. Session ids (and method labels) that
map to one output name (``s 000``, ``s_000``) are refused before any work."""

from __future__ import annotations

import dataclasses
import sys
from functools import partial

from omegaconf import DictConfig

from blenav.configs import cli_overrides
from blenav.eval.result import summary_lines

from .common import run_hydra, write_page
from .outdir import fresh_output

PROG = "blenav-eval"


def task(cfg: DictConfig) -> None:
    """The composed config parsed once into :class:`~blenav.eval.config.EvalConfig` (a missing dataset path, a misspelt
    key, a bad value fail here, before any output), its evaluator built, run into a fresh OUT; the summary printed."""
    from blenav.eval.config import parse_eval_config
    from blenav.eval.evaluators import build_evaluator

    ecfg = parse_eval_config(cfg)
    evaluator = build_evaluator(ecfg)
    inputs = [ecfg.data.path, ecfg.model_path, ecfg.io_model]  # never inside an OUT that overwrite=true deletes
    with fresh_output(ecfg.out, ecfg.overwrite, inputs) as tmp:
        res = evaluator.run(dataclasses.replace(ecfg, out=str(tmp)))
        report = write_page(PROG, tmp) if ecfg.report else None
    for line in summary_lines(res):
        print(line)
    print(f"wrote {ecfg.out}/results.json")
    if report:
        print(f"wrote {ecfg.out}/report.html ({report})")


def main(argv: list[str] | None = None) -> None:
    args = sys.argv[1:] if argv is None else list(argv)
    run_hydra(PROG, "eval", task, args, convert=partial(cli_overrides, deprecated_model_path=True))


if __name__ == "__main__":
    main()
