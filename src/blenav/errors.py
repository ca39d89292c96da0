"""The exceptions more than one package of blenav raises or catches, in the lowest layer so that every layer may
import them (standard library only).

All are ``ValueError`` subclasses: the known-error channel of the command lines (:mod:`blenav.cli.common`), which
end a known error as one line ``PROG: error: MESSAGE``. An exception that only one module raises and catches stays
in that module (e.g. :class:`blenav.runtime.signature.BuildingMismatch`,
:class:`blenav.learn.common.checkpoint.UnsafeCheckpointError`); :mod:`blenav.trust` and :mod:`blenav.limits` keep their
own.

==========================  ======================================================================================
:class:`MissingStream`      a session lacks a stream a method needs (features, filters, localizers, eval, backend)
:class:`DatasetError`       a dataset breaks a rule of format v1 (data, importers, eval, cli)
:class:`ImportError_`       malformed raw input of an importer (importers, cli)
:class:`EvalError`          a bad experiment, dataset or session selection (eval, cli)
:class:`ConfigError`        a command-line override the config does not accept (configs, cli)
==========================  ======================================================================================
"""

from __future__ import annotations

from pathlib import Path

__all__ = ["MissingStream", "DatasetError", "ImportError_", "EvalError", "ConfigError", "EXTRA_OF", "missing_extra"]

#: the install extra (pyproject.toml) that brings a module the base install lacks
EXTRA_OF = {"torch": "train", "lightning": "train", "gtsam": "backend", "hydra": "eval", "omegaconf": "eval",
            "matplotlib": "eval", "plotly": "eval", "sklearn": "eval"}


def missing_extra(exc: BaseException) -> str | None:
    """The extra whose module ``exc`` (an ImportError) could not import, or None: a module of no extra (a bug)."""
    if not isinstance(exc, ImportError):
        return None
    return EXTRA_OF.get((getattr(exc, "name", None) or "").split(".")[0])


class MissingStream(ValueError):
    """The session lacks a stream the method needs (e.g. IMU for the IMU proposal): skip, do not fail."""


class DatasetError(ValueError):
    """A dataset breaks a rule of format v1. ``issues`` holds every error found in the file(s) read: one
    :class:`blenav.data.issues.Issue` or a list of them (an issue has ``is_error`` and a one-line ``str``)."""

    def __init__(self, issues):
        self.issues = [issues] if hasattr(issues, "is_error") else list(issues)
        errors = [i for i in self.issues if i.is_error] or self.issues
        head = "\n".join(str(i) for i in errors[:10])
        more = f"\n... and {len(errors) - 10} more" if len(errors) > 10 else ""
        super().__init__(head + more)


class ImportError_(ValueError):
    """Malformed raw input. The message names the file, the line (1-based) and the problem."""

    def __init__(self, path: Path | str, line: int | None, problem: str):
        self.path, self.line, self.problem = str(path), line, problem
        loc = f"{path}:{line}" if line is not None else str(path)
        super().__init__(f"{loc}: {problem}")


class EvalError(ValueError):
    """A bad experiment, dataset or session selection, with a message that says what to fix."""


class ConfigError(ValueError):
    """A command-line override the config does not accept, with what to write instead."""
