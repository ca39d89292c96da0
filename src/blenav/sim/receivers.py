"""BLE receiver profiles: 15 phones in 5 brands, calibrated to Table 3.2 of Roy (thesis, section 3.1.2).

Table 3.2 gives, per phone, the mean M and variance V of RSSI from one beacon at 1 m for 60 s, on the
thesis' non-negative scale (we take ``u = rssi_dbm + 100``, 0 = not heard), without (subscript 0) and
with (subscript 1) other beacons around as interference. Both the mean drop and the variance under
interference come from two effects a receiver has: a shift of the reported level and missed packets
reported as nothing (zeros on the thesis scale). We model per packet:

    heard with probability 1 - q,  u ~ N(mu, sigma^2)   ->   M = (1 - q) mu,
                                                           V = (1 - q) sigma^2 + q (1 - q) mu^2

and split each (M, V) pair by choosing the dropout share ``q = c * V / (V + M^2)`` (the largest q that
keeps sigma^2 >= 0 is V / (V + M^2)); ``c`` is per brand: the thesis reports "high amounts of receiver
failure" for Huawei and Xiaomi. Then ``mu = M / (1 - q)`` and
``sigma^2 = (V - q M^2 / (1 - q)) / (1 - q)``. Channel fading at 1 m (see :mod:`blenav.sim.radio`) and
quantisation also add variance, so the receiver's own noise is ``sigma^2`` minus those (floored).

Each profile also has: a gain slope around -70 dBm (automatic gain control compresses or expands the
scale differently per chipset, so RSSI-vs-distance slopes differ between phones), a sensitivity (dBm
below which nothing is reported) and a quantisation step (dB). These three are not in the thesis'
table; their spread is chosen to be typical of published phone comparisons and is stated here.

The interference level kappa in [0, 1] (how crowded the channel is, computed by the radio model from
the number of audible beacons) interpolates every parameter between the two columns of the table.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from blenav.features.scale import THESIS_OFFSET_DB  # the thesis scale, shared with the windows

#: Table 3.2 (Roy): phone -> (M0, V0, M1, V1) on the scale u = rssi + 100; 1 m, 60 s.
TABLE_3_2: dict[str, tuple[float, float, float, float]] = {
    "iphone-7": (27.61, 7.18, 26.80, 4.07),
    "iphone-8": (30.20, 1.73, 27.52, 8.25),
    "iphone-xr": (29.17, 2.26, 27.93, 0.37),
    "galaxy-s10": (33.04, 8.09, 20.87, 14.77),
    "galaxy-note9": (30.30, 2.86, 22.35, 40.92),
    "galaxy-a50": (30.83, 17.93, 26.80, 19.03),
    "pixel-4xl": (24.46, 11.47, 11.83, 41.93),
    "pixel-3xl": (30.35, 0.49, 16.41, 42.72),
    "pixel-3axl": (28.98, 3.20, 20.61, 50.37),
    "mi-9": (27.39, 45.90, 19.11, 41.77),
    "mi-9t-pro": (30.39, 55.79, 19.12, 62.34),
    "redmi-note8": (32.33, 4.35, 22.50, 43.95),
    "mate-20-pro": (34.67, 1.39, 26.33, 21.87),
    "honor-20-pro": (28.04, 11.91, 21.07, 35.63),
    "honor-view-20": (26.09, 3.99, 25.17, 7.06),
}

BRAND = {
    "iphone-7": "apple", "iphone-8": "apple", "iphone-xr": "apple",
    "galaxy-s10": "samsung", "galaxy-note9": "samsung", "galaxy-a50": "samsung",
    "pixel-4xl": "google", "pixel-3xl": "google", "pixel-3axl": "google",
    "mi-9": "xiaomi", "mi-9t-pro": "xiaomi", "redmi-note8": "xiaomi",
    "mate-20-pro": "huawei", "honor-20-pro": "huawei", "honor-view-20": "huawei",
}

#: share c of the largest admissible dropout, without / with interference, per brand
DROPOUT_SHARE = {"apple": (0.05, 0.2), "samsung": (0.05, 0.4), "google": (0.05, 0.5),
                 "xiaomi": (0.3, 0.7), "huawei": (0.3, 0.7)}
#: (sensitivity dBm, gain slope) per brand; quantisation per phone below
BRAND_RF = {"apple": (-98.0, 1.00), "samsung": (-100.0, 0.92), "google": (-102.0, 1.08),
            "xiaomi": (-97.0, 0.85), "huawei": (-99.0, 1.12)}
QUANT_DB = {"redmi-note8": 2.0, "honor-view-20": 2.0}

#: the 1 m reference level of the table's beacon (thesis scale: u = rssi + THESIS_OFFSET_DB)
TABLE_REF_1M_DBM = -70.0


@dataclass(frozen=True)
class ReceiverProfile:
    """Per-phone receiver behaviour. Offsets in dB relative to the channel, std in dB, q in [0, 1)."""

    name: str
    brand: str
    offset_db: tuple[float, float]  # (no interference, interference): reported level shift
    std_db: tuple[float, float]  # receiver noise per packet
    dropout: tuple[float, float]  # probability a received packet is not reported
    gain: float  # slope of reported vs. true level around TABLE_REF_1M_DBM
    sensitivity_dbm: float
    quant_db: float

    def at(self, kappa: np.ndarray):
        """Offset, std and dropout (arrays like kappa) at interference level kappa in [0, 1]."""
        k = np.clip(kappa, 0.0, 1.0)
        lerp = lambda p: p[0] + (p[1] - p[0]) * k  # noqa: E731
        return lerp(self.offset_db), lerp(self.std_db), lerp(self.dropout)


def _split(M: float, V: float, c: float, fading_mean: float, extra_var: float) -> tuple[float, float, float]:
    q = c * V / (V + M * M)
    mu = M / (1.0 - q)
    var = (V - q * M * M / (1.0 - q)) / (1.0 - q)
    std = float(np.sqrt(max(var - extra_var, 0.05)))
    return mu - (TABLE_REF_1M_DBM + THESIS_OFFSET_DB) - fading_mean, std, q


def make_profile(name: str, fading_1m: tuple[float, float] = (0.0, 0.0)) -> ReceiverProfile:
    """Build the profile of phone ``name`` from Table 3.2 (see module docstring for the split).

    ``fading_1m``: (mean dB, variance dB^2) of the channel's fading at 1 m in line of sight, which the
    table's numbers already contain, so the receiver's own offset and noise exclude it.
    """
    if name not in TABLE_3_2:
        raise ValueError(f"unknown receiver profile {name!r}; profiles are {sorted(TABLE_3_2)}")
    brand = BRAND[name]
    m0, v0, m1, v1 = TABLE_3_2[name]
    quant = QUANT_DB.get(name, 1.0)
    sens, gain = BRAND_RF[brand]
    f_mean, f_var = fading_1m
    extra = gain**2 * f_var + quant**2 / 12.0
    c0, c1 = DROPOUT_SHARE[brand]
    o0, s0, q0 = _split(m0, v0, c0, gain * f_mean, extra)
    o1, s1, q1 = _split(m1, v1, c1, gain * f_mean, extra)
    return ReceiverProfile(name, brand, (o0, o1), (s0, s1), (q0, q1), gain, sens, quant)
