"""The PyTorch-eager pipeline a runtime bundle must reproduce (tests/runtime/test_bundle.py, benchmarks/runtime_latency.py).

torch LocNet over the session's batch windows -> position fixes; the map prior loaded from its checkpoint with
torch; the bundle's filter settings; :func:`blenav.filters.runner.run_session` with those fixes.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd


def torch_pipeline(bundle, ckpt: Path, mapprior_ckpt: Path, session, seed: int):
    """(t (K,) s, xy (K, 2) world m of run 0, fixes DataFrame t, x, y, std, source) of the eager pipeline for
    ``bundle`` (a :class:`blenav.runtime.bundle.Bundle`: its filter settings) on ``session``."""
    import torch

    from blenav.features.windows import WindowConfig, session_windows
    from blenav.filters.runner import run_session
    from blenav.learn.crossphone.checkpoint import load_module
    from blenav.learn.crossphone.export import streaming_net
    from blenav.learn.mapprior.checkpoint import load_map_prior
    from blenav.runtime.bundle import FIX_SOURCE
    from blenav.runtime.bundle.settings import build_method

    module, meta = load_module(ckpt)
    net = streaming_net(module, meta)
    w = meta["window"]
    win = session_windows(session, meta["beacons"], WindowConfig(
        history=int(w["history"]), step_hz=float(w["step_hz"]), offset_db=float(w["offset_db"]),
        floor_u=float(w["floor_u"]), beacon_subset=w.get("beacon_subset")))
    z = torch.zeros(module.locnet.layers, len(win.S), module.locnet.hidden)
    with torch.no_grad():
        xy = net(torch.from_numpy(win.S), z, z)[0].numpy().astype(float)
    ok = (win.S > 0).reshape(len(win.S), -1).any(axis=1)
    fixes = pd.DataFrame({"t": win.t[ok], "x": xy[ok, 0], "y": xy[ok, 1], "std": np.nan, "source": FIX_SOURCE})
    res = run_session(build_method(bundle.settings, load_map_prior(mapprior_ckpt)), session, 1, seed, fixes=fixes)
    return res.t, res.position[0], fixes
