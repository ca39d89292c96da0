"""ONNX export of the inertial odometry (issue 31): ``python export.py ckpt=RUN/last.ckpt out=IO_DIR`` on a checkpoint
of ``train.py experiment=inertial`` writes ``inertial.onnx`` and ``meta.json`` into IO_DIR (the contract:
:mod:`blenav.runtime.inertial`).

The graph is the network averaged over ``yaw_ensemble`` turns of its input frame
(:class:`blenav.models.inertial.YawEnsemble`; ``python export.py ... yaw_ensemble=K``): by default
:data:`DEFAULT_YAW_ENSEMBLE` for a network of the attitude's frame (``input_frame: world``, trained with random yaws),
1 for one of the heading frame (exactly yaw-equivariant already). Chosen on the training runs' own validation walks
(``benchmarks/inertial_ensemble.py``, docs/inertial.md); the number is in meta.json and the graph's metadata.

Parity (checked on every export; a failing export is deleted): on random IMU-like windows of three batch sizes and,
with ``python export.py ... data=DIR``, on real windows of DIR's first walks, max |onnx - torch| <=
``TOL`` * max(1, max |torch|) for the velocity and the log variance (1e-4), the ensemble in both.
"""

from __future__ import annotations

import hashlib
import json
from pathlib import Path

import numpy as np
import torch
from torch import nn

from blenav.features.inertial import CHANNELS, InertialGrid
from blenav.models.inertial import InertialNet, YawEnsemble
from blenav.onnx_io import blenav_version, check_weights, json_props, max_diff, session
from blenav.runtime.inertial import INERTIAL_ONNX, KIND, META_JSON

from ..common.onnx_export import DEFAULT_OPSET, export_dir, trace_onnx
from .checkpoint import load_inertial

TOL = 1e-4
#: turns of the frame averaged in an export of a world-frame network (module doc)
DEFAULT_YAW_ENSEMBLE = 4


def yaw_ensemble_of(k, input_frame: str) -> int:
    """The turns an export averages: ``k`` (1 .. 64) or, for None, the default of ``input_frame`` (module doc)."""
    if k is None:
        return DEFAULT_YAW_ENSEMBLE if input_frame == "world" else 1
    if isinstance(k, bool) or not isinstance(k, int) or not 1 <= k <= 64:
        raise ValueError(f"yaw_ensemble must be a whole number of turns 1 .. 64 (or null: {DEFAULT_YAW_ENSEMBLE} for a "
                         f"world-frame network, 1 for a heading-frame one), got {k!r}")
    return k


class _Graph(nn.Module):
    """(batch, n_window, 15) -> (velocity (batch, 2), log_var (batch, 2))."""

    def __init__(self, net: nn.Module):
        super().__init__()
        self.net = net

    def forward(self, imu: torch.Tensor):
        out = self.net(imu)
        return out[:, :2], out[:, 2:]


def sample_windows(n: int, n_window: int, seed: int = 0, rate_hz: float = 50.0) -> torch.Tensor:
    """(n, n_window, 15) float32 IMU-like windows: a 2 Hz gait on the vertical and along a random heading, noise,
    rates of a turning walker (parity inputs in the ranges a walk has)."""
    g = torch.Generator().manual_seed(seed)
    t = torch.arange(n_window, dtype=torch.float32) / float(rate_hz)
    ph = 2 * torch.pi * torch.rand(n, 1, generator=g)
    hd = 2 * torch.pi * torch.rand(n, 1, generator=g)
    gait = torch.sin(2 * torch.pi * 2.0 * t[None] + ph)
    x = torch.randn(n, n_window, len(CHANNELS), generator=g) * torch.tensor([0.4, 0.4, 0.5, 0.1, 0.1, 0.2] + [0.02] * 9)
    x[..., 0] += gait * torch.cos(hd)
    x[..., 1] += gait * torch.sin(hd)
    x[..., 2] += 2.0 * gait
    c, s = torch.cos(hd), torch.sin(hd)
    x[..., 6] += s  # device x axis: to the right of the walking direction
    x[..., 7] -= c
    x[..., 9] += c  # device y axis: along it
    x[..., 10] += s
    x[..., 14] += 1.0  # device z axis: up (a phone held flat)
    return x


def parity(net: nn.Module, path: Path, extra: torch.Tensor | None = None) -> dict[str, float]:
    """Relative max differences onnxruntime vs PyTorch of ``velocity`` and ``log_var`` (module doc)."""
    sess = session(path)
    worst = {"velocity": 0.0, "log_var": 0.0}
    sets = [sample_windows(b, net.n_window, seed=b) for b in (1, 7, 64)]
    if extra is not None and len(extra):
        sets.append(extra)
    for x in sets:
        with torch.no_grad():
            out = net(x).numpy()
        v, lv = sess.run(["velocity", "log_var"], {"imu": x.numpy()})
        worst["velocity"] = max(worst["velocity"], max_diff([v], [out[:, :2]], relative=True))
        worst["log_var"] = max(worst["log_var"], max_diff([lv], [out[:, 2:]], relative=True))
    return worst


def real_windows(data: str | None, grid: InertialGrid, attitude: str = "auto", frame: str = "world", walks: int = 4,
                 n: int = 256, yaw: str = "attitude") -> torch.Tensor | None:
    """Up to ``n`` windows of the first ``walks`` walks with an IMU of the dataset ``data`` (the export's ``data=DIR``,
    given by the user: nothing is read that a checkpoint names), as the network sees them (turned into their heading
    frames for ``frame: heading``); None without ``data``."""
    if not data:
        return None
    from blenav.data import Dataset
    from blenav.errors import MissingStream
    from blenav.features.inertial import heading_frame, windows
    from blenav.filters.inertial_odometry import session_frame_imu

    out = []
    for s in Dataset.open(data).sessions():
        if len(out) >= walks:
            break
        try:
            _, X, _ = session_frame_imu(s, grid, attitude, yaw=yaw)
        except MissingStream:
            continue
        W = windows(X, grid)
        out.append(heading_frame(W)[0] if frame == "heading" else W)
    W = np.concatenate(out)[:n] if out else np.zeros(0)
    return torch.from_numpy(W) if len(W) else None


def export_inertial(net: InertialNet, meta: dict, out: str | Path, opset: int = DEFAULT_OPSET,
                    data: str | None = None, yaw_ensemble: int | None = None) -> Path:
    """Write inertial.onnx and meta.json of ``net`` (eval mode), averaged over ``yaw_ensemble`` turns (module doc), and
    its checkpoint ``meta`` into the directory ``out``; check parity (also on windows of the dataset ``data`` when
    given). Returns the directory."""
    k = yaw_ensemble_of(yaw_ensemble, meta.get("input_frame", "world"))
    out = export_dir(out, "an inertial odometry", "inertial.onnx and meta.json")
    net = net.eval()
    graph = YawEnsemble(net, k).eval()
    grid = meta["grid"]
    info = {
        "kind": KIND, "grid": grid, "channels": list(CHANNELS), "frame": meta.get("frame"),
        "input_frame": meta.get("input_frame", "world"),
        "attitude": meta.get("attitude"), "yaw_ensemble": k, "files": {"model": INERTIAL_ONNX},
        "inputs": {"imu": f"(batch, {net.n_window}, {len(CHANNELS)}) float32: the IMU rotated by the device attitude "
                          f"(device->world) with gravity taken off z, and the device's axes in that frame, resampled "
                          f"linearly to {grid['rate_hz']:g} Hz; channels {list(CHANNELS)} in m/s^2, rad/s and unit "
                          "vectors (blenav.features.inertial); input_frame heading: each window first turned by -psi, its heading "
                          "(blenav.features.inertial.heading_frame)"},
        "ensemble": f"the network averaged over {k} turn(s) of the input frame by 360/{k} deg (velocities turned "
                    "back and averaged; variance: the members' mean plus their spread; "
                    "blenav.models.inertial.YawEnsemble)",
        "outputs": {"velocity": f"(batch, 2) float32 m/s: the mean velocity over the window's last {grid['stride_s']:g} s,"
                                " in the input's frame (input_frame heading: turn it back by +psi)",
                    "log_var": "(batch, 2) float32: log variance ((m/s)^2) of the velocity's error per axis"},
        "units": {"acc": "m/s^2", "gyro": "rad/s", "axes": "unit vectors", "velocity": "m/s", "time": "s"},
        "normalisation": {"mean": net.input_mean.tolist(), "std": net.input_std.tolist(),
                          "applied": "inside the graph: (imu - mean) / std"},
        "model": meta.get("model"), "datasets": meta.get("datasets"), "counts": meta.get("counts"),
        "data_hash": meta.get("data_hash"), "blenav_version": blenav_version(),
    }
    props = json_props(info, ("kind", "grid", "channels", "frame", "input_frame", "attitude", "yaw_ensemble", "units",
                              "normalisation", "blenav_version"))
    path = out / INERTIAL_ONNX
    try:
        trace_onnx(_Graph(graph), (torch.zeros(2, net.n_window, 15),), path, ["imu"], ["velocity", "log_var"],
                   {"imu": {0: "batch"}, "velocity": {0: "batch"}, "log_var": {0: "batch"}}, opset, props,
                   f"blenav inertial odometry ({type(net).__name__}): IMU window -> velocity and log variance")
        grid_obj = InertialGrid(**grid)
        att = meta.get("attitude") or {}
        worst = parity(graph, path, real_windows(data, grid_obj, att.get("attitude", "auto"), info["input_frame"],
                                               yaw=att.get("yaw") or "attitude"))
        if not all(v <= TOL for v in worst.values()):
            raise RuntimeError(f"{out}: onnxruntime differs from PyTorch ({worst}) beyond {TOL:g}; export rejected")
    except Exception:
        path.unlink(missing_ok=True)  # never leave a half or rejected export where an app could pick it up
        raise
    info["parity"] = {"tolerance_rel": TOL, **worst}
    info["sha256"] = {INERTIAL_ONNX: hashlib.sha256(path.read_bytes()).hexdigest()}
    info["weights_sha256"] = {INERTIAL_ONNX: check_weights(path)}
    (out / META_JSON).write_text(json.dumps(info, indent=2, sort_keys=True) + "\n", encoding="utf-8")
    return out


def export_checkpoint(ckpt: str | Path, out: str | Path, opset: int = DEFAULT_OPSET, data: str | None = None,
                      yaw_ensemble: int | None = None) -> Path:
    """``last.ckpt`` of ``train.py experiment=inertial`` -> export directory ``out`` (parity also on ``data``'s walks;
    ``yaw_ensemble``: module doc)."""
    net, meta = load_inertial(ckpt)
    return export_inertial(net, meta, out, opset, data, yaw_ensemble)
