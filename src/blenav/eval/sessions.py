"""Which sessions an evaluation scores and which train: the dataset opened, the labelled sessions selected (not the
calibration surveys), checked to lie in their buildings, optionally given wrong floor plans, and split into train and
test walks per building and floor (the experiment's ``split``); the floor classifier's accuracy on the test walks.
"""

from __future__ import annotations

import logging
from pathlib import Path

import numpy as np

from blenav.data import Dataset, check_session_in_building
from blenav.errors import DatasetError, EvalError, MissingStream
from blenav.eval.plan_errors import PlanErrorConfig, perturb_building

from .config import EvalConfig, SplitConfig
from .floors import floor_accuracy

log = logging.getLogger("blenav.eval")

__all__ = ["select_sessions", "with_wrong_plans", "open_dataset", "scored_sessions", "split_sessions", "train_test",
           "floor_accuracy_of"]


def select_sessions(ds: Dataset, ids, exclude: set = frozenset()) -> list:
    """``ids`` (labelled sessions), or every labelled session not in ``exclude``: the moving ones, or the
    static surveys when there is nothing else."""
    if ids:
        wanted = [str(i) for i in (ids if not isinstance(ids, str) else ids.split(","))]
        unknown = [i for i in wanted if i not in ds.session_ids]
        if unknown:
            raise EvalError(f"sessions {unknown} are not in {ds.root} (it has {ds.session_ids[:10]}...)")
        sessions = [ds.session(i) for i in wanted]
        unl = [s.id for s in sessions if not s.labelled]
        if unl:
            raise EvalError(f"sessions {unl} are unlabelled: they have no ground truth to score against")
        return sessions
    sessions = [s for s in ds.sessions(labelled=True) if s.id not in exclude]  # calibration sessions are not scored
    if not sessions:
        raise EvalError(f"{ds.root} has no labelled session to evaluate")
    moving = [s for s in sessions if s.carrier != "static"]
    return moving or sessions  # static surveys are calibration data unless they are all there is


def with_wrong_plans(sessions: list, pe: PlanErrorConfig, out_dir: Path) -> tuple[list, dict]:
    """The sessions with their buildings' plans replaced by wrong ones (one per building, shared by its
    sessions; streams and their caches are kept), and the per-building summaries."""
    wrong, info = {}, {}
    for s in sessions:
        if s.building.id not in wrong:
            wrong[s.building.id], info[s.building.id] = perturb_building(s.building, pe, out_dir)
            log.info("plan errors in %s: %s", s.building.id, info[s.building.id])
    return [s.with_building(wrong[s.building.id]) for s in sessions], info


def open_dataset(cfg: EvalConfig) -> Dataset:
    try:
        return Dataset.open(cfg.data.path)
    except DatasetError as exc:
        raise EvalError(f"cannot open dataset {cfg.data.path}: {exc}") from exc


def scored_sessions(cfg: EvalConfig, ds: Dataset) -> list:
    """The sessions to score (the sessions ``calibration`` names are not scored); every session is checked to lie in
    its building."""
    try:  # the data layer's rules (a floor without free space, ground truth off the plan, ...) are the readers'
        sessions = select_sessions(ds, cfg.session_ids, exclude=cfg.calibration_sessions)
        for s in sessions:
            check_session_in_building(s)
    except DatasetError as exc:
        raise EvalError(str(exc)) from exc
    return sessions


def split_sessions(sessions: list, split: SplitConfig) -> tuple[list, list]:
    """(train, test): per building and floor, a seeded permutation of the walks (by session id, so the
    split depends only on the seed and the walks), the first ``round(train_fraction * n)`` of them train
    (at least one, and at least one left to test when a floor has two or more walks)."""
    frac, seed = float(split.train_fraction), int(split.seed)
    if not 0.0 < frac < 1.0:
        raise EvalError(f"split.train_fraction must be in (0, 1), got {frac}")
    groups: dict = {}
    for s in sorted(sessions, key=lambda s: s.id):
        groups.setdefault((s.building.id, str(s.meta.get("floor"))), []).append(s)
    train, test = [], []
    for i, key in enumerate(sorted(groups, key=str)):
        g = groups[key]
        order = np.random.default_rng([seed, i]).permutation(len(g))
        n = min(max(1, int(round(frac * len(g)))), max(len(g) - 1, 1))
        train += [g[j] for j in order[:n]]
        test += [g[j] for j in order[n:]]
    return train, test


def train_test(cfg: EvalConfig, ds: Dataset, sessions: list) -> tuple[list, list]:
    """(train walks, scored walks) of the experiment's ``split``: ``{train: [ids]}`` names the train walks (not
    scored), ``{train_fraction, seed}`` splits each floor's walks (:func:`split_sessions`); no split: ([], sessions)."""
    split = cfg.split
    if split is None:
        return [], sessions
    if split.train:
        train = select_sessions(ds, split.train)
        test = [s for s in sessions if s.id not in {t.id for t in train}]
        if not test:
            raise EvalError("split.train names every evaluated session: nothing left to score")
        return train, test
    return split_sessions(sessions, split)


def floor_accuracy_of(cfg: EvalConfig, train: list, sessions: list) -> dict | None:
    """Which floor each test walk is on, from the train walks' scans (:mod:`blenav.eval.floors`; several floors)."""
    try:
        return floor_accuracy(cfg.floor_classifier, train, sessions)
    except (ValueError, MissingStream) as exc:
        raise EvalError(f"floor_classifier: {exc}") from exc
