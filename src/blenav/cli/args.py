"""One command-line dialect over two parsers.

blenav's commands are served by Hydra (``sim``, ``eval``, ``train``, ``export``: ``key=value`` overrides) or by
argparse (``validate``, ``import``, ``plot``, ``fixes``, ``calibrate``, ``map``, ``localize``, ``tables``,
``realwalks``: positionals and ``--flags``). Both accept both spellings of the common names:

========================  ==========================================  ==============================================
what                      Hydra commands                              argparse commands
========================  ==========================================  ==============================================
the dataset               ``data=DIR`` or ``--data DIR``              ``DIR`` (positional) or ``data=DIR``
the output                ``out=OUT`` or ``--out OUT``                ``--out OUT`` or ``out=OUT``
sessions                  ``sessions=A,B`` or ``--sessions A,B``      ``--sessions A,B`` or ``sessions=A,B``
progress bars off         ``progress=false`` or ``--no-progress``     ``--no-progress`` or ``progress=false``
any other setting         ``key=value`` or ``--key value``            ``--key value`` or ``key=value``
========================  ==========================================  ==============================================

:func:`blenav.cli.hydra_help.flags_to_overrides` turns the flags a Hydra command is given into overrides (Hydra's own options stay);
:class:`ArgumentParser` reads ``key=value`` for its own options, prints usage as the command was called
(``blenav map``), and answers a wrong flag with one line ``PROG: error: ...`` and exit 1 (argparse: usage and exit
2). :func:`blenav.cli.hydra_help.hydra_help` is the ``--help`` of a Hydra command: a usage line, what it does, the experiments and config
groups it accepts and the keys a user changes, instead of Hydra's config dump (``--cfg job`` still prints that).
"""

from __future__ import annotations

import argparse

from .common import display_prog, fail


class ArgumentParser(argparse.ArgumentParser):
    """argparse with blenav's conventions:

    - ``prog`` as the command was called (:func:`blenav.cli.common.display_prog`: ``blenav map`` under ``blenav``);
    - ``key=value`` for an option ``--key`` (``out=OUT``, ``sessions=A,B``), ``progress=false`` for
      ``--no-progress``, ``data=DIR`` for the positional dataset, ``name=true|false`` for a switch ``--name``;
    - a wrong flag or a missing argument: one line ``PROG: error: ... (PROG --help)`` and exit 1.
    """

    def __init__(self, prog: str, **kw) -> None:
        super().__init__(prog=display_prog(prog), **kw)

    def error(self, message: str) -> None:  # noqa: D401 -- argparse's hook
        fail(self.prog, f"{message} (see {self.prog} --help)")

    def parse_args(self, args=None, namespace=None):  # type: ignore[override]
        return super().parse_args(self.key_values(list(args) if args is not None else None), namespace)

    def key_values(self, args: list[str] | None) -> list[str] | None:
        """``args`` with ``key=value`` words turned into the flags they name (see the class); a positional given as
        ``name=value`` (``data=DIR`` for ``dataset``, ``out=OUT`` for an ``out`` positional) goes where argparse
        expects it: before the bare words when it and every positional before it are given so, after them when it
        and every positional after it are."""
        if args is None:
            return None
        flags = {o.lstrip("-").replace("-", "_"): (o, a) for a in self._actions for o in a.option_strings
                 if o.startswith("--")}
        positional = [a.dest for a in self._actions if not a.option_strings]
        single = [a.dest for a in self._actions if not a.option_strings and a.nargs is None]
        alias = {"data": "dataset"}
        out: list[str] = []
        given: dict[str, str] = {}
        for i, w in enumerate(args):
            if w == "--":
                out.extend(args[i:])
                break
            key, eq, value = w.partition("=")
            if not eq or w.startswith("-"):
                out.append(w)
            elif key in flags:
                opt, action = flags[key]
                if action.nargs == 0:  # a switch: name=true sets it, name=false leaves it off
                    if _truth(key, value):
                        out.append(opt)
                else:
                    out.extend([opt, value])
            elif key == "progress" and "no_progress" in flags:
                if not _truth(key, value):
                    out.append(flags["no_progress"][0])
            elif alias.get(key, key) in single and alias.get(key, key) not in given:
                given[alias.get(key, key)] = value
            else:
                out.append(w)
        if not given:
            return out
        front = []
        for d in positional:  # the leading positionals given as name=value
            if d not in given:
                break
            front.append(given.pop(d))
        back = []
        for d in reversed(positional):  # the trailing ones
            if d not in given:
                break
            back.insert(0, given.pop(d))
        if given:
            raise ValueError(f"{', '.join(f'{k}=' for k in given)}: give it as a positional argument "
                             f"({' '.join(d.upper() for d in positional)})")
        return front + out + back


def _truth(key: str, value: str) -> bool:
    v = value.strip().lower()
    if v in ("true", "1", "yes", "on"):
        return True
    if v in ("false", "0", "no", "off"):
        return False
    raise ValueError(f"{key}={value}: expected true or false")
