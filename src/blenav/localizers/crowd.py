"""A fingerprint survey grown by the walks it localizes (issue 30): the crowd-sourced radio map.

A floor's KNN knows only where its train walks went; a walker anywhere else gets a fix near a surveyed place, and
the fused rows inherit that error (docs/results-ilc20.md: 19-28 % of the test fixes lie over 5 m from any train
walk). The other walks recorded on the same floor went there. :class:`CrowdFingerprint` is the cross-validated KNN of
:class:`~blenav.localizers.fingerprint.FingerprintLocalizer` whose reference set is, besides the train walks' windows
(labelled by their surveyed waypoints), every window of the *other scored walks*, labelled by another row's estimate
of that walk at the window's time (``crowd.labels``: ``fused-offline``, which used no ground truth):

* a walk's own windows are never its neighbours (:class:`blenav.localizers.knn.KnnModel`, ``exclude``), so its fixes
  hear nothing of its own estimate;
* the KNN setting is the one cross-validated on the train walks (as the plain KNN's);
* each fix's std (``fix_std: calibrated``) is refitted with the crowd in the reference set: the train walks' windows
  predicted by the other folds' walks *plus the crowd*, against their surveyed labels
  (:func:`blenav.localizers.knn.out_of_fold_represented` with ``extra``), then times ``crowd.std_scale``: a train walk finds
  surveyed neighbours, a scored walk off the survey mostly crowd ones, whose labels carry the labels row's error, so
  the refit alone states too small a std there (chosen on the train walks: docs/results-ilc20.md).

Transductive: the estimate of one walk depends on which other walks are scored with it. Nothing of a scored walk's
ground truth is read (the labels row is the evaluation's own estimate). The evaluation calls :meth:`prepare_batch`
after the labels row ran on every scored walk (:class:`~blenav.localizers.base.Transductive`); a deployment would
prepare it from its past recordings instead. numpy only.
"""

from __future__ import annotations

import logging
import math

import numpy as np

from blenav.errors import MissingStream
from blenav.features import fingerprints as FP

from . import knn as KNN
from .base import Transductive, batch_settings
from .fingerprint import CV_GRID, MIN_STD_FIT, FingerprintLocalizer, _FloorModel

log = logging.getLogger("blenav.localizers.crowd")

__all__ = ["CrowdFingerprint", "track_labels"]


def track_labels(tw: np.ndarray, t: np.ndarray, xy: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(inside (K,) bool, labels (inside.sum(), 2) m): the window end times ``tw`` (K,) s that lie inside an
    estimate's span, and the estimate (``t`` (T,) s increasing, ``xy`` (T, 2) m, finite) interpolated linearly
    there."""
    inside = (tw >= t[0]) & (tw <= t[-1])
    ti = tw[inside]
    return inside, np.column_stack([np.interp(ti, t, xy[:, 0]), np.interp(ti, t, xy[:, 1])])


class CrowdFingerprint(FingerprintLocalizer, Transductive):
    """The cross-validated KNN with the other scored walks in its survey (module doc). ``crowd``: ``labels``, the
    label of the row whose estimates label them (it must run before this one), ``std_scale`` (> 0), the factor on
    the refitted std (module doc); every other setting is
    :class:`FingerprintLocalizer`'s (``model: knn`` with ``cv`` or ``fix_std: calibrated``)."""

    def __init__(self, name: str, shared=None, crowd: dict | None = None, **settings):
        super().__init__(name, shared, **settings)
        crowd, labels = batch_settings(name, "crowd", crowd, {"std_scale", "max_label_std_m"}, "fused-offline")
        self.std_scale = float(crowd.get("std_scale", 1.0))
        mx = crowd.get("max_label_std_m")
        self.max_label_std_m = None if mx is None else float(mx)
        if not self.std_scale > 0:
            raise ValueError(f"method {name!r}: crowd.std_scale must be > 0, got {self.std_scale}")
        if self.model != "knn" or (self.cv is None and self.fix_std != "calibrated"):
            raise ValueError(f"method {name!r}: the crowd extends the cross-validated KNN (model: knn with cv: {{}} or "
                             f"fix_std: calibrated), got model {self.model}, cv {self.cv}, fix_std {self.fix_std}")
        self.batch_labels = labels
        self._survey: dict[str, _FloorModel] = {}
        self._prepared = False
        self._windows: dict[str, tuple[np.ndarray, np.ndarray]] = {}  # session id -> heard windows, read once

    def fit(self, sessions: list, inputs=None) -> dict:
        report = super().fit(sessions, inputs)
        self._survey, self._prepared = dict(self.floors), False
        return report

    def prepare_batch(self, sessions: list, estimates: dict, inputs=None) -> dict:
        """Put the windows of every walk of ``sessions`` that ``estimates`` (session id -> Estimate of the labels row)
        has into the reference set of its floor; refit each floor's std model with them. Returns per floor: walks,
        windows, and the std model's out-of-fold coverage."""
        info: dict = {"labels": self.batch_labels, "floors": {}}
        self._windows = {}
        for key, fm in self._survey.items():
            base = fm.predict
            X, xy, groups = [], [], []
            for s in sessions:
                est = estimates.get(s.id)
                if est is None or FP.floor_of(s) != key or not len(est.t):
                    continue
                pos = np.asarray(est.position, float).mean(axis=0)  # (T, 2): the runs' mean
                ok = np.isfinite(pos).all(axis=1)
                if self.max_label_std_m is not None and est.cov is not None:
                    sd = np.sqrt(np.trace(np.asarray(est.cov, float).mean(axis=0), axis1=1, axis2=2) / 2.0)
                    ok &= sd <= self.max_label_std_m
                if ok.sum() < 1:
                    continue
                try:
                    S, tw = self._windows[s.id] = self.heard_windows(s, fm.columns)
                except MissingStream:  # the walk lacks this localizer's stream (no rssi.csv for a BLE crowd)
                    continue
                inside, xyc = track_labels(tw, np.asarray(est.t, float)[ok], pos[ok])
                if not inside.any():
                    continue
                X.append(base.represent(S[inside]))
                xy.append(xyc)
                groups.append(np.full(len(xyc), s.id, object))
            n = int(sum(len(a) for a in X))
            if not n:
                self.floors[key] = fm
                info["floors"][key] = {"walks": 0, "windows": 0}
                continue
            Xc, xyc = np.concatenate(X), np.concatenate(xy)
            std_model, cov_info = self._crowd_std(base, Xc, xyc)
            self.floors[key] = _FloorModel(fm.columns, base.extended(Xc, xyc, np.concatenate(groups), std_model))
            info["floors"][key] = {"walks": len(X), "windows": n, "survey_windows": int(len(base.X)), **cov_info}
            log.info("%s: %s survey of %d windows + %d windows of %d walks labelled by %s", self.name, key,
                     len(base.X), n, len(X), self.batch_labels)
        self._prepared = True
        return info

    def _crowd_std(self, base: KNN.KnnModel, Xc: np.ndarray, xyc: np.ndarray):
        """The std model refitted with the crowd (Xc (M, D) represented, labels xyc (M, 2) m) in every fold's
        reference set (module doc), and its coverage; the survey's own model where there are too few train windows
        to refit it."""
        if base.std_model is None or base.walk_of is None:
            return base.std_model, {}
        folds = self.cv["folds"] if self.cv is not None else CV_GRID["folds"]
        err, spread, d1 = KNN.out_of_fold_represented(base.X, base.xy, base.walk_of, base.setting, base.cov_floor_m,
                                                      folds=folds, seed=self.seed, extra=(Xc, xyc))
        if len(err) < MIN_STD_FIT:
            return base.std_model, {}
        fitted = KNN.fit_std_model(err, spread, d1)
        model = KNN.StdModel((fitted.c[0] + math.log(self.std_scale), *fitted.c[1:]))  # log std + log std_scale
        r = err / model.std(spread, d1)
        return model, {"fix_std_c": list(model.c), "out_of_fold_error_m": float(np.mean(err)),
                       "coverage_1sigma": float(np.mean(r <= 1.0)), "coverage_2sigma": float(np.mean(r <= 2.0))}

    def heard_windows(self, session, columns: dict[str, int]) -> tuple[np.ndarray, np.ndarray]:
        """:meth:`FingerprintLocalizer.heard_windows`, read once: a scored walk's windows read by
        :meth:`prepare_batch` are handed over (and forgotten) when the walk is run."""
        cached = self._windows.pop(session.id, None)
        return cached if cached is not None else super().heard_windows(session, columns)

    def run(self, session, n_runs: int, seed: int, inputs=None):
        if not self._prepared:
            raise MissingStream(f"{self.name}: the crowd was not prepared (row {self.batch_labels!r} must run on the "
                                f"scored walks before it)")
        return super().run(session, n_runs, seed, inputs)
