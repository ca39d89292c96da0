"""Floor classification of walks from their radio scans (issue 17): which floor a test walk is on.

:func:`classify_floors` fits a k-nearest-neighbour classifier (Euclidean, on the fingerprint scale of
:mod:`blenav.features.fingerprints`: u = rssi - ``fill_dbm``, 0 = not heard, one vector per WiFi scan, or per
``ble_step_s`` BLE step, scaled to unit norm: cosine similarity, see
:func:`~blenav.features.fingerprints.unit_windows`) on every scan of the train walks, labelled with the walk's
``building/floor`` (session.yaml), classifies every scan of each test walk, and gives the walk the floor most of
its scans vote for (a tie goes to the floor whose votes have the smaller mean neighbour distance). Scans in which no
feature of the training vocabulary was heard do not vote; a walk without any voting scan is counted as
wrong (``no_scan``). The experiment node::

    floor_classifier: {features: wifi, k: 5}     # + any FingerprintConfig setting (fill_dbm, wifi_max_age_s, ...)

Result (``floor_accuracy`` in results.json): ``accuracy`` (share of test walks whose floor is right),
``walks``, ``scan_accuracy`` (share of voting scans), ``per_floor`` {floor: {accuracy, walks}},
``confusion`` {true floor: {predicted floor: walks}}, ``features``, ``k``, ``train_walks``, ``fit_s``.
"""

from __future__ import annotations

import time

import numpy as np

from blenav.errors import MissingStream
from blenav.features import fingerprints as FP

__all__ = ["classify_floors", "floor_accuracy"]


def _scan_vectors(sessions: list, columns: dict[str, int], cfg: FP.FingerprintConfig) -> list[np.ndarray | None]:
    out = []
    for s in sessions:
        try:
            w = FP.session_windows(s, columns, cfg)
        except MissingStream:
            out.append(None)
            continue
        out.append(FP.unit_windows(w.S[w.heard, :, -1]))  # (K, F): one unit vector per heard step
    return out


def classify_floors(train: list, test: list, features: str = "wifi", k: int = 5, **settings) -> dict:
    """Floor accuracy of a KNN scan classifier with majority vote per walk (see the module docstring).

    ``train`` / ``test``: sessions (their floor from session.yaml); ``settings``: further
    :class:`~blenav.features.fingerprints.FingerprintConfig` fields (``history`` is 1 here: one scan a vector).
    Raises ValueError when the train walks span fewer than two floors or have no scans."""
    from sklearn.neighbors import KNeighborsClassifier

    t0 = time.perf_counter()
    cfg = FP.FingerprintConfig(features=str(features), **{**settings, "history": 1})
    floors = sorted({FP.floor_of(s) for s in train})
    if len(floors) < 2:
        raise ValueError(f"floor_classifier: the train walks are on {len(floors)} floor(s) {floors}; need two or more")
    tables, used = FP.readable(train, cfg)
    if not used:
        raise ValueError(f"floor_classifier: no train walk has {features} readings")
    columns = {n: i for i, n in enumerate(FP.vocabulary(tables))}
    X, y = [], []
    for s, rd in zip(used, tables):
        w = FP.session_windows(s, columns, cfg, rd)
        X.append(FP.unit_windows(w.S[w.heard, :, -1]))
        y.append(np.full(int(w.heard.sum()), floors.index(FP.floor_of(s))))
    X, y = np.concatenate(X), np.concatenate(y)
    clf = KNeighborsClassifier(n_neighbors=min(int(k), len(X))).fit(X, y)
    walk_ok, scans_ok, scans_n = [], 0, 0
    confusion: dict[str, dict[str, int]] = {}
    for s, V in zip(test, _scan_vectors(test, columns, cfg)):
        truth = FP.floor_of(s)
        if V is None or not len(V):
            pred = "no_scan"
        else:
            dist, idx = clf.kneighbors(V)
            votes = y[idx]  # (K, k) neighbour floors
            scan_pred = np.array([np.bincount(v, minlength=len(floors)).argmax() for v in votes])
            counts = np.bincount(scan_pred, minlength=len(floors))
            best = np.flatnonzero(counts == counts.max())
            if len(best) > 1:  # tie: the floor whose voting scans are closer to their neighbours
                mean_d = [dist[scan_pred == f].mean() for f in best]
                best = best[[int(np.argmin(mean_d))]]
            pred = floors[int(best[0])]
            scans_ok += int((scan_pred == floors.index(truth)).sum()) if truth in floors else 0
            scans_n += len(V)
        walk_ok.append(pred == truth)
        row = confusion.setdefault(truth, {})
        row[pred] = row.get(pred, 0) + 1
    per_floor = {}
    for f in sorted(confusion):
        n = sum(confusion[f].values())
        per_floor[f] = {"accuracy": confusion[f].get(f, 0) / n, "walks": n}
    return {"accuracy": float(np.mean(walk_ok)) if walk_ok else None, "walks": len(walk_ok),
            "scan_accuracy": scans_ok / scans_n if scans_n else None, "per_floor": per_floor, "confusion": confusion,
            "features": cfg.features, "k": int(k), "train_walks": len(used), "train_scans": int(len(X)),
            "fit_s": time.perf_counter() - t0}


def floor_accuracy(node, train: list, test: list) -> dict | None:
    """``results["floor_accuracy"]`` of an experiment's ``floor_classifier`` node (a mapping of
    :func:`classify_floors` keywords; None: not asked) on the split's ``train`` / ``test`` walks; None when the
    walks are on one floor only (nothing to classify). Without train walks (no ``split``) a ValueError."""
    if node is None:
        return None
    from omegaconf import DictConfig, OmegaConf

    kw = OmegaConf.to_container(node, resolve=True) if isinstance(node, DictConfig) else dict(node)
    if len({FP.floor_of(s) for s in list(train) + list(test)}) < 2:
        return None
    if not train:
        raise ValueError("floor_classifier needs train walks: give the experiment a split {train_fraction, seed}")
    return classify_floors(train, test, **kw)
