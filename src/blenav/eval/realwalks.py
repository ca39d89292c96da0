"""Real phone walks (issue 17, the ILC 2.0 recordings): the train walks of ``experiment=realwalks``.

The experiment's PDR rows run :class:`blenav.localizers.realwalk.RealWalkPF` (its PDR odometry:
:mod:`blenav.filters.pdr_odometry`); its tables are written by :mod:`blenav.reporting.realwalks`.
"""

from __future__ import annotations

import numpy as np

__all__ = ["train_ids", "coverage", "COVERAGE_BINS_M"]

#: distance bins (m) from a fix's true position to the nearest train-walk position (:func:`coverage`)
COVERAGE_BINS_M = (0.0, 1.0, 2.0, 5.0, 10.0, np.inf)


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


def coverage(cfg, row: str = "knn_both", step_s: float = 0.5) -> dict:
    """Why fingerprint fixes are off where they are: the experiment's fingerprint row ``row`` (a ``methods`` key) fitted
    on the train walks, and each fix of the test walks (at its own time, against the ground truth interpolated there)
    binned by the distance of its true position to the nearest train-walk position (waypoints and the straight lines
    between them, every ``step_s`` s): per bin (:data:`COVERAGE_BINS_M`) the share of the fixes and their mean / median
    error (m). A KNN answers with positions the train walks visited: fixes far from them cannot be close. The entry
    point composes ``cfg`` (``python -m blenav.cli.realwalks coverage DATA``)."""
    from blenav.errors import MissingStream
    from blenav.features import fingerprints as FP
    from blenav.localizers import build_localizer

    from .config import parse_eval_config
    from .sessions import open_dataset, scored_sessions, train_test

    ecfg = parse_eval_config(cfg)
    ds = open_dataset(ecfg)
    train, test = train_test(ecfg, ds, scored_sessions(ecfg, ds))
    if not train:
        raise ValueError("coverage: the experiment has no train walks (split)")
    node = (ecfg.methods or {}).get(row)
    if node is None:
        raise ValueError(f"coverage: the experiment has no method {row!r} (methods: {sorted(ecfg.methods or {})})")
    if not str(node.get("_target_", "")).endswith("FingerprintLocalizer"):
        raise ValueError(f"coverage: method {row!r} is not a fingerprint localizer ({node.get('_target_')})")
    loc = build_localizer(str(node.get("label", row)), node, ecfg.shared())
    loc.fit(train)
    seen = {}
    for s in train:
        gt = s.groundtruth
        t = np.arange(float(gt["t"].iloc[0]), float(gt["t"].iloc[-1]) + 1e-9, step_s)
        seen.setdefault(FP.floor_of(s), []).append(s.positions_at(t)[:, :2])
    seen = {k: np.concatenate(v) for k, v in seen.items()}  # per building/floor: the train walks' positions, once
    err, dist, where, first = [], [], [], None
    skipped = {}
    for s in test:
        try:
            est = loc.run(s, 1, 0)
        except MissingStream as exc:  # a walk without the row's scans: skipped, and said
            skipped[s.id] = str(exc)
            continue
        gt_t = s.groundtruth["t"].to_numpy(float)
        truth = s.positions_at(est.t)[:, :2]
        ok = np.isfinite(truth).all(axis=1) & (est.t >= gt_t[0]) & (est.t <= gt_t[-1])  # inside the survey
        ref = seen.get(FP.floor_of(s), np.zeros((0, 2)))
        if not ok.any() or not len(ref):
            continue
        err.append(np.linalg.norm(est.position[0][ok] - truth[ok], axis=1))
        where.append(truth[ok])
        first = first or s
        d = np.full(int(ok.sum()), np.inf)
        for i in range(0, len(ref), 4096):  # bounded memory
            d = np.minimum(d, np.linalg.norm(truth[ok][:, None] - ref[None, i:i + 4096], axis=2).min(axis=1))
        dist.append(d)
    if not err:
        raise ValueError(f"coverage: {node.get('label', row)} gave no fix inside the waypoints of the "
                         f"{len(test)} test walks ({len(skipped)} skipped)")
    err, dist = np.concatenate(err), np.concatenate(dist)
    bins = []
    for lo, hi in zip(COVERAGE_BINS_M[:-1], COVERAGE_BINS_M[1:]):
        m = (dist >= lo) & (dist < hi)
        bins.append({"from_m": lo, "to_m": None if np.isinf(hi) else hi, "share": float(m.mean()),
                     "error_mean_m": float(err[m].mean()) if m.any() else None,
                     "error_median_m": float(np.median(err[m])) if m.any() else None})
    return {"row": str(node.get("label", row)), "fixes": int(len(err)), "error_mean_m": float(err.mean()),
            "train_walks": len(train), "test_walks": len(test), "skipped": skipped, "bins": bins,
            # for the figure (python -m blenav.cli.realwalks coverage DATA --plot FILE): not written to JSON
            "_points": {"session": first, "train": seen.get(FP.floor_of(first), np.zeros((0, 2))),
                        "truth": np.concatenate(where), "error": err}}
