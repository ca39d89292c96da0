"""The one-beacon, one-metre experiment of Roy (thesis, section 3.1.2), run through the simulator's own
channel and receiver code, so its statistics can be set beside Table 3.2.

A beacon at 1 m in line of sight advertises for ``duration_s``; every advertisement the scanner catches
(``scan_prob``) is passed through Rician fading and the receiver profile at interference level kappa
(0: the table's 'no interference' column, 1: 'with interference'). The series is on the thesis scale
u = rssi + 100 with 0 for a packet the receiver did not report.
"""

from __future__ import annotations

import numpy as np

from .radio import BleConfig, fading_moments_db, k_factor, receive, rician_db
from .receivers import TABLE_REF_1M_DBM, THESIS_OFFSET_DB, ReceiverProfile, make_profile


def profile_for(name: str, cfg: BleConfig) -> ReceiverProfile:
    """Receiver profile whose offsets and noise exclude this channel's fading at 1 m."""
    return make_profile(name, fading_moments_db(float(k_factor(cfg, np.array(1.0), np.array(0.0)))))


def one_metre_series(rng: np.random.Generator, profile: ReceiverProfile, cfg: BleConfig, kappa: float,
                     duration_s: float = 60.0) -> np.ndarray:
    """Thesis-scale series (N,) of one beacon at 1 m; 0 where the receiver reported nothing."""
    n = int(duration_s * cfg.adv_rate_hz * cfg.scan_prob)
    k = k_factor(cfg, np.ones(n), np.zeros(n))
    channel = TABLE_REF_1M_DBM + rician_db(rng, k)
    rssi, kept = receive(rng, profile, channel, np.full(n, kappa))
    return np.where(kept, rssi + THESIS_OFFSET_DB, 0.0)
