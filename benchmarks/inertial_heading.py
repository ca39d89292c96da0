"""Where the learned odometry's heading error comes from (issue 31): the segment error of the plain odometry tracks of a
floor's test walks (the split of ``experiment=realwalks``) with each yaw source, beside PDR's on the same attitude.

* ``attitude``: the rotation vector's own yaw (magnetic north, wandering with the field indoors);
* ``gyro``: the gyroscope's yaw held to the rotation vector's running mean (:mod:`blenav.filters.yaw_hold`);
* ``gyro + walk offset (oracle)``: that track turned by its own walk's median segment angle, measured against the
  ground truth: not a method (it reads the test walk's waypoints), the bound on what estimating one heading offset
  per walk could give: what the walk-constant part of the rotation vector's error costs.

The tracks are the odometry itself (:func:`blenav.filters.inertial_odometry.lio_odometry`,
:func:`blenav.filters.pdr_odometry.pdr_odometry` with the default 0.7 m step, ``DEFAULT_STEP_M``), not the PF rows of the evaluation (whose
cloud's mean adds a few centimetres). Segment error: |(p(b) - p(a)) - (g(b) - g(a))| per waypoint segment, mean (m);
heading: the median absolute angle of the segments of 2 m or more (deg).

    .venv/bin/python benchmarks/inertial_heading.py IO_DIR FLOOR_DATA
"""

from __future__ import annotations

import argparse

import numpy as np

from blenav.cli.realwalks import experiment_config
from blenav.eval.config import parse_eval_config
from blenav.eval.metrics import MIN_SEGMENT_FOR_ANGLE_M, pool_segment_errors, segment_errors
from blenav.eval.sessions import open_dataset, scored_sessions, train_test
from blenav.filters.inertial_odometry import lio_odometry
from blenav.filters.pdr_odometry import DEFAULT_STEP_M, pdr_odometry
from blenav.runtime.inertial import InertialModel


def _segments(track, gt) -> dict:
    return segment_errors(track["t"].to_numpy(float), track[["x", "y"]].to_numpy(float)[None],
                          gt["t"].to_numpy(float), gt[["x", "y"]].to_numpy(float))


def _turned(track, angle_deg: float):
    a = np.radians(angle_deg)
    out = track.copy()
    x, y = track["x"].to_numpy(float), track["y"].to_numpy(float)
    out["x"], out["y"] = np.cos(a) * x - np.sin(a) * y, np.sin(a) * x + np.cos(a) * y
    return out


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("io_dir")
    p.add_argument("data")
    args = p.parse_args()
    cfg = parse_eval_config(experiment_config(f"data={args.data}"))
    ds = open_dataset(cfg)
    _, test = train_test(cfg, ds, scored_sessions(cfg, ds))
    model = InertialModel(args.io_dir)
    trained = model.yaw  # its own; each row below sets the yaw it runs with
    rows: dict[str, list] = {}
    for s in test:
        gt = s.groundtruth
        if len(gt) < 2:
            continue
        for yaw in ("attitude", "gyro"):
            model.yaw = yaw
            track = lio_odometry(s, model)
            seg = _segments(track, gt)
            rows.setdefault(f"LIO, yaw {yaw}", []).append(seg)
            rows.setdefault(f"PDR, yaw {yaw}", []).append(
                _segments(pdr_odometry(s, "orientation", DEFAULT_STEP_M, yaw=yaw), gt))
            long = seg["true"] >= MIN_SEGMENT_FOR_ANGLE_M
            if yaw == "gyro" and long.any():
                off = float(np.median(seg["angle"][0, long]))
                rows.setdefault("LIO, yaw gyro + walk offset (oracle)", []).append(_segments(_turned(track, -off), gt))
    model.yaw = trained
    print(f"{args.data}: {len(test)} test walks, model {args.io_dir} (trained with yaw {trained})")
    print(f"{'track':40s} {'segment mean':>12s} {'length':>7s} {'heading':>8s} {'segments':>8s}")
    for name, segs in rows.items():
        r = pool_segment_errors(segs)
        print(f"{name:40s} {r['mean']:12.3f} {r['length_abs_mean']:7.3f} {r['heading_abs_median_deg']:8.2f} "
              f"{r['segments']:8d}")


if __name__ == "__main__":
    main()
