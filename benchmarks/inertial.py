"""Learned inertial odometry (issue 31): ONNX parity, the streaming step with the network in the loop, and training time.

Given an export directory (``python export.py ckpt=RUN/last.ckpt out=IO_DIR``) and a dataset with IMU walks:

* parity: the export's own record (meta.json ``parity``: max relative |onnxruntime - PyTorch| on random and real windows,
  gate 1e-4), and, when ``--ckpt RUN/last.ckpt`` is given, the same measured here on the dataset's first walk's windows;
* streaming step: what a phone does, through the push API's own code (:class:`blenav.filters.inertial_odometry.StreamingLio`,
  the walk's rotation vector or AHRS pushed with its IMU in time order): per IMU sample (rotate, resample) and per
  stride (0.5 s: the sample that completes a window, with its heading frame, one onnxruntime call on one window and the
  track advanced); median and p99 of the stride's, against the 5 ms target (ratio <= 1: met); and the largest
  difference of the live track from the batch one (:func:`~blenav.filters.inertial_odometry.lio_odometry`);
* batch throughput: the whole walk's windows in one call (what the evaluation does), ms per walk-minute;
* the stated uncertainty: the growth of the track's variance per axis (``var`` of
  :func:`blenav.filters.inertial_odometry.lio_odometry`, m^2 per s of walk: what ``motion.odo_var_scale`` scales),
  median and 10-90 % over every step of the walks, beside Roy's fixed 0.1 m^2/s;
* training time: ``RUN/training.json``'s ``fit_wall_s`` and steps, when ``--ckpt`` is given;
* ``--int8``: the graph dynamically quantised to int8 weights (onnxruntime.quantization, as the bundle's localizer):
  its size, one window's latency, the largest velocity difference, and the segment error (|(p(b) - p(a)) -
  (g(b) - g(a))| over each waypoint segment, the challenge's measure) of the float and int8 tracks on the walks.

    .venv/bin/python benchmarks/inertial.py IO_DIR DATA [--walks 5] [--ckpt RUN/last.ckpt] [--int8]
"""

from __future__ import annotations

import argparse
import json
import os
import time
from pathlib import Path

import numpy as np

from blenav.data import Dataset
from blenav.features.inertial import heading_frame, rotate_velocity, windows
from blenav.filters.attitude import AttitudeConfig
from blenav.filters.inertial_odometry import StreamingLio, world_frame_imu
from blenav.filters.measurement import AnchorTable
from blenav.filters.pdr_odometry import attitude_track, resolve_heading
from blenav.filters.runner import hard_iron_offset
from blenav.filters.steps import SessionArrays
from blenav.runtime.inertial import InertialModel

TARGET_MS = 5.0


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("io_model", help="an export directory of python export.py on a train.py experiment=inertial run")
    ap.add_argument("data", help="a dataset with IMU walks")
    ap.add_argument("--walks", type=int, default=5)
    ap.add_argument("--ckpt", default=None, help="the run's last.ckpt: parity measured here and its training time")
    ap.add_argument("--int8", action="store_true", help="also the int8-quantised graph: size, latency, accuracy")
    args = ap.parse_args()
    model = InertialModel(args.io_model)
    g = model.grid
    print(f"load average {os.getloadavg()[0]:.2f}; model {args.io_model}: {model.meta['model']['net']['_target_']}, "
          f"{g.rate_hz:g} Hz, window {g.window_s:g} s, stride {g.stride_s:g} s, frame {model.frame}")
    print(f"parity at export: {model.meta['parity']}")
    walks = [s for s in Dataset.open(args.data).sessions() if (s.root / "imu.csv").is_file()][: args.walks]
    step_ms, sample_ms, live_diff, batch_ms, minutes, growth = [], [], 0.0, 0.0, 0.0, []
    for s in walks:
        cache: dict = {}  # the walk's attitude (an AHRS run) once, for every track below
        odo = model.odometry(s, cache=cache)
        growth.append(np.diff(odo["var"].to_numpy(float)) / np.diff(odo["t"].to_numpy(float)))
        imu = s.imu
        t, acc, gyr = imu["t"].to_numpy(float), imu[["ax", "ay", "az"]].to_numpy(float), imu[["gx", "gy", "gz"]].to_numpy(float)
        q_t, q = attitude_track(s, model.attitude, cache=cache)  # what the phone pushes (its rotation vector)
        _, X = world_frame_imu(t, acc, gyr, *attitude_track(s, model.attitude, cache=cache, yaw=model.yaw), g.rate_hz)
        a = time.perf_counter()
        W = windows(X, g)
        W, psi = heading_frame(W) if model.frame == "heading" else (W, None)
        v, lv = model.predict(W)
        if psi is not None:
            rotate_velocity(v, lv, psi)
        batch_ms += 1e3 * (time.perf_counter() - a)
        minutes += (t[-1] - t[0]) / 60.0
        # streaming: the push API's StreamingLio, its samples in time order (the batch path's attitude source; the
        # AHRS with the walk's hard-iron offset as the batch fits it)
        source = resolve_heading(s, model.attitude)  # the reference track's own source
        off = hard_iron_offset(SessionArrays.from_session(s, AnchorTable.empty()), AttitudeConfig())
        lio = StreamingLio(model, source, mag_offset=off, gyro_calibrated=s.gyro_calibrated)
        ev = [(float(tm), 1, qq) for tm, qq in zip(q_t, q)] if source == "orientation" else \
            [(float(tm), 0, m) for tm, m in zip(s.mag["t"].to_numpy(float), s.mag[["mx", "my", "mz"]].to_numpy(float))]
        ev += [(float(tm), 2, i) for i, tm in enumerate(t)]
        pts = []
        for e in sorted(ev, key=lambda e: (e[0], e[1])):
            if e[1] == 0:
                lio.push_mag(e[0], e[2])
            elif e[1] == 1:
                pts += lio.push_orientation(e[0], e[2])
            else:
                a = time.perf_counter()
                new = lio.push_imu(e[0], acc[e[2]], gyr[e[2]])
                dt_ms = 1e3 * (time.perf_counter() - a)
                (step_ms if any(p[0] > t[0] for p in new) else sample_ms).append(dt_ms)
                pts += new
        live = np.array([[p[0], *p[1], p[2]] for p in pts])
        ref = odo[["t", "x", "y", "var"]].to_numpy(float)
        live_diff = max(live_diff, float(np.abs(live - ref).max()) if live.shape == ref.shape else float("inf"))
    st = np.array(step_ms)
    med, p99 = float(np.median(st)), float(np.percentile(st, 99))
    print(f"streaming (StreamingLio, the push API's): per IMU sample median {np.median(sample_ms):.3f} ms "
          f"({len(sample_ms)} samples); per stride, the window's network run included ({len(st)} strides of "
          f"{len(walks)} walks): median {med:.2f} ms, p99 {p99:.2f} ms; target {TARGET_MS:g} ms: ratio "
          f"{p99 / TARGET_MS:.2f} (p99); live track vs batch track: largest difference {live_diff:.1e}")
    print(f"batch (the evaluation): {batch_ms / max(minutes, 1e-9):.1f} ms per walk-minute over {minutes:.1f} min")
    gr = np.concatenate(growth) if growth else np.zeros(0)
    if len(gr):
        lo, med_g, hi = np.percentile(gr, [10, 50, 90])
        print(f"stated variance growth per axis: median {med_g:.3f} m^2/s (10-90 %: {lo:.3f}-{hi:.3f}) over {len(gr)} "
              f"steps; Roy's fixed noise 0.1 m^2/s")
    if args.int8:
        int8(model, walks)
    if args.ckpt:
        import torch

        from blenav.learn.inertial.checkpoint import load_inertial

        net, _ = load_inertial(args.ckpt)
        s = walks[0]
        q_t, q = attitude_track(s, model.attitude, yaw=model.yaw)
        imu = s.imu
        _, X = world_frame_imu(imu["t"].to_numpy(float), imu[["ax", "ay", "az"]].to_numpy(float),
                               imu[["gx", "gy", "gz"]].to_numpy(float), q_t, q, g.rate_hz)
        W, _ = heading_frame(windows(X, g)) if model.frame == "heading" else (windows(X, g), None)
        v, lv = model.predict(W)
        with torch.no_grad():
            ref = net(torch.from_numpy(W)).numpy()
        scale = max(1.0, float(np.abs(ref).max()))
        print(f"parity here ({len(W)} windows of {s.id}): velocity {np.abs(v - ref[:, :2]).max() / scale:.2e}, "
              f"log_var {np.abs(lv - ref[:, 2:]).max() / scale:.2e} (gate 1e-4)")
        tj = Path(args.ckpt).parent / "training.json"
        if tj.is_file():
            info = json.loads(tj.read_text())
            d = info.get("data", {}).get("train", {})
            print(f"training: {info.get('steps')} steps ({info.get('stop_reason')}), {info.get('fit_wall_s') or float('nan'):.0f} s "
                  f"wall on {d.get('walks')} walks / {d.get('segment_s', 0) / 60:.0f} min of supervised segments; best "
                  f"validation segment error {info.get('best_val_error_m') or float('nan'):.3f} m vs PDR "
                  f"{info.get('baseline_val_error_m') or float('nan'):.3f} m")


class _Graph:
    """An onnxruntime session of an inertial graph with :class:`blenav.filters.inertial_odometry.VelocityModel`'s
    protocol (the int8 graph), so :func:`~blenav.filters.inertial_odometry.lio_odometry` runs it as it runs the float
    one."""

    def __init__(self, like: InertialModel, sess, tag: str):
        self.grid, self.frame, self.sess, self.key = like.grid, like.frame, sess, f"{tag}:{like.key}"
        self.yaw = like.yaw

    def predict(self, W):
        return tuple(self.sess.run(["velocity", "log_var"], {"imu": np.ascontiguousarray(W, np.float32)}))


def int8(model: InertialModel, walks: list) -> None:
    """The int8 graph against the float one on ``walks`` (see the module docstring)."""
    import contextlib
    import io
    import logging
    import tempfile

    from onnxruntime.quantization import QuantType, quantize_dynamic

    from blenav.eval.metrics import segment_errors
    from blenav.filters.inertial_odometry import lio_odometry, session_frame_imu
    from blenav.onnx_io import session

    g = model.grid
    src = Path(model.root) / "inertial.onnx"
    with tempfile.TemporaryDirectory() as tmp:
        dst = Path(tmp) / "inertial.int8.onnx"
        logging.disable(logging.WARNING)  # the quantiser's progress lines and graph dumps
        with contextlib.redirect_stdout(io.StringIO()):
            quantize_dynamic(str(src), str(dst), weight_type=QuantType.QInt8)
        logging.disable(logging.NOTSET)
        graphs = {"float": model, "int8": _Graph(model, session(dst, 1), "int8")}
        dv, seg, lat = 0.0, {"float": [], "int8": []}, {"float": [], "int8": []}
        for s in walks:
            gt = s.groundtruth
            cache: dict = {}  # the walk's attitude once for both graphs
            for name, m in graphs.items():  # each graph's track, as the evaluation makes it
                odo = lio_odometry(s, m, model.attitude, cache=cache)
                seg[name].append(segment_errors(odo["t"].to_numpy(float), odo[["x", "y"]].to_numpy(float)[None],
                                                gt["t"].to_numpy(float), gt[["x", "y"]].to_numpy(float))["err"][0])
            _, X, _ = session_frame_imu(s, g, model.attitude, cache=cache, yaw=model.yaw)  # the walk's windows: the velocity difference and one window's latency
            W = heading_frame(windows(X, g))[0] if model.frame == "heading" else windows(X, g)
            dv = max(dv, float(np.abs(graphs["float"].predict(W)[0] - graphs["int8"].predict(W)[0]).max()))
            for name, m in graphs.items():
                for _ in range(20):
                    a = time.perf_counter()
                    m.predict(W[-1:])
                    lat[name].append(1e3 * (time.perf_counter() - a))
        e = {k: np.concatenate(v) for k, v in seg.items()}
        print(f"int8: {dst.stat().st_size / 1e3:.0f} kB vs float {src.stat().st_size / 1e3:.0f} kB; one window "
              f"{np.median(lat['int8']):.3f} ms vs {np.median(lat['float']):.3f} ms; largest velocity difference "
              f"{dv:.4f} m/s; segment error ({len(e['float'])} segments) mean {e['int8'].mean():.3f} m vs float "
              f"{e['float'].mean():.3f} m (median {np.median(e['int8']):.3f} vs {np.median(e['float']):.3f})")

if __name__ == "__main__":
    main()
