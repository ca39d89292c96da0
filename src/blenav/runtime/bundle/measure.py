"""How a bundle's variants compare with its float models: per graph the file size, the latency of one call and the
largest output difference, and per variant the whole pipeline's error on labelled sessions (the manifest's
``measured``, written by :func:`blenav.runtime.bundle.write.finish_bundle`)."""

from __future__ import annotations

import json
import time
from pathlib import Path

import numpy as np

from blenav.features.mapgrid import pad_to_multiple
from blenav.onnx_io import session

from .format import LOCALIZER, MAP_DIR, MAP_GRAPHS, VARIANTS, graph_paths, variant_name
from .read import Bundle


def _latency_ms(sess, feeds: dict, reps: int) -> dict:
    sess.run(None, feeds)
    ts = []
    for _ in range(reps):
        t0 = time.perf_counter()
        sess.run(None, feeds)
        ts.append((time.perf_counter() - t0) * 1e3)
    return {"median": float(np.median(ts)), "p90": float(np.percentile(ts, 90)), "reps": reps}


def _feeds(base: str, sess, meta_prior: dict | None, mask: np.ndarray | None, seed: int = 0) -> dict:
    rng = np.random.default_rng(seed)
    ins = sess.get_inputs()
    if base == LOCALIZER:
        B, H = int(ins[0].shape[1]), int(ins[0].shape[2])
        L, Hd = int(ins[1].shape[0]), int(ins[1].shape[2])
        S = (rng.uniform(0, 70, (1, B, H)) * (rng.uniform(size=(1, B, H)) < 0.7)).astype(np.float32)
        z = np.zeros((L, 1, Hd), np.float32)
        return {"S": S, "h0": z, "c0": z}
    if base.endswith(MAP_GRAPHS[0]):
        m = mask if mask is not None else np.ones((64, 64), np.float32)
        return {"mask": pad_to_multiple(m.astype(np.float32), int(meta_prior["size_multiple"]))[None, None]}
    n = int(meta_prior["window"]["n_points"])
    steps = rng.normal(0, 0.7, (36, n, 2)).cumsum(axis=1)
    return {"odometry": (steps - steps[:, :1]).astype(np.float32)}


def measure_variants(root: Path, has_prior: bool, dataset_sessions: list | None = None, reps: int = 200,
                     seed: int = 0) -> dict:
    """Per graph and variant: file size, latency of one call on one thread (the localizer: one window; the trajectory
    encoder: 36 heading windows; the map encoder: the floor, once per building) and the largest output difference
    from the float graph on the same inputs; per variant, with ``dataset_sessions`` (labelled sessions of the
    bundle's building), the whole pipeline's RMSE against ground truth and its change from the float bundle."""
    meta_prior = json.loads((root / MAP_DIR / "meta.json").read_text()) if has_prior else None
    mask = None
    if dataset_sessions:
        fl = dataset_sessions[0].floor
        if has_prior:
            from blenav.features.mapgrid import net_grid

            mask = net_grid(fl, float(meta_prior["resolution_m"]))[1].astype(np.float32)
    out: dict = {"graphs": {}, "pipeline": {}}
    for base in graph_paths(has_prior):
        ref_out = None
        per = {}
        for v in VARIANTS:
            p = root / variant_name(base, v)
            if not p.is_file():
                continue
            sess = session(p, 1)
            feeds = _feeds(base, sess, meta_prior, mask, seed)
            res = sess.run(None, feeds)
            r = {"file": p.name, "bytes": p.stat().st_size,
                 "latency_ms": _latency_ms(sess, feeds, 3 if base.endswith(MAP_GRAPHS[0]) else reps)}
            if ref_out is None:
                ref_out = res
            else:
                r["max_abs_diff_vs_float"] = float(max(np.max(np.abs(a - b)) for a, b in zip(res[:1], ref_out[:1])))
            per[v] = r
        fl = per.get("float", {})
        for v, r in per.items():
            if v != "float" and fl:
                r["size_vs_float"] = r["bytes"] / fl["bytes"]
                r["latency_vs_float"] = r["latency_ms"]["median"] / fl["latency_ms"]["median"]
        out["graphs"][base] = per
    if dataset_sessions:
        for v in VARIANTS:
            try:
                b = Bundle.open(root, variant=v, verify=False)
            except ValueError:
                continue
            errs, ferrs, steps = [], [], 0
            t0 = time.perf_counter()
            for s in dataset_sessions:
                est = b.run_session(s, seed=seed)
                t = np.array([e.t for e in est])
                xy = np.array([[e.x, e.y] for e in est])
                gt = s.groundtruth
                ok = (t >= gt["t"].iloc[0]) & (t <= gt["t"].iloc[-1])
                errs.append(np.hypot(*(xy[ok] - s.positions_at(t[ok])).T))
                fx = np.array(b.last_fixes)
                if len(fx):
                    okf = (fx[:, 0] >= gt["t"].iloc[0]) & (fx[:, 0] <= gt["t"].iloc[-1])
                    ferrs.append(np.hypot(*(fx[okf, 1:] - s.positions_at(fx[okf, 0])).T))
                steps += len(est)
            e = np.concatenate(errs)
            fe = np.concatenate(ferrs) if ferrs else np.zeros(0)
            out["pipeline"][v] = {"rmse_m": float(np.sqrt(np.mean(e ** 2))), "mean_m": float(e.mean()),
                                  "fix_rmse_m": float(np.sqrt(np.mean(fe ** 2))) if len(fe) else None,
                                  "steps": int(steps), "wall_s": time.perf_counter() - t0}
        ref = out["pipeline"].get("float")
        for v, r in out["pipeline"].items():
            if ref and v != "float":
                r["rmse_change_m"] = r["rmse_m"] - ref["rmse_m"]
        out["pipeline_sessions"] = [s.id for s in dataset_sessions]
    return out

