"""Classical / learned baselines of the cross-phone BLE localizer (Roy, Table 3.5; refs. [16]-[20] there).

The thesis compares its TransNet + LocNet against KNN regression, Bayesian grid localization, kernel ridge
regression followed by a Kalman filter (KRR+KF) and DL-RNN (Bai et al. 2020). The first three are here
(numpy + scikit-learn); DL-RNN is a network, :class:`blenav.models.DLRNN`, trained by ``train.py
model=dlrnn`` like LocNet.

Input: RSSI windows S (N, B, H) on the thesis scale u = rssi_dBm + 100 (0 = not heard), B beacons in the
model's fixed order by H steps of 1 / ``step_hz`` s (:mod:`blenav.features.windows`). *Not* the network scale
u / 100. Labels xy (N, 2) in metres (world frame); rows with a NaN label are dropped by ``fit``.

Feature (all three baselines): the **fingerprint** F (N, B) of :func:`fingerprint`: per beacon, the mean
over the window's H steps of the steps in which it was heard (entries > 0), 0 if it was heard in none.

Common interface::

    model = make_baseline("KNN" | "Bayesian" | "KRR+KF", **kw).fit(S, xy)   # -> self
    model.predict(S)            # (K, 2) m, each window independently
    model.predict_sequence(S)   # (K, 2) m, S = consecutive windows of ONE session at step_hz
                                # (the Kalman filter of KRR+KF; = predict for the others)

Everything is vectorised over windows and grid cells (the Bayesian likelihood is evaluated in chunks of
windows to bound memory); randomness only through explicit ``seed`` arguments.
"""

from __future__ import annotations

import numpy as np
from scipy import ndimage, signal
from scipy.linalg import solve_discrete_are
from scipy.spatial.distance import pdist
from sklearn.kernel_approximation import Nystroem
from sklearn.linear_model import Ridge
from sklearn.neighbors import KNeighborsRegressor


def fingerprint(S: np.ndarray) -> np.ndarray:
    """Windows S (N, B, H) thesis scale -> fingerprints (N, B): mean over heard steps (> 0), 0 if never heard."""
    S = np.asarray(S, float)
    if S.ndim != 3:
        raise ValueError(f"windows must be (N, B, H), got shape {S.shape}")
    heard = S > 0
    n = heard.sum(axis=2)
    return np.divide(np.where(heard, S, 0.0).sum(axis=2), n, out=np.zeros(S.shape[:2]), where=n > 0)


class Baseline:
    """Shared checks: ``fit`` stores B and drops unlabelled rows; ``predict_sequence`` defaults to ``predict``."""

    n_beacons_: int | None = None

    def _fit_inputs(self, S: np.ndarray, xy: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        F = fingerprint(S)
        xy = np.asarray(xy, float)
        if xy.shape != (len(F), 2):
            raise ValueError(f"labels must be ({len(F)}, 2) metres, got shape {xy.shape}")
        keep = ~np.isnan(xy).any(axis=1)
        if keep.sum() < 2:
            raise ValueError(f"need at least 2 labelled windows to fit, got {int(keep.sum())}")
        self.n_beacons_ = F.shape[1]
        return F[keep], xy[keep]

    def _features(self, S: np.ndarray) -> np.ndarray:
        if self.n_beacons_ is None:
            raise RuntimeError(f"{type(self).__name__} is not fitted; call fit(S, xy) first")
        F = fingerprint(S)
        if F.shape[1] != self.n_beacons_:
            raise ValueError(f"{type(self).__name__} was fitted on {self.n_beacons_} beacons, got {F.shape[1]}")
        return F

    def fit(self, S: np.ndarray, xy: np.ndarray) -> "Baseline":
        raise NotImplementedError

    def predict(self, S: np.ndarray) -> np.ndarray:
        raise NotImplementedError

    def predict_sequence(self, S: np.ndarray) -> np.ndarray:
        """Consecutive windows of one session (K, B, H) -> (K, 2) m. Default: :meth:`predict`."""
        return self.predict(S)


class KNNBaseline(Baseline):
    """K-nearest-neighbour regression on the fingerprint (Euclidean, thesis scale): mean of the k neighbours'
    positions, uniformly or inverse-distance weighted (``weights="distance"``)."""

    def __init__(self, k: int = 5, weights: str = "uniform"):
        if weights not in ("uniform", "distance"):
            raise ValueError(f"weights must be 'uniform' or 'distance', got {weights!r}")
        self.k, self.weights = int(k), weights

    def fit(self, S, xy):
        F, xy = self._fit_inputs(S, xy)
        self.model_ = KNeighborsRegressor(n_neighbors=min(self.k, len(F)), weights=self.weights).fit(F, xy)
        return self

    def predict(self, S):
        return self.model_.predict(self._features(S))


class BayesianGrid(Baseline):
    """Bayesian grid (histogram) localization on the fingerprint.

    Grid: square cells of ``cell_m`` metres from the lower-left corner of the training labels' bounding box.
    Per cell c and beacon b, from the training fingerprints whose label falls in c: ``p_cb`` the share in
    which b was heard (clipped to [``p_min``, 1 - ``p_min``]) and ``mu_cb`` the mean fingerprint value of b
    where heard. Candidates: cells that hold training data or touch one (8-neighbourhood, i.e. within one
    cell); the rest of the box is never a candidate. A candidate without data takes ``p`` from the nearest
    cell with data, and ``mu_cb`` always comes from the nearest cell in which b was heard (Euclidean
    distance transform on the grid).

    Likelihood of a window with fingerprint f (uniform prior over candidates, log space)::

        log L(c) = sum_{b heard} [log p_cb + log N(f_b; mu_cb, sigma^2)] + sum_{b not heard} log(1 - p_cb)

    with one ``sigma`` for all cells and beacons: the pooled within-cell residual std of the heard
    training values (degrees of freedom corrected), at least ``sigma_floor`` (u units = dB).
    The estimate is the posterior mean of the candidate cell centres, so it lies inside the grid.
    """

    def __init__(self, cell_m: float = 1.0, sigma_floor: float = 2.0, p_min: float = 0.02,
                 chunk_elems: int = 2 ** 22):
        if cell_m <= 0:
            raise ValueError(f"cell_m must be positive, got {cell_m}")
        self.cell_m, self.sigma_floor, self.p_min, self.chunk_elems = float(cell_m), sigma_floor, p_min, chunk_elems

    def fit(self, S, xy):
        F, xy = self._fit_inputs(S, xy)
        heard = F > 0
        B, cell = F.shape[1], self.cell_m
        origin = xy.min(axis=0)
        shape = (np.floor((xy.max(axis=0) - origin) / cell).astype(int) + 1)
        ij = np.minimum(np.floor((xy - origin) / cell).astype(int), shape - 1)  # (N, 2)
        c = np.ravel_multi_index((ij[:, 0], ij[:, 1]), shape)
        C = int(np.prod(shape))
        n = np.bincount(c, minlength=C).astype(float)  # windows per cell
        h = np.zeros((C, B))
        s = np.zeros((C, B))
        np.add.at(h, c, heard.astype(float))
        np.add.at(s, c, F)
        mu_raw = np.divide(s, h, out=np.zeros_like(s), where=h > 0)
        # pooled within-cell std of heard values: sum of squared residuals / (n_heard - n_groups)
        resid = np.where(heard, F - mu_raw[c], 0.0)
        dof = heard.sum() - (h > 0).sum()
        sigma = np.sqrt((resid ** 2).sum() / dof) if dof > 0 else 0.0
        self.sigma_ = float(max(sigma, self.sigma_floor))

        has = (n > 0).reshape(shape)
        cand = ndimage.binary_dilation(has, structure=np.ones((3, 3), bool)).ravel()
        src = np.ravel_multi_index(ndimage.distance_transform_edt(~has, return_distances=False,
                                                                  return_indices=True), shape).ravel()
        p = (h / np.maximum(n, 1)[:, None])[src]  # (C, B): from the nearest cell with data
        mu = np.zeros((C, B))
        for b in range(B):  # over beacons only: nearest cell where beacon b was heard
            hb = (h[:, b] > 0).reshape(shape)
            if hb.any():
                sb = np.ravel_multi_index(ndimage.distance_transform_edt(~hb, return_distances=False,
                                                                         return_indices=True), shape).ravel()
                mu[:, b] = mu_raw[sb, b]
        p = np.clip(p, self.p_min, 1.0 - self.p_min)

        ci, cj = np.unravel_index(np.flatnonzero(cand), shape)
        self.grid_origin_, self.grid_shape_ = origin, tuple(int(v) for v in shape)
        self.centres_ = origin + (np.stack([ci, cj], axis=1) + 0.5) * cell  # (Cc, 2) m
        self.mu_, self.p_ = mu[cand], p[cand]
        s2 = self.sigma_ ** 2
        # log L = m @ A.T + (m * f) @ Bm.T + (1 - m) @ log(1 - p).T + const(window)
        self._A = np.log(self.p_) - self.mu_ ** 2 / (2 * s2)
        self._Bm = self.mu_ / s2
        self._log1mp = np.log1p(-self.p_)
        return self

    def log_posterior(self, S) -> np.ndarray:
        """(K, Cc) normalised log posterior over the candidate cells (``centres_``). Memory K x Cc."""
        return self._log_posterior(self._features(S))

    def _log_posterior(self, F: np.ndarray) -> np.ndarray:
        m = (F > 0).astype(float)
        L = m @ self._A.T + (m * F) @ self._Bm.T + (1.0 - m) @ self._log1mp.T
        L -= L.max(axis=1, keepdims=True)
        return L - np.log(np.exp(L).sum(axis=1, keepdims=True))

    def predict(self, S):
        F = self._features(S)
        out = np.empty((len(F), 2))
        step = max(1, self.chunk_elems // len(self.centres_))
        for a in range(0, len(F), step):  # chunks of windows bound the (chunk, Cc) likelihood matrix
            out[a:a + step] = np.exp(self._log_posterior(F[a:a + step])) @ self.centres_
        return out


def median_heuristic_gamma(F: np.ndarray, seed: int = 0, max_points: int = 1000) -> float:
    """RBF gamma = 1 / median of the pairwise squared distances of (a seeded subsample of) the rows of F."""
    rng = np.random.default_rng(seed)
    X = F[rng.choice(len(F), max_points, replace=False)] if len(F) > max_points else F
    d2 = pdist(X, "sqeuclidean")
    d2 = d2[d2 > 0]
    return 1.0 / float(np.median(d2)) if len(d2) else 1.0


def cv_kalman_gain(dt: float, q: float, r: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Steady-state constant-velocity Kalman filter of one axis: (F, K, P).

    State (position m, velocity m/s); F = [[1, dt], [0, 1]]; white-noise acceleration of spectral density
    ``q`` (m^2/s^3): Q = q [[dt^3/3, dt^2/2], [dt^2/2, dt]]; position measured with std ``r`` (m).
    P is the steady-state prior (predicted) covariance from the discrete algebraic Riccati equation,
    K = P H^T / (H P H^T + r^2) the gain (2,).
    """
    F = np.array([[1.0, dt], [0.0, 1.0]])
    Q = q * np.array([[dt ** 3 / 3, dt ** 2 / 2], [dt ** 2 / 2, dt]])
    H = np.array([[1.0, 0.0]])
    P = solve_discrete_are(F.T, H.T, Q, np.array([[r * r]]))
    K = (P @ H.T / (H @ P @ H.T + r * r)).ravel()
    return F, K, P


def cv_kalman_smooth(z: np.ndarray, dt: float, q: float, r: float) -> np.ndarray:
    """Constant-velocity Kalman filter (causal) of measured positions z (K, 2) m -> filtered positions (K, 2).

    The axes are independent and the gain is the steady-state one (:func:`cv_kalman_gain`), i.e. an exact
    Kalman filter started with the steady-state covariance at state (z_0, velocity 0). Its recursion
    s_k = (I - K H) F s_{k-1} + K z_k is a 2nd-order linear filter, run with ``scipy.signal.lfilter``.
    """
    z = np.asarray(z, float)
    if len(z) == 0:
        return z.reshape(0, 2)
    F, K, _ = cv_kalman_gain(dt, q, r)
    H = np.array([[1.0, 0.0]])
    A = (np.eye(2) - np.outer(K, H)) @ F
    # state-space in sigma_k = s_{k-1}: sigma_{k+1} = A sigma_k + K z_k ; y_k = H A sigma_k + H K z_k
    b, a = signal.ss2tf(A, K[:, None], H @ A, H @ K[:, None])
    b, a = b.ravel() / a[0], a / a[0]
    zi = signal.lfilter_zi(b, a)  # steady state for a constant input: state (z_0, 0)
    return signal.lfilter(b, a, z, axis=0, zi=zi[:, None] * z[0][None, :])[0]


class KRRKF(Baseline):
    """Kernel ridge regression (RBF kernel) on the fingerprint, then a constant-velocity Kalman filter.

    Exact KRR needs the N x N kernel matrix (O(N^2) memory: 20k+ windows would be > 3 GB), so the kernel
    is approximated by a Nystroem feature map (``n_components`` landmarks, ``random_state=seed``) followed
    by linear ridge regression (``alpha``) -- KRR with a low-rank kernel. ``gamma`` None: median heuristic
    (:func:`median_heuristic_gamma`) on the training fingerprints.

    :meth:`predict` is KRR alone, window by window. :meth:`predict_sequence` filters the KRR positions of
    one session's consecutive windows with :func:`cv_kalman_smooth` (dt = 1 / ``step_hz``; process noise
    ``q`` m^2/s^3; measurement noise ``r_m`` metres, None: the per-axis RMS of KRR's residuals on a seeded
    ``val_fraction`` of the training windows held out of a first fit -- an out-of-sample estimate, as
    in-sample residuals of a flexible regressor are too small -- after which the model is refitted on all).
    """

    def __init__(self, n_components: int = 1000, gamma: float | None = None, alpha: float = 1e-2,
                 q: float = 0.5, r_m: float | None = None, step_hz: float = 1.0, val_fraction: float = 0.2,
                 seed: int = 0):
        self.n_components, self.gamma, self.alpha = int(n_components), gamma, float(alpha)
        self.q, self.r_m, self.step_hz, self.val_fraction, self.seed = q, r_m, step_hz, val_fraction, seed

    def _regressor(self, F, xy):
        feat = Nystroem(kernel="rbf", gamma=self.gamma_, n_components=min(self.n_components, len(F)),
                        random_state=self.seed).fit(F)
        ridge = Ridge(alpha=self.alpha).fit(feat.transform(F), xy)
        return feat, ridge

    def fit(self, S, xy):
        F, xy = self._fit_inputs(S, xy)
        self.gamma_ = float(self.gamma) if self.gamma is not None else median_heuristic_gamma(F, self.seed)
        if self.r_m is not None:
            self.r_m_ = float(self.r_m)
        else:
            rng = np.random.default_rng(self.seed)
            val = rng.random(len(F)) < self.val_fraction
            if val.sum() < 2 or (~val).sum() < 2:
                raise ValueError(f"too few windows ({len(F)}) to estimate r_m; pass r_m explicitly")
            feat, ridge = self._regressor(F[~val], xy[~val])
            res = ridge.predict(feat.transform(F[val])) - xy[val]
            self.r_m_ = float(max(np.sqrt(np.mean(res ** 2)), 1e-3))
        self.feat_, self.ridge_ = self._regressor(F, xy)
        return self

    def predict(self, S):
        return self.ridge_.predict(self.feat_.transform(self._features(S)))

    def predict_sequence(self, S):
        return cv_kalman_smooth(self.predict(S), 1.0 / self.step_hz, self.q, self.r_m_)


BASELINES: dict[str, type[Baseline]] = {"KNN": KNNBaseline, "Bayesian": BayesianGrid, "KRR+KF": KRRKF}


def make_baseline(name: str, **kw) -> Baseline:
    """A baseline of Roy, Table 3.5 by name ("KNN", "Bayesian", "KRR+KF"), constructed with ``kw``."""
    if name not in BASELINES:
        raise ValueError(f"unknown baseline {name!r}; known: {sorted(BASELINES)} "
                         "(DL-RNN is a network: train.py model=dlrnn)")
    return BASELINES[name](**kw)
