"""How far a learned inertial odometry's displacements are from the truth, against the std it states (issue 31, the
back-end's between-factors: ``backend.odometry.var_scale``): on every pedestrian walk with a dense ground-truth
trajectory (simulated walks), the track of :func:`blenav.filters.inertial_odometry.lio_odometry` (the model's own
attitude and yaw) over windows of W seconds, |(p(t + W) - p(t)) - (g(t + W) - g(t))| mean, beside the stated std
per axis sqrt(var(t + W) - var(t)) (median) and the true displacement's mean length.

    .venv/bin/python benchmarks/lio_displacement.py IO_DIR DATA [--windows 1 10]
"""

from __future__ import annotations

import argparse

import numpy as np

from blenav.data import Dataset
from blenav.runtime.inertial import InertialModel


def displacement_errors(t: np.ndarray, xy: np.ndarray, var: np.ndarray, gt: np.ndarray, window_s: float):
    """(error mean m, stated std median m, true length mean m) over windows of ``window_s`` starting at every track
    point (t (T,) s evenly spaced, xy / gt (T, 2) m, var (T,) m^2 accumulated); None when the track is shorter."""
    n = int(round(window_s / float(np.median(np.diff(t)))))
    if n < 1 or len(t) <= n:
        return None
    i, j = np.arange(len(t) - n), np.arange(n, len(t))
    err = np.linalg.norm((xy[j] - xy[i]) - (gt[j] - gt[i]), axis=1)
    return float(err.mean()), float(np.median(np.sqrt(var[j] - var[i]))), float(np.linalg.norm(gt[j] - gt[i], axis=1).mean())


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("io_dir")
    p.add_argument("data")
    p.add_argument("--windows", type=float, nargs="+", default=[1.0, 10.0])
    args = p.parse_args()
    model = InertialModel(args.io_dir)
    ds = Dataset.open(args.data)
    print(f"{args.data}: model {args.io_dir} (attitude {model.attitude}, yaw {model.yaw})")
    print(f"{'session':36s} {'window':>7s} {'error':>7s} {'stated std':>10s} {'true length':>11s}")
    for sid in ds.session_ids:
        s = ds.session(sid)
        if s.carrier != "pedestrian" or not s.labelled or s.groundtruth_sparse:
            continue
        tr = model.odometry(s)
        t = tr["t"].to_numpy(float)
        gt = s.positions_at(t)
        for w in args.windows:
            r = displacement_errors(t, tr[["x", "y"]].to_numpy(float), tr["var"].to_numpy(float), gt, w)
            if r is not None:
                print(f"{sid:36s} {w:6.1f}s {r[0]:6.2f}m {r[1]:9.3f}m {r[2]:10.2f}m")


if __name__ == "__main__":
    main()
