"""Export a trained localizer to ONNX: ``python export.py ckpt=RUN/last.ckpt out=MODEL.onnx`` (see conf/export.yaml),
or a runtime bundle: ``python export.py bundle=true ckpt=RUN/last.ckpt out=BUNDLE [mapprior=RUN2/last.ckpt]``
(:mod:`blenav.runtime.bundle`). Errors the user can fix print one line (``--debug`` shows the traceback)."""

import json
import shutil
import sys
from pathlib import Path
from types import SimpleNamespace

from omegaconf import DictConfig, OmegaConf

from blenav.cli.common import run_hydra


def _data_path(cfg: DictConfig, meta: dict) -> str | None:
    """The dataset of the localizer: ``data=``, else the path the checkpoint records, else RUN/config.yaml's."""
    if OmegaConf.select(cfg, "data.path", default=None):
        return str(cfg.data.path)
    if meta.get("data_path"):
        return str(meta["data_path"])
    run_cfg = Path(cfg.ckpt).parent / "config.yaml"
    if run_cfg.is_file():
        node = OmegaConf.load(run_cfg)
        path = OmegaConf.select(node, "data.path", default=None)
        return str(path) if path else None
    return None


def bundle(cfg: DictConfig) -> Path:
    """Write the runtime bundle of conf/export.yaml's bundle keys into ``cfg.out`` (replacing a bundle there)."""
    from blenav.data import Dataset
    from blenav.learn.common.checkpoint import read_meta
    from blenav.learn.export import export
    from blenav.runtime.bundle import LOCALIZER, MANIFEST, MAP_DIR, finish_bundle, variant_name
    from blenav.runtime.map_prior import MapPrior
    from blenav.runtime.signature import BuildingMismatch, building_signature, compare
    from blenav.trust import check_targets

    out = Path(cfg.out)
    if out.exists() and not (out.is_dir() and (not any(out.iterdir()) or (out / MANIFEST).is_file())):
        raise ValueError(f"out={out} exists and is not a bundle: choose a new folder")
    if not Path(cfg.ckpt).is_file():
        raise FileNotFoundError(f"checkpoint {cfg.ckpt} does not exist")
    meta = read_meta(cfg.ckpt)
    if meta.get("kind") == "mapprior":
        raise ValueError(f"ckpt={cfg.ckpt} is a map prior: a bundle is made around a cross-phone localizer "
                         "(ckpt=RUN/last.ckpt of train.py experiment=crossphone_*); pass the map prior as mapprior=...")
    path = _data_path(cfg, meta)
    building, sessions = None, []
    if path:
        if not Path(path).is_dir():
            raise FileNotFoundError(f"dataset {path} (the localizer's training data) does not exist: pass data=DIR")
        ds = Dataset.open(path)
        if meta.get("building") not in ds.building_ids:
            raise ValueError(f"dataset {path} has no building {meta.get('building')!r} (the localizer's; it has "
                             f"{ds.building_ids})")
        building = ds.building(meta["building"])
        trained = set(meta.get("train_sessions") or [])
        mine = [s for s in ds.sessions(labelled=True) if s.meta.get("building") == building.id
                and len(s.rssi) and len(s.groundtruth)]
        if "odometry" in str(cfg.runtime.motion.get("_target_", "")).lower():
            mine = [s for s in mine if len(s.odometry)]
        unseen = [s for s in mine if s.id not in trained]
        sessions = (unseen or mine)[: int(cfg.eval_sessions)]
    sig = meta.get("building_signature")
    if sig is None and building is None:
        raise ValueError("the bundle needs the localizer's building (beacons, floor plans) and the checkpoint does "
                         "not record it: name its dataset, data=DIR")
    if building is not None:
        here = building_signature(building)
        if sig is not None and compare(sig, here):
            raise BuildingMismatch(f"dataset {path}: building {building.id!r} is not the one the localizer was trained "
                                   f"on: {'; '.join(compare(sig, here))}")
        sig = sig or here
    tmp = out.with_name(out.name + ".part")
    shutil.rmtree(tmp, ignore_errors=True)
    tmp.mkdir(parents=True)
    try:
        opset = int(cfg.get("opset") or 17)
        export(SimpleNamespace(ckpt=str(cfg.ckpt), out=str(tmp / variant_name(LOCALIZER, "float")), opset=opset))
        models = {"localizer": {"checkpoint": str(Path(cfg.ckpt).resolve()), "building": meta.get("building"),
                                "data_hash": meta.get("data_hash")}}
        if cfg.get("mapprior"):
            mp = Path(cfg.mapprior)
            if mp.is_dir():
                MapPrior(mp)  # checks the export (hashes) before it is copied
                shutil.copytree(mp, tmp / MAP_DIR, ignore=shutil.ignore_patterns("dmt_*"))
            elif mp.is_file():
                if read_meta(mp).get("kind") != "mapprior":
                    raise ValueError(f"mapprior={mp} is not a map prior checkpoint (train.py experiment=mapprior)")
                export(SimpleNamespace(ckpt=str(mp), out=str(tmp / MAP_DIR), opset=opset))
            else:
                raise FileNotFoundError(f"mapprior={mp} does not exist (a last.ckpt or an export directory)")
            models["map_prior"] = {"source": str(mp.resolve())}
        settings = OmegaConf.to_container(cfg.runtime, resolve=True)
        check_targets(settings, "export config", prefix="runtime")  # settings.json may name only blenav's classes
        finish_bundle(tmp, sig, settings, variants=bool(cfg.variants), sessions=sessions,
                      extra={"models": models, "data": str(Path(path).resolve()) if path else None})
        shutil.rmtree(out, ignore_errors=True)
        tmp.rename(out)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)  # never leave half a bundle
        raise
    return out


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
    from blenav.learn.export import export

    for key, what in (("ckpt", "the checkpoint to export: ckpt=RUN/last.ckpt"),
                      ("out", "where to write: out=MODEL.onnx (a directory for a map prior or a bundle)")):
        if OmegaConf.is_missing(cfg, key):
            raise ValueError(f"name {what}")
    if cfg.get("bundle"):
        print(_summary(bundle(cfg)))
        return
    print(f"wrote {export(cfg)}")


def main() -> None:
    from blenav.configs import cli_overrides

    run_hydra("export.py", "export", task, sys.argv[1:], convert=cli_overrides)  # data=DIR -> data.path=DIR


if __name__ == "__main__":
    main()
