"""What a localizer receives from the run it is part of: :class:`RunInputs`, with the session's position
:class:`Fixes` already resolved.

``localizer.run(session, n_runs, seed, inputs)``: the evaluation (or any caller) decides beforehand which fixes
each role of a :class:`~blenav.localizers.FixConsumer` uses on the session (a named ``fixes.csv`` source, or fixes
computed by another localizer: :mod:`blenav.eval.fixes`) and hands them over as arrays; the localizer never calls
back into the evaluation. A role whose fixes could not be had carries the reason, and asking for it raises
:class:`~blenav.filters.runner.MissingStream` (the method is then skipped on that session, as for any missing
stream).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from blenav.errors import MissingStream

__all__ = ["RoleFixes", "Fixes", "RunInputs"]


@dataclass(frozen=True)
class RoleFixes:
    """The fixes of one role on one session.

    t (F,) s; xy (F, 2) world m; std (F,) m (NaN where the source gives none); ``source``: the ``fixes.csv``
    source name the fixes have (a fix likelihood selects its rows by it); ``computed``: not in the session's
    fixes.csv (a filter adds them to its fixes in memory); ``wall_s``: seconds the localizer that computed them took
    (one run), None when they were read; ``off_log_ratio`` (F,): what each fix's scan says of its walker being off the
    survey (a log Bayes factor, :class:`blenav.localizers.knn.NoveltyModel`), None where the source says nothing."""

    t: np.ndarray
    xy: np.ndarray
    std: np.ndarray
    source: str
    computed: bool = False
    wall_s: float | None = None
    off_log_ratio: np.ndarray | None = None  # (F,): the log Bayes factor for "off the survey" each fix's scan gives

    def __post_init__(self):
        if self.xy.shape != (len(self.t), 2) or self.std.shape != (len(self.t),):
            raise ValueError(f"fixes {self.source!r}: t (F,), xy (F, 2), std (F,) expected, got {self.t.shape}, "
                             f"{self.xy.shape}, {self.std.shape}")
        if self.off_log_ratio is not None and np.shape(self.off_log_ratio) != (len(self.t),):
            raise ValueError(f"fixes {self.source!r}: off_log_ratio (F,) expected, got {np.shape(self.off_log_ratio)}")


@dataclass(frozen=True)
class Fixes:
    """Per role, the fixes of one session (``roles``), or why there are none (``missing``: role -> reason)."""

    roles: dict[str, RoleFixes] = field(default_factory=dict)
    missing: dict[str, str] = field(default_factory=dict)

    def __getitem__(self, role: str) -> RoleFixes:
        """The fixes of ``role``; :class:`MissingStream` when the session has none, ValueError for a role the run
        was not given."""
        if role in self.roles:
            return self.roles[role]
        if role in self.missing:
            raise MissingStream(self.missing[role])
        raise ValueError(f"no fixes of role {role!r} were resolved for this run (roles: "
                         f"{sorted(set(self.roles) | set(self.missing))})")

    def __contains__(self, role: str) -> bool:
        return role in self.roles or role in self.missing


@dataclass(frozen=True)
class RunInputs:
    """What one run of a localizer gets besides the session.

    ``cache``: a dict shared by all methods on the same sessions (per-floor map geometry, per-session AHRS; keys
    are the methods' own); ``fixes``: this session's fixes per role (None: the run has no ``fixes`` block);
    ``out``: the evaluation's output folder (None outside an evaluation: a method that writes, e.g. a training
    run, uses a temporary folder); ``run``: which run this call makes when the evaluation calls a method once per
    run (each run on its own perturbed beacon map: :func:`blenav.eval.beacon_map.run_per_run_maps`), None when one
    call makes every run."""

    cache: dict = field(default_factory=dict)
    fixes: Fixes | None = None
    out: Path | None = None
    run: int | None = None

    def with_fixes(self, fixes: Fixes | None) -> "RunInputs":
        """The same inputs (the same cache) with ``fixes`` for another session."""
        return RunInputs(self.cache, fixes, self.out, self.run)

    def for_run(self, run: int | None) -> "RunInputs":
        """The same inputs for the call that makes run ``run`` alone."""
        return RunInputs(self.cache, self.fixes, self.out, run)
