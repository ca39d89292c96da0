"""RSSI windows for the learned BLE localizer (Roy, section 3.1.3).

A window is the matrix S in R_{>=0}^{B x H}: B beacons in one fixed order (stored with a model) by H
time steps of ``1 / step_hz`` seconds (H = 5 at 1 Hz in the thesis). Each entry is the mean, on the
thesis' non-negative scale u = rssi_dBm + ``offset_db`` (clipped at 0), of the packets of that beacon in
that step; a beacon not heard in the step is 0 ("not heard = 0"). The label of the window ending at step
k is the ground-truth position (x, y, metres, world frame) at the end of step k.

The scale: Table 3.2 of the thesis reports about 30 for a beacon at 1 m; with the -70 dBm 1 m level of
our receiver model that is u = rssi + 100 (:data:`blenav.features.scale.THESIS_OFFSET_DB`). Readings below
-``offset_db`` dBm would be negative and are clipped to a small positive value (``floor_u``), not 0, so
that a weak packet is never confused with none (:func:`rssi_to_u`, the transform an exported model's
metadata describes and :class:`blenav.runtime.OnnxLocalizer` applies).

Torch-free (numpy, pandas): training (:mod:`blenav.learn`), the runtime (:mod:`blenav.runtime`) and the
evaluation all window sessions with these functions.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field

import numpy as np
import pandas as pd
from numpy.lib.stride_tricks import sliding_window_view

from .scale import THESIS_OFFSET_DB

log = logging.getLogger("blenav.learn")  # the name it logged under before it moved here (log filters keep working)


@dataclass
class WindowConfig:
    history: int = 5  # H
    step_hz: float = 1.0
    offset_db: float = THESIS_OFFSET_DB
    floor_u: float = 0.5  # value of a packet weaker than -offset_db dBm (heard, but barely)
    steps: str = "time"  # "time": steps of 1 / step_hz s; "scan": one step per scan (distinct RSSI time)
    # None: the rows are all of the building's BLE beacons; else the rule that chose a deliberate subset
    # ("spread:K" = spread_beacons(K), "list" = named ids): the building's other beacons are then left out
    # on purpose and not reported as unknown
    beacon_subset: str | None = None


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


def spread_beacons(anchors: pd.DataFrame, k: int, floor_id=None, floor=None, grid_m: float = 1.0) -> list[str]:
    """Ids of ``k`` BLE anchors spread over the floor so that they cover it (greedy k-median, deterministic).

    Candidates: ``kind == 'ble'`` anchors on ``floor_id`` (when the table's ``floor`` column has it).
    Demand points: one free pixel centre per ``grid_m`` cell of the floor (``floor``, a
    :class:`~blenav.data.Floor`), the cell's first free pixel in image row order (its top-most row, so a
    slight northward bias within each cell); without ``floor``, the anchors themselves. Greedy: start from nothing and add,
    k times, the anchor that most reduces the mean distance from the demand points to their nearest chosen
    anchor (ties by anchor id). Unlike farthest-point sampling, which starts at the corners of the floor,
    this places the few beacons where they serve most of the walkable area, as one would install them.
    Fewer than k candidates: all of them."""
    a = anchors[anchors["kind"] == "ble"] if len(anchors) else anchors
    if floor_id is not None and "floor" in a and (a["floor"].astype(str) == str(floor_id)).any():
        a = a[a["floor"].astype(str) == str(floor_id)]
    a = a.assign(anchor_id=a["anchor_id"].astype(str)).sort_values("anchor_id", kind="stable")
    ids = a["anchor_id"].to_numpy()
    xy = a[["x", "y"]].to_numpy(float)
    if len(ids) <= k:
        return list(ids)
    pts = xy
    if floor is not None:
        free = floor.free_points()
        if len(free):
            cell = np.floor(free / grid_m).astype(np.int64)
            _, first = np.unique(cell, axis=0, return_index=True)
            pts = free[np.sort(first)]
    d = np.sqrt(np.sum((pts[:, None, :] - xy[None, :, :]) ** 2, axis=-1))  # (P, A)
    best = np.full(len(pts), np.inf)
    chosen: list[int] = []
    for _ in range(k):  # k greedy rounds, vectorised over candidates and points
        cost = np.minimum(best[:, None], d).mean(axis=0)
        cost[chosen] = np.inf
        j = int(np.argmin(cost))
        chosen.append(j)
        best = np.minimum(best, d[:, j])
    return [str(ids[i]) for i in chosen]


def select_beacons(building, beacons=None, floor_id=None, floor=None) -> tuple[list[str], str | None]:
    """(the model's beacon rows, the subset rule for :attr:`WindowConfig.beacon_subset`) of ``building``.

    ``beacons`` None: every BLE beacon (:func:`beacon_order`), rule None; an int k: the k beacons of
    :func:`spread_beacons` on ``floor_id`` / ``floor`` (exactly the choice of the evaluation's
    ``fixes.sparse_beacons: k``), rule ``"spread:k"``; a list of ids: those, rule ``"list"``. The rows are
    sorted by id either way. Unknown ids, duplicates, an empty list or k < 1 are errors."""
    have = beacon_order(building)
    if beacons is None:
        return have, None
    if isinstance(beacons, bool):
        raise ValueError(f"beacons must be null, a count or a list of BLE anchor ids, got {beacons!r}")
    if isinstance(beacons, (int, np.integer)):
        k = int(beacons)
        if k < 1:
            raise ValueError(f"beacons={k}: need at least one beacon")
        return sorted(spread_beacons(building.anchors, k, floor_id, floor)), f"spread:{k}"
    if isinstance(beacons, str):
        raise ValueError(f"beacons must be null, a count or a list of BLE anchor ids, got the string {beacons!r}")
    ids = [str(b) for b in beacons]
    if not ids:
        raise ValueError("beacons is an empty list: name at least one BLE anchor id (null = all beacons)")
    unknown = sorted(set(ids) - set(have))
    if unknown:
        raise ValueError(f"beacons {unknown} are not BLE anchors of building {building.id!r} "
                         f"(it has {len(have)}: {', '.join(have[:5])}{', ...' if len(have) > 5 else ''})")
    dup = sorted({b for b in ids if ids.count(b) > 1})
    if dup:
        raise ValueError(f"beacons lists {dup} more than once")
    return sorted(ids), "list"


def rssi_to_u(rssi_dbm, offset_db: float, floor_u: float) -> np.ndarray:
    """dBm -> thesis scale u = rssi + offset_db, at least ``floor_u`` for any received packet (float64; NaN
    stays NaN: the caller decides what "not heard" is)."""
    return np.maximum(np.asarray(rssi_dbm, float) + float(offset_db), float(floor_u))


def rssi_to_scale(rssi_dbm: np.ndarray, cfg: WindowConfig) -> np.ndarray:
    """dBm -> thesis scale u with the window settings ``cfg`` (:func:`rssi_to_u`)."""
    return rssi_to_u(rssi_dbm, cfg.offset_db, cfg.floor_u)


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
    empty.unknown = _unknown(r, keep, session, beacons, cfg)
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


def _unknown(r, keep: np.ndarray, session, beacons: list[str], cfg: WindowConfig) -> dict:
    """Packets of anchors outside the model's beacon list: ignored (they are no row of S), counted, said once.
    With a beacon subset (``cfg.beacon_subset``) the building's other BLE beacons are left out on purpose:
    their packets are dropped silently and only anchors the building does not list count as unknown."""
    if keep.all():
        return {}
    other = ~keep
    if cfg.beacon_subset:
        left_out = set(beacon_order(session.building)) - set(beacons)
        other &= ~r["anchor_id"].astype(str).isin(left_out).to_numpy()
        if not other.any():
            return {}
    session_id = session.id
    counts = r.loc[other, "anchor_id"].astype(str).value_counts().to_dict()
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
