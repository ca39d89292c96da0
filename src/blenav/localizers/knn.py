"""KNN fingerprinting with its settings chosen by cross-validation on the train walks (issue 29, part 2): the metric,
k, the neighbours' weighting and (WiFi + BLE) the weight of the BLE part, picked by leave-walks-out cross-validation
on the walks it is fitted on, so that no scored walk's label reaches the choice.

Metrics, on windows S (N, F, H) of the u scale of :mod:`blenav.features.fingerprints` (u = rssi - fill_dbm, 0 = not
heard, the not-heard value is ``fill_dbm``):

* ``cosine``: S scaled to unit norm (Euclidean distance between unit vectors = a function of the cosine);
* ``powed``: u / -fill_dbm (in [0, 1]) raised to the power e, then unit norm: the "powed" representation of
  Torres-Sospedra et al. (2015), which shrinks weak readings (a -90 dBm access point is heard or not by chance)
  against strong ones;
* ``euclidean``: S as it is (dBm differences, a not-heard access point at ``fill_dbm``).

With features from WiFi and BLE each kind's part is scaled to unit norm on its own and the BLE part is multiplied by
``ble_weight`` before the distance (0: WiFi only).

Weighting of the k neighbours: ``uniform``; ``distance`` (1 / distance); or a number tau: softmax of -d^2 / tau,
d^2 the squared distance on the unit-norm scale (0..4), relative to the nearest neighbour's.

Each fix has a covariance: the neighbours' weighted position covariance plus ``cov_floor_m``^2 I (its std is
what the fused filters' fix likelihood may use).

Cross-validation (:func:`cross_validate`): the fitted walks are dealt into ``folds`` groups (seeded permutation);
each walk's windows are predicted by a model of the other folds' walks, the fixes interpolated at the walk's
waypoint times (a waypoint before the first fix / after the last against that fix, as the scoring holds the ends)
and the mean error over every waypoint of every walk is the score of a setting. Ties: the first in grid order.
numpy only.
"""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass

import numpy as np

METRICS = ("cosine", "powed", "euclidean")
POWED_EXPONENT = float(np.e)


@dataclass(frozen=True)
class KnnSetting:
    """One KNN setting: metric (METRICS), k neighbours, weights (uniform | distance | tau > 0), ble_weight."""

    metric: str = "cosine"
    k: int = 5
    weights: object = "uniform"
    ble_weight: float = 1.0

    def __post_init__(self):
        if self.metric not in METRICS:
            raise ValueError(f"metric must be one of {METRICS}, got {self.metric!r}")
        if int(self.k) < 1:
            raise ValueError(f"k must be >= 1, got {self.k}")
        if self.weights not in ("uniform", "distance"):
            try:
                ok = float(self.weights) > 0
            except (TypeError, ValueError):
                ok = False
            if not ok:
                raise ValueError(f"weights must be uniform, distance or a softmax temperature > 0, got {self.weights!r}")
        if not float(self.ble_weight) >= 0:
            raise ValueError(f"ble_weight must be >= 0, got {self.ble_weight}")


def represent(S: np.ndarray, metric: str, is_ble: np.ndarray, ble_weight: float, fill_dbm: float) -> np.ndarray:
    """(N, F*H) float64 vectors of windows S (N, F, H) u scale for ``metric`` (module doc); ``is_ble`` (F,) bool marks
    the BLE features (their part normalised on its own and scaled by ``ble_weight`` when both kinds are present)."""
    X = np.asarray(S, float)
    if metric == "euclidean":
        return X.reshape(len(X), -1)
    if metric == "powed":
        X = np.clip(X / -float(fill_dbm), 0.0, 1.0) ** POWED_EXPONENT
    parts = []
    kinds = [is_ble, ~is_ble] if is_ble.any() and (~is_ble).any() else [np.ones(len(is_ble), bool)]
    for m in kinds:
        P = X[:, m].reshape(len(X), -1)
        n = np.sqrt(np.einsum("nf,nf->n", P, P))
        P = P / np.where(n > 0, n, 1.0)[:, None]
        parts.append(P * float(ble_weight) if len(kinds) == 2 and m is is_ble else P)
    return np.concatenate(parts, axis=1)


def _sqdist(A: np.ndarray, B: np.ndarray, bb: np.ndarray | None = None) -> np.ndarray:
    """(K, N) squared Euclidean distances of the rows of A (K, D) and B (N, D); ``bb`` (N,): B's squared norms when
    already computed (the same numbers)."""
    bb = np.einsum("nf,nf->n", B, B) if bb is None else bb
    return np.maximum(np.einsum("nf,nf->n", A, A)[:, None] + bb[None] - 2.0 * A @ B.T, 0.0)


def nearest_distance(Q: np.ndarray, X: np.ndarray, bb: np.ndarray | None = None, chunk: int = 512) -> np.ndarray:
    """(K,) the Euclidean distance of each row of Q (K, D) to the nearest row of X (N, D), ``chunk`` x N distances at a
    time (bounded memory); ``bb``: X's squared norms when already computed."""
    bb = np.einsum("nf,nf->n", X, X) if bb is None else bb
    d2 = [_sqdist(Q[i:i + chunk], X, bb).min(axis=1) for i in range(0, len(Q), chunk)]
    return np.sqrt(np.concatenate(d2) if d2 else np.zeros(0))


def neighbours(Q: np.ndarray, X: np.ndarray, kmax: int) -> tuple[np.ndarray, np.ndarray]:
    """(idx (K, k), d2 (K, k)): the k = min(kmax, N) nearest rows of X (N, D) to each row of Q (K, D), nearest first,
    squared Euclidean distances (ties by row order)."""
    return _nearest(_sqdist(Q, X), kmax)


def _nearest(D: np.ndarray, kmax: int) -> tuple[np.ndarray, np.ndarray]:
    """:func:`neighbours` of a squared-distance matrix D (K, N) already computed."""
    k = min(int(kmax), D.shape[1])
    idx = np.argsort(D, axis=1, kind="stable")[:, :k]
    return idx, np.take_along_axis(D, idx, 1)


def combine(idx: np.ndarray, d2: np.ndarray, xy: np.ndarray, k: int, weights, cov_floor_m: float = 1.0
            ) -> tuple[np.ndarray, np.ndarray]:
    """(estimates (K, 2) m, covariances (K, 2, 2) m^2) from the first k neighbours ``idx`` / ``d2`` (K, >= k) of
    labels ``xy`` (N, 2): the weighted mean, and the weighted covariance of the neighbours' positions +
    cov_floor_m^2 I."""
    k = min(int(k), idx.shape[1])
    d2 = d2[:, :k]
    if weights == "uniform":
        W = np.ones_like(d2)
    elif weights == "distance":
        W = 1.0 / (np.sqrt(d2) + 1e-6)
    else:
        W = np.exp(-(d2 - d2[:, :1]) / float(weights))
    W = W / W.sum(axis=1, keepdims=True)
    P = xy[idx[:, :k]]  # (K, k, 2)
    est = np.einsum("nk,nkj->nj", W, P)
    d = P - est[:, None]
    cov = np.einsum("nk,nki,nkj->nij", W, d, d) + float(cov_floor_m) ** 2 * np.eye(2)
    return est, cov


def waypoint_errors(t: np.ndarray, est: np.ndarray, gt_t: np.ndarray, gt_xy: np.ndarray) -> np.ndarray:
    """(W,) m: the fixes ``est`` (K, 2) at times ``t`` (K,) (sorted), interpolated linearly at the waypoint times
    ``gt_t`` (W,), against the waypoints ``gt_xy`` (W, 2); ends held (the scoring's ``hold_ends``)."""
    x = np.interp(gt_t, t, est[:, 0])
    y = np.interp(gt_t, t, est[:, 1])
    return np.hypot(x - gt_xy[:, 0], y - gt_xy[:, 1])


def grid(metrics, ks, weights, ble_weights) -> list[KnnSetting]:
    """Every combination, in this order (the tie-break of :func:`cross_validate`)."""
    return [KnnSetting(m, int(k), w, float(b)) for m, k, w, b in itertools.product(metrics, ks, weights, ble_weights)]


def deal_folds(n_walks: int, folds: int, seed: int) -> tuple[int, np.ndarray]:
    """(folds, fold (n_walks,)): the walks dealt into max(2, min(folds, n_walks)) groups by a seeded permutation (the
    same deal for :func:`cross_validate` and :func:`out_of_fold`)."""
    folds = max(2, min(int(folds), n_walks))
    return folds, np.random.default_rng(seed).permutation(np.arange(n_walks) % folds)


def cross_validate(S: np.ndarray, xy: np.ndarray, t: np.ndarray, walk_of: np.ndarray, waypoints: list,
                   settings: list[KnnSetting], is_ble: np.ndarray, fill_dbm: float, folds: int = 5, seed: int = 0
                   ) -> tuple[KnnSetting, list[dict]]:
    """The setting of ``settings`` with the least leave-walks-out error, and every setting's score.

    S (N, F, H) u scale, xy (N, 2) m labels, t (N,) s the windows' times, walk_of (N,) int the walk of each window
    (index into ``waypoints``: per walk (gt_t (W,), gt_xy (W, 2)), the walk's own waypoints). Every array is of the
    fitted (train) walks only: nothing else is read. Scores: mean error (m) over all waypoints of the walks."""
    folds, fold = deal_folds(len(waypoints), folds, seed)
    kmax = max(s.k for s in settings)
    err: dict[KnnSetting, list] = {s: [] for s in settings}
    for rep_key in sorted({(s.metric, s.ble_weight) for s in settings}, key=str):
        X = represent(S, rep_key[0], is_ble, rep_key[1], fill_dbm)
        same_rep = [s for s in settings if (s.metric, s.ble_weight) == rep_key]
        for f in range(folds):
            tr = fold[walk_of] != f
            if not tr.any():
                continue
            # the other folds' windows, labels and squared norms once per fold; the distances per held-out walk (a
            # product per walk: the same numbers as one per fold would give only up to rounding) and, from its kmax
            # nearest, every k and weighting of this representation
            X_tr, xy_tr = X[tr], xy[tr]
            bb = np.einsum("nf,nf->n", X_tr, X_tr)
            for w in np.flatnonzero(fold == f):
                q = np.flatnonzero(walk_of == w)
                if not len(q):
                    continue
                o = q[np.argsort(t[q], kind="stable")]
                idx, d2 = _nearest(_sqdist(X[o], X_tr, bb), kmax)
                for s in same_rep:
                    est, _ = combine(idx, d2, xy_tr, s.k, s.weights)
                    err[s].append(waypoint_errors(t[o], est, *waypoints[w]))
    table = [{"metric": s.metric, "k": s.k, "weights": s.weights, "ble_weight": s.ble_weight,
              "cv_error_m": float(np.concatenate(err[s]).mean()) if err[s] else float("inf")} for s in settings]
    best = int(np.argmin([r["cv_error_m"] for r in table]))
    return settings[best], table


@dataclass(frozen=True)
class StdModel:
    """A fix's std (m, isotropic 2-D) from what the KNN saw (issue 30, "fix uncertainty that means what it says"):

        log std = c0 + c1 log(1 + spread) + c2 d1

    spread (m): the RMS distance per axis of the k neighbours' positions from the estimate (their disagreement);
    d1: the distance of the query to its nearest fingerprint on the setting's representation (how far the scan is
    from anything surveyed: large where the train walks never went). Fitted by :func:`fit_std_model` on
    out-of-fold errors of the train walks."""

    c: tuple = (math.log(3.0), 0.0, 0.0)

    def std(self, spread: np.ndarray, d1: np.ndarray) -> np.ndarray:
        c0, c1, c2 = self.c
        return np.exp(np.clip(c0 + c1 * np.log1p(spread) + c2 * d1, -3.0, 6.0))


def std_features(idx: np.ndarray, d2: np.ndarray, cov: np.ndarray, cov_floor_m: float) -> tuple[np.ndarray, np.ndarray]:
    """(spread (K,) m, d1 (K,)) of the queries whose neighbours are ``idx`` / ``d2`` (K, >= 1) and whose
    :func:`combine` covariance (floor ``cov_floor_m`` included) is ``cov`` (K, 2, 2) (:class:`StdModel`)."""
    var = (np.trace(cov, axis1=1, axis2=2) / 2.0 - float(cov_floor_m) ** 2).clip(0.0)
    return np.sqrt(var), np.sqrt(d2[:, 0])


def fit_std_model(err: np.ndarray, spread: np.ndarray, d1: np.ndarray) -> StdModel:
    """The :class:`StdModel` maximising the isotropic 2-D Gaussian likelihood of the errors ``err`` (K,) m (norm of
    the estimate minus the label) given their features: per fix, 2 log std + err^2 / (2 std^2), summed; a convex
    problem in c, solved by damped Newton steps on standardised features (each step halved until the cost drops).
    Fewer than 3 finite fixes, or no finite optimum: the constant model of their RMS error (std^2 = mean err^2 / 2),
    else :class:`StdModel`'s default."""
    err, spread, d1 = (np.asarray(a, float) for a in (err, spread, d1))
    ok = np.isfinite(err) & np.isfinite(spread) & np.isfinite(d1)
    err, spread, d1 = err[ok], spread[ok], d1[ok]
    e2 = err**2 + 1e-6
    if len(err) < 3:
        return StdModel((0.5 * math.log(float(np.mean(e2)) / 2.0), 0.0, 0.0)) if len(err) else StdModel()
    F = np.column_stack([np.log1p(spread), d1])
    mu, sd = F.mean(axis=0), F.std(axis=0)
    sd = np.where(sd > 1e-9, sd, 1.0)  # a constant feature keeps its (zero) coefficient
    A = np.column_stack([np.ones(len(err)), (F - mu) / sd])

    def cost(c):
        z = A @ c
        return float(np.sum(2.0 * z + 0.5 * e2 * np.exp(-2.0 * np.clip(z, -30.0, 30.0))))

    c = np.array([0.5 * math.log(float(np.mean(e2)) / 2.0), 0.0, 0.0])  # 2-D: E|e|^2 = 2 std^2
    f = cost(c)
    for _ in range(100):  # f(c) = sum 2 a.c + e2 exp(-2 a.c) / 2
        z = np.exp(-2.0 * np.clip(A @ c, -30.0, 30.0))
        g = A.T @ (2.0 - e2 * z)
        H = (A * (2.0 * e2 * z)[:, None]).T @ A + 1e-9 * np.eye(3)
        try:
            step = np.linalg.solve(H, g)
        except np.linalg.LinAlgError:
            break
        t = 1.0
        while t > 1e-6 and not cost(c - t * step) <= f:
            t *= 0.5
        if t <= 1e-6:
            break
        c, f = c - t * step, cost(c - t * step)
        if np.abs(t * step).max() < 1e-10:
            break
    # back to the raw features: c0 + c1 (x1 - mu1) / sd1 + c2 (x2 - mu2) / sd2
    raw = np.array([c[0] - c[1] * mu[0] / sd[0] - c[2] * mu[1] / sd[1], c[1] / sd[0], c[2] / sd[1]])
    if not np.isfinite(raw).all():
        return StdModel((0.5 * math.log(float(np.mean(e2)) / 2.0), 0.0, 0.0))
    return StdModel(tuple(float(v) for v in raw))


@dataclass(frozen=True)
class NoveltyModel:
    """How much a fix's scan says its walker is off the survey (issue 30: the fused rows' ``novelty``): a scan far in
    signal space from every fingerprint (d1, :class:`StdModel`'s feature) is mostly heard where no train walk went.

        P(off | d1) = sigmoid(a + b d1),  off: the walker more than ``off_m`` from every train walk's position

    fitted by logistic regression on the train walks' out-of-fold windows (each window's d1 against the other folds'
    fingerprints, its distance to the other folds' walks: :func:`fit_novelty_model`); ``base``: the share of those
    windows off. :meth:`log_ratio` is the log Bayes factor of "off" against "on" a fix's d1 gives, log p(d1 | off) -
    log p(d1 | on) = logit P(off | d1) - logit(base), which a grid filter adds to its cells off the survey."""

    a: float
    b: float
    base: float
    off_m: float = 5.0

    def log_ratio(self, d1: np.ndarray) -> np.ndarray:
        """(K,) log Bayes factor of off the survey against on it for fixes whose d1 is ``d1`` (K,)."""
        z = np.clip(self.a + self.b * np.asarray(d1, float), -30.0, 30.0)
        return z - math.log(self.base / (1.0 - self.base))


def fit_novelty_model(d1: np.ndarray, survey_m: np.ndarray, off_m: float = 5.0,
                      min_each: int = 5) -> NoveltyModel | None:
    """The :class:`NoveltyModel` of windows with signal distance ``d1`` (N,) to the nearest fingerprint and distance
    ``survey_m`` (N,) m to the nearest surveyed position (both out of fold): logistic regression of ``survey_m >
    off_m`` on d1 by Newton steps on the standardised feature (a 1e-6 ridge keeps a separable set finite). None with
    fewer than ``min_each`` windows on either side (nothing to learn the difference from)."""
    d1, sm = np.asarray(d1, float), np.asarray(survey_m, float)
    ok = np.isfinite(d1) & np.isfinite(sm)
    d1, y = d1[ok], (sm[ok] > float(off_m)).astype(float)
    if y.sum() < min_each or (1.0 - y).sum() < min_each:
        return None
    mu, sd = float(d1.mean()), float(d1.std()) or 1.0
    A = np.column_stack([np.ones(len(d1)), (d1 - mu) / sd])
    w = np.array([math.log(y.mean() / (1.0 - y.mean())), 0.0])
    for _ in range(50):
        p = 1.0 / (1.0 + np.exp(-np.clip(A @ w, -30.0, 30.0)))
        g = A.T @ (p - y) + 1e-6 * w
        H = (A * (p * (1.0 - p))[:, None]).T @ A + 1e-6 * np.eye(2)
        step = np.linalg.solve(H, g)
        w = w - step
        if np.abs(step).max() < 1e-10:
            break
    a, b = float(w[0] - w[1] * mu / sd), float(w[1] / sd)
    if not (math.isfinite(a) and math.isfinite(b)):
        return None
    return NoveltyModel(a, b, float(y.mean()), float(off_m))


def out_of_fold_survey(X: np.ndarray, xy: np.ndarray, walk_of: np.ndarray, paths: list, folds: int = 5,
                       seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """(d1 (N,), survey_m (N,) m) of windows already represented X (N, D), labelled xy (N, 2) m, from walks
    ``walk_of`` (N,) indexing ``paths`` (each walk's positions (P_w, 2) m, e.g. every half second between its
    waypoints): each window's signal distance to the nearest window of the other folds' walks (the same seeded deal
    as :func:`cross_validate`) and the distance of its label to the nearest position of those walks."""
    from scipy.spatial import cKDTree

    folds, fold = deal_folds(len(paths), folds, seed)
    d1, sm = np.full(len(X), np.nan), np.full(len(X), np.nan)
    for f in range(folds):
        te = fold[walk_of] == f
        others = [np.asarray(paths[w], float) for w in range(len(paths)) if fold[w] != f and len(paths[w])]
        if not te.any() or te.all() or not others:
            continue
        d1[te] = nearest_distance(X[te], X[~te])
        sm[te] = cKDTree(np.concatenate(others)).query(np.asarray(xy, float)[te])[0]
    ok = np.isfinite(d1) & np.isfinite(sm)
    return d1[ok], sm[ok]


def out_of_fold(S: np.ndarray, xy: np.ndarray, walk_of: np.ndarray, setting: KnnSetting, is_ble: np.ndarray,
                fill_dbm: float, cov_floor_m: float, folds: int = 5, seed: int = 0,
                extra: tuple[np.ndarray, np.ndarray] | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(errors (N,) m, spread (N,), d1 (N,)): every window of the fitted walks predicted by ``setting`` fitted on the
    other folds' walks (the same seeded deal of the walks as :func:`cross_validate`), against its own label.
    ``extra``: (S_e (M, F, H), xy_e (M, 2)) windows in every fold's reference set besides the other folds' (the
    crowd's pseudo-labelled windows, :mod:`blenav.localizers.crowd`), never predicted themselves. The windows
    represented for ``setting``, then :func:`out_of_fold_represented`."""
    rep = (lambda A: represent(A, setting.metric, is_ble, setting.ble_weight, fill_dbm))
    ext = None if extra is None or not len(extra[0]) else (rep(extra[0]), extra[1])
    return out_of_fold_represented(rep(S), xy, walk_of, setting, cov_floor_m, folds, seed, ext)


def out_of_fold_represented(X: np.ndarray, xy: np.ndarray, walk_of: np.ndarray, setting: KnnSetting,
                            cov_floor_m: float, folds: int = 5, seed: int = 0,
                            extra: tuple[np.ndarray, np.ndarray] | None = None
                            ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """:func:`out_of_fold` of windows already represented for ``setting`` (:func:`represent`): X (N, D), ``extra``
    (X_e (M, D), xy_e (M, 2)) or None."""
    folds, fold = deal_folds(int(walk_of.max()) + 1 if len(walk_of) else 0, folds, seed)
    Xe, xye = (np.zeros((0, X.shape[1])), np.zeros((0, 2))) if extra is None or not len(extra[0]) else \
        (np.asarray(extra[0], float), np.asarray(extra[1], float))
    err, spread, d1 = np.full(len(X), np.nan), np.zeros(len(X)), np.zeros(len(X))
    for f in range(folds):
        te = fold[walk_of] == f
        if not te.any() or te.all():
            continue
        idx, d2 = _nearest(_sqdist(X[te], np.concatenate([X[~te], Xe])), setting.k)
        est, cov = combine(idx, d2, np.concatenate([xy[~te], xye]), setting.k, setting.weights, cov_floor_m)
        err[te] = np.hypot(*(est - xy[te]).T)
        spread[te], d1[te] = std_features(idx, d2, cov, cov_floor_m)
    ok = np.isfinite(err)
    return err[ok], spread[ok], d1[ok]


class KnnModel:
    """A fitted KNN (:func:`fit`): ``model(Sq)`` -> (xy (K, 2) m, cov (K, 2, 2) m^2) of windows Sq (K, F, H). It keeps
    what it was fitted on: ``X`` (N, D) the reference windows represented for ``setting`` (:func:`represent`; the raw
    windows are not kept), ``xy``, ``setting``, ``std_model``, ``walk_of`` (N,) the train walk index of each window
    when known, ``groups`` (N,) str the walk each reference window comes from ("" for the surveyed ones), so that
    ``model(Sq, exclude=g)`` leaves out group g's windows (a crowd-labelled walk is never its own neighbour)."""

    def __init__(self, X, xy, setting: KnnSetting, is_ble, fill_dbm: float, cov_floor_m: float,
                 std_model: StdModel | None = None, groups: np.ndarray | None = None,
                 walk_of: np.ndarray | None = None):
        self.X, self.xy, self.setting, self.is_ble = np.asarray(X, float), np.asarray(xy, float), setting, \
            np.asarray(is_ble, bool)
        self.fill_dbm, self.cov_floor_m, self.std_model = float(fill_dbm), float(cov_floor_m), std_model
        self.groups = np.full(len(self.X), "", object) if groups is None else np.asarray(groups, object)
        self.walk_of = walk_of
        self.bb = np.einsum("nf,nf->n", self.X, self.X)  # X's squared norms, once for every query
        self.novelty_model: NoveltyModel | None = None  # set by the fingerprint localizer (fix_std: calibrated)

    def represent(self, S: np.ndarray) -> np.ndarray:
        """(K, D): windows S (K, F, H) on this model's representation (:func:`represent`)."""
        st = self.setting
        return represent(S, st.metric, self.is_ble, st.ble_weight, self.fill_dbm)

    def extended(self, Xe: np.ndarray, xye: np.ndarray, groups: np.ndarray, std_model: StdModel | None
                 ) -> "KnnModel":
        """A model of the same setting whose reference set also holds Xe (M, D) (already represented) labelled xye
        (M, 2) m, from walks ``groups`` (M,) str, with ``std_model``; no ``walk_of`` (its rows are not all train
        windows: a refit reads the model it extends)."""
        X = np.concatenate([self.X, np.asarray(Xe, float)])
        return KnnModel(X, np.concatenate([self.xy, np.asarray(xye, float)]), self.setting, self.is_ble, self.fill_dbm,
                        self.cov_floor_m, std_model, np.concatenate([self.groups, np.asarray(groups, object)]))

    def __call__(self, Sq, exclude: str | None = None) -> tuple[np.ndarray, np.ndarray]:
        return self.predict(Sq, exclude)[:2]

    def predict(self, Sq, exclude: str | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(xy (K, 2) m, cov (K, 2, 2) m^2, d1 (K,)) of windows Sq (K, F, H): :meth:`__call__`'s estimates and each
        window's distance to its nearest reference window (:class:`StdModel`'s and :class:`NoveltyModel`'s feature),
        from the one neighbour search."""
        st = self.setting
        drop = None if exclude is None else self.groups == exclude
        X, bb, xy = (self.X, self.bb, self.xy) if drop is None or not drop.any() else \
            (self.X[~drop], self.bb[~drop], self.xy[~drop])
        Q = self.represent(Sq)
        out_xy, out_cov, out_d1 = np.zeros((len(Q), 2)), np.zeros((len(Q), 2, 2)), np.zeros(len(Q))
        for i in range(0, len(Q), 512):  # bounded memory: 512 x N distances at a time
            idx, d2 = _nearest(_sqdist(Q[i:i + 512], X, bb), st.k)
            est, cov = combine(idx, d2, xy, st.k, st.weights, self.cov_floor_m)
            spread, d1 = std_features(idx, d2, cov, self.cov_floor_m)
            if self.std_model is not None:
                cov = (self.std_model.std(spread, d1) ** 2)[:, None, None] * np.eye(2)
            out_xy[i:i + 512], out_cov[i:i + 512], out_d1[i:i + 512] = est, cov, d1
        return out_xy, out_cov, out_d1


def fit(S: np.ndarray, xy: np.ndarray, setting: KnnSetting, is_ble: np.ndarray, fill_dbm: float,
        cov_floor_m: float, std_model: StdModel | None = None, walk_of: np.ndarray | None = None,
        groups: np.ndarray | None = None) -> KnnModel:
    """The :class:`KnnModel` of ``setting`` on windows S (N, F, H) with labels xy (N, 2): predict S (K, F, H) ->
    (xy (K, 2), cov (K, 2, 2)), the covariance the neighbours' (:func:`combine`) or, with ``std_model``, its std^2 I;
    ``walk_of`` (N,): the walk index of each window (for a refit); ``groups`` (N,): :class:`KnnModel`'s."""
    X = represent(S, setting.metric, np.asarray(is_ble, bool), setting.ble_weight, fill_dbm)
    return KnnModel(X, xy, setting, is_ble, fill_dbm, cov_floor_m, std_model, groups=groups, walk_of=walk_of)
