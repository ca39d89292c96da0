"""One stream file of a session folder read and checked against the spec (:func:`load_stream`): plausible
ranges, IMU rate, positions on the floor, quaternions normalised, anchored rows (bursts, rates, exact duplicates,
unknown anchors). The readers (:class:`blenav.data.session.Session`) and ``blenav-validate`` both call it."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd

from .building import Building
from .building_files import FLOOR_MAX_SIDE_M
from .floor import OCCUPIED, Floor, floor_key
from .issues import MAX_ROWS_PER_RULE, Issue, error, warning
from .schema import (
    ANCHORED_STREAMS,
    IMU_MAX_MEAN_DT_S,
    IMU_MIN_MEAN_DT_S,
    IMU_RATE_MIN_ROWS,
    QUAT_MIN_NORM,
    STREAMS,
    plausible,
)
from .tables import _rows_issue, read_stream

#: More than this fraction of a labelled session's ground truth outside its floor's plan is an error.
GT_OFF_FLOOR_MAX = 0.5
#: A world position (ground truth, visual, fixes) further than this outside its floor's plan is an error at its
#: line ('position-off-floor'): no floor is that large (FLOOR_MAX_SIDE_M), so the value is corrupt, or in another
#: unit or frame; one such row among many would otherwise make the error statistics infinite.
POSITION_OFF_FLOOR_MAX_M = FLOOR_MAX_SIDE_M
WORLD_POSITION_STREAMS = ("groundtruth", "visual", "fixes")

#: rssi.csv / rtt.csv: more than BURST_MAX_ROWS rows of one anchor at one time stamp is a warning ('reading-burst')
#: naming the anchor, the time and the count (a logging loop or a replayed buffer; the real datasets have at most
#: 11); an anchor with RATE_MIN_ROWS rows or more heard faster than ANCHOR_MAX_RATE_HZ on average over its rows'
#: span is a warning ('reading-rate'; BLE advertises at most every 20 ms, the real datasets reach 6.5 Hz).
BURST_MAX_ROWS = 100
ANCHOR_MAX_RATE_HZ = 100.0
RATE_MIN_ROWS = 100


def load_stream(root: Path, name: str, building: Building | None, labelled: bool, floor_id=None
                ) -> tuple[pd.DataFrame, list[Issue], dict[str, int]]:
    """Read and check one stream of a session folder; applies every per-stream rule of the spec.

    Returns ``(frame, issues, dropped)``. Rows for unknown anchors are dropped and reported as one warning
    (count and first ids), and so are exact duplicates of anchored rows (kept once; bursts and rates far too
    high are warnings: :func:`reading_bursts`); ``dropped`` counts the rows the reader left out, per reason (the
    rule's name: ``unknown-anchor``, ``duplicate-row``, ``groundtruth-unlabelled``). ``floor_id`` (the session's
    floor) enables the ground-truth-on-floor rule.
    """
    spec = STREAMS[name]
    path = root / spec.filename
    if not path.is_file():
        if name == "groundtruth" and labelled:
            gone = error(path, "groundtruth-missing", "labelled: true but groundtruth.csv is absent")
            return _empty(spec), [gone], {}
        return _empty(spec), [], {}
    df, issues = read_stream(path, spec)
    if df is None:
        return _empty(spec), issues, {}
    if len(df) == 0:
        if name == "imu":
            issues.append(error(path, "empty-required", "imu.csv is present but has no rows"))
        if name == "groundtruth" and labelled:
            issues.append(error(path, "empty-required", "labelled: true but groundtruth.csv has no rows"))
        return _empty(spec), issues, {}
    if name == "groundtruth" and not labelled:
        issues.append(warning(path, "groundtruth-unlabelled",
                              f"labelled: false but groundtruth.csv has {len(df)} rows; they are ignored"))
        return _empty(spec), issues, {"groundtruth-unlabelled": len(df)}
    # Row checks run before unknown-anchor rows are dropped (row index = line - 2) and skip rows whose
    # cells were already reported, so one bad cell is one violation.
    reported = _reported_rows(df, spec, issues)
    more = check_ranges(path, df, name, reported)
    issues += more
    if name == "imu" and not any(i.rule == "time-range" for i in more):
        issues += _check_imu_rate(path, df, reported)
    dropped: dict[str, int] = {}
    far: list[Issue] = []
    if name in WORLD_POSITION_STREAMS and building is not None and floor_key(floor_id, building.floors) is not None:
        far = positions_far_off_floor(path, df, building.floor(floor_id), reported)
        issues += far
    if name == "orientation":  # the phone's orientation estimate: normalised like ground-truth quaternions
        df, more = _check_quaternions(path, df, reported)
        issues += more
    if name == "groundtruth":
        df, more = _check_quaternions(path, df, reported)
        issues += more
        if building is not None and floor_key(floor_id, building.floors) is not None and not far:
            issues += groundtruth_off_floor(path, df[~reported], building.floor(floor_id), building.id)
    if name in ANCHORED_STREAMS:
        issues += reading_bursts(path, df, reported)
        df, more, n_dup = _collapse_duplicates(path, df)
        issues += more
        if n_dup:
            dropped["duplicate-row"] = n_dup
        n = len(df)
        df, more = _check_anchored(path, df, building, name)
        issues += more
        if len(df) < n:
            dropped["unknown-anchor"] = n - len(df)
    return df, issues, dropped


def _empty(spec) -> pd.DataFrame:
    """A stream's frame without rows (the spec's columns and dtypes), built only when returned: 0.15-0.27 ms a
    frame, about 9% of reading every stream of an ILC 2.0 floor when it was built for each."""
    return pd.DataFrame({c: pd.Series(dtype=str if c in spec.string else float) for c in spec.columns})


def reading_bursts(path: Path, df: pd.DataFrame, skip: np.ndarray) -> list[Issue]:
    """Warnings for pathological anchored streams (rows in ``skip`` were already reported, rows are lines - 2):
    'reading-burst', more than :data:`BURST_MAX_ROWS` rows of one anchor at one time stamp (anchor, t, count, at
    the group's first line; the first :data:`MAX_ROWS_PER_RULE` groups, then a count), and 'reading-rate', an
    anchor heard faster than :data:`ANCHOR_MAX_RATE_HZ` on average (see the constants)."""
    ok = ~skip
    t = df["t"].to_numpy(dtype=float)[ok]
    if len(t) < min(RATE_MIN_ROWS, BURST_MAX_ROWS + 1):
        return []
    ids = df["anchor_id"].to_numpy(dtype=object)[ok]
    rows = np.flatnonzero(ok)
    issues: list[Issue] = []
    if len(t) > BURST_MAX_ROWS:
        dt = np.diff(t)
        change = np.flatnonzero(dt != 0)  # runs of one time stamp (t is sorted, else 'time-backwards')
        runs = np.diff(np.concatenate([[0], change + 1, [len(t)]]))
        if runs.max() > BURST_MAX_ROWS or (dt < 0).any():
            g = pd.DataFrame({"t": t, "a": ids, "r": rows}).groupby(["t", "a"], sort=False)["r"].agg(["size", "min"])
            big = g[g["size"] > BURST_MAX_ROWS].sort_values("min")
            for (tt, a), (n, r) in big.head(MAX_ROWS_PER_RULE).iterrows():
                issues.append(warning(path, "reading-burst", f"{n:,} readings of anchor {a!r} at t = {tt:g} s, more "
                                      f"than {BURST_MAX_ROWS} at one instant (a logging loop or a replayed buffer?); "
                                      "exact duplicates are kept once", line=int(r) + 2))
            if len(big) > MAX_ROWS_PER_RULE:
                issues.append(warning(path, "reading-burst", f"{len(big) - MAX_ROWS_PER_RULE} more (anchor, time) "
                                      f"pairs with more than {BURST_MAX_ROWS} readings"))
    if len(t) >= RATE_MIN_ROWS:
        # per anchor (first-seen order; a missing id, already an error, is left out): rows, first and last time
        codes, names = pd.factorize(ids)
        c, tc = codes[codes >= 0], t[codes >= 0]
        n = np.bincount(c, minlength=len(names))
        t0, t1 = np.full(len(names), np.inf), np.full(len(names), -np.inf)
        np.minimum.at(t0, c, tc)  # t of rows not skipped is finite
        np.maximum.at(t1, c, tc)
        span = t1 - t0
        with np.errstate(divide="ignore", invalid="ignore"):
            hz = np.where(n >= RATE_MIN_ROWS, (n - 1) / span, 0.0)  # one instant: infinitely fast
        for k in np.argsort(-hz, kind="stable")[:MAX_ROWS_PER_RULE]:
            if not hz[k] > ANCHOR_MAX_RATE_HZ:
                break
            issues.append(warning(path, "reading-rate", f"anchor {names[k]!r} heard {int(n[k]):,} times within "
                                  f"{span[k]:g} s ({hz[k]:,.0f} Hz on average), faster than any receiver reports one "
                                  f"transmitter ({ANCHOR_MAX_RATE_HZ:g} Hz): duplicated rows, or t in another unit?"))
    return issues


def _collapse_duplicates(path: Path, df: pd.DataFrame) -> tuple[pd.DataFrame, list[Issue], int]:
    """Rows equal in every column to an earlier row (same t, anchor and values) kept once (row = line - 2): the
    frame, one warning ('duplicate-row') and the number of rows dropped; a frame without duplicates is returned
    as it is (the same object)."""
    t = df["t"].to_numpy(dtype=float)
    if len(t) < 2:
        return df, [], 0
    same, back = t[1:] == t[:-1], (t[1:] < t[:-1]).any()
    if not (same.any() or back):
        return df, [], 0  # duplicates share a time stamp: in a sorted stream none adjacent means none at all
    if not back and not np.isnan(t).any():
        # sorted: duplicates share a run of equal t and an anchor id (a missing one: code 0); no (run, anchor)
        # pair twice (the real scans: many anchors at one t, each once) means no duplicate, without comparing rows
        codes = pd.factorize(df["anchor_id"].to_numpy(dtype=object))[0].astype(np.int64) + 1
        key = np.sort(np.concatenate([[0], np.cumsum(~same)]) * (int(codes.max()) + 1) + codes)
        if not (key[1:] == key[:-1]).any():
            return df, [], 0
    dup = df.duplicated(keep="first").to_numpy()
    n = int(dup.sum())
    if not n:
        return df, [], 0
    return df[~dup].reset_index(drop=True), [warning(
        path, "duplicate-row", f"{n:,} rows repeat an earlier row exactly (same t, anchor and values; the first "
        f"at line {int(np.flatnonzero(dup)[0]) + 2}); each reading is kept once")], n


def positions_far_off_floor(path: Path, df: pd.DataFrame, floor: Floor, skip: np.ndarray) -> list[Issue]:
    """Rows whose world position (x, y) lies more than :data:`POSITION_OFF_FLOOR_MAX_M` outside the floor's plan:
    one error per row (capped), 'position-off-floor'. Rows in ``skip`` were already reported."""
    xy = df[["x", "y"]].to_numpy(dtype=float)
    x0, x1, y0, y1 = floor.extent
    with np.errstate(invalid="ignore"):
        d = np.maximum.reduce([x0 - xy[:, 0], xy[:, 0] - x1, y0 - xy[:, 1], xy[:, 1] - y1, np.zeros(len(xy))])
        bad = np.flatnonzero((d > POSITION_OFF_FLOOR_MAX_M) & ~skip)
    out = [error(path, "position-off-floor", f"({xy[r, 0]:g}, {xy[r, 1]:g}) m lies {d[r]:g} m outside floor "
                 f"{floor.id!r}'s plan (x {x0:.1f}..{x1:.1f}, y {y0:.1f}..{y1:.1f} m), further than any floor is large "
                 f"({POSITION_OFF_FLOOR_MAX_M:g} m): a corrupt value, or another unit or frame?", line=int(r) + 2)
           for r in bad[:MAX_ROWS_PER_RULE]]
    if len(bad) > MAX_ROWS_PER_RULE:
        out.append(error(path, "position-off-floor", f"{len(bad) - MAX_ROWS_PER_RULE} more rows further than "
                         f"{POSITION_OFF_FLOOR_MAX_M:g} m outside the plan (lines {int(bad[MAX_ROWS_PER_RULE]) + 2}.."
                         f"{int(bad[-1]) + 2})"))
    return out


def check_ranges(path: Path, df: pd.DataFrame, name: str, skip: np.ndarray) -> list[Issue]:
    """Values outside the plausible range of their column (:func:`blenav.data.schema.plausible`): one error
    per row and column (capped per column), naming the value; rows in ``skip`` were already reported."""
    spec = STREAMS[name]
    issues: list[Issue] = []
    for c in spec.present(df.columns):
        p = plausible(name, c)
        if p is None or c in spec.string:
            continue
        v = df[c].to_numpy(dtype=float)
        bad = np.flatnonzero(p.outside(v) & ~skip)
        for r in bad[:MAX_ROWS_PER_RULE]:
            issues.append(error(path, p.rule, f"{c} {v[r]:g} {p.unit} is outside {p.describe()}: {p.hint}",
                                line=int(r) + 2))
        if len(bad) > MAX_ROWS_PER_RULE:
            issues.append(error(path, p.rule, f"{c}: {len(bad) - MAX_ROWS_PER_RULE} more rows outside "
                                f"{p.describe()} (lines {int(bad[MAX_ROWS_PER_RULE]) + 2}..{int(bad[-1]) + 2})"))
    return issues


def _check_imu_rate(path: Path, df: pd.DataFrame, skip: np.ndarray) -> list[Issue]:
    t = df["t"].to_numpy(dtype=float)[~skip]
    if len(t) < IMU_RATE_MIN_ROWS:
        return []
    dt = (t[-1] - t[0]) / (len(t) - 1)
    if dt < IMU_MIN_MEAN_DT_S:
        return [error(path, "imu-rate", f"{len(t)} rows within {t[-1] - t[0]:g} s, one every {dt:g} s on average: no "
                      f"inertial sensor samples faster than every {IMU_MIN_MEAN_DT_S:g} s; does t advance, in seconds?")]
    if dt <= IMU_MAX_MEAN_DT_S:
        return []
    return [error(path, "imu-rate", f"{len(t)} rows over {t[-1] - t[0]:g} s, one every {dt:g} s on average: an "
                  f"inertial sensor samples far faster than every {IMU_MAX_MEAN_DT_S:g} s; is t in milliseconds?")]


def groundtruth_off_floor(path: Path, gt: pd.DataFrame, floor: Floor, building_id: str) -> list[Issue]:
    """A labelled session whose ground truth lies mostly (> :data:`GT_OFF_FLOOR_MAX`) outside its floor's plan
    (the image's extent) names the wrong building or floor, or the plan's resolution/origin is wrong."""
    xy = gt[["x", "y"]].to_numpy(dtype=float)
    if len(xy) == 0:
        return []
    x0, x1, y0, y1 = floor.extent
    outside = (xy[:, 0] < x0) | (xy[:, 0] > x1) | (xy[:, 1] < y0) | (xy[:, 1] > y1)
    off = float(np.mean(outside))
    if off <= GT_OFF_FLOOR_MAX:
        # on the plan, a walk goes through free space: mostly on obstacles, the image is inverted (or the origin,
        # resolution or thresholds are wrong). Real and simulated data: at most 2% on occupied pixels.
        on = floor.lookup(xy[~outside])
        occ = float(np.mean(on == OCCUPIED)) if len(on) else 0.0
        if occ <= GT_OFF_FLOOR_MAX:
            return []
        return [error(path, "groundtruth-in-obstacles",
                      f"{occ:.0%} of the ground truth on the floor plan of building {building_id} floor {floor.id!r} "
                      f"lies on occupied pixels of {floor.image_path.name}: is the image inverted (negate: 1 in "
                      "building.yaml), or are its origin, resolution or thresholds wrong?")]
    return [error(path, "groundtruth-off-floor",
                  f"{off:.0%} of the ground truth lies outside the floor plan of building {building_id} floor "
                  f"{floor.id!r} (x {x0:.1f}..{x1:.1f}, y {y0:.1f}..{y1:.1f} m); are 'building' and 'floor' in "
                  "session.yaml right, and the floor's resolution and origin in building.yaml?")]


def _reported_rows(df: pd.DataFrame, spec, issues: list[Issue]) -> np.ndarray:
    """Rows (bool mask) with a cell error already reported by the table checks."""
    out = np.zeros(len(df), dtype=bool)
    for c in spec.present(df.columns):
        if c in spec.string:
            continue
        v = df[c].to_numpy(dtype=float)
        out |= ~np.isfinite(v) if c in spec.required else np.isinf(v)
    for i in issues:  # e.g. not-a-number in a nullable column (read as NaN, like an empty cell)
        if i.is_error and i.line is not None and 2 <= i.line < len(df) + 2:
            out[i.line - 2] = True
    return out


def _check_anchored(path: Path, df: pd.DataFrame, building: Building | None, name: str):
    if building is None:  # unknown or unreadable building: already reported where it is named or defined
        return df, []
    if len(building.anchors) == 0:
        return df, [error(path, "anchors-missing", f"{name}.csv has rows but the building has no anchors.csv "
                          "(or it is empty)")]
    df["anchor_id"] = df["anchor_id"].fillna("").astype(str).str.strip()
    # an empty id is already an error ('empty-value'), not an unknown anchor
    drop = (~df["anchor_id"].isin(set(building.anchors["anchor_id"])) & (df["anchor_id"] != "")).to_numpy()
    if not drop.any():
        return df, []
    unknown = df.loc[drop, "anchor_id"]
    first = ", ".join(unknown.drop_duplicates().head(5))
    issue = warning(path, "unknown-anchor", f"{int(drop.sum())} rows name anchors not in anchors.csv "
                    f"({unknown.nunique()} ids, first: {first}); these rows are dropped")
    return df[~drop].reset_index(drop=True), [issue]


def _check_quaternions(path: Path, df: pd.DataFrame, skip: np.ndarray | None = None):
    """Normalise quaternions; rows in ``skip`` (already reported) are not checked again."""
    q = df[["qw", "qx", "qy", "qz"]].to_numpy(float)
    ok = np.ones(len(q), dtype=bool) if skip is None else ~skip
    isnan = np.isnan(q)
    if isnan[ok].all():
        return df, []
    partial = np.flatnonzero(isnan.any(axis=1) & ok)
    issues: list[Issue] = []
    if len(partial):
        issues += _rows_issue(path, "quaternion-partial", partial,
                              "orientation is empty on this row but not on others (empty on every row, or none)")
        return df, issues
    norm = np.linalg.norm(q, axis=1)
    bad = np.flatnonzero((norm < QUAT_MIN_NORM) & ok)
    if len(bad):
        issues += _rows_issue(path, "quaternion-norm", bad, f"quaternion norm below {QUAT_MIN_NORM}")
        return df, issues
    with np.errstate(invalid="ignore", divide="ignore"):  # skipped rows are errors: the frame is not used
        df[["qw", "qx", "qy", "qz"]] = q / norm[:, None]
    return df, issues
