"""Which beacon map the methods get, and how far the maps they return are from the truth (000, Figs. 3-5).

``beacon_map`` block of an experiment (schema :class:`BeaconMapConfig`)::

    beacon_map:
      source: given     # given: anchors.csv's x, y, z; true: its x_true, y_true, z_true (a simulation; a dataset
                        #   without them keeps the given map, said in results.json)
      noise_m: 0.0      # per-axis std (m) of a perturbation drawn anew for every run (000 sec. VI: N(0, 3 I),
                        #   "up to 3 x 3 m away along each axis": 3 m)
      vertical: true    # perturb z as well (000 perturbs in 3-D)
      per_walk: true    # a draw per walk and run; false: run r gives every walk the same draw (one deployed map)
      seed: 0

With ``noise_m > 0`` every run of every method is a separate call on the session with its own perturbed map;
run r of session i gets the same map for every method (paired comparison); with ``per_walk: false`` every session
of run r gets it (a building's walks then share one wrong map, as a deployment's do: what pooling the walks to
correct it needs, ``benchmarks/pooled_map.py``).

Metrics: for a method whose estimate has ``outputs['beacon_map']``, ``beacon_error_m = {prior, optimized}``: the
mean horizontal distance over beacons and runs between the true positions (``x_true, y_true`` when the dataset
has them, else anchors.csv) and the map the method was given / the map it returned. Beacons the method did not
optimize count with their prior position (its map holds them there). ``beacon_error_m.by_heard``: the same per bin
of how often a beacon was heard in the session (its rssi.csv rows; bins :data:`HEARD_BINS`), pooled over sessions
and runs (issue 32: "the error per beacon against how often it was heard").
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np
import pandas as pd

from blenav.backend.mapping import mean_map  # noqa: F401  (re-exported: runs' maps averaged)
from blenav.localizers.base import Estimate

from .metrics import finite_number

TRUE_COLS = ("x_true", "y_true", "z_true")


@dataclass
class BeaconMapConfig:
    source: str = "given"  # given | true
    noise_m: float = 0.0  # m, per axis, per run
    vertical: bool = True
    per_walk: bool = True  # a draw per (session, run); false: per run, shared by every session
    seed: int = 0

    def __post_init__(self):
        self.source = str(self.source).lower()  # `beacon_map.source=true` on a command line arrives as 'True'
        if self.source not in ("given", "true"):
            raise ValueError(f"beacon_map.source must be 'given' or 'true', got {self.source!r}")
        if not (np.isfinite(self.noise_m) and self.noise_m >= 0):
            raise ValueError(f"beacon_map.noise_m must be a non-negative number of metres, got {self.noise_m!r}")

    @property
    def perturbed(self) -> bool:
        return self.noise_m > 0


def has_truth(anchors: pd.DataFrame) -> bool:
    return all(c in anchors for c in TRUE_COLS[:2]) and bool(
        np.isfinite(anchors[list(TRUE_COLS[:2])].to_numpy(float)).all())


def true_xy(anchors: pd.DataFrame) -> pd.DataFrame:
    """anchor_id -> true x, y (x_true, y_true when known, else x, y) of the BLE anchors."""
    a = anchors[anchors["kind"] == "ble"] if "kind" in anchors else anchors
    cols = ["x_true", "y_true"] if has_truth(a) else ["x", "y"]
    return pd.DataFrame(a[cols].to_numpy(float), columns=["x", "y"], index=a["anchor_id"].astype(str))


def with_source(sessions: list, cfg: BeaconMapConfig) -> tuple[list, dict]:
    """The sessions with their buildings' maps from ``cfg.source`` (one building object per building), and
    what was done, per building."""
    if cfg.source == "given":
        return sessions, {}
    new, info = {}, {}
    for s in sessions:
        b = s.building
        if b.id in new:
            continue
        a = b.anchors
        if has_truth(a):
            a = a.copy()
            z = "z_true" if "z_true" in a and np.isfinite(a["z_true"].to_numpy(float)).all() else "z"
            a[["x", "y", "z"]] = a[["x_true", "y_true", z]].to_numpy(float)
            new[b.id], info[b.id] = replace(b, anchors=a), "true beacon positions (x_true, y_true, z_true)"
        else:
            new[b.id], info[b.id] = b, "the dataset has no true beacon positions: anchors.csv as given"
    return [s.with_building(new[s.building.id]) for s in sessions], info


#: bins of rssi.csv rows per beacon for ``beacon_error_m.by_heard``: [0, 10), [10, 50), [50, 200), [200, inf)
HEARD_BINS = (0, 10, 50, 200)


def heard_bins() -> list[tuple[int, int | None, str]]:
    """(from, to, label) of each :data:`HEARD_BINS` bin: rssi.csv rows in [from, to) (to None: no upper end), label
    ``"from-(to-1)"`` or ``"from+"`` as the tables print it."""
    edges = list(HEARD_BINS) + [None]
    return [(lo, hi, f"{lo}-{hi - 1}" if hi is not None else f"{lo}+") for lo, hi in zip(edges[:-1], edges[1:])]


def checked_by_heard(entries) -> dict[str, dict]:
    """label -> entry of a results.json's ``by_heard`` list (maybe a stranger's): only entries whose from / to are one
    of :func:`heard_bins`' bins, with an int ``beacons`` and finite (or null optimized) errors; anything else is left
    out, so what a file holds cannot add columns or break a table."""
    known = {(lo, hi): label for lo, hi, label in heard_bins()}
    out: dict[str, dict] = {}
    for e in entries if isinstance(entries, list) else []:
        if not isinstance(e, dict):
            continue
        label = known.get((e.get("from"), e.get("to")))
        if label and isinstance(e.get("beacons"), int) and finite_number(e.get("given_m")) is not None \
                and (e.get("optimized_m") is None or finite_number(e.get("optimized_m")) is not None):
            out[label] = e
    return out


def heard_counts(session) -> pd.Series:
    """anchor_id -> rssi.csv rows of the session (0 for a beacon never heard)."""
    r = session.rssi
    return r["anchor_id"].astype(str).value_counts() if len(r) else pd.Series(dtype=int)


def beacon_rows(given: pd.DataFrame, optimized: pd.DataFrame | None, truth: pd.DataFrame,
                heard: pd.Series) -> pd.DataFrame:
    """One row per beacon of ``truth`` in ``given``: heard (rssi.csv rows), given_m and optimized_m (horizontal
    error of the given map and of ``optimized``, m; NaN where that map lacks the beacon)."""
    def err(m):
        if m is None or not len(m):
            return pd.Series(np.nan, index=truth.index)
        m = m.assign(anchor_id=m["anchor_id"].astype(str)).drop_duplicates("anchor_id").set_index("anchor_id")
        xy = m.reindex(truth.index)[["x", "y"]].to_numpy(float)
        return pd.Series(np.hypot(*(xy - truth[["x", "y"]].to_numpy(float)).T), index=truth.index)

    g = err(given)
    keep = g.notna()
    return pd.DataFrame({"anchor_id": truth.index[keep], "heard": heard.reindex(truth.index[keep]).fillna(0).astype(int)
                         .to_numpy(), "given_m": g[keep].to_numpy(), "optimized_m": err(optimized)[keep].to_numpy()})


def by_heard(rows: pd.DataFrame | list[pd.DataFrame]) -> list[dict]:
    """Per :data:`HEARD_BINS` bin of ``rows`` (:func:`beacon_rows`, or a list of them, pooled): from / to (rssi rows; to
    None for the last), beacons, given_m and optimized_m (mean horizontal errors, m); empty bins left out."""
    if isinstance(rows, list):
        rows = pd.concat(rows, ignore_index=True)
    out = []
    for lo, hi, _ in heard_bins():
        m = (rows["heard"] >= lo) & ((rows["heard"] < hi) if hi is not None else True)
        if m.any():
            opt = rows.loc[m, "optimized_m"]
            out.append({"from": lo, "to": hi, "beacons": int(m.sum()), "given_m": float(rows.loc[m, "given_m"].mean()),
                        "optimized_m": float(opt.mean()) if opt.notna().any() else None})
    return out


def perturb(building, cfg: BeaconMapConfig, session_index: int, run: int):
    """``building`` with every BLE anchor moved by N(0, noise_m^2) per axis (z too when ``vertical``), seeded by
    (seed, session, run), or by (seed, run) without ``per_walk``; the stated ``std_m`` is kept."""
    rng = np.random.default_rng([int(cfg.seed), int(session_index) if cfg.per_walk else 0, int(run)])
    a = building.anchors.copy()
    ble = (a["kind"] == "ble").to_numpy() if "kind" in a else np.ones(len(a), bool)
    cols = ["x", "y", "z"] if cfg.vertical else ["x", "y"]
    a.loc[ble, cols] = a.loc[ble, cols].to_numpy(float) + cfg.noise_m * rng.standard_normal((int(ble.sum()), len(cols)))
    # anchors.csv's std_m (the map's stated uncertainty) is left as it was: as in 000, the methods are not told
    # how wrong the map is (telling the back-end, 3 m priors, made its beacons worse: docs/results-000-002.md)
    return replace(building, anchors=a)


def map_error(bmap: pd.DataFrame | None, truth: pd.DataFrame) -> float | None:
    """Mean horizontal distance (m) between ``bmap`` (anchor_id, x, y) and ``truth`` over their common beacons."""
    if bmap is None or not len(bmap):
        return None
    m = bmap.assign(anchor_id=bmap["anchor_id"].astype(str)).set_index("anchor_id")
    common = truth.index.intersection(m.index)
    if not len(common):
        return None
    d = m.loc[common, ["x", "y"]].to_numpy(float) - truth.loc[common, ["x", "y"]].to_numpy(float)
    return float(np.mean(np.hypot(d[:, 0], d[:, 1])))


def given_map(building) -> pd.DataFrame:
    a = building.anchors_of("ble")
    return pd.DataFrame({"anchor_id": a["anchor_id"].astype(str), "x": a["x"].to_numpy(float),
                         "y": a["y"].to_numpy(float)})


def run_per_run_maps(method, session, si: int, runs: int, seed: int, inputs_for, cfg: BeaconMapConfig) -> Estimate:
    """``method`` on ``session`` once per run, each run with its own perturbed map; the estimates stacked
    (``outputs['beacon_error']`` holds the per-run prior / optimized errors). ``inputs_for(session)``: the run's
    :class:`~blenav.localizers.inputs.RunInputs` for the session with that run's map (its fixes resolved on it); the
    method gets them with ``run`` = r."""
    truth = true_xy(session.building.anchors)
    heard = heard_counts(session)
    ests, prior_err, opt_err, rows = [], [], [], []
    seeds = np.random.SeedSequence(int(seed)).generate_state(runs)
    for r in range(runs):
        b = perturb(session.building, cfg, si, r)
        s = session.with_building(b)
        est = method.run(s, 1, int(seeds[r]), inputs_for(s).for_run(r))
        prior_err.append(map_error(given_map(b), truth))
        opt_err.append(map_error(est.outputs.get("beacon_map"), truth))
        if est.outputs.get("beacon_map") is not None:
            rows.append(beacon_rows(given_map(b), est.outputs["beacon_map"], truth, heard))
        ests.append(est)
    out = stack_runs(ests)
    out.outputs["beacon_error"] = {"prior": prior_err, "optimized": opt_err}
    if rows:
        out.outputs["beacon_rows"] = pd.concat(rows, ignore_index=True)
    return out


def stack_runs(ests: list[Estimate]) -> Estimate:
    """One-run estimates of the same method and session as one R-run estimate (arrays with a run axis of 1
    concatenated, beacon maps averaged, events renumbered, times summed)."""
    e0 = ests[0]
    pos = np.concatenate([e.position for e in ests])
    cov = np.concatenate([e.cov for e in ests]) if all(e.cov is not None for e in ests) else None
    events = [replace(ev, run=r) for r, e in enumerate(ests) for ev in e.events]
    outputs = {}
    for k, v in e0.outputs.items():
        if isinstance(v, np.ndarray) and v.ndim >= 1 and v.shape[0] == 1:
            outputs[k] = np.concatenate([e.outputs[k] for e in ests])
        elif k == "beacon_map" and isinstance(v, pd.DataFrame):
            outputs[k] = mean_map([e.outputs[k] for e in ests if e.outputs.get(k) is not None])
        else:
            outputs[k] = v
    notes = []
    for e in ests:
        notes += [n for n in e.notes if n not in notes]
    return Estimate(e0.method, e0.session, e0.t, pos, cov, events, outputs, sum(e.wall_s for e in ests), notes)


def optimized_anchors(building, bmap: pd.DataFrame) -> pd.DataFrame:
    """anchors.csv rows of the building's BLE anchors with x, y, z from ``bmap`` and its std_m / status columns
    (the corrected anchors a user loads as a new map)."""
    a = building.anchors_of("ble").copy()
    a["anchor_id"] = a["anchor_id"].astype(str)
    m = bmap.assign(anchor_id=bmap["anchor_id"].astype(str)).set_index("anchor_id")
    have = a["anchor_id"].isin(m.index).to_numpy()
    ids = a.loc[have, "anchor_id"]
    a.loc[have, ["x", "y", "z"]] = m.loc[ids, ["x", "y", "z"]].to_numpy(float)
    for c in ("std_m", "status"):
        if c in m:
            a[c] = np.nan if c == "std_m" else ""
            a.loc[have, c] = m.loc[ids, c].to_numpy()
    return a


__all__ = ["BeaconMapConfig", "with_source", "perturb", "map_error", "run_per_run_maps", "stack_runs", "mean_map",
           "optimized_anchors", "true_xy", "given_map", "HEARD_BINS", "heard_bins", "checked_by_heard", "heard_counts",
           "beacon_rows", "by_heard"]
