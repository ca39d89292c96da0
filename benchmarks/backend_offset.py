"""The receiver's RSSI offset in the back-end (issue 14 sec. 4, issue 32): as a variable of the graph
(``range.estimate_offset``) or refitted between LM passes (``range.refit_channel``: level, or level and exponent).

One simulated 384 s office walk and a copy whose RSSI reads 10 dB low (every row of rssi.csv shifted); the path
loss fitted on the normal walk, the IMU front-end run on each, then the back-end (LM) on the first
``--window`` seconds: plain, with the offset variable, with the offset and the exponent as variables
(``range.estimate_exponent``), with the channel refit (level; line). Printed: the offset estimate (the variables'
with their std; the refit's level and exponent), the smoothed RMSE against the ground truth, and the solve time (the
variables' range factors are GTSAM CustomFactors with a Python error function, ``range.channel_group`` keyframes'
ranges to one factor; the refit is a second LM pass on plain range factors).

    .venv/bin/python benchmarks/backend_offset.py [--window 60]
"""

from __future__ import annotations

import argparse
import os
import shutil
import tempfile
import time
from pathlib import Path

import numpy as np
import pandas as pd

from blenav.backend.config import load_backend_config
from blenav.backend.graph import smooth
from blenav.backend.inputs import (beacon_priors, keyframes_from_front_end, path_loss_model, session_attitude,
                                   session_imu, session_ranges)
from blenav.backend.loop import window_inputs
from blenav.cli.sim import run as sim_run
from blenav.configs import compose
from blenav.data import Dataset
from blenav.eval.harness import build_methods
from blenav.filters.calibration import apply_fit, fit_sessions
from blenav.filters.runner import run_session


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--window", type=float, default=60.0)
    ap.add_argument("--low-db", type=float, default=10.0)
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        normal, low = Path(tmp) / "office", Path(tmp) / "office_low"
        sim_run(compose("sim", "sim=office_45x55", "seed=0", f"out={normal}", "duration_s=384", "sessions=1",
                        "progress=false"))
        shutil.copytree(normal, low)
        for f in (low / "sessions").glob("*/rssi.csv"):
            r = pd.read_csv(f)
            r["rssi"] = r["rssi"] - args.low_db
            r.to_csv(f, index=False)
        sid = Dataset.open(normal).session_ids[0]
        fit = fit_sessions([Dataset.open(normal).session(sid)])
        print(f"path loss fitted on the normal receiver: a_X {fit.a_x:.1f} dBm, gamma {fit.gamma:.2f}; the copy reads "
              f"{args.low_db:g} dB low; back-end (LM) on the first {args.window:g} s")
        print(f"{'receiver':10s} {'offset':>15s} {'offset [dB]':>24s} {'RMSE [m]':>9s} {'solve [s]':>9s}")
        for root, name in ((normal, "normal"), (low, f"-{args.low_db:g} dB")):
            s = Dataset.open(root).session(sid)
            m = build_methods(compose("eval", "experiment=frontend_000", "data=x", "filter.n_particles=300"))["IMU"].method
            apply_fit(m.measurements, fit)
            front = run_session(m, s, 1, seed=0)
            att = session_attitude(s)
            for mode in ("none", "variable", "variables", "refit level", "refit line"):
                cfg = load_backend_config(overrides=["solver.method=lm",
                                                     f"range.estimate_offset={mode.startswith('variable')}",
                                                     f"range.estimate_exponent={mode == 'variables'}",
                                                     f"range.refit_channel={mode.split()[-1] if 'refit' in mode else 'none'}",
                                                     f"range.a_x={fit.a_x}", f"range.gamma={fit.gamma}",
                                                     f"range.d0={fit.d0}"])
                a = s.building.anchors_of("ble")
                bp = beacon_priors(a, cfg.priors.beacon_sigma_m, cfg.priors.beacon_sigma_z_m)
                sel = front.t < front.t[0] + args.window
                kf, _ = keyframes_from_front_end(front.t[sel], front.position[:, sel], *att, cfg)
                imu, ranges = window_inputs(session_imu(s), session_ranges(s, bp, path_loss_model(cfg), a), kf.t[0], kf.t[-1])
                t0 = time.perf_counter()
                res = smooth(cfg, kf, imu, ranges, bp)
                dt = time.perf_counter() - t0
                gt = s.positions_at(kf.t)
                rmse = float(np.sqrt(np.mean(np.sum((res.position[:, :2] - gt) ** 2, -1))))
                off = "-"
                if mode.startswith("variable"):
                    off = f"{res.offset_db:+.2f} +- {res.offset_std_db:.2f}"
                    if mode == "variables":
                        off += f" (exponent {res.channel_exponent:.2f} +- {res.channel_exponent_std:.2f})"
                elif np.isfinite(res.channel_offset_db):
                    off = f"{res.channel_offset_db:+.2f} (exponent {res.channel_exponent:.2f})"
                print(f"{name:10s} {mode:>15s} {off:>24s} {rmse:9.2f} {dt:9.2f}")
        print(f"load average {os.getloadavg()[0]:.2f}")


if __name__ == "__main__":
    main()
