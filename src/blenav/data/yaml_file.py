"""Reading a YAML file of a dataset (dataset.yaml, building.yaml, a session's meta.yaml) as data: a mapping or
an issue naming the file and line, never an exception; a truncated file or an alias bomb is refused.
"""

from __future__ import annotations

from pathlib import Path

import yaml

from .issues import Issue, error
from .tables import read_text

__all__ = ["load_yaml", "YAML_MAX_NODES"]


def load_yaml(path: Path) -> tuple[dict | None, list[Issue]]:
    """Parse a YAML mapping; syntax errors name the line. UTF-8 only (a byte-order mark is fine). Like a CSV file,
    a YAML file whose last byte is not a line end is refused ('truncated'): its last value may have been cut and
    still parse, to another value (``free_thresh: 0.19`` from ``0.196``)."""
    if not path.is_file():
        return None, [error(path, "missing-file", "file does not exist")]
    text, issues = read_text(path)
    if text is None:
        return None, issues
    if text and not text.endswith(("\n", "\r")):
        return None, [error(path, "truncated", "the file does not end with a newline, so its last line may be cut "
                            "short (a number missing digits): add a newline at the end if the line is complete, or "
                            "fix the line", line=len(text.splitlines()))]
    try:
        doc = yaml.safe_load(text)
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        line = mark.line + 1 if mark is not None else None
        return None, [error(path, "yaml-syntax", str(getattr(exc, "problem", exc)), line=line)]
    except RecursionError:  # '[[[[...' thousands deep: Python's parser gives up, so do we, in one line
        return None, [error(path, "yaml-syntax", "nested too deeply to read (thousands of [ or { levels)")]
    if not isinstance(doc, dict):
        return None, [error(path, "yaml-not-mapping", "top level must be a mapping of keys to values")]
    if _yaml_nodes_exceed(doc, YAML_MAX_NODES):
        return None, [error(path, "yaml-size", f"the document expands to more than {YAML_MAX_NODES} values (YAML "
                            "aliases repeating aliases?): no dataset file is that large")]
    return doc, []


#: A YAML document that expands to more values than this is refused ('yaml-size'): a few lines of aliases of
#: aliases expand to billions (a 'billion laughs'), and printing one value of it would never end.
YAML_MAX_NODES = 1_000_000


def _yaml_nodes_exceed(doc, budget: int) -> bool:
    """Whether ``doc``, with its aliases expanded, has more than ``budget`` values (stops counting there)."""
    stack, n = [doc], 0
    while stack:
        x = stack.pop()
        n += 1
        if n > budget:
            return True
        if isinstance(x, dict):
            stack.extend(x.keys())
            stack.extend(x.values())
        elif isinstance(x, (list, tuple)):
            stack.extend(x)
    return False
