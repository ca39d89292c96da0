"""ONNX export of the cross-phone localizer (TransNet + LocNet, Roy section 3.1) for streaming on a device.

The exported graph, for a model of B beacons and windows of H steps (both fixed; the batch is dynamic):

- inputs ``S`` (batch, B, H) float32 on the thesis scale u (u = rssi_dbm + offset_db, at least floor_u for a
  heard packet, 0 = not heard; rows in the model's beacon order, columns oldest..newest step), ``h0`` and
  ``c0`` (layers, batch, hidden) float32, the LSTM state (zeros: see ``lstm_state`` below);
- outputs ``xy`` (batch, 2) float32, world x, y in metres at the end of the window's newest step, and
  ``h``, ``c`` (layers, batch, hidden), the LSTM state after the window; a LocNet with a std head (``std_head: true``,
  issue 29) adds ``std_m`` (batch,) float32, the network's own 1-sigma per axis in metres (isotropic 2-D Gaussian),
  calibrated: the head's sigma times the scale fitted on the validation windows at the training's end (LocNet's
  ``std_scale``, part of the weights; the training report's ``fix_std``).

The graph divides S by ``u_scale`` itself (the networks are trained on u / u_scale, see
:mod:`blenav.learn.crossphone.losses`) and applies TransNet when the model has one, so an app feeds u, the same numbers
it would write in a dataset window, and never scales them.

``metadata_props`` (every value a JSON string) say all an app needs without reading Python:

- ``input_units`` {tensor, unit, per_packet, weak_packet, scaling, graph_divides_by}: what one entry of S is
  and that the graph scales it (feed u as it is);
- ``window_recipe`` {step_s, step_hz, history_H, window_s, step_of_packet, aggregation, rows, columns,
  stride, output_time, other_beacons}: how a window is built from packets (t, beacon id, rssi dBm), in the
  words of :func:`blenav.features.windows.session_windows`, which ``blenav-fixes`` runs;
- ``not_heard`` {value, meaning, empty_window}: 0 for a beacon without a packet in a step; a window with
  nothing heard gives no fix;
- ``lstm_state`` {carry, h0_c0, why}: start every window from zeros, do not carry h, c (the model was
  trained on independent windows that overlap by H - 1 steps);
- ``output_frame`` {xy, frame, building, time}: the output's coordinates and frame;
- ``beacons`` (the row order), ``beacon_subset`` (null: the building's BLE beacons are all the model's rows;
  else the rule that chose a deliberate subset, ``"spread:k"`` or ``"list"``, see ``data.beacons``),
  ``window`` (history, step_hz, offset_db, floor_u, steps, beacon_subset: the numbers the recipe uses; the
  checkpoint's ``u_scale`` is left out, the graph applies it), ``input_transform`` (one line,
  :data:`INPUT_TRANSFORM`), ``building``, ``data_hash``, ``model`` (the model node of the training config),
  ``model_name``, ``train_devices``, ``known_devices``, ``unlabelled_devices``, ``blenav_version``;
- ``weights_sha256``, ``weights_sha256_tensors``: the weights hash every loader checks
  (:mod:`blenav.onnx_io`).

:class:`blenav.runtime.OnnxLocalizer` reads them back.

:func:`blenav.learn.export.export` (``python export.py ckpt=RUN/last.ckpt out=MODEL.onnx``) loads a checkpoint
written by ``train(cfg)`` (:func:`blenav.learn.crossphone.checkpoint.load_module`); :func:`export_module` does the
rest for an already built module (benchmarks use it). Every export is checked with ``onnx.checker`` and against
PyTorch on random inputs (max abs diff <= ``TOL``). The pieces :class:`StreamingLocalizer`, :func:`random_inputs`,
:func:`export_onnx` and :func:`onnx_max_diff` work for bare networks too. Tracing, metadata and sessions are shared
with the map prior's export (:mod:`blenav.learn.common.onnx_export`, :mod:`blenav.onnx_io`).
"""

from __future__ import annotations

from pathlib import Path

import torch
from torch import nn

from blenav.onnx_io import STD_OUTPUT, blenav_version, json_props, max_diff, session

from ..common.onnx_export import DEFAULT_OPSET, trace_onnx
from .model_node import states_std

TOL = 1e-4  # max abs difference between onnxruntime and PyTorch outputs (metres and state units)
INPUT_NAMES = ("S", "h0", "c0")
OUTPUT_NAMES = ("xy", "h", "c")
INPUT_TRANSFORM = ("per packet u = max(rssi_dbm + offset_db, floor_u); per step and beacon the mean of u over its "
                   "packets, 0 when not heard; S rows in beacons order, columns oldest..newest step; feed u as it "
                   "is (the graph divides by u_scale itself)")
META_KEYS = ("input_units", "window_recipe", "not_heard", "lstm_state", "output_frame", "beacons", "beacon_subset",
             "window", "input_transform", "building", "data_hash", "model", "model_name", "train_devices",
             "known_devices", "unlabelled_devices", "train_sessions", "blenav_version")
REQUIRED_META = ("model", "beacons", "window")
_DOCS = {
    "S": "(batch, B, H) float32 RSSI windows on the thesis scale u, not scaled (metadata input_units, window_recipe)",
    "h0": "(layers, batch, hidden) float32 LSTM hidden state: zeros for every window (metadata lstm_state)",
    "c0": "(layers, batch, hidden) float32 LSTM cell state: zeros for every window (metadata lstm_state)",
    "xy": "(batch, 2) float32 world x, y in metres at the end of the window's newest step (metadata output_frame)",
    "h": "(layers, batch, hidden) float32 LSTM hidden state after the window (not fed back: metadata lstm_state)",
    "c": "(layers, batch, hidden) float32 LSTM cell state after the window (not fed back: metadata lstm_state)",
    STD_OUTPUT: "(batch,) float32 the network's 1-sigma per axis in metres, scaled on its validation windows",
}


def output_names(locnet: nn.Module) -> tuple[str, ...]:
    """The exported graph's outputs for this LocNet: :data:`OUTPUT_NAMES`, plus :data:`STD_OUTPUT` with a std head."""
    return OUTPUT_NAMES + ((STD_OUTPUT,) if getattr(locnet, "std_head", False) else ())


class StreamingLocalizer(nn.Module):
    """(S on the thesis scale, h0, c0) -> (xy m, h, c[, std_m]): divide by ``u_scale``, TransNet if any, LocNet with
    state (and its std with a std head)."""

    def __init__(self, locnet: nn.Module, transnet: nn.Module | None = None, u_scale: float = 1.0):
        super().__init__()
        self.locnet, self.transnet, self.u_scale = locnet, transnet, float(u_scale)

    def forward(self, S: torch.Tensor, h0: torch.Tensor, c0: torch.Tensor):
        g = S / self.u_scale
        if self.transnet is not None:
            g = self.transnet(g)
        if getattr(self.locnet, "std_head", False):
            xy, std, h, c = self.locnet.forward_state_std(g, h0, c0)
            return xy, h, c, std
        return self.locnet.forward_state(g, h0, c0)


def random_inputs(n_beacons: int, history: int, layers: int, hidden: int, batch: int = 3, seed: int = 0,
                  u_max: float = 70.0, p_heard: float = 0.7, zero_state: bool = False):
    """(S, h0, c0) float32 tensors: S uniform in [0, u_max) with about 1 - p_heard of the entries 0 (not heard),
    state standard normal (or zeros). Own generator, no global random state."""
    g = torch.Generator().manual_seed(seed)
    S = torch.rand(batch, n_beacons, history, generator=g) * u_max
    S = S * (torch.rand(batch, n_beacons, history, generator=g) < p_heard)
    if zero_state:
        h0 = torch.zeros(layers, batch, hidden)
        c0 = torch.zeros(layers, batch, hidden)
    else:
        h0 = torch.randn(layers, batch, hidden, generator=g)
        c0 = torch.randn(layers, batch, hidden, generator=g)
    return S, h0, c0


def export_onnx(net: nn.Module, inputs: tuple, path: str | Path, opset: int = DEFAULT_OPSET,
                metadata: dict[str, str] | None = None, doc: str = "") -> Path:
    """Trace ``net(S, h0, c0) -> (xy, h, c[, std_m])`` to ONNX at ``path`` with a dynamic batch, write ``metadata``
    (str -> str) into ``metadata_props``, run ``onnx.checker``. Returns the path."""
    names = output_names(net.locnet) if hasattr(net, "locnet") else OUTPUT_NAMES
    dynamic = {"S": {0: "batch"}, "h0": {1: "batch"}, "c0": {1: "batch"}, "xy": {0: "batch"}, "h": {1: "batch"},
               "c": {1: "batch"}, STD_OUTPUT: {0: "batch"}}
    return trace_onnx(net, inputs, path, INPUT_NAMES, names, {k: dynamic[k] for k in (*INPUT_NAMES, *names)},
                      opset=opset, metadata=metadata, doc=doc, io_docs=_DOCS)


def onnx_max_diff(path: str | Path, net: nn.Module, inputs: tuple) -> float:
    """Max abs difference over all outputs between onnxruntime (one thread) and ``net`` on ``inputs``."""
    names = output_names(net.locnet) if hasattr(net, "locnet") else OUTPUT_NAMES
    got = session(path, threads=1).run(list(names), {n: t.numpy() for n, t in zip(INPUT_NAMES, inputs)})
    with torch.no_grad():
        ref = [b.numpy() for b in net.eval()(*inputs)]
    # std_m relative to its own size (a sigma of thousands of metres rounds past 1e-4 m in float32)
    return max(max_diff(got[:3], ref[:3]), max_diff(got[3:], ref[3:], relative=True))


def onnx_metadata(meta: dict) -> dict[str, str]:
    """The ``metadata_props`` (JSON strings) of an export from a checkpoint's ``meta`` (see
    :mod:`blenav.learn.crossphone.checkpoint`)."""
    missing = [k for k in REQUIRED_META if k not in meta]
    if missing:
        raise ValueError(f"checkpoint metadata lacks {missing} (has {sorted(meta)}); it must come from train(cfg)")
    model = meta["model"]
    window = {k: v for k, v in (meta["window"] or {}).items() if k != "u_scale"}  # the graph applies u_scale
    values = {
        **app_contract(meta),
        "beacons": [str(b) for b in meta["beacons"]],
        "beacon_subset": window.get("beacon_subset"),  # also at top level: what loaders check
        "window": window,
        "building": meta.get("building"),
        "data_hash": meta.get("data_hash"),
        "model": model,
        "model_name": model.get("name") if isinstance(model, dict) else None,
        "train_devices": meta.get("train_devices"),
        "known_devices": meta.get("known_devices"),
        "unlabelled_devices": meta.get("unlabelled_devices"),
        "train_sessions": meta.get("train_sessions"),  # None for a checkpoint written before it was recorded
        "blenav_version": blenav_version(),
        "input_transform": INPUT_TRANSFORM,
    }
    return json_props(values, META_KEYS)


def app_contract(meta: dict) -> dict:
    """The metadata entries that tell an app developer how to feed the graph and read its output (see the module
    docstring), from a checkpoint's meta: ``input_units``, ``window_recipe``, ``not_heard``, ``lstm_state``,
    ``output_frame``. Numbers come from the checkpoint's window, texts say what blenav's windowing
    (:func:`blenav.features.windows.session_windows`) and runtime (:mod:`blenav.runtime.fixes`) do."""
    w = meta["window"]
    if "fill_dbm" in w:  # a fingerprint model of real walks (WiFi scans / BLE advertisements)
        return fingerprint_contract(meta)
    H, hz = int(w["history"]), float(w["step_hz"])
    off, floor_u, u_scale = float(w["offset_db"]), float(w["floor_u"]), float(w.get("u_scale", 1.0))
    steps = str(w.get("steps", "time"))
    u_def = f"u = max(rssi_dbm + {off:g}, {floor_u:g})"
    input_units = {
        "tensor": "S (batch, B, H) float32, B = len(beacons), H = window.history",
        "unit": f"dB on the thesis scale u = rssi_dbm + {off:g} (offset_db): -70 dBm -> {-70 + off:g}",
        "per_packet": u_def,
        "weak_packet": f"a received packet weaker than {-off:g} dBm counts {floor_u:g} (floor_u): heard, never 0",
        "scaling": f"none: feed u as it is; the graph divides S by {u_scale:g} itself (do not divide again)",
        "graph_divides_by": u_scale,
    }
    if steps == "scan":
        step_of_packet = ("one step per scan: packets with the same time t form one step (a fingerprint survey); "
                          "a window is H consecutive scans at one surveyed point")
        stride, out_time = "one window per scan", "the time of the window's newest scan"
    else:
        step_of_packet = (f"step k = floor((t - t0) * {hz:g}) for a packet at t seconds, t0 = the time of the first "
                          f"packet (any beacon); steps are {1 / hz:g} s long (a live app may start t0 anywhere)")
        stride = f"one window per step: the window ending at step k (k >= {H - 1}); consecutive windows share {H - 1} steps"
        out_time = f"t0 + (k + 1) * {1 / hz:g} s: the end of the window's newest step k"
    window_recipe = {
        "step_s": None if steps == "scan" else 1.0 / hz, "step_hz": hz, "history_H": H,
        "window_s": None if steps == "scan" else H / hz,
        "history_meaning": f"H = {H}: a window holds the last {H} steps, one column per step",
        "step_of_packet": step_of_packet,
        "aggregation": (f"per step and beacon: the mean of u ({u_def}) over that beacon's packets in the step "
                        "(the mean of u, not of dBm); 0 when it sent none"),
        "rows": "S[b] is beacon beacons[b] (the metadata list, sorted anchor ids of anchors.csv)",
        "columns": f"S[:, i] is step k - {H - 1} + i: column 0 the oldest, column {H - 1} the newest",
        "stride": stride,
        "output_time": out_time,
        "other_beacons": "packets of beacons not in the list are ignored",
    }
    not_heard = {
        "value": 0.0,
        "meaning": "S[b, i] = 0: beacon b sent no packet in step i (never a sentinel such as -100 or -200)",
        "empty_window": ("a window with every entry 0 (nothing heard) gives only the network's prior: discard its xy "
                         "(blenav writes no fix for it)"),
    }
    lstm_state = {
        "carry": False,
        "h0_c0": "zeros of the shape of inputs h0 and c0 (layers, batch, hidden) for every window",
        "why": (f"the model was trained on independent windows, each from a zero state; consecutive windows share "
                f"{H - 1} of their {H} steps, so feeding h, c back would read those steps twice. blenav-fixes and "
                "OnnxLocalizer.predict start every window from zeros; h and c are outputs for experiments only"),
    }
    output_frame = {
        "xy": "(batch, 2) float32: x, y in metres",
        "frame": ("the building's world frame: right-handed, x east, y north, metres, one origin per building; the "
                  "frame of its anchors.csv and floor plans (docs/dataset-format.md)"),
        "building": meta.get("building"),
        "time": out_time,
    }
    model = meta.get("model") if isinstance(meta.get("model"), dict) else {}
    if states_std(model):
        output_frame["std_m"] = ("(batch,) float32: the fix's 1-sigma per axis in metres (an isotropic 2-D Gaussian "
                                 "N(xy, std_m^2 I)), the network's own sigma scaled on its validation windows")
    return {"input_units": input_units, "window_recipe": window_recipe, "not_heard": not_heard,
            "lstm_state": lstm_state, "output_frame": output_frame}


def fingerprint_contract(meta: dict) -> dict:
    """:func:`app_contract` of a fingerprint model trained on real walks (``blenav-eval experiment=realwalks``'s
    learned rows, :mod:`blenav.localizers.fingerprint`): its window is a
    :class:`blenav.features.fingerprints.FingerprintConfig` (features WiFi access points ``wifi:<bssid>`` and/or BLE
    anchors ``ble:<id>``, one step per WiFi scan), whose recipe :mod:`blenav.features.fingerprints` documents."""
    w, model = meta["window"], meta.get("model") if isinstance(meta.get("model"), dict) else {}
    H, fill, floor_u = int(w["history"]), float(w["fill_dbm"]), float(w["floor_u"])
    u_scale, kind = float(w.get("u_scale", 1.0)), str(w.get("features", "wifi"))
    u_def = f"u = rssi_dbm - ({fill:g}), at least {floor_u:g} for a heard reading"
    age = w.get("wifi_max_age_s")
    ref = "the newest t_seen of the scan's rows" if w.get("wifi_age_ref") == "scan" else "the scan's delivery time"
    when = ("the median t_seen of the rows kept" if w.get("wifi_time") == "heard" else "the scan's delivery time")
    if kind == "ble":
        step = (f"one step every {float(w['ble_step_s']):g} s from the first advertisement, each the advertisements "
                f"of the {float(w['ble_window_s']):g} s up to it")
    else:
        step = (f"one step per WiFi scan (the rows delivered together); a row heard more than {age} s before {ref} "
                f"is stale and dropped; the step's time is {when}"
                + (f"; its BLE part the advertisements of the {float(w['ble_window_s']):g} s up to that time"
                   if kind == "both" else ""))
    return {
        "input_units": {"tensor": "S (batch, F, H) float32, F = len(beacons) features, H = window.history",
                        "unit": f"dB above the not-heard level: {u_def}", "per_packet": u_def,
                        "scaling": f"none: feed u as it is; the graph divides S by {u_scale:g} itself",
                        "graph_divides_by": u_scale},
        "window_recipe": {"history_H": H, "step_of_packet": step, "features": kind,
                          "aggregation": "per step and feature: the mean of u over its readings; 0 when not heard",
                          "rows": "S[f] is beacons[f]: 'wifi:<bssid>' (wifi.csv) or 'ble:<anchor id>' (rssi.csv)",
                          "columns": f"S[:, i]: column 0 the oldest of the last {H} steps, column {H - 1} the newest",
                          "stride": "one window per step", "output_time": "the time of the window's newest step",
                          "other_beacons": "access points and anchors not in the list are ignored"},
        "not_heard": {"value": 0.0, "meaning": f"S[f, i] = 0: not heard in step i (= {fill:g} dBm)",
                      "empty_window": "a window with nothing heard gives no fix"},
        "lstm_state": {"carry": False, "h0_c0": "zeros of the shape of inputs h0 and c0 for every window",
                       "why": "each window is localized on its own (a PlaceNet has no state: h, c pass through)"},
        "output_frame": {"xy": "(batch, 2) float32: x, y in metres", "building": meta.get("building"),
                         "frame": "the building's world frame (the waypoints' frame of the walks it was trained on)",
                         "time": "the time of the window's newest step",
                         **({"std_m": "(batch,) float32: the fix's 1-sigma per axis in metres, scaled on the "
                                      "validation walks"}
                            if states_std(model) else {})},
    }


def streaming_net(module, meta: dict) -> StreamingLocalizer:
    """The :class:`StreamingLocalizer` of a :class:`~blenav.learn.crossphone.module.CrossPhoneModule` and its meta."""
    window = meta["window"]
    if "u_scale" not in window or "history" not in window:
        raise ValueError(f"checkpoint metadata 'window' lacks history/u_scale: {window}")
    return StreamingLocalizer(module.locnet, module.transnet, float(window["u_scale"])).eval()


def export_module(module, meta: dict, out: str | Path, opset: int = DEFAULT_OPSET, seed: int = 0) -> Path:
    """Export a built module (eval mode, any weights) with its meta; check parity on random inputs."""
    props = onnx_metadata(meta)
    net = streaming_net(module, meta)
    loc = module.locnet
    B, H = len(meta["beacons"]), int(meta["window"]["history"])
    if getattr(loc, "n_beacons", B) != B:
        raise ValueError(f"LocNet has {loc.n_beacons} inputs but the metadata lists {B} beacons")
    u_max = float(meta["window"].get("u_scale", 100.0)) * 0.7
    example = random_inputs(B, H, loc.layers, loc.hidden, batch=2, seed=seed, u_max=u_max, zero_state=True)
    name = meta["model"].get("name", "model") if isinstance(meta["model"], dict) else "model"
    doc = (f"blenav cross-phone localizer '{name}' for building {meta.get('building')}: S (batch, {B}, {H}) "
           f"thesis scale, h0/c0 ({loc.layers}, batch, {loc.hidden}) -> xy (batch, 2) m, h, c"
           + (", std_m (batch,) m" if getattr(loc, "std_head", False) else ""))
    path = export_onnx(net, example, out, opset=opset, metadata=props, doc=doc)
    worst = 0.0
    for i, batch in enumerate((1, 3, 5)):  # other batch sizes than traced, random non-zero state
        inputs = random_inputs(B, H, loc.layers, loc.hidden, batch=batch, seed=seed + 1 + i, u_max=u_max,
                               zero_state=(i == 0))
        worst = max(worst, onnx_max_diff(path, net, inputs))
    if not worst <= TOL:
        path.unlink(missing_ok=True)  # never leave a rejected model where an app could pick it up
        raise RuntimeError(f"{path}: onnxruntime differs from PyTorch by {worst:.3g} > {TOL:g}; export rejected")
    return path
