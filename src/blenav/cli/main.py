"""``blenav COMMAND [ARGS ...]``: every blenav tool behind one command.

``blenav`` alone (or ``--help``) lists the commands; ``blenav COMMAND --help`` shows one command's usage, what it
accepts and the settings a user changes. The old console scripts (``blenav-eval``, ``blenav-sim``, ...) and
``python train.py`` / ``python export.py`` stay as aliases of the same functions. Both spellings of the common
names work in every command (``data=DIR`` / ``--data DIR``, ``out=``, ``sessions=A,B``, ``progress=false`` /
``--no-progress``: :mod:`blenav.cli.args`).
"""

from __future__ import annotations

import difflib
import importlib
import sys
from dataclasses import dataclass

from blenav.errors import missing_extra

from .common import called_as, fail


@dataclass(frozen=True)
class Command:
    module: str  #: the module under blenav.cli whose ``main(argv)`` runs it
    summary: str  #: one line for ``blenav --help``
    needs: str = ""  #: the extra it needs beyond the base install ('' = base)


#: every command, in the order a user meets them
COMMANDS: dict[str, Command] = {
    "sim": Command("sim", "simulate a building and walks into a dataset (sim=PRESET seed=N out=DIR)", "eval"),
    "import": Command("importer", "convert a public recording to the dataset format (KIND SRC OUT)"),
    "validate": Command("validate", "check a dataset against the format (DATASET)"),
    "plot": Command("plot", "overview figures of a dataset (DATASET [--out DIR])", "eval"),
    "eval": Command("eval", "run an experiment: methods x sessions x runs (experiment=NAME data=DIR out=OUT)", "eval"),
    "train": Command("train", "train a network from its config (experiment=NAME data=DIR out=RUN)", "train"),
    "export": Command("export", "a trained network to ONNX, or a runtime bundle (ckpt=RUN/last.ckpt out=...)",
                      "train"),
    "merge": Command("merge", "the jobs of a fan-out over methods (-m only=A,B) as one evaluation (OUT JOB...)",
                     "eval"),
    "report": Command("report", "the HTML page of an evaluation: leaderboard, CDFs, tracks on the plan (OUT)", "eval"),
    "localize": Command("localize", "run a runtime bundle on a session, torch-free (BUNDLE SESSION --out CSV)"),
    "fixes": Command("fixes", "write an ONNX localizer's fixes into a dataset (DATASET MODEL.onnx)", "eval"),
    "calibrate": Command("calibrate", "fit the path-loss model on labelled walks (DATASET [--out FILE])", "eval"),
    "map": Command("map", "beacon positions from labelled walks (DATASET --sessions A,B --out DIR)", "backend"),
    "tables": Command("tables", "merge evaluation results into the docs' tables (merge|leaderboard|crf|feng ...)",
                      "eval"),
    "realwalks": Command("realwalks", "real-walk helpers: train ids, fix coverage, tables (train-ids DATA | ...)",
                         "eval"),
}
#: the console scripts kept as aliases (pyproject.toml [project.scripts])
ALIASES = {f"blenav-{name}": name for name in COMMANDS if name not in ("tables", "realwalks", "report", "merge")}


def usage() -> str:
    from blenav import __version__

    width = max(map(len, COMMANDS))
    lines = [f"usage: blenav COMMAND [ARGS ...]   (blenav {__version__})", "",
             "Indoor localization from BLE beacons, WiFi, inertial sensors and floor plans.", "", "commands:"]
    lines += [f"  {name:<{width}}  {c.summary}" for name, c in COMMANDS.items()]
    lines += ["", "blenav COMMAND --help: that command's usage and settings. --debug: tracebacks of known errors.",
              "Install extras: the base install runs `localize`, `import` and `validate`; "
              "pip install 'blenav[all]' gives every command."]
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    args = sys.argv[1:] if argv is None else list(argv)
    debug = [a for a in args[:1] if a == "--debug"]  # blenav --debug COMMAND ...: the command's --debug
    args = args[len(debug):]
    if not args or args[0] in ("-h", "--help", "help"):
        print(usage())
        return 0
    if args[0] in ("-V", "--version"):
        from blenav import __version__

        print(f"blenav {__version__}")
        return 0
    name, rest = args[0], args[1:]
    name = ALIASES.get(name, name)
    if name not in COMMANDS:
        near = difflib.get_close_matches(name, COMMANDS, n=1)
        hint = f"; did you mean {near[0]}?" if near else ""
        fail("blenav", f"unknown command {args[0]!r}{hint} (blenav --help lists them)")
    cmd = COMMANDS[name]
    try:
        module = importlib.import_module(f"blenav.cli.{cmd.module}")
    except ImportError as exc:  # a command of an extra the install lacks (else a bug: its traceback)
        if missing_extra(exc) is None or debug:
            raise
        fail(f"blenav {name}", f"{exc} -- `blenav {name}` needs pip install 'blenav[{cmd.needs or 'all'}]'")
    with called_as(f"blenav {name}"):
        return int(module.main(rest + debug) or 0)


if __name__ == "__main__":
    sys.exit(main())
