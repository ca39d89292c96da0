"""Problems found in a dataset.

Readers and the validator share the same checks: a check returns :class:`Issue` objects; the validator
collects them all, a reader raises :class:`blenav.errors.DatasetError` (the one exception type of
:mod:`blenav.data`) on the first file that has an error and logs the warnings.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass
from pathlib import Path

from blenav.errors import DatasetError

log = logging.getLogger("blenav.data")

ERROR = "error"
WARNING = "warning"

#: At most this many rows of one rule in one file are reported one by one; the rest are counted.
MAX_ROWS_PER_RULE = 20


@dataclass(frozen=True)
class Issue:
    """One violation (``severity == 'error'``) or remark (``'warning'``) about one place in a file.

    ``line`` is the 1-based text line (the CSV header is line 1) or ``None`` for whole-file issues;
    ``where`` replaces it for structured files (e.g. ``feature[3]`` in GeoJSON).
    """

    severity: str
    path: str
    rule: str
    message: str
    line: int | None = None
    where: str | None = None

    def __str__(self) -> str:
        loc = self.path
        if self.line is not None:
            loc += f":{self.line}"
        elif self.where:
            loc += f":{self.where}"
        return f"{self.severity.upper()} {loc}: [{self.rule}] {self.message}"

    @property
    def is_error(self) -> bool:
        return self.severity == ERROR


def error(path: Path | str, rule: str, message: str, line: int | None = None, where: str | None = None) -> Issue:
    return Issue(ERROR, str(path), rule, message, line, where)


def warning(path: Path | str, rule: str, message: str, line: int | None = None, where: str | None = None) -> Issue:
    return Issue(WARNING, str(path), rule, message, line, where)


def raise_or_log(issues: list[Issue]) -> None:
    """Raise :class:`DatasetError` if any issue is an error, else log the warnings."""
    if any(i.is_error for i in issues):
        raise DatasetError(issues)
    for i in issues:
        log.warning("%s", i)
