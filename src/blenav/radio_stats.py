"""Radio statistics without plotting: RSSI against anchor distance, and the log-distance path-loss fit.

Used by :mod:`blenav.plotting` (``blenav-plot``) and reusable by benchmarks without matplotlib.

Model: ``rssi = A - 10 n log10(d)`` with ``d`` the 3-D distance in metres between phone and anchor,
``A`` the RSSI at 1 m (dBm) and ``n`` the path-loss exponent (2 in free space, typically 1.5-4 indoors).
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from blenav.data import Building, Session
from blenav.data.schema import ANCHOR_TRUE_COLUMNS

PAIR_COLUMNS = ("t", "anchor_id", "rssi", "distance_m")


def anchor_positions(building: Building, prefer_true: bool = True) -> pd.DataFrame:
    """World (x, y, z) in metres of every anchor, indexed by ``anchor_id``.

    With ``prefer_true`` an anchor's true position (``x_true, y_true, z_true``, written by simulators) is
    used where all three are known, else its prior (surveyed) position. Column ``true`` says which.
    """
    a = building.anchors
    xyz = a[["x", "y", "z"]].to_numpy(dtype=float)
    true = np.zeros(len(a), dtype=bool)
    if prefer_true and all(c in a.columns for c in ANCHOR_TRUE_COLUMNS):
        t = a[list(ANCHOR_TRUE_COLUMNS)].apply(pd.to_numeric, errors="coerce").to_numpy(dtype=float)
        true = np.isfinite(t).all(axis=1)
        xyz = np.where(true[:, None], t, xyz)
    return pd.DataFrame({"x": xyz[:, 0], "y": xyz[:, 1], "z": xyz[:, 2], "true": true},
                        index=pd.Index(a["anchor_id"].astype(str), name="anchor_id"))


def rssi_distance_pairs(session: Session, prefer_true: bool = True) -> pd.DataFrame:
    """Each RSSI reading of a labelled session with the 3-D distance (m) from phone to anchor.

    The phone position (x, y and height z) is the ground truth interpolated linearly at the reading's time;
    readings outside the ground truth's time span are left out (no extrapolation). The anchor position is
    its true position when the dataset knows it (see :func:`anchor_positions`), else the prior.

    Returns a frame with columns ``t`` (s), ``anchor_id``, ``rssi`` (dBm), ``distance_m``; empty when the
    session has no RSSI or no ground truth.
    """
    empty = pd.DataFrame({"t": pd.Series(dtype=float), "anchor_id": pd.Series(dtype=str),
                          "rssi": pd.Series(dtype=float), "distance_m": pd.Series(dtype=float)})
    if not session.labelled:
        return empty
    rssi, gt = session.rssi, session.groundtruth
    if len(rssi) == 0 or len(gt) == 0:
        return empty
    tg = gt["t"].to_numpy(dtype=float)
    t = rssi["t"].to_numpy(dtype=float)
    keep = (t >= tg[0]) & (t <= tg[-1])
    if not keep.any():
        return empty
    t = t[keep]
    ids = rssi["anchor_id"].to_numpy()[keep].astype(str)
    phone = np.stack([np.interp(t, tg, gt[c].to_numpy(dtype=float)) for c in ("x", "y", "z")], axis=-1)
    # the reader has dropped rows of unknown anchors, so every id is in anchors.csv
    anchor = anchor_positions(session.building, prefer_true).loc[ids, ["x", "y", "z"]].to_numpy(dtype=float)
    d = np.linalg.norm(phone - anchor, axis=-1)
    return pd.DataFrame({"t": t, "anchor_id": ids, "rssi": rssi["rssi"].to_numpy(dtype=float)[keep],
                         "distance_m": d})


def path_loss_rssi(distance_m, a_dbm: float, n: float) -> np.ndarray:
    """Model RSSI (dBm) at ``distance_m``: ``A - 10 n log10(d)``."""
    return a_dbm - 10.0 * n * np.log10(np.asarray(distance_m, dtype=float))


def fit_path_loss(distance_m, rssi) -> tuple[float, float, float]:
    """Least-squares fit of ``rssi = A - 10 n log10(d)``.

    Non-finite values and distances <= 0 are ignored. Returns ``(A_dbm, n, residual_std_db)`` where the
    residual standard deviation uses N - 2 degrees of freedom. Raises ``ValueError`` with fewer than two
    usable points or when all distances are equal (``n`` is then undetermined).
    """
    d = np.asarray(distance_m, dtype=float).ravel()
    r = np.asarray(rssi, dtype=float).ravel()
    if d.shape != r.shape:
        raise ValueError(f"distance_m and rssi differ in length ({d.size} vs {r.size})")
    ok = np.isfinite(d) & np.isfinite(r) & (d > 0)
    d, r = d[ok], r[ok]
    if d.size < 2 or np.ptp(np.log10(d)) == 0:
        raise ValueError(f"need at least two distinct distances to fit a path-loss model, got {d.size} point(s)")
    x = -10.0 * np.log10(d)
    design = np.column_stack([np.ones_like(x), x])
    (a_dbm, n), *_ = np.linalg.lstsq(design, r, rcond=None)
    resid = r - design @ np.array([a_dbm, n])
    std = float(np.sqrt(np.sum(resid**2) / max(d.size - 2, 1)))
    return float(a_dbm), float(n), std
