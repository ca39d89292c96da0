"""Fingerprinting on real walks: KNN, LocNet and TransNet+LocNet on WiFi scans, BLE advertisements or both,
trained on the labelled train walks of the dataset it is evaluated on (the experiment's ``split``).

Config: ``conf/localizer/fingerprint.yaml``::

    _target_: blenav.localizers.fingerprint.FingerprintLocalizer
    model: knn            # knn | locnet | transnet_locnet | placenet
    features: wifi        # wifi | ble | both
    training: {data, trainer, models: {locnet, transnet_locnet}}   # composed by its defaults list

``training`` is the networks' training config, the nodes of ``conf/train.yaml`` (``conf/windows/default.yaml``,
``conf/trainer/cpu.yaml``, ``conf/model/<model>.yaml``) composed into the method's node by the YAML's defaults, so
that :meth:`FingerprintLocalizer.fit` composes nothing; a node without it (e.g. an inline ``fixes.compute``) runs
``knn`` only.

:meth:`FingerprintLocalizer.fit` (the harness calls it with the train walks, :class:`~blenav.localizers.Trained`),
per building and floor:

1. the readings of every train walk (:func:`blenav.features.fingerprints.readings`); the feature vocabulary
   (the WiFi access points / BLE anchors heard in at least ``min_count`` readings, the ``max_features`` most
   heard: ``auto`` = all for KNN and LocNet, 256 for TransNet+LocNet, whose statistics matrix and SSL loss are
   F x F; LocNet on site1 F1: 11.9 m mean with 256, 10.5 m with all 2,298);
2. windows of H = ``history`` steps (a step = one WiFi scan; BLE: every ``ble_step_s`` s), values
   u = rssi - ``fill_dbm`` with 0 = not heard (= ``fill_dbm``, -100 dBm by default);
3. labels: the position at the window's last step time, **interpolated linearly between the surveyed
   waypoints** (sparse ground truth; :meth:`Session.positions_at`); windows outside the waypoints' time span
   are dropped (counted in the report), as are windows in which no feature was heard;
4. ``knn``: :class:`blenav.learn.crossphone.baselines.KNNBaseline` (k nearest fingerprints, the mean over a window's heard
   steps; the cross-phone evaluation's KNN) on windows scaled to unit norm (``metric: cosine``, the default:
   a scan listing few access points is otherwise the nearest neighbour of everything) or on the u scale as it is
   (``euclidean``); ``locnet`` / ``transnet_locnet`` / ``placenet`` (a classifier of the survey's places,
   :class:`blenav.models.PlaceNet`): the networks of ``conf/model/<model>.yaml`` trained by
   :func:`blenav.learn.fingerprint.train.train_network` (the project's trainer: step budget + early stopping of
   ``conf/trainer/cpu.yaml``, seeded; labels normalised by the network's ``xy_mean`` / ``xy_scale``, or its places;
   inputs u / 100) with a seeded ``val_fraction`` of the train walks held out for validation; with ``refit: true``
   then trained again on every train walk for as many epochs as the validation run's best check, stating that run's
   std calibration (:mod:`blenav.localizers.fingerprint_net`). Torch is imported only there.

:meth:`FingerprintLocalizer.run`: one estimate per window of the session in which a feature of the
vocabulary was heard (times: the window's last step, session clock s); the floor's model is the one of the
session's ``building`` / ``floor`` (session.yaml); no estimate is invented before the first window or after the
last (scoring may hold the ends: :func:`blenav.eval.metrics.waypoint_metrics` ``hold_ends``). ``beacons`` (attribute,
None: all): the BLE anchor ids the localizer hears at run time (the others' advertisements are dropped), e.g. the
sparse beacon subset of :mod:`blenav.eval.fixes`. Deterministic: R identical runs.
``cov``: KNN: the (weighted) covariance of the k neighbours' positions plus ``cov_floor_m``^2 I; the networks: none
by default, with ``net_cov: validation`` (opt-in) their RMS error per axis on their validation walks (squared) plus
``cov_floor_m``^2, the same for every fix (none when no walk was held out for validation); with ``net_cov:
predicted`` (a LocNet with its std head, ``net: {locnet: {std_head: true}}``, issue 29) each fix's own sigma, trained
with the Gaussian negative log-likelihood and scaled on the validation walks (:mod:`blenav.models.locnet`), squared,
plus ``cov_floor_m``^2; with ``net_cov: calibrated`` (the default of experiment=realwalks' learned rows) a std of
:class:`~blenav.localizers.knn.StdModel`'s form from that sigma and the window's signal distance to the windows the
network trained on, fitted on the validation walks' errors
(:func:`blenav.localizers.fingerprint_net.net_std_model`). Its std is what the fused
filters may use (:mod:`blenav.eval.fixes`), so it can change a fused row fed by a network's fixes.

**Issue 29** (reading scans the way they were heard; KNN done well): WiFi steps are the scans at the times their
readings were heard, stale cached readings dropped (``wifi_max_age_s``, ``wifi_age_ref``, ``wifi_time``:
:mod:`blenav.features.fingerprints`); with ``cv`` (``cv: {}``: the grid :data:`CV_GRID`) the KNN's
metric (cosine / powed / euclidean), k, the neighbours' weighting and the BLE part's weight (``both``) are chosen
per floor by leave-walks-out cross-validation on the train walks this localizer is fitted on, scored at their own
waypoints (:mod:`blenav.localizers.knn`; the choice and every setting's score in the training report's ``cv``).
Measured on site1 (``blenav-eval experiment=realwalks data=FLOOR runs=1``, mean error at the test waypoints, F1 / F2 /
B1, 2026-11-27, on 0cd3045; the opted-in KNN rows, the ablation and the defaults on F1 rerun on 9d79a80: the same,
docs/results-ilc20.md): KNN-WiFi 9.00 / 9.63 / 8.66 m before, 8.20 / 8.06 / 8.58 m opted in; KNN-WiFi+BLE 8.87 /
9.59 / 8.59 -> 7.98 / 8.10 / 8.63 m; KNN-BLE 12.48 / 15.19 / 14.10 -> 12.92 / 16.01 / 14.46 m (the cross-validated
choice generalises worse than k = 5 uniform cosine there). Ablation (this localizer on the same splits, WiFi): the
scans read as heard with the old KNN (cosine, k = 5, uniform) 9.00 / 9.82 / 8.55 m; the cross-validated KNN on the old
reading (age from the delivery time, fix at the delivery) 7.92 / 7.91 / 8.61 m: the gain is the KNN's, the heard times
change the test error by under 0.3 m either way (the train-walk CV prefers them on F1 and B1, 6.39 vs 6.45 and 8.56 vs
8.76 m, not on F2, 8.31 vs 8.24 m). All of it is **opt-in** (the defaults, ``wifi_age_ref`` / ``wifi_time: delivery``,
``cv: null``, ``net_cov: none``, are the pre-issue-29 behaviour the published tables were made with): the overrides
are in docs/results-ilc20.md.
A session without the stream (wifi.csv / rssi.csv) or without a trained floor raises :class:`MissingStream`.
"""

from __future__ import annotations

import logging
import time
from dataclasses import asdict

import numpy as np

from blenav.errors import MissingStream
from blenav.features import fingerprints as FP
from blenav.learn.crossphone.model_node import states_std

from . import knn as KNN
from .base import Estimate, Localizer, RunInputs, Trained
from .fingerprint_net import MIN_STD_FIT, fit_network  # MIN_STD_FIT: also fix_std: calibrated's out-of-fold fixes
from .survey import walk_positions

log = logging.getLogger("blenav.localizers.fingerprint")
# the KNN settings issue 29 cross-validated (``cv: {}``; each key may be given instead): 2 x 7 x 5 x 3 settings
CV_GRID = {"folds": 5, "metric": ["cosine", "powed"], "k": [1, 3, 5, 7, 10, 15, 20],
           "weights": ["uniform", "distance", 0.02, 0.05, 0.1], "ble_weight": [0.25, 0.5, 1.0]}

MODELS = ("knn", "locnet", "transnet_locnet", "placenet")
#: the networks' fix covariance: none, the validation walks' RMS error, the std head's own calibrated sigma, or a
#: std model of that sigma and the scan's distance to the survey
NET_COVS = ("none", "validation", "predicted", "calibrated")
#: features kept by ``max_features: auto`` for TransNet+LocNet (its SSL loss holds b x F x F x H values)
NET_MAX_FEATURES = 256


class _FloorModel:
    """A fitted model of one floor: columns (feature -> column), predict(S) -> (xy (K, 2) m, cov (K, 2, 2) or
    None); a :class:`~blenav.localizers.knn.KnnModel` predict is called with ``exclude=`` the session's id (a
    crowd-labelled walk's own reference windows left out: :mod:`blenav.localizers.crowd`)."""

    def __init__(self, columns: dict[str, int], predict):
        self.columns, self.predict = columns, predict

    def __call__(self, S: np.ndarray, session_id: str):
        if isinstance(self.predict, KNN.KnnModel):
            return self.predict(S, exclude=session_id)
        return self.predict(S)


def knn_model(S: np.ndarray, xy: np.ndarray, k: int, weights: str, cov_floor_m: float, metric: str = "cosine"):
    """KNN on windows S (N, F, H) u scale with labels xy (N, 2) m (:class:`~blenav.learn.crossphone.baselines.KNNBaseline`,
    on :func:`~blenav.features.fingerprints.unit_windows` when ``metric`` is ``cosine``, on S itself when
    ``euclidean``); returns predict: S (K, F, H) -> (xy (K, 2), cov (K, 2, 2)), cov the neighbours' position
    covariance (population, uniform weights) + cov_floor_m^2 I."""
    from blenav.learn.crossphone.baselines import KNNBaseline, fingerprint

    if metric not in ("cosine", "euclidean"):
        raise ValueError(f"metric must be 'cosine' or 'euclidean', got {metric!r}")
    scale = FP.unit_windows if metric == "cosine" else (lambda a: a)
    knn = KNNBaseline(k=k, weights=weights).fit(scale(S), xy)
    kk = knn.model_.n_neighbors

    def predict(Sq):
        Sq = scale(Sq)
        idx = knn.model_.kneighbors(fingerprint(Sq), n_neighbors=kk, return_distance=False)  # (K, k): one search
        mean = xy[idx].mean(axis=1, keepdims=True)  # (K, 1, 2): KNeighborsRegressor's uniform prediction
        est = mean[:, 0] if weights == "uniform" else knn.predict(Sq)
        d = xy[idx] - mean  # (K, k, 2)
        cov = np.einsum("kni,knj->kij", d, d) / kk + float(cov_floor_m) ** 2 * np.eye(2)
        return est, cov

    return predict


class FingerprintLocalizer(Localizer, Trained):
    """Fingerprinting (KNN / LocNet / TransNet+LocNet) on WiFi, BLE or both; see the module docstring."""

    uses_floor_plan = False  # radio fingerprints only: estimates are not moved into free space
    states_fix_std = True  # its covariance is each fix's stated uncertainty: scored as fix_coverage {own}

    def __init__(self, name: str, shared=None, model: str = "knn", features: str = "wifi", k: int = 5,
                 weights: str = "uniform", metric: str = "cosine", history: int = 1, fill_dbm: float = -100.0,
                 floor_u: float = 0.5, ble_window_s: float = 3.0, ble_step_s: float = 1.0,
                 wifi_max_age_s: float | None = 5.0, wifi_age_ref: str = "delivery", wifi_time: str = "delivery",
                 min_count: int = 1, max_features="auto", cov_floor_m: float = 1.0, cv: dict | None = None,
                 net_cov: str = "none", fix_std: str = "neighbours",
                 net: dict | None = None, trainer: dict | None = None, val_fraction: float = 0.2,
                 batch_size: int = 256, seed: int = 0, threads: int | None = 1, plots: bool = False,
                 training: dict | None = None, refit: bool = False):
        super().__init__(name, shared)
        if model not in MODELS:
            raise ValueError(f"method {name!r}: model must be one of {MODELS}, got {model!r}")
        from omegaconf import DictConfig, OmegaConf

        if isinstance(training, DictConfig):  # build_localizer hands nested nodes over unconverted
            training = OmegaConf.to_container(training, resolve=True)
        if model != "knn" and model not in ((training or {}).get("models") or {}):
            raise ValueError(f"method {name!r}: model {model} needs the networks' training config, training.models."
                             f"{model} (with training.data and training.trainer), which conf/localizer/fingerprint.yaml "
                             f"composes: build the method from that YAML (+localizer@methods.NAME=fingerprint)")
        self.training = training
        if int(k) < 1:
            raise ValueError(f"method {name!r}: k must be >= 1, got {k}")
        if weights not in ("uniform", "distance"):
            raise ValueError(f"method {name!r}: weights must be 'uniform' or 'distance', got {weights!r}")
        if not (max_features == "auto" or max_features is None or int(max_features) >= 1):
            raise ValueError(f"method {name!r}: max_features must be auto, null or >= 1, got {max_features!r}")
        try:
            self.cfg = FP.FingerprintConfig(features=str(features), history=int(history), fill_dbm=float(fill_dbm),
                                            floor_u=float(floor_u), ble_window_s=float(ble_window_s),
                                            ble_step_s=float(ble_step_s),
                                            wifi_max_age_s=None if wifi_max_age_s is None else float(wifi_max_age_s),
                                            wifi_age_ref=str(wifi_age_ref), wifi_time=str(wifi_time))
        except ValueError as exc:
            raise ValueError(f"method {name!r}: {exc}") from None
        if metric not in ("cosine", "euclidean"):
            raise ValueError(f"method {name!r}: metric must be 'cosine' or 'euclidean', got {metric!r}")
        self.model, self.k, self.weights, self.metric = model, int(k), weights, metric
        self.cv = self._cv_grid(name, cv)
        if net_cov not in NET_COVS:
            raise ValueError(f"method {name!r}: net_cov must be one of {NET_COVS}, got {net_cov!r}")
        self.net_cov = net_cov
        if fix_std not in ("neighbours", "calibrated"):
            raise ValueError(f"method {name!r}: fix_std must be 'neighbours' or 'calibrated', got {fix_std!r}")
        if fix_std == "calibrated" and model != "knn":
            raise ValueError(f"method {name!r}: fix_std: calibrated is the KNN's (the networks' std: net_cov)")
        self.fix_std = fix_std
        self.min_count, self.cov_floor_m = int(min_count), float(cov_floor_m)
        self.beacons: tuple | None = None  # BLE anchor ids heard at run time (None: all)
        if max_features == "auto":
            max_features = NET_MAX_FEATURES if model == "transnet_locnet" else None
        self.max_features = None if max_features is None else int(max_features)
        self.net, self.trainer = dict(net or {}), dict(trainer or {})
        if net_cov in ("predicted", "calibrated") and not self._std_head(model):
            raise ValueError(f"method {name!r}: net_cov: {net_cov} needs a network that states a std: LocNet's std "
                             f"head (model: locnet or transnet_locnet, net: {{locnet: {{std_head: true}}}}) or "
                             f"model: placenet")
        self.val_fraction, self.batch_size, self.seed = float(val_fraction), int(batch_size), int(seed)
        self.refit = bool(refit)
        self.threads, self.plots = threads, bool(plots)
        self.floors: dict[str, _FloorModel] = {}
        self._unfitted = "was not fitted (no train walks: the experiment needs a split)"  # why run() cannot

    def _std_head(self, model: str) -> bool:
        """Whether the network this method trains states a std (:func:`blenav.learn.crossphone.model_node.states_std`
        of its model node with ``net`` over it: LocNet's std head, or a PlaceNet)."""
        if model == "knn":
            return False
        node = dict(((self.training or {}).get("models") or {}).get(model, {}).get("locnet") or {})
        return states_std({"locnet": {**node, **dict(self.net.get("locnet") or {})}})

    @staticmethod
    def _cv_grid(name: str, cv) -> dict | None:
        """The KNN's cross-validation block (:mod:`blenav.localizers.knn`): {folds, metric, k, weights, ble_weight}
        lists, checked; a key left out takes :data:`CV_GRID`'s (``cv: {}``: that whole grid, the one issue 29
        measured); None: no cross-validation (k, weights, metric as given)."""
        if cv is None:
            return None
        from omegaconf import DictConfig, OmegaConf

        if isinstance(cv, DictConfig):
            cv = OmegaConf.to_container(cv, resolve=True)
        unknown = set(cv) - {"folds", "metric", "k", "weights", "ble_weight"}
        if unknown:
            raise ValueError(f"method {name!r}: cv: unknown keys {sorted(unknown)} "
                             f"(folds, metric, k, weights, ble_weight)")
        out = {"folds": int(cv.get("folds", CV_GRID["folds"]))}
        for key in ("metric", "k", "weights", "ble_weight"):
            v = cv.get(key, CV_GRID[key])
            out[key] = list(v) if isinstance(v, (list, tuple)) else [v]
            if not out[key]:
                raise ValueError(f"method {name!r}: cv.{key} is empty")
        try:
            KNN.grid(out["metric"], out["k"], out["weights"], out["ble_weight"])
        except ValueError as exc:
            raise ValueError(f"method {name!r}: cv: {exc}") from None
        return out

    def _settings(self) -> dict:
        """The fingerprint settings for the training report: issue 29's reading keys (``wifi_age_ref``,
        ``wifi_time``) only when not at their pre-issue-29 value ``delivery``, so that the report (and results.json)
        of the default reading is the one written before they existed."""
        out = asdict(self.cfg)
        for key in ("wifi_age_ref", "wifi_time"):
            if out[key] == "delivery":
                del out[key]
        return out

    # ------------------------------------------------------------------ training
    def fit(self, sessions: list, inputs: RunInputs | None = None) -> dict:
        """Fit one model per building/floor on the labelled ``sessions``; returns the training report
        (``labels``, ``features``, ``model``, per floor: walks, windows, dropped windows, features, fit_s,
        and the network's training report)."""
        groups: dict[str, list] = {}
        for s in sorted(sessions, key=lambda s: s.id):
            if s.labelled:
                groups.setdefault(FP.floor_of(s), []).append(s)
        if not groups:
            self._unfitted = "was not fitted: no labelled train walk to build fingerprints from"
            raise MissingStream(f"{self.name}: no labelled train walk to build fingerprints from")
        report = {"model": self.model, "features": self.cfg.features, "settings": self._settings(),
                  "labels": "position at each window's last step time, interpolated linearly between the surveyed "
                            "waypoints (Session.positions_at); windows outside the waypoints' span dropped",
                  "fill": f"a source not heard = {self.cfg.fill_dbm:g} dBm (u = 0)", "floors": {}}
        self.floors = {}
        for key, walks in groups.items():
            report["floors"][key] = self._fit_floor(key, walks, inputs)
        if not self.floors:
            what = {"wifi": "WiFi scans (wifi.csv)", "ble": "BLE readings (rssi.csv)",
                    "both": "both WiFi scans (wifi.csv) and BLE readings (rssi.csv)"}.get(self.cfg.features,
                                                                                        self.cfg.features)
            why = f"no train walk has {what} inside its waypoints (features: {self.cfg.features})"
            self._unfitted = f"was not fitted: {why}"
            raise MissingStream(f"{self.name}: {why}")
        return report

    def _fit_floor(self, key: str, walks: list, inputs) -> dict:
        t0 = time.perf_counter()
        tables, used = FP.readable(walks, self.cfg)
        info = {"train_walks": len(walks), "walks_with_readings": len(used)}
        if not used:
            return {**info, "unavailable": f"no train walk has {self.cfg.features} readings"}
        names = FP.vocabulary(tables, self.min_count, self.max_features)
        columns = {n: i for i, n in enumerate(names)}
        S, P, xy, walk_of, T = [], [], [], [], []
        outside = silent = 0
        for i, (s, rd) in enumerate(zip(used, tables)):
            w, n_out = FP.label_windows(s, FP.session_windows(s, columns, self.cfg, rd))
            outside += n_out
            ok = ~np.isnan(w.xy).any(axis=1)
            silent += int((ok & ~w.heard).sum())
            keep = ok & w.heard
            prev = np.r_[False, keep[1:]]  # windows with a previous window of the same walk (smoothness loss)
            keep_idx = np.flatnonzero(keep)
            S.append(w.S[keep_idx])
            P.append(w.S[np.where(prev[keep_idx], keep_idx - 1, keep_idx)])
            xy.append(w.xy[keep_idx])
            walk_of.append(np.full(len(keep_idx), i))
            T.append(w.t[keep_idx])
        S, P, xy, walk_of, T = (np.concatenate(a) for a in (S, P, xy, walk_of, T))
        info.update({"windows": int(len(S)), "dropped_outside_waypoints": int(outside), "dropped_nothing_heard": silent,
                     "n_features": len(names),
                     "n_features_kind": {k: sum(n.startswith(k + ":") for n in names) for k in ("wifi", "ble")}})
        if len(S) < 2:
            return {**info, "unavailable": f"{len(S)} labelled windows (need 2)"}
        if self.model == "knn" and (self.cv is not None or self.fix_std == "calibrated"):
            predict = self._fit_knn_cv(S, xy, T, walk_of, used, names, info)
        elif self.model == "knn":
            predict = knn_model(S, xy, self.k, self.weights, self.cov_floor_m, self.metric)
        else:
            predict = fit_network(self, key, S, P, xy, walk_of, used, names, inputs, info)
        self.floors[key] = _FloorModel(columns, predict)
        info["fit_s"] = time.perf_counter() - t0
        log.info("%s: %s fitted on %d windows of %d walks, %d features (%.1f s)", self.name, key, len(S), len(used),
                 len(names), info["fit_s"])
        return info

    def _fit_knn_cv(self, S, xy, T, walk_of, used, names, info):
        """KNN with metric / k / weights / BLE weight chosen by leave-walks-out cross-validation on ``used`` (the
        train walks of this floor, whose windows S, labels xy, times T, walk index walk_of these are): their own
        waypoints score the folds (:func:`blenav.localizers.knn.cross_validate`); no other walk is read. Without
        ``cv`` the setting is the given k / weights / metric. ``fix_std: calibrated``: each fix's std from
        :class:`blenav.localizers.knn.StdModel` fitted on the same walks' out-of-fold errors."""
        is_ble = np.array([n.startswith("ble:") for n in names])
        if self.cv is None:
            model = KNN.fit(S, xy, KNN.KnnSetting(self.metric, self.k, self.weights, 1.0), is_ble, self.cfg.fill_dbm,
                            self.cov_floor_m, walk_of=walk_of)
            model.std_model = self._std_model(model, info, CV_GRID["folds"])
            model.novelty_model = self._novelty_model(model, used, info, CV_GRID["folds"])
            return model
        ble_w = self.cv["ble_weight"] if self.cfg.features == "both" else [1.0]
        settings = KNN.grid(self.cv["metric"], self.cv["k"], self.cv["weights"], ble_w)
        waypoints = [(s.groundtruth["t"].to_numpy(float), s.groundtruth[["x", "y"]].to_numpy(float)) for s in used]
        best, table = KNN.cross_validate(S, xy, T, walk_of, waypoints, settings, is_ble, self.cfg.fill_dbm,
                                         folds=self.cv["folds"], seed=self.seed)
        info["cv"] = {"chosen": asdict(best), "folds": self.cv["folds"],
                      "scored": "mean error (m) at the train walks' waypoints, each walk predicted by a model of "
                                "the other folds' walks", "table": table}
        log.info("%s: cross-validated KNN setting %s (%.2f m)", self.name, best,
                 min(r["cv_error_m"] for r in table))
        model = KNN.fit(S, xy, best, is_ble, self.cfg.fill_dbm, self.cov_floor_m, walk_of=walk_of)
        model.std_model = self._std_model(model, info, self.cv["folds"])
        model.novelty_model = self._novelty_model(model, used, info, self.cv["folds"])
        return model

    def _std_model(self, model: KNN.KnnModel, info: dict, folds: int):
        """The calibrated std model (``fix_std: calibrated``) of the KNN ``model`` (its train windows, their walks and
        its setting: :func:`blenav.localizers.knn.out_of_fold_represented`), or None."""
        if self.fix_std != "calibrated":
            return None
        err, spread, d1 = KNN.out_of_fold_represented(model.X, model.xy, model.walk_of, model.setting,
                                                      model.cov_floor_m, folds=folds, seed=self.seed)
        if len(err) < MIN_STD_FIT:
            info["fix_std"] = f"neighbours: {len(err)} out-of-fold fixes (need {MIN_STD_FIT}) to calibrate"
            return None
        model = KNN.fit_std_model(err, spread, d1)
        sd = model.std(spread, d1)
        r = err / sd
        info["fix_std"] = {"model": "log std = c0 + c1 log(1 + spread) + c2 d1 (blenav.localizers.knn.StdModel)",
                           "c": list(model.c), "out_of_fold_fixes": int(len(err)),
                           "coverage_1sigma": float(np.mean(r <= 1.0)), "coverage_2sigma": float(np.mean(r <= 2.0)),
                           "median_std_m": float(np.median(sd))}
        return model

    def _novelty_model(self, model: KNN.KnnModel, used: list, info: dict, folds: int):
        """With ``fix_std: calibrated``: the :class:`blenav.localizers.knn.NoveltyModel` of the KNN ``model`` (how far
        a scan is from every fingerprint against how far its walker is from every train walk), fitted out of fold on
        the train walks ``used`` (their positions as the fused rows count the survey:
        :func:`blenav.localizers.survey.walk_positions`), or None; what was fitted, or why not, in ``info``."""
        if self.fix_std != "calibrated":
            return None
        d1, sm = KNN.out_of_fold_survey(model.X, model.xy, model.walk_of, [walk_positions(s) for s in used],
                                        folds=folds, seed=self.seed)
        nm = KNN.fit_novelty_model(d1, sm)
        info["novelty"] = {**asdict(nm), "windows": int(len(d1))} if nm is not None else \
            f"not fitted: {int(np.sum(sm > 5.0))} of {len(sm)} out-of-fold windows off the survey"
        return nm

    # ------------------------------------------------------------------ running
    def heard_windows(self, session, columns: dict[str, int]) -> tuple[np.ndarray, np.ndarray]:
        """(S (K, F, H), t (K,) s): the windows of ``session`` on ``columns`` that heard something, as :meth:`run`
        localizes them (``beacons``: BLE readings of the other beacons left out)."""
        rd = None
        if self.beacons is not None:
            rd = FP.readings(session, self.cfg)
            keep = {f"ble:{b}" for b in self.beacons}
            rd = rd[(rd["kind"] != "ble") | rd["feature"].isin(keep)]
        w = FP.session_windows(session, columns, self.cfg, rd)
        return w.S[w.heard], w.t[w.heard]

    def run(self, session, n_runs: int, seed: int, inputs: RunInputs | None = None) -> Estimate:
        t0 = time.perf_counter()
        key = FP.floor_of(session)
        if key not in self.floors:
            why = self._unfitted if not self.floors else \
                f"has no model for floor {key} (trained: {sorted(self.floors)})"
            raise MissingStream(f"{self.name} {why}")
        fm = self.floors[key]
        S, t = self.heard_windows(session, fm.columns)
        if not len(t):
            raise MissingStream(f"session {session.id}: no {self.cfg.features} source of the training walks heard")
        knn = fm.predict if isinstance(fm.predict, KNN.KnnModel) and fm.predict.novelty_model is not None else None
        xy, cov, d1 = knn.predict(S, exclude=session.id) if knn is not None else (*fm(S, session.id), None)
        outputs = {} if knn is None else {"off_survey_log_ratio": knn.novelty_model.log_ratio(d1)}
        if not np.isfinite(xy).all():
            raise ValueError(f"{self.name}: non-finite position on session {session.id}")
        R = int(n_runs)
        pos = np.broadcast_to(xy, (R,) + xy.shape).copy()
        covr = None if cov is None else np.broadcast_to(cov, (R,) + cov.shape).copy()
        return Estimate(self.name, session.id, t, pos, covr, wall_s=time.perf_counter() - t0,
                        notes=[f"{self.model} on {self.cfg.features} fingerprints, {len(fm.columns)} features "
                               f"(floor {key})"], outputs=outputs)
