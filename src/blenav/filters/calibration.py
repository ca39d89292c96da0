"""Fit the path-loss model rssi = a_X - 10 gamma log10(d / d0) (d0 = 1 m) from labelled sessions.

What a deployer does before running PF-PL or PF-PS (Ghaffari Jadidi et al.: "the path-loss model
parameters can be estimated as explained in [9]"; Patel et al. Table I lists the fitted a_X, gamma):
pair every RSSI reading of labelled sessions with the distance from the ground-truth position to the
anchor's *prior* (surveyed) position -- the map a user has, not the simulator's true one -- and fit by
least squares (:func:`blenav.radio_stats.fit_path_loss`). Readings are censored by receiver sensitivity
at long range, which flattens the fitted exponent; that is what the data say and what the filter sees.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np
import pandas as pd

from blenav.radio_stats import fit_path_loss, rssi_distance_pairs


@dataclass
class PathLossFit:
    a_x: float  # dBm at d0
    gamma: float
    d0: float
    residual_std_db: float
    n_readings: int
    sessions: list

    def as_dict(self) -> dict:
        return asdict(self)


def fit_sessions(sessions) -> PathLossFit:
    """Fit a_X and gamma on every RSSI reading of the given labelled sessions (prior anchor positions)."""
    pairs = [rssi_distance_pairs(s, prefer_true=False) for s in sessions]
    used = [s.id for s, p in zip(sessions, pairs) if len(p)]
    if not used:
        raise ValueError("no labelled session with RSSI readings to fit the path-loss model on")
    p = pd.concat([q for q in pairs if len(q)], ignore_index=True)
    p = p[np.isfinite(p["distance_m"].to_numpy(float))]  # beacons without a position (not yet mapped) say nothing
    if not len(p):
        raise ValueError(f"no RSSI reading of a beacon with a known position in sessions {used} to fit the "
                         f"path-loss model on (estimate the beacons first: blenav-map)")
    a, n, std = fit_path_loss(p["distance_m"].to_numpy(), p["rssi"].to_numpy())
    if not (np.isfinite(a) and np.isfinite(n)) or n <= 0:
        raise ValueError(f"path-loss fit failed (a_X={a}, gamma={n}) on sessions {used}")
    return PathLossFit(float(a), float(n), 1.0, float(std), int(len(p)), used)


def apply_fit(models: list, fit: PathLossFit) -> None:
    """Give every measurement model that asks for calibration (``calibrated=True``) the fitted parameters."""
    for m in models:
        if m.calibrated:
            m.a_x, m.gamma, m.d0 = fit.a_x, fit.gamma, fit.d0
            m.use_anchor_tx_power = False
