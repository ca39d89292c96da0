"""The Hydra side of :mod:`blenav.cli.args`: flags turned into overrides (:func:`flags_to_overrides`) and the
``--help`` of a Hydra command (:func:`hydra_help`). Imports nothing of :mod:`blenav.cli.common`, which uses it."""

from __future__ import annotations

import re
from pathlib import Path


def flags_to_overrides(args: list[str], hydra_options: dict[str, str | None]) -> list[str]:
    """``--key value`` / ``--key=value`` -> ``key=value``; ``--no-key`` -> ``key=false``; a ``--key`` with no value
    (last, or before another option or an override) -> ``key=true``; dashes in a key become underscores. Hydra's
    own options (``hydra_options``: long name -> short name), spelt in full or, for those of several words, as an
    unambiguous abbreviation (``--config-pa``; ``--experiment`` is a key, not ``--experimental-rerun``), and their
    values stay as they are, so does everything after ``--``. A value may start
    with ``-`` when it is a number (``--seed -1``); a word that looks like an override (``runs=2``) is never taken
    as a value (write ``--out=a=b`` for a value holding ``=``)."""
    short = {v for v in hydra_options.values() if v}
    out: list[str] = []
    i = 0
    while i < len(args):
        a = args[i]
        i += 1
        if a == "--":
            out.extend(args[i:])
            break
        if not a.startswith("--") or a in short:
            out.append(a)
            continue
        name, eq, value = a.partition("=")
        if name not in hydra_options and "-" in name[2:]:  # an abbreviation of a multi-word option: --config-pa
            hits = [o for o in hydra_options if o.startswith(name)]
            name = hits[0] if len(hits) == 1 else name
        if name in hydra_options:
            out.append(a)
            if not eq and i < len(args) and _is_value(args[i]) and name in _VALUED_OPTIONS:
                out.append(args[i])
                i += 1
            continue
        key = name[2:].replace("-", "_")
        if not key:
            out.append(a)
            continue
        if not eq:
            if key.startswith("no_") and len(key) > 3:
                key, value = key[3:], "false"
            elif i < len(args) and _is_value(args[i]):
                value, i = args[i], i + 1
            else:
                value = "true"
        out.append(f"{key}={value}")
    return out


#: Hydra's options (hydra/_internal/utils.py get_args_parser); those that take a value; those that only print
_HYDRA_OPTS = {"--help": "-h", "--hydra-help": None, "--version": None, "--cfg": "-c", "--resolve": None,
               "--package": "-p", "--run": "-r", "--multirun": "-m", "--shell-completion": "-sc",
               "--config-path": "-cp", "--config-name": "-cn", "--config-dir": "-cd", "--experimental-rerun": None,
               "--info": "-i"}
_VALUED = {"--cfg", "--package", "--config-path", "--config-name", "--config-dir", "--experimental-rerun"}
_PRINT_ONLY = {"--help", "--hydra-help", "--version", "--cfg", "--shell-completion", "--info"}
_INFO_CHOICES = {"all", "config", "defaults", "defaults-tree", "plugins", "searchpath"}
#: Hydra's options that take a value here (``--info`` takes one of _INFO_CHOICES when one follows)
_VALUED_OPTIONS = _VALUED | {"--info"}
_OVERRIDE = re.compile(r"^[+~]*[A-Za-z_][\w.@/-]*=")
_NUMBER = re.compile(r"^-?(\d+\.?\d*|\.\d+)([eE][-+]?\d+)?$")


def _is_value(word: str) -> bool:
    """Whether ``word``, after a ``--key`` without ``=``, is that key's value: not an option (a negative number
    is a value), not an override."""
    if word.startswith("-") and not _NUMBER.match(word):
        return False
    return not _OVERRIDE.match(word)


def hydra_help(prog: str, config_name: str, overrides: list[str], doc: str | None) -> str:
    """The ``--help`` text of a Hydra command: usage, the first paragraph of ``doc``, the experiments and config
    groups it accepts, and the config's keys with their values after ``overrides`` (``experiment=X --help`` shows
    that experiment's values); nested settings as ``node.key`` one level down, lists shortened."""
    from blenav.configs import compose
    from blenav.paths import conf_dir

    lines = [f"usage: {prog} [KEY=VALUE | --KEY VALUE ...] [-m] [--debug] [--help]", ""]
    if doc:
        import textwrap

        para = " ".join(doc.strip().split("\n\n")[0].split()).replace("``", "")
        lines += [*textwrap.wrap(para, 100), ""]
    try:
        cfg = compose(config_name, *overrides)
        note = f" (with {' '.join(overrides)})" if overrides else ""
    except Exception as exc:  # noqa: BLE001 -- a bad override: show the defaults and say why
        cfg = compose(config_name)
        note = f" (defaults: the overrides given did not compose: {' '.join(str(exc).split())[:200]})"
    from omegaconf import OmegaConf

    root = conf_dir()
    experiments = sorted(p.stem for p in (root / "experiment").glob("*.yaml") if not p.stem.startswith("_"))
    if config_name in ("eval", "train"):
        lines.append("experiments (experiment=NAME):")
        lines += _wrapped(experiments)
        lines.append("")
    groups = [g for g in _default_groups(root / f"{config_name}.yaml") if g != "experiment"]
    if groups:
        lines.append("config groups (GROUP=OPTION):")
        for g in groups:
            opts = sorted(p.stem for p in (root / g).glob("*.yaml") if not p.stem.startswith("_"))
            lines += _wrapped(opts, f"  {g}: ")
        lines.append("")
    lines.append(f"settings{note}:")
    container = OmegaConf.to_container(cfg, resolve=False)
    scalars = {k: v for k, v in container.items() if not isinstance(v, dict)}
    nodes = {k: v for k, v in container.items() if isinstance(v, dict)}
    lines += [f"  {k}={_short(v)}" for k, v in scalars.items()]
    for key, node in nodes.items():
        inner = {k: v for k, v in node.items() if not isinstance(v, dict)}
        subs = [k for k, v in node.items() if isinstance(v, dict)]
        if not inner:  # a node of nodes (methods, fix sets): their names
            lines += _wrapped(subs, f"  {key} ({len(subs)}): ", width=118)
            continue
        words = [f"{key}.{k}={_short(v, 24)}" for k, v in inner.items()]
        if subs:
            words.append(f"{key}.{{{','.join(subs)}}}.*")
        lines.append(_one_line(words))
    lines += ["", f"Every setting: {prog} --cfg job [overrides]; Hydra's own options: {prog} --hydra-help.",
              "Errors print one line and exit 1 (--debug: with the traceback)."]
    return "\n".join(lines)


def _default_groups(path: Path) -> list[str]:
    """The config groups named in a primary config's defaults list (``- model: locnet`` -> ``model``)."""
    import yaml

    try:
        defaults = (yaml.safe_load(path.read_text()) or {}).get("defaults", [])
    except (OSError, yaml.YAMLError):
        return []
    groups = []
    for d in defaults:
        if isinstance(d, dict):
            for k in d:
                k = str(k).split("@")[0].replace("override ", "").strip()
                if "/" not in k and not k.startswith("hydra") and (path.parent / k).is_dir():
                    groups.append(k)
    return groups


def _short(v, width: int = 60) -> str:
    s = "null" if v is None else (str(v).lower() if isinstance(v, bool) else str(v))
    if isinstance(v, list) and len(s) > width:
        s = f"[{len(v)} items]"
    return s if len(s) <= width else s[: width - 3] + "..."


def _one_line(words: list[str], width: int = 118) -> str:
    """``words`` joined on one line of at most ``width`` characters, the rest counted."""
    line = " "
    for i, w in enumerate(words):
        rest = f" ... (+{len(words) - i} more)"
        if len(line) + len(w) + 1 + (len(rest) if i < len(words) - 1 else 0) > width:
            return line + rest
        line += " " + w
    return line


def _wrapped(words: list[str], first: str = "  ", width: int = 100) -> list[str]:
    lines, cur = [], first
    for w in words:
        if len(cur) + len(w) + 2 > width and cur.strip():
            lines.append(cur.rstrip().rstrip(","))
            cur = " " * len(first)
        cur += w + ", "
    lines.append(cur.rstrip().rstrip(","))
    return lines
