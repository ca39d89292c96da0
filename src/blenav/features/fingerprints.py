"""RSSI fingerprints of walks: WiFi scans and BLE advertisements as vectors per step, for fingerprinting
(KNN, LocNet, TransNet+LocNet on real walks: :mod:`blenav.localizers.fingerprint`) and floor classification
(:mod:`blenav.eval.floors`).

A *feature* is one radio source: a WiFi access point (``wifi:<bssid>``, wifi.csv) or a BLE anchor
(``ble:<anchor_id>``, rssi.csv). The feature list (the vocabulary, columns of every vector) is fixed when a
model is fitted: the sources heard in the training walks (:func:`vocabulary`); a source the training walks
never heard is ignored at run time (it has no column).

Steps (the times at which a vector is formed, :func:`step_times`):

* ``wifi`` and ``both``: one step per WiFi scan (the distinct ``t`` of wifi.csv; an ILC scan is about every
  2-3 s). The WiFi part of a step is that scan only; the BLE part (``both``) is every advertisement of the
  ``ble_window_s`` seconds up to the scan time, [t - ble_window_s, t].
* ``ble``: steps every ``ble_step_s`` seconds from the first advertisement (BLE is heard irregularly, often
  one beacon per second on the ILC walks), each the advertisements of [t - ble_window_s, t].

Values are on the non-negative scale of the learned localizers (:mod:`blenav.features.windows`):
u = rssi_dBm - ``fill_dbm`` (``fill_dbm`` = -100 dBm gives the thesis scale u = rssi + 100), a source not
heard in the step is 0 = the *fill* value ``fill_dbm``; a reading at or below ``fill_dbm`` is kept as a weak
but heard ``floor_u`` (:func:`blenav.features.windows.rssi_to_u`). Several readings of one source in a step
are averaged on that scale. A window is H = ``history`` consecutive steps, S (K, F, H), oldest step first,
the layout :class:`blenav.models.LocNet`, :class:`blenav.models.TransNet` and the baselines of
:mod:`blenav.learn.crossphone.baselines` read.

**Reading a scan the way it was heard** (wifi.csv's optional ``t_seen`` column, when present; ILC 2.0 walks have it).
A WiFi row's ``t`` is when the scan was *delivered*; ``t_seen`` is when the phone last heard that access point.
Android hands over a cached list: in a delivery of the ILC walks (one every ~2 s) the access points of the scan just
made were heard 0.5-2 s before it, the rest seconds to minutes before (cached from earlier scans, metres away).
So, per delivery (the rows sharing ``t``):

* its *scan time* is the newest ``t_seen`` of its rows (``wifi_age_ref: scan``; ``delivery``, the default: ``t``
  itself, the pre-issue-29 rule);
* a row whose ``t_seen`` is more than ``wifi_max_age_s`` before the scan time is stale and dropped (None: keep all);
* the step (the fix) is placed at the *median* ``t_seen`` of the rows kept (``wifi_time: heard``; ``delivery``,
  the default: at ``t``), where the readings were taken, about 1-1.5 s before the delivery on the ILC walks (a
  walker covers 1.5-2 m in that time). Labels and fixes both take that time.

Measured on the train walks of site1 F1 / F2 / B1 only (5-fold leave-walks-out cross-validation of a KNN on
powed unit-norm scans, its best k and weighting, mean error at the held-out walks' waypoints, m: the least
``cv_error_m`` of the training report's ``cv`` table of ``blenav-eval experiment=realwalks data=FLOOR runs=1
methods.knn_wifi.wifi_max_age_s=A methods.knn_wifi.wifi_age_ref=scan methods.knn_wifi.wifi_time=heard
'methods.knn_wifi.cv={metric: [powed]}'``, on 9d79a80): A = 3 / 5 / 10 s gave 6.73 / 6.39 / 6.35 (F1),
8.50 / 8.31 / 8.71 (F2), 8.84 / 8.61 / 8.81 (B1), mean of the floors 8.02 / 7.77 / 7.96: 5 s, the threshold
(``conf/localizer/fingerprint.yaml``); on F1 1 and 2 s (nearly this scan only: 7.50, 6.81) were worse, and so was
keeping everything (A null: 7.59). Chosen on these three floors of one building and checked on no other: no other
recording at hand has WiFi scans with ``t_seen`` (the ILC importer is the only one that writes wifi.csv) and the
simulator writes none (its WiFi is RTT, rtt.csv). The defaults (``delivery`` / ``delivery``, 5 s) are the
pre-issue-29 reading, which the published tables were made with; ``scan`` / ``heard`` is opt-in until they are rerun
(docs/results-ilc20.md). A row without ``t_seen`` (column absent or cell empty) is kept and keeps its delivery
time. BLE advertisements (rssi.csv) are already at their own times: each row is one advertisement, stamped when it
was received.

Labels (:func:`label_windows`): the ground-truth position at the window's end (its last step), interpolated
linearly between the surveyed waypoints (:meth:`Session.positions_at`) for sparse ground truth; windows ending
outside the span of the ground truth get NaN (no label: dropped from training).

Torch-free (numpy, pandas).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pandas as pd
from numpy.lib.stride_tricks import sliding_window_view

from blenav.errors import MissingStream

from .windows import rssi_to_u

FEATURES = ("wifi", "ble", "both")


def floor_of(session) -> str:
    """``building/floor`` of a session: the unit a fingerprint model (and the floor classifier) is trained for."""
    return f"{session.building.id}/{session.meta.get('floor')}"


@dataclass(frozen=True)
class FingerprintConfig:
    """How walks become fingerprint windows (see the module docstring); units s and dBm."""

    features: str = "wifi"  # wifi | ble | both
    history: int = 1  # H steps per window
    fill_dbm: float = -100.0  # the value of a source not heard (u = 0); u = rssi - fill_dbm
    floor_u: float = 0.5  # u of a reading at or below fill_dbm (heard, barely)
    ble_window_s: float = 3.0  # BLE advertisements of [t - ble_window_s, t] form the BLE part of a step
    ble_step_s: float = 1.0  # features=ble: a step every so many seconds
    wifi_max_age_s: float | None = 5.0  # drop WiFi rows heard more than this before their scan time (None: keep all)
    wifi_age_ref: str = "delivery"  # a row's age from: the delivery time t (delivery) | its newest t_seen (scan)
    wifi_time: str = "delivery"  # a scan's step time: delivery time t (delivery) | median t_seen of kept rows (heard)

    def __post_init__(self):
        if self.features not in FEATURES:
            raise ValueError(f"features must be one of {FEATURES}, got {self.features!r}")
        if int(self.history) < 1:
            raise ValueError(f"history must be >= 1 step, got {self.history}")
        if self.ble_window_s < 0 or self.ble_step_s <= 0:
            raise ValueError(f"ble_window_s must be >= 0 and ble_step_s > 0, got {self.ble_window_s}, "
                             f"{self.ble_step_s}")
        if self.wifi_age_ref not in ("scan", "delivery") or self.wifi_time not in ("heard", "delivery"):
            raise ValueError(f"wifi_age_ref must be scan or delivery and wifi_time heard or delivery, got "
                             f"{self.wifi_age_ref!r}, {self.wifi_time!r}")

    @property
    def uses_wifi(self) -> bool:
        return self.features in ("wifi", "both")

    @property
    def uses_ble(self) -> bool:
        return self.features in ("ble", "both")


def readings(session, cfg: FingerprintConfig) -> pd.DataFrame:
    """The session's readings the config uses: DataFrame ``t`` (s), ``feature`` (``wifi:<bssid>`` /
    ``ble:<anchor_id>``), ``rssi`` (dBm), ``kind`` (``wifi`` | ``ble``). Raises :class:`MissingStream` when the
    session has none of the streams the config needs (``both``: neither)."""
    parts = []
    have = []
    if cfg.uses_wifi and (session.root / "wifi.csv").is_file():
        w = session.wifi
        t = heard_scans(w["t"].to_numpy(float), w["t_seen"].to_numpy(float) if "t_seen" in w else None, cfg)
        keep = np.isfinite(t)
        if keep.any():
            have.append("wifi")
            parts.append(pd.DataFrame({"t": t[keep], "feature": "wifi:" + w["bssid"].astype(str).to_numpy()[keep],
                                       "rssi": w["rssi_dbm"].to_numpy(float)[keep], "kind": "wifi"}))
    if cfg.uses_ble and (session.root / "rssi.csv").is_file():
        r = session.rssi
        if len(r):
            have.append("ble")
            parts.append(pd.DataFrame({"t": r["t"].to_numpy(float), "feature": "ble:" + r["anchor_id"].astype(str),
                                       "rssi": r["rssi"].to_numpy(float), "kind": "ble"}))
    need = {"wifi": "wifi.csv (WiFi scans)", "ble": "rssi.csv (BLE advertisements)",
            "both": "wifi.csv (WiFi scans: the steps of features=both)"}[cfg.features]
    if cfg.features == "both" and "wifi" not in have or not have:
        raise MissingStream(f"session {session.id} has no {need}")
    out = pd.concat(parts, ignore_index=True)
    return out[np.isfinite(out["t"].to_numpy()) & np.isfinite(out["rssi"].to_numpy())]


def heard_scans(t: np.ndarray, t_seen: np.ndarray | None, cfg: FingerprintConfig) -> np.ndarray:
    """The step time (s) of each WiFi row, NaN for a stale row (dropped): ``t`` (n,) the delivery times, ``t_seen``
    (n,) when each access point was last heard (NaN or None: unknown, the row is kept at its delivery time). See
    the module docstring (scan time, ``wifi_max_age_s``, ``wifi_time``)."""
    t = np.asarray(t, float)
    if t_seen is None or not len(t):
        return t.copy()
    seen = np.asarray(t_seen, float)
    known = np.isfinite(seen)
    _, inv = np.unique(t, return_inverse=True)
    newest = np.full(inv.max() + 1, -np.inf)
    np.maximum.at(newest, inv[known], seen[known])
    ref = np.where(np.isfinite(newest[inv]), newest[inv], t) if cfg.wifi_age_ref == "scan" else t
    stale = known & (ref - seen > float(cfg.wifi_max_age_s)) if cfg.wifi_max_age_s is not None \
        else np.zeros(len(t), bool)
    out = np.where(stale, np.nan, t)
    if cfg.wifi_time == "heard":
        med = pd.Series(np.where(stale, np.nan, seen)).groupby(inv).median().reindex(range(inv.max() + 1)).to_numpy()
        at = med[inv]
        out = np.where(~stale & np.isfinite(at), at, out)
    return out


def readable(walks: list, cfg: FingerprintConfig) -> tuple[list[pd.DataFrame], list]:
    """(:func:`readings` of each walk that has the streams ``cfg`` needs, those walks): the others are skipped."""
    tables, used = [], []
    for s in walks:
        try:
            tables.append(readings(s, cfg))
            used.append(s)
        except MissingStream:
            continue
    return tables, used


def vocabulary(tables: list[pd.DataFrame], min_count: int = 1, max_features: int | None = None) -> list[str]:
    """The features of the training readings ``tables``: heard in at least ``min_count`` readings, the
    ``max_features`` most often heard (ties by name) when given; sorted by name (the columns' order)."""
    counts = pd.concat([t["feature"] for t in tables], ignore_index=True).value_counts()
    counts = counts[counts >= int(min_count)]
    if max_features is not None and len(counts) > int(max_features):
        order = sorted(counts.items(), key=lambda kv: (-kv[1], kv[0]))[:int(max_features)]
        return sorted(k for k, _ in order)
    return sorted(counts.index.astype(str))


def step_times(rd: pd.DataFrame, cfg: FingerprintConfig) -> np.ndarray:
    """(K,) s: the step times of one session's readings ``rd`` (see the module docstring)."""
    if cfg.uses_wifi:
        return np.unique(rd.loc[rd["kind"] == "wifi", "t"].to_numpy(float))
    t = rd["t"].to_numpy(float)
    if not len(t):
        return np.zeros(0)
    return t.min() + np.arange(int(np.floor((t.max() - t.min()) / cfg.ble_step_s)) + 1) * cfg.ble_step_s


def step_vectors(rd: pd.DataFrame, columns: dict[str, int], tau: np.ndarray, cfg: FingerprintConfig) -> np.ndarray:
    """(K, F) float32 on the u scale: per step time ``tau`` (K,) and feature (``columns``: name -> column), the
    mean u of the readings in the step's span (WiFi: the scan at exactly tau_k; BLE: [tau_k - ble_window_s,
    tau_k]); 0 where not heard. Readings of features outside ``columns`` are ignored.

    Vectorised: each reading covers the consecutive steps k_lo..k_hi (two ``searchsorted``); a difference
    array over the steps, cumulated, gives sums and counts per step."""
    K, F = len(tau), len(columns)
    j = rd["feature"].map(columns).to_numpy()
    keep = pd.notna(j)
    if not K or not keep.any():
        return np.zeros((K, F), np.float32)
    t = rd["t"].to_numpy(float)[keep]
    j = j[keep].astype(np.int64)
    span = np.where(rd["kind"].to_numpy()[keep] == "wifi", 0.0, float(cfg.ble_window_s))
    lo = np.searchsorted(tau, t, side="left")  # first step at or after the reading
    hi = np.searchsorted(tau, t + span, side="right")  # one past the last step whose span holds it
    ok = hi > lo
    u = rssi_to_u(rd["rssi"].to_numpy(float)[keep], -float(cfg.fill_dbm), cfg.floor_u)
    d_sum = np.zeros((K + 1, F))
    d_cnt = np.zeros((K + 1, F))
    np.add.at(d_sum, (lo[ok], j[ok]), u[ok])
    np.add.at(d_sum, (hi[ok], j[ok]), -u[ok])
    np.add.at(d_cnt, (lo[ok], j[ok]), 1.0)
    np.add.at(d_cnt, (hi[ok], j[ok]), -1.0)
    sums, cnt = np.cumsum(d_sum, axis=0)[:K], np.rint(np.cumsum(d_cnt, axis=0)[:K])
    return np.divide(sums, cnt, out=np.zeros((K, F)), where=cnt > 0).astype(np.float32)


def unit_windows(S: np.ndarray) -> np.ndarray:
    """Windows S (N, F, H) (or vectors (N, F)) scaled to unit Euclidean norm over F x H (all-zero ones stay 0):
    Euclidean distance between them is then a function of the cosine similarity, so a scan that lists fewer access
    points (a shorter vector) is not nearer to every other one (the hubs of plain Euclidean KNN on sparse scans:
    on site1 one F1 region with short scan lists was the nearest neighbour of whole test walks, 100 m away)."""
    flat = S.reshape(len(S), -1)
    n = np.sqrt(np.einsum("nf,nf->n", flat, flat, dtype=float))
    return (S / np.where(n > 0, n, 1.0).reshape((-1,) + (1,) * (S.ndim - 1))).astype(S.dtype)


@dataclass
class FingerprintWindows:
    """Windows of one session: S (K, F, H) float32 u scale, t (K,) s (the window's last step), xy (K, 2) m
    (NaN: no label), heard (K,) bool (any feature heard in the window)."""

    S: np.ndarray
    t: np.ndarray
    xy: np.ndarray
    heard: np.ndarray


def session_windows(session, columns: dict[str, int], cfg: FingerprintConfig,
                    rd: pd.DataFrame | None = None) -> FingerprintWindows:
    """Every complete window of H steps of ``session`` (:func:`step_vectors`), unlabelled (xy NaN); ``rd``: the
    session's :func:`readings` when already read."""
    rd = readings(session, cfg) if rd is None else rd
    tau = step_times(rd, cfg)
    steps = step_vectors(rd, columns, tau, cfg)
    H, F = int(cfg.history), len(columns)
    if len(tau) < H:
        return FingerprintWindows(np.zeros((0, F, H), np.float32), np.zeros(0), np.zeros((0, 2)), np.zeros(0, bool))
    S = np.ascontiguousarray(sliding_window_view(steps, H, axis=0))  # (K-H+1, F, H), oldest step first
    return FingerprintWindows(S, tau[H - 1:], np.full((len(S), 2), np.nan), (S > 0).any(axis=(1, 2)))


def label_windows(session, w: FingerprintWindows) -> tuple[FingerprintWindows, int]:
    """``w`` with labels: the ground truth at each window's end time (sparse waypoints: interpolated linearly
    between them), NaN outside the ground truth's time span; returns (windows, how many ended outside)."""
    gt = session.groundtruth
    if not len(gt) or not len(w.t):
        return w, len(w.t)
    inside = (w.t >= gt["t"].iloc[0]) & (w.t <= gt["t"].iloc[-1])
    xy = np.full((len(w.t), 2), np.nan)
    xy[inside] = session.positions_at(w.t[inside])
    return FingerprintWindows(w.S, w.t, xy, w.heard), int((~inside).sum())
