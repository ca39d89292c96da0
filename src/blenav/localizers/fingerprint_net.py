"""The networks of :class:`blenav.localizers.fingerprint.FingerprintLocalizer` (``model``: locnet, transnet_locnet,
placenet): trained on a floor's windows, refitted on every train walk (``refit``), and each fix's std
(``net_cov``). Functions of the localizer ``loc`` whose settings they read; torch only through
:mod:`blenav.learn.fingerprint.train`, imported when a network is trained.
"""

from __future__ import annotations

import math
import tempfile
import time
from pathlib import Path

import numpy as np

from blenav.runtime.calibration import coverage, std_scale_fit

from . import knn as KNN

#: errors needed to fit a std model (``net_cov: calibrated``'s validation windows; fewer: the head's sigma)
MIN_STD_FIT = 10


def fit_network(loc, key, S, P, xy, walk_of, used, names, inputs, info):
    """Train ``loc.model`` on one floor's windows S (N, F, H) u scale, previous windows P, labels xy (N, 2) m, walk
    index ``walk_of`` into ``used`` (feature ``names``) in OUT/fingerprint/<method>/<floor> (``inputs.out``, else a
    temporary folder); refit it on every walk with ``loc.refit``; returns predict: S (K, F, H) -> (xy (K, 2) m,
    cov (K, 2, 2) or None) by ``loc.net_cov``. ``info`` (the floor's report) gets ``training``, ``refit``,
    ``fix_std``."""
    from blenav.learn.fingerprint.train import split_walks

    given = inputs.out if inputs is not None else None
    root = Path(given) if given is not None else Path(tempfile.mkdtemp(prefix="fp_"))
    out = root / "fingerprint" / loc.name.replace("/", "_").replace(" ", "_") / key.replace("/", "_")
    data = (S, P, xy, walk_of, used, names)
    net_predict, rep = _train(loc, data, out, trainer=loc.trainer, val_fraction=loc.val_fraction)
    info["training"] = rep
    val_predict = None  # refitted: the network that never saw the validation walks, whose errors fit the stds
    if loc.refit:
        refitted = refit(loc, data, out / "refit", rep, info)
        if refitted is not None:
            val_predict, net_predict = net_predict, refitted
    if loc.net_cov == "calibrated":
        predict = net_std_model(loc, net_predict, S, xy, walk_of, names, info, val_predict=val_predict)
        if predict is not None:
            return predict
    if loc.net_cov in ("predicted", "calibrated"):  # each fix's own sigma (LocNet's std head) + cov_floor_m^2;
        # calibrated comes here when too few validation windows fit its model
        if "fix_std" not in rep:
            raise ValueError(f"method {loc.name!r}: net_cov: {loc.net_cov} needs a LocNet with a std head "
                             f"(net.locnet.std_head: true)")
        info["fix_std"] = rep["fix_std"]

        def predict(Sq):
            xy_q, std = net_predict(Sq)
            var = std ** 2 + loc.cov_floor_m ** 2
            return xy_q, var[:, None, None] * np.eye(2)

        return predict
    # net_cov: validation (opt-in; none by default): each fix's std is the network's RMS error per axis on its
    # validation walks (held out of its training), one isotropic covariance for every fix; none without them
    val = split_walks(walk_of, loc.val_fraction, loc.seed) if loc.net_cov == "validation" else None
    cov = None
    if val is not None and val.any():
        var = float(np.mean(np.sum(((val_predict or net_predict)(S[val])[0] - xy[val]) ** 2, axis=1))) / 2.0
        cov = (var + loc.cov_floor_m ** 2) * np.eye(2)
        info["fix_std_m"] = float(np.sqrt(var + loc.cov_floor_m ** 2))

    def predict(Sq):
        xy_q = net_predict(Sq)[0]
        return xy_q, None if cov is None else np.broadcast_to(cov, (len(xy_q), 2, 2)).copy()

    return predict


def _train(loc, data: tuple, out: Path, **kw):
    """:func:`blenav.learn.fingerprint.train.train_network` (torch: imported only on the learned path) of ``data`` =
    (S, P, xy, walk_of, used, names) in ``out`` with ``loc``'s network settings and ``kw``."""
    from blenav.learn.fingerprint.train import train_network

    return train_network(*data, loc.cfg, loc.model, loc.training, out, seed=loc.seed, net=loc.net,
                         batch_size=loc.batch_size, threads=loc.threads, plots=loc.plots, **kw)


def refit(loc, data: tuple, out: Path, rep: dict, info: dict):
    """``refit``: the network trained again on ``data`` (:func:`_train`'s: every train walk, none held out) for as
    many epochs as the validation run's best check had (its best step times all windows / its training windows),
    with that run's std scale; its predict, or None (``info["refit"]`` says why) when the validation run had no best
    check."""
    best, n_train = rep.get("best_step"), int(rep.get("train_windows") or 0)
    if not best or not n_train:
        info["refit"] = "not refitted: the validation run had no validation check (too few walks to hold out)"
        return None
    n_all = len(data[0])
    steps = int(math.ceil(int(best) * n_all / n_train))
    budget = {**dict(loc.trainer.get("budget") or {}), "max_steps": steps, "patience": None}
    fs = rep.get("fix_std")
    t0 = time.perf_counter()
    predict, rep2 = _train(loc, data, out, trainer={**loc.trainer, "budget": budget},
                           val_fraction=0.0, std_scale=fs.get("scale") if isinstance(fs, dict) else None)
    info["refit"] = {"steps": steps, "windows": n_all, "from_best_step": int(best),
                     "fit_s": time.perf_counter() - t0, "run": rep2.get("run")}
    return predict


def net_std_model(loc, net_predict, S, xy, walk_of, names, info, val_predict=None):
    """``net_cov: calibrated``: each network fix's std from :class:`blenav.localizers.knn.StdModel`'s form, log std
    = c0 + c1 log(1 + sigma) + c2 d1, sigma the std head's and d1 the window's cosine signal distance to the
    nearest window the network trained on (large where the survey did not go), fitted by maximum likelihood on the
    errors of the validation walks (held out of the training); plus ``cov_floor_m``^2. None (and the reason in
    ``info["fix_std_calibrated"]``) with fewer than :data:`MIN_STD_FIT` validation windows: the caller then states
    the head's own sigma (``net_cov: predicted``). ``val_predict`` (``refit``): the network the errors are
    measured on, the one trained without the validation walks (default ``net_predict``); the fitted model then
    states ``net_predict``'s fixes, their signal distance taken to every window it trained on."""
    from blenav.learn.fingerprint.train import split_walks

    val = split_walks(walk_of, loc.val_fraction, loc.seed)
    if val.sum() < MIN_STD_FIT:
        info["fix_std_calibrated"] = (f"not fitted: {int(val.sum())} validation windows (need {MIN_STD_FIT}); the "
                                      f"std head's own sigma instead (net_cov: predicted)")
        return None
    is_ble = np.array([n.startswith("ble:") for n in names])
    def reference(Sr):  # the windows a network trained on and their squared norms, once (as KNN.fit)
        X = KNN.represent(Sr, "cosine", is_ble, 1.0, loc.cfg.fill_dbm)
        return X, np.einsum("nf,nf->n", X, X)

    def features(Sq, predict=net_predict, ref=None):
        xy_q, sigma = predict(Sq)
        X, bb = ref or ref_run
        return xy_q, sigma, KNN.nearest_distance(KNN.represent(Sq, "cosine", is_ble, 1.0, loc.cfg.fill_dbm), X, bb)

    ref_fit = reference(S[~val])
    ref_run = ref_fit if val_predict is None else reference(S)
    xy_v, sigma_v, d1_v = features(S[val], predict=val_predict or net_predict, ref=ref_fit)
    err = np.hypot(*(xy_v - xy[val]).T)
    model = KNN.fit_std_model(err, sigma_v, d1_v)
    stated = np.sqrt(model.std(sigma_v, d1_v) ** 2 + loc.cov_floor_m ** 2)  # the std the fixes state
    scale, fit = std_scale_fit(err, stated)
    own = "the place scores' spread" if loc.model == "placenet" else "sigma of the std head"
    info["fix_std"] = {"model": f"log std = c0 + c1 log(1 + {own}) + c2 d1 (signal distance to the training "
                                "windows), fitted on the validation walks' errors; + cov_floor_m",
                       "c": list(model.c), "windows": int(len(err)), **coverage(err, stated),
                       "rank_correlation": fit.get("rank_correlation"),
                       "ml_scale": None if "uncalibrated" in fit else scale}

    def predict(Sq):
        xy_q, sigma, d1 = features(Sq)
        var = model.std(sigma, d1) ** 2 + loc.cov_floor_m ** 2
        return xy_q, var[:, None, None] * np.eye(2)

    return predict
