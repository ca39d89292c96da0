"""Real phone walks (issue 17, the ILC 2.0 recordings): the train walks of ``experiment=realwalks``.

The experiment's PDR rows run :class:`blenav.localizers.realwalk.RealWalkPF` (its PDR odometry:
:mod:`blenav.filters.pdr_odometry`); its tables are written by :mod:`blenav.reporting.realwalks`.
"""

from __future__ import annotations

__all__ = ["train_ids"]


def train_ids(cfg) -> list[str]:
    """The train walks of the composed experiment ``cfg`` (its ``data`` and ``split``), split by the harness itself
    (:func:`blenav.eval.sessions.train_test`, the one source of the split), so that a beacon map estimated from them
    by ``blenav-map --sessions`` sees no test walk. The entry point composes ``cfg``
    (``python -m blenav.cli.realwalks train-ids DATA``)."""
    from .config import parse_eval_config
    from .sessions import open_dataset, scored_sessions, train_test

    cfg = parse_eval_config(cfg)
    ds = open_dataset(cfg)
    train, _ = train_test(cfg, ds, scored_sessions(cfg, ds))
    return [s.id for s in train]
