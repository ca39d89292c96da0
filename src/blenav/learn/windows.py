"""RSSI windows for the learned BLE localizer (Roy, section 3.1.3).

A window is the matrix S in R_{>=0}^{B x H}: B beacons in one fixed order (stored with a model) by H
time steps of ``1 / step_hz`` seconds (H = 5 at 1 Hz in the thesis). Each entry is the mean, on the
thesis' non-negative scale u = rssi_dBm + ``offset_db`` (clipped at 0), of the packets of that beacon in
that step; a beacon not heard in the step is 0 ("not heard = 0"). The label of the window ending at step
k is the ground-truth position (x, y, metres, world frame) at the end of step k.

The scale: Table 3.2 of the thesis reports about 30 for a beacon at 1 m; with the -70 dBm 1 m level of
our receiver model that is u = rssi + 100 (:data:`blenav.sim.receivers.THESIS_OFFSET_DB`). Readings below
-``offset_db`` dBm would be negative and are clipped to a small positive value (``floor_u``), not 0, so
that a weak packet is never confused with none.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field

import numpy as np
from numpy.lib.stride_tricks import sliding_window_view

from blenav.sim.receivers import THESIS_OFFSET_DB

log = logging.getLogger("blenav.learn")


@dataclass
class WindowConfig:
    history: int = 5  # H
    step_hz: float = 1.0
    offset_db: float = THESIS_OFFSET_DB
    floor_u: float = 0.5  # value of a packet weaker than -offset_db dBm (heard, but barely)
    steps: str = "time"  # "time": steps of 1 / step_hz s; "scan": one step per scan (distinct RSSI time)


@dataclass
class Windows:
    """S (K, B, H) float32 on the thesis scale, labels xy (K, 2) m (NaN when unlabelled), t (K,) s (window ends)."""

    S: np.ndarray
    xy: np.ndarray
    t: np.ndarray
    beacons: list[str]
    device_model: str
    session: str
    unknown: dict = field(default_factory=dict)  # anchor id -> packets ignored (not in ``beacons``)


def beacon_order(building) -> list[str]:
    """The building's BLE anchor ids, sorted: the fixed row order of S stored with a model."""
    a = building.anchors
    return sorted(a.loc[a["kind"] == "ble", "anchor_id"].astype(str).tolist())


def rssi_to_scale(rssi_dbm: np.ndarray, cfg: WindowConfig) -> np.ndarray:
    """dBm -> thesis scale u = rssi + offset, at least ``floor_u`` for any received packet."""
    return np.maximum(np.asarray(rssi_dbm, float) + cfg.offset_db, cfg.floor_u)


def session_windows(session, beacons: list[str], cfg: WindowConfig = WindowConfig()) -> Windows:
    """Every complete window of a session (steps from the session's first RSSI time).

    ``cfg.steps == "scan"`` is for fingerprint surveys (e.g. the UJI set): each distinct RSSI timestamp is
    one step, and a window is H consecutive scans at one surveyed point (equal ground-truth positions),
    never spanning the walk between two points; its label is that point.
    """
    if cfg.steps == "scan":
        return _scan_windows(session, beacons, cfg)
    if cfg.steps != "time":
        raise ValueError(f"window steps must be 'time' or 'scan', got {cfg.steps!r}")
    r = session.rssi
    B, H = len(beacons), cfg.history
    empty = Windows(np.zeros((0, B, H), np.float32), np.zeros((0, 2)), np.zeros(0), beacons, session.device_model,
                    session.id)
    if len(r) == 0:
        return empty
    col = {b: i for i, b in enumerate(beacons)}
    j = r["anchor_id"].astype(str).map(col)
    keep = j.notna().to_numpy()
    empty.unknown = _unknown(r, keep, session.id)
    if not keep.any():
        return empty
    t = r["t"].to_numpy(float)[keep]
    j = j.to_numpy()[keep].astype(int)
    t0 = float(r["t"].iloc[0])
    k = np.floor((t - t0) * cfg.step_hz).astype(int)
    K = int(k.max()) + 1
    sums = np.zeros((K, B))
    counts = np.zeros((K, B))
    np.add.at(sums, (k, j), rssi_to_scale(r["rssi"].to_numpy(float)[keep], cfg))
    np.add.at(counts, (k, j), 1.0)
    steps = np.divide(sums, counts, out=np.zeros_like(sums), where=counts > 0)  # (K, B): 0 = not heard
    if K < H:
        return empty
    S = sliding_window_view(steps, H, axis=0).astype(np.float32)  # (K-H+1, B, H), oldest step first
    t_end = t0 + (np.arange(H - 1, K) + 1) / cfg.step_hz
    xy = np.full((len(t_end), 2), np.nan)
    if session.labelled and len(session.groundtruth):
        gt = session.groundtruth
        inside = (t_end >= gt["t"].iloc[0]) & (t_end <= gt["t"].iloc[-1])
        xy[inside] = session.positions_at(t_end[inside])
    return Windows(np.ascontiguousarray(S), xy, t_end, beacons, session.device_model, session.id, empty.unknown)


def _unknown(r, keep: np.ndarray, session_id: str) -> dict:
    """Packets of anchors outside the model's beacon list: ignored (they are no row of S), counted, said once."""
    if keep.all():
        return {}
    counts = r.loc[~keep, "anchor_id"].astype(str).value_counts().to_dict()
    ids = sorted(counts)
    log.warning("session %s: %d packet(s) from %d beacon(s) outside the model's beacon list ignored (%s%s)",
                session_id, sum(counts.values()), len(ids), ", ".join(ids[:5]), ", ..." if len(ids) > 5 else "")
    return counts


def _scan_windows(session, beacons: list[str], cfg: WindowConfig) -> Windows:
    r = session.rssi
    B, H = len(beacons), cfg.history
    col = {b: i for i, b in enumerate(beacons)}
    j = r["anchor_id"].astype(str).map(col) if len(r) else r.get("anchor_id")
    keep = j.notna().to_numpy() if len(r) else np.zeros(0, bool)
    empty = Windows(np.zeros((0, B, H), np.float32), np.zeros((0, 2)), np.zeros(0), beacons, session.device_model,
                    session.id)
    if not keep.any() or not (session.labelled and len(session.groundtruth)):
        return empty
    t_all = r["t"].to_numpy(float)[keep]
    scans, k = np.unique(t_all, return_inverse=True)
    K = len(scans)
    sums, counts = np.zeros((K, B)), np.zeros((K, B))
    jj = j.to_numpy()[keep].astype(int)
    np.add.at(sums, (k, jj), rssi_to_scale(r["rssi"].to_numpy(float)[keep], cfg))
    np.add.at(counts, (k, jj), 1.0)
    steps = np.divide(sums, counts, out=np.zeros_like(sums), where=counts > 0)
    if K < H:
        return empty
    xy = session.positions_at(scans)  # (K, 2)
    same = np.r_[True, np.linalg.norm(np.diff(xy, axis=0), axis=1) < 1e-3]  # scan k at the point of k-1
    run_start = np.maximum.accumulate(np.where(~same, np.arange(K), 0))  # first scan of each point's run
    ends = np.flatnonzero(np.arange(K) - run_start >= H - 1)  # windows ending here stay at one point
    if len(ends) == 0:
        return empty
    S = sliding_window_view(steps, H, axis=0)[ends - (H - 1)].astype(np.float32)
    return Windows(np.ascontiguousarray(S), xy[ends], scans[ends], beacons, session.device_model, session.id)


def split_by_device(sessions, train_devices=None, test_devices=None, unlabelled_devices=None,
                    holdout: float = 0.0, unlabelled_share: float = 0.5, seed: int = 0) -> dict[str, list]:
    """Sessions grouped as 'train' / 'test' / 'unlabelled' by their ``device_model`` (session.yaml).

    - ``train_devices`` None: every device not named in ``unlabelled_devices`` or ``test_devices``. Only
      labelled sessions train.
    - ``test_devices`` None: every device. A device both trained on and tested gives ``holdout`` of its
      labelled sessions (rounded, at least one when holdout > 0 and it has two or more) to the test set,
      so no session is on both sides.
    - ``unlabelled_devices``: their sessions without ground truth are unlabelled training data; a device
      that is also tested and has no such session gives ``unlabelled_share`` of its sessions to the
      unlabelled set (their labels unused) and the rest to the test set (scenario 3 of Roy).
    Session choice is seeded and whole sessions move, never windows. A device in train and unlabelled,
    or a named device without sessions, is an error naming the devices present.
    """
    known = sorted({s.device_model for s in sessions})
    for name, devs in (("train", train_devices), ("test", test_devices), ("unlabelled", unlabelled_devices)):
        missing = sorted(set(devs or []) - set(known))
        if missing:
            raise ValueError(f"{name} devices {missing} have no session; device models here: {known}")
    U = set(unlabelled_devices or [])
    T = set(train_devices) if train_devices is not None else set(known) - U - set(test_devices or [])
    E = set(test_devices) if test_devices is not None else set(known)
    both = sorted(T & U)
    if both:
        raise ValueError(f"device model(s) {both} are in both train and unlabelled devices")
    rng = np.random.default_rng(seed)
    out = {"train": [], "test": [], "unlabelled": []}
    for d in known:
        mine = sorted((s for s in sessions if s.device_model == d), key=lambda s: s.id)
        lab = [s for s in mine if s.labelled]
        unl = [s for s in mine if not s.labelled]
        order = [lab[i] for i in rng.permutation(len(lab))]  # drawn for every device: stable across configs
        if d in T:
            k = 0
            if d in E and holdout > 0 and len(lab) >= 2:
                k = min(max(1, int(round(holdout * len(lab)))), len(lab) - 1)
            out["test"] += sorted(order[:k], key=lambda s: s.id)
            out["train"] += sorted(order[k:], key=lambda s: s.id)
        elif d in U:
            if unl or d not in E:
                out["unlabelled"] += unl if d in E else mine
                out["test"] += lab if d in E else []
            else:
                k = min(max(1, int(round(unlabelled_share * len(lab)))), max(len(lab) - 1, 1))
                out["unlabelled"] += sorted(order[:k], key=lambda s: s.id)
                out["test"] += sorted(order[k:], key=lambda s: s.id)
        elif d in E:
            out["test"] += lab
    return out
