"""ONNX export of the Map Prior Network (Roy, section 3.2.2) in two graphs plus ``meta.json``.

``python export.py ckpt=RUN/last.ckpt out=DIR`` on a map prior checkpoint writes into DIR:

- ``map_encoder.onnx`` (run once per floor): input ``mask`` (1, 1, H, W) float32, the floor's free mask at
  ``resolution_m`` (1 = free, 0 = obstacle/unknown; row 0 on top), H and W multiples of ``size_multiple``
  (zero-pad bottom/right, zero = obstacle; crop the output back) -> ``dmt`` (1, c, H, W), the Deep Map Tensor.
  H, W (and the batch) are dynamic.
- ``trajectory_encoder.onnx`` (run per step and heading hypothesis): input ``odometry`` (batch, n_points, 2)
  float32, positions in metres relative to the window start, world-aligned axes (x east, y north),
  ``n_points`` samples at ``step_hz`` (the graph divides by ``resolution_m`` itself) -> ``dtv`` (batch, c).
- ``meta.json``: kind, resolution_m, window {window_s, step_hz, n_points}, channels, size_multiple, how to
  resample a floor and score (eq. 3.8: S = dmt[:, row, col] . dtv, log floor), the model node, buildings,
  data_hash, blenav_version, the parity numbers, ``sha256`` (of each .onnx file) and ``weights_sha256`` (of
  each graph's weights, :mod:`blenav.onnx_io`). The same entries but the hashes and parity, as JSON strings,
  are in each graph's ``metadata_props``, with the graph's own ``weights_sha256`` and
  ``weights_sha256_tensors``. :class:`blenav.runtime.map_prior.MapPrior` checks both hashes on load and
  refuses a directory whose files were changed after export.

The dot product of eq. 3.8 is not a graph: it is c multiply-adds per particle, done where the DMT lives
(:class:`blenav.runtime.map_prior.MapPrior` with the export directory does it in numpy).

Parity (checked on every export; a failing export is deleted): on random masks of two sizes (one not a
multiple of size_multiple, padded as the runtime does) and random walks of three batch sizes,
max |onnx - torch| <= ``TOL`` * max(1, max |torch|) for the DMT, the DTV and the scores S at every pixel
(1e-4, relative to the output's scale when that exceeds 1).
"""

from __future__ import annotations

import hashlib
import json
from pathlib import Path

import numpy as np
import torch
from torch import nn

from blenav.features.mapgrid import pad_to_multiple
from blenav.models.mapprior import MapPriorNet
from blenav.onnx_io import blenav_version, check_weights, json_props, max_diff, session
from blenav.runtime.map_prior import LOG_FLOOR, MAP_ENCODER_ONNX, META_JSON, SCORE_FLOOR, TRAJECTORY_ENCODER_ONNX

from ..common.onnx_export import DEFAULT_OPSET, export_dir, trace_onnx
from .checkpoint import load_mapprior

TOL = 1e-4


class _MapGraph(nn.Module):
    def __init__(self, net: MapPriorNet):
        super().__init__()
        self.enc = net.map_encoder

    def forward(self, mask: torch.Tensor) -> torch.Tensor:
        return self.enc.forward_padded(mask)


class _TrajectoryGraph(nn.Module):
    """(batch, n_points, 2) metres -> DTV (batch, c): divides by resolution_m, then g(O)."""

    def __init__(self, net: MapPriorNet, resolution_m: float):
        super().__init__()
        self.enc, self.inv_res = net.trajectory_encoder, 1.0 / float(resolution_m)

    def forward(self, odometry: torch.Tensor) -> torch.Tensor:
        return self.enc(odometry * self.inv_res)


def parity(net: MapPriorNet, out_dir: Path, resolution_m: float, seed: int = 0) -> dict[str, float]:
    """Relative max differences onnxruntime vs PyTorch: ``dmt``, ``dtv``, ``score`` (see module doc)."""
    g = torch.Generator().manual_seed(seed)
    k = net.map_encoder.size_multiple
    map_sess, traj_sess = session(out_dir / MAP_ENCODER_ONNX), session(out_dir / TRAJECTORY_ENCODER_ONNX)
    worst = {"dmt": 0.0, "dtv": 0.0, "score": 0.0}
    for (h, w), batch in zip(((37, 52), (4 * k, 3 * k)), (1, 3)):
        mask = (torch.rand(h, w, generator=g) > 0.3).float()
        odo_m = torch.cumsum(torch.randn(batch, net.n_points, 2, generator=g), dim=1)
        odo_m = odo_m - odo_m[:, :1]
        with torch.no_grad():
            dmt_t = net.encode_map(mask[None, None]).numpy()[0]
            dtv_t = net.encode_trajectory(odo_m / resolution_m).numpy()
        padded = pad_to_multiple(mask.numpy(), k)
        dmt_o = map_sess.run(["dmt"], {"mask": padded[None, None]})[0][0, :, :h, :w]
        dtv_o = traj_sess.run(["dtv"], {"odometry": odo_m.numpy()})[0]
        s_t = np.einsum("chw,bc->bhw", dmt_t, dtv_t)
        s_o = np.einsum("chw,bc->bhw", dmt_o, dtv_o)
        for key, got, ref in (("dmt", dmt_o, dmt_t), ("dtv", dtv_o, dtv_t), ("score", s_o, s_t)):
            worst[key] = max(worst[key], max_diff([got], [ref], relative=True))
    return worst


def export_mapprior(net: MapPriorNet, meta: dict, out: str | Path, opset: int = DEFAULT_OPSET) -> Path:
    """Write the two graphs and meta.json of a map prior (``net`` in eval mode, ``meta`` of its checkpoint) into
    the directory ``out``; check parity. Returns the directory."""
    out = export_dir(out, "a map prior", "two .onnx files and meta.json")
    net = net.eval()
    res = float(meta["resolution_m"])
    k = net.map_encoder.size_multiple
    c = net.c
    w = meta["window"]
    info = {
        "kind": "mapprior", "resolution_m": res, "window": w, "channels": c, "size_multiple": k,
        "files": {"map_encoder": MAP_ENCODER_ONNX, "trajectory_encoder": TRAJECTORY_ENCODER_ONNX},
        "inputs": {
            "mask": f"(1, 1, H, W) float32 free mask at resolution_m (1 free, 0 obstacle/unknown), row 0 on top, "
                    f"H and W zero-padded bottom/right to multiples of {k}; crop dmt back",
            "odometry": f"(batch, {w['n_points']}, 2) float32 metres relative to the window start, world axes "
                        f"(x east, y north), {w['step_hz']:g} Hz"},
        "outputs": {"dmt": f"(1, {c}, H, W) float32 Deep Map Tensor",
                    "dtv": f"(batch, {c}) float32 Deep Trajectory Vector"},
        "resample": ("floor free mask (occupancy == FREE) to resolution_m on a grid with the floor's lower-left "
                     "origin, H2 = round(H * res / resolution_m): coarser -> free only if every covered pixel is free; "
                     "finer -> nearest pixel centre (blenav.features.mapgrid.resample_free)"),
        "score": "S(x) = dmt[:, row(x), col(x)] . dtv (eq. 3.8, Roy); log score = log(max(S, score_floor))",
        "score_floor": SCORE_FLOOR, "log_floor": LOG_FLOOR,
        "model": meta.get("model"), "buildings": meta.get("buildings"), "val_buildings": meta.get("val_buildings"),
        "data_hash": meta.get("data_hash"), "target": meta.get("target"), "blenav_version": blenav_version(),
        # what it was trained on (floors, datasets, session ids, waypoint ground truth interpolated)
        **{k: meta[k] for k in ("floors", "datasets", "sessions", "waypoint_sessions") if k in meta},
    }
    props = json_props(info, ("kind", "resolution_m", "window", "channels", "size_multiple", "score",
                              "blenav_version"))
    paths = [out / MAP_ENCODER_ONNX, out / TRAJECTORY_ENCODER_ONNX, out / META_JSON]
    try:
        trace_onnx(_MapGraph(net), (torch.zeros(1, 1, 4 * k, 5 * k),), paths[0], ["mask"], ["dmt"],
                   {"mask": {0: "batch", 2: "H", 3: "W"}, "dmt": {0: "batch", 2: "H", 3: "W"}}, opset, props,
                   f"blenav map prior: map encoder f(M) at {res:g} m/px -> DMT (c = {c})")
        trace_onnx(_TrajectoryGraph(net, res), (torch.zeros(2, int(w["n_points"]), 2),), paths[1], ["odometry"],
                   ["dtv"], {"odometry": {0: "batch"}, "dtv": {0: "batch"}}, opset, props,
                   f"blenav map prior: trajectory encoder g(O), {w['n_points']} points in metres -> DTV (c = {c})")
        worst = parity(net, out, res)
        if not all(v <= TOL for v in worst.values()):
            raise RuntimeError(f"{out}: onnxruntime differs from PyTorch ({worst}) beyond {TOL:g}; export rejected")
    except Exception:
        for p in paths:
            p.unlink(missing_ok=True)  # never leave a half or rejected export where an app could pick it up
        raise
    info["parity"] = {"tolerance_rel": TOL, **worst}
    info["sha256"] = {p.name: hashlib.sha256(p.read_bytes()).hexdigest() for p in paths[:2]}
    info["weights_sha256"] = {p.name: check_weights(p) for p in paths[:2]}
    paths[2].write_text(json.dumps(info, indent=2, sort_keys=True) + "\n", encoding="utf-8")
    return out


def export_checkpoint(ckpt: str | Path, out: str | Path, opset: int = DEFAULT_OPSET) -> Path:
    """``last.ckpt`` of ``train.py experiment=mapprior`` -> export directory ``out``."""
    net, meta = load_mapprior(ckpt)
    return export_mapprior(net, meta, out, opset)
