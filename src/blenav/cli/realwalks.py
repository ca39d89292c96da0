"""``python -m blenav.cli.realwalks train-ids DATA | coverage DATA [ROW] [--plot FILE] | tables OUT_ROOT SUMMARY.md
[FLOORS_DIR] [README] | priors MAIN OTHER PRIOR_PATTERN PAGE.md [README] | inertial OUT_ROOT PAGE.md | runs-json OUT.json
RUN_DIR...``: the steps of ``make realwalks-tables`` (docs/results-ilc20.md) and ``make inertial-tables``
(docs/results-inertial.md: :func:`~blenav.reporting.realwalks_inertial.write_inertial`; ``runs-json`` gathers the training
runs' reports), and ``coverage``: a fingerprint row's fix errors (default ``knn_both``, KNN-WiFi+BLE) by how
far each true position lies from the train walks (:func:`~blenav.eval.realwalks.coverage`).

An entry point composes ``conf/`` (:func:`blenav.configs.compose`, ``experiment=realwalks``) and hands the nodes
down to :mod:`blenav.eval.realwalks` and :mod:`blenav.reporting.realwalks`, which compose nothing: ``train-ids``
prints the experiment's train walks of the dataset DATA, comma-separated, for ``blenav-map --sessions``
(:func:`~blenav.eval.realwalks.train_ids`, the harness's own split); ``tables`` writes the per-floor pages, the
summary and the README table from the floors' results.json (:func:`~blenav.reporting.realwalks.write_tables`), in
the rows of the composed experiment (:func:`~blenav.reporting.realwalks.table_rows`); ``priors`` writes the
learned-map rows of both map priors beside the heuristic map PF
(:func:`~blenav.reporting.realwalks_priors.write_priors`).
"""

from __future__ import annotations

import sys

from .common import display_prog, guarded, pop_debug, subcommand_args

PROG = "python -m blenav.cli.realwalks"
USAGE = (f"usage: {PROG} train-ids DATA | coverage DATA [ROW] [--plot FILE.png] | tables OUT_ROOT SUMMARY.md [FLOORS_DIR] [README] | "
         f"priors MAIN OTHER PRIOR_PATTERN PAGE.md [README] | inertial OUT_ROOT PAGE.md | runs-json OUT.json RUN_DIR...")


def experiment_config(*overrides: str, experiment: str = "realwalks"):
    """The composed ``conf/eval.yaml`` with ``experiment=<experiment>`` and command-line style ``overrides``."""
    from blenav.configs import compose

    return compose("eval", f"experiment={experiment}", *overrides)


def train_ids_of(data: str, train_fraction: float | None = None, seed: int | None = None,
                 experiment: str = "realwalks") -> list[str]:
    """The train walks (:func:`blenav.eval.realwalks.train_ids`) of ``experiment`` composed on the dataset ``data``;
    ``train_fraction`` / ``seed`` override its ``split`` (as ``split.train_fraction=...`` on its command line)."""
    from blenav.eval.realwalks import train_ids

    over = [f"split.train_fraction={train_fraction}"] if train_fraction is not None else []
    over += [f"split.seed={seed}"] if seed is not None else []
    return train_ids(experiment_config(f"data={data}", *over, experiment=experiment))


def table_rows_of(experiment: str = "realwalks") -> dict[str, tuple[str, ...]]:
    """The table rows (:func:`blenav.reporting.realwalks.table_rows`) of the composed ``experiment``'s methods."""
    from omegaconf import OmegaConf

    from blenav.reporting.realwalks import table_rows

    return table_rows(OmegaConf.to_container(experiment_config(experiment=experiment).methods, resolve=False))


def _main(argv: list[str]) -> int:
    cmd, args = (argv[0], argv[1:]) if argv else ("", [])
    if cmd == "train-ids" and len(args) == 1:
        print(",".join(train_ids_of(args[0])))
    elif cmd == "coverage" and 1 <= len(args) <= 4:
        from blenav.eval.realwalks import coverage

        plot = None
        if "--plot" in args:
            i = args.index("--plot")
            if i + 1 >= len(args):
                sys.exit(USAGE.replace(PROG, display_prog(PROG)))
            plot, args = args[i + 1], args[:i] + args[i + 2:]
        if len(args) not in (1, 2):
            sys.exit(USAGE.replace(PROG, display_prog(PROG)))
        rep = coverage(experiment_config(f"data={args[0]}"), *args[1:])
        print(f"{rep['row']}: {rep['fixes']} fixes of {rep['test_walks']} test walks, mean error "
              f"{rep['error_mean_m']:.2f} m; by the distance of the true position to the {rep['train_walks']} train walks:")
        for b in rep["bins"]:
            to = "" if b["to_m"] is None else f"{b['to_m']:g}"
            err = "--" if b["error_mean_m"] is None else f"{b['error_mean_m']:.2f} / {b['error_median_m']:.2f} m"
            print(f"  {b['from_m']:g}-{to} m: {100 * b['share']:.0f} % of the fixes, error mean / median {err}")
        if plot:
            from blenav.plotting.common import save_figure
            from blenav.plotting.evaluation import figure_coverage

            pts = rep["_points"]
            path = save_figure(figure_coverage(pts["session"], pts["train"], pts["truth"], pts["error"],
                                               f"{rep['row']}: test fixes by error, train walks in grey"), plot)
            print(f"wrote {path}")
    elif cmd == "tables" and 2 <= len(args) <= 4:
        from blenav.reporting.realwalks import write_tables

        print(write_tables(args[0], args[1], table_rows_of(), floors_dir=args[2] if len(args) > 2 else None,
                           readme=args[3] if len(args) > 3 else None))
    elif cmd == "inertial" and len(args) == 2:
        from blenav.reporting.realwalks_inertial import write_inertial

        print(write_inertial(args[0], args[1]))
    elif cmd == "runs-json" and len(args) >= 2:  # OUT.json RUN_DIR...: the runs' training.json in one file
        import json
        from pathlib import Path

        runs = {}
        for d in args[1:]:
            info = json.loads((Path(d) / "training.json").read_text(encoding="utf-8"))
            info.pop("history", None)
            cfg = Path(d) / "config.yaml"
            if cfg.is_file():
                import yaml

                info["model"] = (yaml.safe_load(cfg.read_text(encoding="utf-8")).get("model") or {}).get("name")
            runs[Path(d).name] = info
        from blenav.eval.common import write_text

        write_text(Path(args[0]), json.dumps(runs, indent=1) + "\n")
        print(f"wrote {args[0]} ({len(runs)} runs)")
    elif cmd == "priors" and len(args) in (4, 5):
        from blenav.reporting.realwalks_priors import write_priors

        print(write_priors(args[0], args[1], args[2], args[3], args[4] if len(args) > 4 else None))
    else:
        sys.exit(USAGE.replace(PROG, display_prog(PROG)))
    return 0


def main(argv: list[str] | None = None) -> int:
    """Errors the user can fix print one line and exit 1 (``--debug``: with the traceback)."""
    debug, argv = pop_debug(sys.argv[1:] if argv is None else list(argv))
    argv = subcommand_args(PROG, USAGE, argv)
    return 0 if argv is None else guarded(PROG, lambda: _main(argv), debug)


if __name__ == "__main__":
    sys.exit(main())
