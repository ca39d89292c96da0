"""A stated std's calibration on held-out errors (numpy only): the maximum-likelihood scale of per-fix stds and what
the scaled std says about the errors. LocNet's std head is scaled with it at a training stage's end
(:meth:`blenav.learn.crossphone.module.CrossPhoneModule.calibrate`), and ``blenav-fixes --calibrate`` reports with
it how an exported model's stated std fits labelled walks (:func:`blenav.runtime.fixes.calibrate_model_fixes`)."""

from __future__ import annotations

import numpy as np
from scipy import stats


def coverage(err_m: np.ndarray, std_m: np.ndarray) -> dict:
    """``{coverage_1sigma, coverage_2sigma}``: the shares of 2-D errors of norm ``err_m`` (N,) m within 1 and 2 stated
    stds ``std_m`` (N,) m, as stated (a 2-D Gaussian holds 39.3 / 86.5 %); N > 0."""
    return {"coverage_1sigma": float(np.mean(err_m <= std_m)), "coverage_2sigma": float(np.mean(err_m <= 2.0 * std_m))}


def std_scale_fit(err_m: np.ndarray, sigma_m: np.ndarray) -> tuple[float, dict]:
    """The maximum-likelihood scale c of stated stds sigma_m (N,) m for 2-D errors of norm err_m (N,) m, each error
    N(0, (c sigma)^2 I): c^2 = mean(err^2 / sigma^2) / 2, over the rows where both are finite and sigma > 0; and what
    the scaled std says about those errors: ``{scale, windows, coverage_1sigma, coverage_2sigma, median_std_m,
    rank_correlation}`` (coverage: the share within 1 / 2 scaled sigma, a 2-D Gaussian holds 39.3 / 86.5 %;
    rank_correlation: Spearman's between sigma and the error, 0 for a sigma that says nothing of which fix is worse,
    None where it is undefined: fewer than 2 rows, or either constant). Without such rows, or where the fit is not a
    finite positive number (every error 0), the scale is 1 and the report says ``uncalibrated`` (a string) instead:
    nothing non-finite is ever returned."""
    err, sigma = np.asarray(err_m, float).ravel(), np.asarray(sigma_m, float).ravel()
    ok = np.isfinite(err) & np.isfinite(sigma) & (sigma > 0)
    err, sigma = err[ok], sigma[ok]
    r2 = (err / sigma) ** 2
    c = float(np.sqrt(r2.mean() / 2.0)) if len(err) else float("nan")
    if not (np.isfinite(c) and c > 0):
        return 1.0, {"uncalibrated": f"scale 1: {len(err)} windows with a finite error and a positive std, and no "
                                     f"finite positive maximum-likelihood scale from them"}
    r = np.sqrt(r2) / c
    rho = float(stats.spearmanr(sigma, err)[0]) if len(err) > 1 else float("nan")
    return c, {"scale": c, "windows": int(len(err)), "coverage_1sigma": float(np.mean(r <= 1.0)),
               "coverage_2sigma": float(np.mean(r <= 2.0)), "median_std_m": float(np.median(sigma) * c),
               "rank_correlation": rho if np.isfinite(rho) else None}
