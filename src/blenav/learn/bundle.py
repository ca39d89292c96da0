"""``export_bundle(cfg)``: ``python export.py bundle=true ckpt=RUN/last.ckpt out=BUNDLE [mapprior=...] [data=DIR]``
(conf/export.yaml's bundle keys) as a plain function: a cross-phone localizer checkpoint, its building and optionally
a map prior -> one runtime bundle folder (:mod:`blenav.runtime.bundle` lays it out, measures the variants and writes
manifest.json). It lives in learn/ because the localizer is traced to ONNX from its torch checkpoint here.
"""

from __future__ import annotations

import shutil
from pathlib import Path
from types import SimpleNamespace

from omegaconf import DictConfig, OmegaConf

from blenav.data import Dataset
from blenav.data.yaml_file import load_yaml
from blenav.runtime.bundle import INERTIAL_DIR, LOCALIZER, MANIFEST, MAP_DIR, variant_name
from blenav.runtime.bundle.settings import motion_needs
from blenav.runtime.bundle.write import finish_bundle
from blenav.runtime.map_prior import MapPrior
from blenav.runtime.signature import BuildingMismatch, building_signature, compare
from blenav.trust import check_targets

from .common.checkpoint import read_meta
from .common.trainer import check_run_folder
from .export import export


def _data_path(cfg: DictConfig, meta: dict) -> str | None:
    """The dataset of the localizer: ``data=``, else the path the checkpoint records, else RUN/config.yaml's."""
    if OmegaConf.select(cfg, "data.path", default=None):
        return str(cfg.data.path)
    if meta.get("data_path"):
        return str(meta["data_path"])
    run_cfg = Path(cfg.ckpt).parent / "config.yaml"
    if run_cfg.is_file():
        # the run folder may be a stranger's: read as data (alias bombs refused, nothing resolved; train.py writes
        # resolved values) -- a 444-byte config.yaml of aliases of aliases kept OmegaConf.load busy past a minute
        doc, issues = load_yaml(run_cfg)
        if doc is None:
            raise ValueError(str(issues[0]))
        data = doc.get("data")
        path = data.get("path") if isinstance(data, dict) else None
        return str(path) if path else None
    return None


def export_bundle(cfg: DictConfig) -> Path:
    """Write the runtime bundle of conf/export.yaml's bundle keys into ``cfg.out`` (replacing a bundle there); returns
    ``cfg.out``. It is built in ``OUT.part`` and renamed when whole, so a failure leaves no half bundle. The
    checkpoint must be a localizer of the dataset's building (same signature); the variants' pipeline runs on up to
    ``cfg.eval_sessions`` labelled sessions of that building, the ones not trained on when there are such."""
    out = Path(cfg.out)
    if out.exists() and not (out.is_dir() and (not any(out.iterdir()) or (out / MANIFEST).is_file())):
        raise ValueError(f"out={out} exists and is not a bundle: choose a new folder")
    check_run_folder(out, "a bundle")  # not /, not inside the dataset it was trained on
    inertial = None
    if cfg.get("io_model"):  # before anything is exported: the model, and a motion model that reads odometry
        if "odo" not in _motion_needs(cfg.runtime.motion):
            raise ValueError(f"io_model={cfg.io_model}: the bundle's motion model ({cfg.runtime.motion.get('_target_')}) "
                             "reads no odometry; the learned odometry would not be used")
        inertial = _check_inertial(Path(cfg.io_model))
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
        needs = _motion_needs(cfg.runtime.motion)  # the streams the bundle's motion model reads
        if "odo" in needs and not cfg.get("io_model"):
            mine = [s for s in mine if len(s.odometry)]
        if "odo" in needs and cfg.get("io_model"):  # the bundle's inertial odometry runs on the IMU
            mine = [s for s in mine if len(s.imu)]
        if any(n in needs for n in ("acc_w", "heading", "steps")):
            mine = [s for s in mine if len(s.imu)]
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
        opset = cfg.get("opset")  # None: export() takes the default (learn.common.onnx_export.DEFAULT_OPSET)
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
        if inertial is not None:
            models["inertial"] = _copy_inertial(inertial, tmp / INERTIAL_DIR)
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


def _check_inertial(io: Path):
    """The learned inertial odometry export ``io`` (``export.py`` on a ``train.py experiment=inertial`` run), checked:
    its hashes, grid, channels (:class:`blenav.runtime.inertial.InertialModel`, returned)."""
    from blenav.runtime.inertial import InertialModel

    if not io.exists():
        raise FileNotFoundError(f"io_model={io} does not exist (an export directory of `python export.py "
                                "ckpt=RUN/last.ckpt out=IO_DIR` on a train.py experiment=inertial run)")
    return InertialModel(io)


def _copy_inertial(model, dest: Path) -> dict:
    """The export of ``model`` (checked by :func:`_check_inertial`, before anything was exported) copied to ``dest``:
    its graph and meta.json only (the bundle's manifest hashes the copies). Returns its manifest entry."""
    from blenav.runtime.inertial import INERTIAL_ONNX, META_JSON

    io = Path(model.root)
    dest.mkdir(parents=True)
    for name in (INERTIAL_ONNX, META_JSON):
        shutil.copy(io / name, dest / name)
    return {"source": str(io.resolve()), "rate_hz": model.grid.rate_hz, "attitude": model.attitude}


def _motion_needs(motion) -> tuple[str, ...]:
    """The ``needs`` of the motion model class the runtime settings name (:func:`blenav.runtime.bundle.settings.
    motion_needs`, the bundle reader's own check: one of blenav's motion models, imported, not built)."""
    motion = OmegaConf.to_container(motion, resolve=True) if isinstance(motion, DictConfig) else dict(motion or {})
    if not motion.get("_target_"):
        return ()
    return motion_needs(motion, "export config runtime")
