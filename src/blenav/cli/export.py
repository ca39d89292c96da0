"""``python export.py`` / ``blenav-export``: a trained localizer to ONNX, ``ckpt=RUN/last.ckpt out=MODEL.onnx``
(see conf/export.yaml), or a runtime bundle, ``bundle=true ckpt=RUN/last.ckpt out=BUNDLE [mapprior=RUN2/last.ckpt]``
(:mod:`blenav.runtime.bundle`). The work is :func:`blenav.learn.export.export` and
:func:`blenav.learn.bundle.export_bundle`; errors the user can fix print one line (``--debug`` shows the traceback)."""

from __future__ import annotations

import json
import sys
from pathlib import Path

from omegaconf import DictConfig, OmegaConf

from .common import run_hydra


def _summary(out: Path) -> str:
    m = json.loads((out / "manifest.json").read_text())
    lines = [f"wrote bundle {out}: building {m['building']['building']!r}, {len(m['beacons'])} beacons, "
             f"map prior: {'yes' if m['has_map_prior'] else 'no'}, variants {m['variants_available']}"]
    meas = m.get("measured") or {}
    for g, per in (meas.get("graphs") or {}).items():
        for v, r in per.items():
            extra = f", max |diff| vs float {r['max_abs_diff_vs_float']:.3g}" if "max_abs_diff_vs_float" in r else ""
            lines.append(f"  {g} [{v}]: {r['bytes'] / 1024:.1f} KiB, {r['latency_ms']['median']:.3f} ms median, "
                         f"{r['latency_ms']['p90']:.3f} ms p90{extra}")
    for v, r in (meas.get("pipeline") or {}).items():
        ch = f" ({r['rmse_change_m']:+.3f} m vs float)" if "rmse_change_m" in r else ""
        fx = f", its fixes {r['fix_rmse_m']:.3f} m" if r.get("fix_rmse_m") is not None else ""
        lines.append(f"  pipeline [{v}] on {meas.get('pipeline_sessions')}: RMSE {r['rmse_m']:.3f} m{ch}{fx}")
    for k, why in (m.get("variants_failed") or {}).items():
        lines.append(f"  not made: {k}: {why}")
    return "\n".join(lines)


def task(cfg: DictConfig) -> None:
    """Export ``cfg`` (conf/export.yaml composed with the command line) and print what was written."""
    for key, what in (("ckpt", "the checkpoint to export: ckpt=RUN/last.ckpt"),
                      ("out", "where to write: out=MODEL.onnx (a directory for a map prior or a bundle)")):
        if OmegaConf.is_missing(cfg, key):
            raise ValueError(f"name {what}")
    if cfg.get("bundle"):
        from blenav.learn.bundle import export_bundle

        print(_summary(export_bundle(cfg)))
        return
    from blenav.learn.export import export

    print(f"wrote {export(cfg)}")


def main(argv: list[str] | None = None) -> None:
    from blenav.configs import cli_overrides

    prog = "export.py" if sys.argv[0].endswith("export.py") else "blenav-export"
    run_hydra(prog, "export", task, sys.argv[1:] if argv is None else list(argv), convert=cli_overrides)  # data=DIR -> data.path=DIR
