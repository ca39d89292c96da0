"""Per-window latency of the exported cross-phone localizer: onnxruntime vs PyTorch eager, one thread, batch 1.

Default model sizes (conf/model/transnet_locnet.yaml and conf/model/locnet.yaml), B = 50 beacons, H = 5 steps.
Weights are untrained (latency does not depend on them) but the ONNX file is written by the same code
path as ``python export.py`` (:func:`blenav.learn.crossphone.export.export_module`, with its checks). One call = one
window with explicit LSTM state in and out (the streaming step of an app). Median over ``--calls`` calls
after ``--warmup`` calls; the target is 1 ms per window (Roy measured about 20 ms for the BLE model on an
iPhone 8 with PyTorch mobile, section 4).

    .venv/bin/python benchmarks/onnx_speed.py [--calls 2000] [--beacons 50] [--history 5]
"""

from __future__ import annotations

import argparse
import tempfile
from pathlib import Path

import torch
from omegaconf import OmegaConf

from blenav.configs import compose
from blenav.features.scale import U_SCALE
from blenav.features.windows import WindowConfig
from blenav.learn.crossphone.checkpoint import build_networks
from blenav.learn.crossphone.export import export_module, random_inputs, streaming_net
from blenav.learn.crossphone.module import CrossPhoneModule
from blenav.runtime import OnnxLocalizer
from timing import median_ms

TARGET_MS = 1.0


def build(model: str, B: int, H: int):
    """An untrained module and a checkpoint-like meta for ``conf/model/<model>.yaml``."""
    model_cfg = OmegaConf.to_container(compose("train", f"model={model}", "data.path=x").model, resolve=True)
    with torch.random.fork_rng():  # fixed init without touching the caller's global RNG
        torch.manual_seed(0)
        locnet, transnet = build_networks(model_cfg, B)
    module = CrossPhoneModule(locnet, transnet).eval()
    w = WindowConfig(history=H)
    meta = {"model": model_cfg, "beacons": [f"ble-{i:03d}" for i in range(B)], "building": "bench",
            "window": {"history": w.history, "step_hz": w.step_hz, "offset_db": w.offset_db, "floor_u": w.floor_u,
                       "u_scale": U_SCALE}, "data_hash": None, "train_devices": [], "known_devices": [],
            "unlabelled_devices": []}
    return module, meta




def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--calls", type=int, default=2000)
    ap.add_argument("--warmup", type=int, default=200)
    ap.add_argument("--beacons", type=int, default=50)
    ap.add_argument("--history", type=int, default=5)
    args = ap.parse_args()
    if args.calls < 1000:
        ap.error("--calls must be at least 1000")
    torch.set_num_threads(1)
    B, H = args.beacons, args.history
    print(f"B = {B} beacons, H = {H} steps, batch 1, 1 thread, median of {args.calls} calls after {args.warmup}")
    print(f"{'model':16s} {'params':>8s} {'onnx [KiB]':>10s} {'ORT [ms]':>9s} {'step() [ms]':>11s} "
          f"{'torch [ms]':>10s} {'torch/ORT':>9s}")
    verdict = None
    with tempfile.TemporaryDirectory() as tmp:
        for model in ("locnet", "transnet_locnet"):
            module, meta = build(model, B, H)
            path = export_module(module, meta, Path(tmp) / f"{model}.onnx")
            loc = OnnxLocalizer(path, threads=1)
            net = streaming_net(module, meta)
            S, h0, c0 = random_inputs(B, H, loc.layers, loc.hidden, batch=1, seed=1, u_max=70.0)
            feed = {"S": S.numpy(), "h0": h0.numpy(), "c0": c0.numpy()}
            sess = loc.session

            def ort_call():
                sess.run(None, feed)

            def torch_call():
                with torch.no_grad():
                    net(S, h0, c0)

            S_np = S.numpy()
            ort_ms = median_ms(ort_call, args.calls, args.warmup)
            step_ms = median_ms(lambda: loc.step(S_np), args.calls, args.warmup)
            torch_ms = median_ms(torch_call, args.calls, args.warmup)
            n_par = sum(p.numel() for p in module.parameters())
            print(f"{model:16s} {n_par:8,d} {path.stat().st_size / 1024:10.0f} {ort_ms:9.3f} {step_ms:11.3f} "
                  f"{torch_ms:10.3f} {torch_ms / ort_ms:8.1f}x")
            if model == "transnet_locnet":
                verdict = (ort_ms, step_ms)
    ort_ms, step_ms = verdict
    ok = step_ms < TARGET_MS
    print(f"verdict: {'MEETS' if ok else 'MISSES'} the {TARGET_MS:g} ms/window target: TransNet+LocNet "
          f"{ort_ms:.3f} ms in onnxruntime ({step_ms:.3f} ms through OnnxLocalizer.step, incl. input checks), "
          f"{TARGET_MS / step_ms:.0f}x {'under' if ok else 'over'} budget")


if __name__ == "__main__":
    main()
