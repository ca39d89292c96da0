"""How much of the fingerprints' error is the survey's density (issue 29 / 30): a KNN on a floor's WiFi + BLE windows,
scored on the test walks' windows (label: the waypoint interpolation at the window's time, as the KNN rows' training
labels), with three reference sets:

* ``survey``: the train walks' windows (the KNN rows' own);
* ``+ others, true labels`` (an oracle bound, not a method: it reads the other test walks' ground truth): every other
  test walk's windows labelled by their waypoint interpolation; what a survey twice as dense would give;
* ``+ others, ROW's labels`` (with ``--eval OUT --row ROW``): the other test walks' windows labelled by a row's
  trajectory of an evaluation of the same floor (``OUT/<session>/trajectories/<ROW>.tum``; fused-offline: no ground
  truth), as :class:`blenav.localizers.crowd.CrowdFingerprint` does (without its label filter and std).

A walk's own windows are never in its reference set (the KNN's ``exclude``, as the crowd's). Setting: the one
cross-validated on the train walks over the KNN rows' grid (``blenav.localizers.fingerprint.CV_GRID``, as
KNN-WiFi+BLE chooses it), printed with the results.

    .venv/bin/python benchmarks/survey_density.py FLOOR_DATA [--eval OUT --row fused-offline]
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from blenav.cli.realwalks import experiment_config
from blenav.eval.config import parse_eval_config
from blenav.eval.sessions import open_dataset, scored_sessions, train_test
from blenav.features import fingerprints as FP
from blenav.localizers import knn as KNN
from blenav.localizers.crowd import track_labels
from blenav.localizers.fingerprint import CV_GRID

CFG = FP.FingerprintConfig(features="both", wifi_age_ref="scan", wifi_time="heard")


def _labelled(session, columns):
    w, _ = FP.label_windows(session, FP.session_windows(session, columns, CFG))
    ok = w.heard & np.isfinite(w.xy).all(axis=1)
    return w.S[ok], w.xy[ok], w.t[ok]


def _track_labels(path: Path, t: np.ndarray) -> np.ndarray:
    """The TUM trajectory ``path`` at times t (K,) s (held at its ends, as the scoring holds them)."""
    tr = np.loadtxt(path, ndmin=2)  # TUM: t x y z qx qy qz qw
    return track_labels(np.clip(t, tr[0, 0], tr[-1, 0]), tr[:, 0], tr[:, 1:3])[1]


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("data")
    p.add_argument("--eval", type=Path, help="an evaluation's output folder on the same floor")
    p.add_argument("--row", default="fused-offline", help="the row of --eval whose trajectories label the others")
    args = p.parse_args()
    cfg = parse_eval_config(experiment_config(f"data={args.data}"))
    ds = open_dataset(cfg)
    train, test = train_test(cfg, ds, scored_sessions(cfg, ds))
    tables, used = FP.readable(train, CFG)
    names = FP.vocabulary(tables, 1)
    columns = {n: i for i, n in enumerate(names)}
    is_ble = np.array([n.startswith("ble:") for n in names])
    survey = [_labelled(s, columns) for s in used]
    S, xy, T = (np.concatenate(a) for a in zip(*survey))
    walk_of = np.concatenate([np.full(len(w[0]), i) for i, w in enumerate(survey)])
    waypoints = [(s.groundtruth["t"].to_numpy(float), s.groundtruth[["x", "y"]].to_numpy(float)) for s in used]
    settings = KNN.grid(CV_GRID["metric"], CV_GRID["k"], CV_GRID["weights"], CV_GRID["ble_weight"])
    setting, _ = KNN.cross_validate(S, xy, T, walk_of, waypoints, settings, is_ble, CFG.fill_dbm, CV_GRID["folds"])
    walks = [_labelled(s, columns) for s in test]
    sets = {"survey": None, "+ others, true labels (oracle bound)": [w[1] for w in walks]}
    if args.eval is not None:
        sets[f"+ others, {args.row}'s labels"] = [
            _track_labels(args.eval / s.id / "trajectories" / f"{args.row}.tum", w[2]) for s, w in zip(test, walks)]
    print(f"{args.data}: {len(used)} train walks ({len(S)} windows), {len(test)} test walks "
          f"({sum(len(w[0]) for w in walks)} windows); KNN {setting} (cross-validated on the train walks)")
    for name, labels in sets.items():
        groups = [np.full(len(w[0]), s.id, object) for s, w in zip(test, walks)] if labels is not None else []
        model = KNN.fit(np.concatenate([S] + ([w[0] for w in walks] if labels is not None else [])),
                        np.concatenate([xy] + (labels or [])), setting, is_ble, CFG.fill_dbm, 1.0,
                        groups=np.concatenate([np.full(len(S), "", object)] + groups))
        e = np.concatenate([np.hypot(*(model(w[0], exclude=s.id)[0] - w[1]).T) for s, w in zip(test, walks)
                            if len(w[0])])
        print(f"{name:42s} mean {e.mean():6.2f}  median {np.median(e):6.2f}  p90 {np.percentile(e, 90):6.2f} m")


if __name__ == "__main__":
    main()
