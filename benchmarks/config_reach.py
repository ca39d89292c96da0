"""How far the eval config travels: the blenav modules and functions that receive it, from ``blenav-eval`` down.

    python benchmarks/config_reach.py experiment=NAME data=DIR [more blenav-eval overrides]

Runs ``blenav-eval`` in this process under :func:`sys.settrace` and, at every call of a function of ``blenav``,
looks at its arguments: a call *receives the config* when an argument is an omegaconf DictConfig / ListConfig (the
composed one, one of its nodes, or one built from them: the localizers' ``shared`` settings, the cross-phone training
config), or the parsed :class:`blenav.eval.config.EvalConfig` or any dict, list or dataclass reachable from it (e.g.
a ``methods`` node handed to ``build_localizer``); ``self`` does not count (a config object's own methods). Prints
the number of distinct modules and of distinct functions ("stops") that received it, and the modules, in the order
first reached; then the calls from a localizer
(``blenav.localizers``, ``blenav.backend``) into ``blenav.eval`` (a localizer calling back up into the evaluation).
Counts calls, not imports; a module that reads the config through an attribute of an object it was given (not an
argument) is not counted. Also the count of modules that receive the composed DictConfig itself, a copy of it (its
root has the eval root's keys), or one of their nodes.
"""

from __future__ import annotations

import dataclasses
import sys
from pathlib import Path

SRC = str(Path(__file__).resolve().parents[1] / "src")


def _reachable(obj, out: set[int]) -> set[int]:
    stack = [obj]
    while stack:
        o = stack.pop()
        if id(o) in out or isinstance(o, (str, bytes, int, float, bool, type(None))):
            continue
        if dataclasses.is_dataclass(o) and not isinstance(o, type):
            out.add(id(o))
            stack.extend(getattr(o, f.name) for f in dataclasses.fields(o))
        elif isinstance(o, dict):
            out.add(id(o))
            stack.extend(o.values())
        elif isinstance(o, (list, tuple)):
            out.add(id(o))
            stack.extend(o)
    return out


def main(args: list[str]) -> None:
    from omegaconf import DictConfig, ListConfig

    roots: list = []  # the composed DictConfig
    typed: set[int] = set()  # ids reachable from every EvalConfig seen
    seen_typed: set[int] = set()
    stops: dict[tuple[str, str], None] = {}
    modules: dict[str, None] = {}
    upcalls: dict[str, None] = {}

    raw: dict[str, None] = {}  # modules that receive the composed DictConfig or one of its nodes

    def kind(v) -> str | None:
        if isinstance(v, (DictConfig, ListConfig)):
            try:  # the composed eval config, a node of it, or a copy of it (its root has the eval root's keys)
                root = v._get_root()
                copy = {"experiment", "data", "runs"} <= set(root)
                return "raw" if copy or any(root is r for r in roots) else "built"
            except Exception:  # noqa: BLE001 -- a node in construction
                return "built"
        if type(v).__name__ == "EvalConfig" and id(v) not in seen_typed:
            seen_typed.add(id(v))
            _reachable(v, typed)
        return "typed" if id(v) in typed else None

    def tracer(frame, event, arg):
        if event != "call":
            return None
        fn = frame.f_code.co_filename
        if "/blenav/" not in fn:
            return None
        mod = frame.f_globals.get("__name__", fn)
        code = frame.f_code
        if not roots and mod == "blenav.cli.eval" and code.co_name == "task":
            roots.append(frame.f_locals["cfg"])
        if not roots:
            return None
        caller = frame.f_back.f_globals.get("__name__", "") if frame.f_back is not None else ""
        if mod.startswith("blenav.eval") and caller.startswith(("blenav.localizers", "blenav.backend")):
            upcalls.setdefault(f"{caller}.{frame.f_back.f_code.co_name} -> {mod}.{code.co_name}", None)
        names = code.co_varnames[:code.co_argcount + code.co_kwonlyargcount]
        loc = frame.f_locals
        vals = [loc.get(n) for n in names]
        if code.co_flags & 0x08:  # **kwargs
            n = code.co_argcount + code.co_kwonlyargcount + bool(code.co_flags & 0x04)
            vals += list(loc.get(code.co_varnames[n], {}).values())
        if names and names[0] == "self":  # a method of the config object itself (a property) is not a stop
            vals = vals[1:]
        kinds = {kind(v) for v in vals} - {None}
        if kinds:
            stops.setdefault((mod, code.co_name), None)
            modules.setdefault(mod, None)
        if "raw" in kinds:
            raw.setdefault(mod, None)
        return None

    from blenav.cli import eval as cli_eval

    sys.argv = ["blenav-eval", *args]
    sys.settrace(tracer)
    try:
        cli_eval.main()
    except SystemExit:
        pass
    finally:
        sys.settrace(None)
    print(f"{len(modules)} modules, {len(stops)} functions receive the eval config")
    for m in modules:
        print(f"  {m}: {', '.join(f for mm, f in stops if mm == m)}")
    print(f"{len(raw)} modules receive the composed DictConfig itself or its nodes: {', '.join(raw)}")
    print(f"{len(upcalls)} distinct calls from a localizer into blenav.eval")
    for c in upcalls:
        print(f"  {c}")


if __name__ == "__main__":
    main(sys.argv[1:])
