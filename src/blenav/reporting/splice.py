"""The one way a generated block goes into a hand-written markdown file: between a pair of HTML-comment markers."""

from __future__ import annotations

from pathlib import Path

from blenav.eval.common import write_text

__all__ = ["markers", "splice"]


def markers(tag: str) -> tuple[str, str]:
    """The start and end markers of the block ``tag``: ``<!-- tag -->`` and ``<!-- /tag -->`` (invisible in the
    rendered markdown)."""
    return f"<!-- {tag} -->", f"<!-- /{tag} -->"


def splice(path, body: str, tag: str, append: bool = False) -> bool:
    """Put ``body`` between the markers of ``tag`` (:func:`markers`) in the file ``path``, replacing what is there
    (the text before the first start marker and after the first end marker that follows it is kept as read in text
    mode, line ends as ``\n``); without both markers in that order, append them with ``body`` (``append``: a results
    page gets its block) or leave the file alone (a README gets a table only where it asks for one). Written
    atomically (UTF-8). Returns whether the file was written."""
    path = Path(path)
    start, end = markers(tag)
    text = path.read_text() if path.is_file() else ""
    head, found, rest = text.partition(start)
    _, closed, tail = rest.partition(end)
    if found and closed:
        write_text(path, head + start + "\n" + body + "\n" + end + tail)
    elif append:
        write_text(path, text + f"\n{start}\n{body}\n{end}\n")
    else:
        return False
    return True
