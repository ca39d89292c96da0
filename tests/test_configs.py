"""Configs mirror what is built: every experiment composes and builds, a misspelt key fails at composition
naming it, modes are Enums, ``model=`` means a network config everywhere, and the cross-phone experiment's
simulator device names follow the train devices."""

from __future__ import annotations

import shutil
from pathlib import Path

import pytest
import yaml
from hydra.errors import ConfigCompositionException
from hydra.utils import get_class, instantiate
from omegaconf import DictConfig, OmegaConf

from blenav.configs import cli_overrides, compose
from blenav.paths import conf_dir

EXPERIMENTS = sorted(p.stem for p in (conf_dir() / "experiment").glob("*.yaml") if not p.stem.startswith("_"))


def _is_eval(name: str) -> bool:
    """Evaluation experiments name themselves (experiment.name); the others configure train.py."""
    doc = yaml.safe_load((conf_dir() / "experiment" / f"{name}.yaml").read_text()) or {}
    return "name" in (doc.get("experiment") or {})


EVAL = [e for e in EXPERIMENTS if _is_eval(e)]
TRAIN = [e for e in EXPERIMENTS if not _is_eval(e)]


def _targets(node, path: str = ""):
    """(path, node) of every node below ``node`` that has a ``_target_``."""
    if isinstance(node, DictConfig):
        for k, v in node.items_ex(resolve=False):
            if isinstance(v, DictConfig):
                if "_target_" in v:
                    yield f"{path}.{k}", v
                yield from _targets(v, f"{path}.{k}")


def test_experiment_lists_are_complete():
    assert {"frontend_000", "mapfusion_002", "mapprior_003_table36", "mapprior_003_table37", "crossphone_003"} <= set(EVAL)
    assert {"crossphone_s1", "crossphone_s2", "crossphone_s3", "mapprior"} <= set(TRAIN)


@pytest.mark.parametrize("experiment", EVAL)
def test_every_eval_experiment_composes_and_builds(experiment):
    from blenav.eval.config import parse_eval_config
    from blenav.eval.harness import build_methods

    cfg = compose("eval", f"experiment={experiment}", "data=DIR")
    OmegaConf.to_container(cfg, resolve=True)  # every interpolation resolves
    typed = parse_eval_config(cfg)  # every key known to the eval schema
    if typed.experiment.evaluator_target.endswith("CrossPhoneEvaluator"):  # learned methods: model configs
        for key, spec in cfg.experiment.learned.items():
            if spec is not None:
                assert spec.model.name, key
        return
    methods = build_methods(cfg)
    assert len(methods) == len([m for m in cfg.methods.values() if m is not None])
    # every component with a _target_ instantiates on its own, with its configured arguments
    for key, method in cfg.methods.items():
        if method is None:
            continue
        assert "_target_" not in method or get_class(method._target_)
        for path, node in _targets(method, key):
            if ".training.models." in path:  # a network's config: built with the building's n_beacons when trained
                assert get_class(node._target_).__name__ == node._target_.rsplit(".", 1)[-1], path
                continue
            obj = instantiate(node)
            assert type(obj).__name__ == node._target_.rsplit(".", 1)[-1], path


@pytest.mark.parametrize("experiment", TRAIN)
def test_every_train_experiment_composes(experiment):
    from blenav.learn.crossphone.data_config import WindowDataConfig
    from blenav.learn.inertial.data_config import InertialDataConfig
    from blenav.learn.mapprior.data_config import MapPriorDataConfig

    cfg = compose("train", f"experiment={experiment}", "data=DIR")
    OmegaConf.to_container(cfg, resolve=True)
    schema = {"mapprior": MapPriorDataConfig, "inertial": InertialDataConfig}.get(cfg.task, WindowDataConfig)
    assert OmegaConf.get_type(cfg.data) is schema
    if "_target_" in (cfg.model.get("net") or {}):
        get_class(cfg.model.net._target_)


@pytest.fixture(scope="module")
def typo_conf(tmp_path_factory) -> Path:
    """A search-path folder with configs that each misspell one key of one node kind."""
    root = tmp_path_factory.mktemp("conf")
    (root / "experiment").mkdir()
    (root / "sim").mkdir()
    typos = {"filter": ("filter", "n_particle: 3"), "attitude": ("attitude", "use_magg: false"),
             "plan_error": ("plan_error", "barriers: 1"), "data": ("data", "histroy: 3")}
    for name, (node, line) in typos.items():
        (root / "experiment" / f"typo_{name}.yaml").write_text(
            f"# @package _global_\ndefaults:\n  - frontend_000\n{node}:\n  {line}\n")
    (root / "experiment" / "typo_mapprior_data.yaml").write_text(
        "# @package _global_\ndefaults:\n  - mapprior\ndata:\n  crop_pxx: 32\n")
    (root / "experiment" / "typo_mode.yaml").write_text(
        "# @package _global_\ndefaults:\n  - frontend_000\nfilter:\n  estimate: medain\n")
    (root / "sim" / "typo.yaml").write_text("defaults:\n  - small\n  - _self_\nn_beacon: 3\n")
    return root


@pytest.mark.parametrize("config,override,key", [
    ("eval", "experiment=typo_filter", "n_particle"),
    ("eval", "experiment=typo_attitude", "use_magg"),
    ("eval", "experiment=typo_plan_error", "barriers"),
    ("eval", "experiment=typo_data", "histroy"),
    ("train", "experiment=typo_data", "histroy"),
    ("train", "experiment=typo_mapprior_data", "crop_pxx"),
    ("eval", "experiment=typo_mode", "medain"),
    ("sim", "sim=typo", "n_beacon"),
])
def test_a_misspelt_key_fails_at_composition_naming_it(typo_conf, config, override, key):
    extra = ["data=DIR"] if config != "sim" else []
    with pytest.raises(ConfigCompositionException) as err:
        compose(config, override, *extra, f"hydra.searchpath=[file://{typo_conf}]")
    assert key in str(err.value) + str(err.value.__cause__)


@pytest.mark.parametrize("override,key", [
    ("filter.estimate=medain", "medain"), ("filter.resampling=lowvar", "lowvar"),
    ("attitude.filter=kalman", "kalman"), ("data.steps=scans", "scans"),
])
def test_modes_are_enums(override, key):
    with pytest.raises(ConfigCompositionException) as err:
        compose("eval", "data=DIR", override)
    assert key in str(err.value) + str(err.value.__cause__)


def test_enum_modes_compare_as_strings():
    from blenav.filters.attitude import AttitudeConfig
    from blenav.filters.engine import EstimateMode, FilterConfig, Resampling
    from blenav.filters.resampling import SCHEMES

    cfg = compose("eval", "experiment=mapprior_003_table36", "data=DIR")
    f = OmegaConf.to_object(cfg.filter)
    assert isinstance(f, FilterConfig) and f.estimate == "median" and f.estimate is EstimateMode.median
    assert f.resampling == "low_variance" and str(f.resampling) == "low_variance"
    assert {r.value for r in Resampling} == set(SCHEMES)  # one name per scheme of blenav.filters.resampling
    assert OmegaConf.to_object(cfg.attitude).filter == "madgwick"
    with pytest.raises(ValueError, match="madgwick"):
        AttitudeConfig(filter="kalman")


def test_method_map_spec_typo_is_named():
    """Methods are free-form nodes (a _target_ plus its settings): their map spec is checked when built."""
    from blenav.eval.harness import build_methods

    cfg = compose("eval", "experiment=frontend_000", "data=DIR", "+methods.RW.map.inti=fix")
    with pytest.raises(Exception, match="inti"):
        build_methods(cfg)


def test_model_means_a_network_config_everywhere():
    assert compose("train", "model=dlrnn", "data=DIR").model.name == "dlrnn"
    cfg = compose("eval", "experiment=mapprior_003_table36", "data=DIR", "model_path=/some/prior")
    assert cfg.model_path == "/some/prior"
    with pytest.warns(FutureWarning, match="model_path=/old"):  # the old blenav-eval spelling, for one release
        assert compose("eval", "data=DIR", "model=/old").model_path == "/old"
    assert cli_overrides(["model=locnet"]) == ["model=locnet"]


def test_tables_36_and_37_share_their_rows():
    t36 = compose("eval", "experiment=mapprior_003_table36", "data=DIR")
    t37 = compose("eval", "experiment=mapprior_003_table37", "data=DIR")
    assert list(t36.methods) == ["pdr", "io", "heuristic", "learned", "heuristic_noreinit"]
    assert [m.label for m in t36.methods.values()] == ["PDR", "IO", "heuristic-PF", "learned-map-prior",
                                                      "heuristic-PF-noreinit"]
    assert [m.label for m in t37.methods.values()] == ["IO", "sparse-BLE+IO", "IO+map", "sparse-BLE+IO+map",
                                                      "heuristic-PF", "heuristic-PF-noreinit", "PDR", "dense-BLE",
                                                      "sparse-BLE"]
    assert t36.filter == t37.filter and t36.filter.n_particles == 1000
    for key in ("pdr", "io", "heuristic", "heuristic_noreinit"):
        assert t36.methods[key] == t37.methods[key]
    same = {k: v for k, v in t36.methods.learned.items() if k != "label"}
    assert same == {k: v for k, v in t37.methods.io_map.items() if k != "label"}


# --------------------------------------------------------------------------- cross-phone device names

def test_crossphone_device_defaults_follow_the_train_devices():
    sim = compose("eval", "experiment=crossphone_003", "data=DIR").data
    assert list(sim.known_devices) == ["iphone-7", "iphone-8", "iphone-xr"]
    assert list(sim.unlabelled_devices) == ["mi-9", "mi-9t-pro", "redmi-note8"]
    other = compose("eval", "experiment=crossphone_003", "data=DIR", "data.train_devices=[A,B]",
                    "data.test_devices=[C,D]").data
    assert other.known_devices is None and other.unlabelled_devices is None
    given = compose("eval", "experiment=crossphone_003", "data=DIR", "data.train_devices=[A,B]",
                    "data.known_devices=[A]", "data.unlabelled_devices=[E]").data
    assert list(given.known_devices) == ["A"] and list(given.unlabelled_devices) == ["E"]
    s3 = compose("train", "experiment=crossphone_s3", "data=DIR", "data.train_devices=[A]").data
    assert s3.known_devices is None and s3.unlabelled_devices is None
    assert list(compose("train", "experiment=crossphone_s3", "data=DIR").data.unlabelled_devices) == [
        "mi-9", "mi-9t-pro", "redmi-note8"]


@pytest.fixture
def renamed_phones(two_phones, tmp_path) -> Path:
    """two_phones with receivers the simulator does not know (as another dataset's)."""
    root = Path(shutil.copytree(two_phones, tmp_path / "renamed"))
    names = {"iphone-8": "phone-a", "galaxy-s10": "phone-b"}
    for f in root.glob("sessions/*/session.yaml"):
        meta = yaml.safe_load(f.read_text())
        meta["device_model"] = names[meta["device_model"]]
        f.write_text(yaml.safe_dump(meta, sort_keys=False))
    return root


def test_crossphone_split_on_other_receiver_names(renamed_phones):
    """The documented override: only data.train_devices and data.test_devices are named."""
    from blenav.learn.crossphone.data import WindowDataModule
    from blenav.learn.crossphone.train import data_config

    cfg = compose("eval", "experiment=crossphone_003", f"data={renamed_phones}", "data.train_devices=[phone-a]",
                  "data.test_devices=[phone-b]")
    dm = WindowDataModule(data_config(cfg))
    dm.setup()
    assert {s.device_model for s in dm.groups["train"] + dm.groups["val"]} == {"phone-a"}
    assert {s.device_model for s in dm.groups["test"]} == {"phone-b"}
    assert dm.groups["unlabelled"] == [] and dm.sets["known"] is not None  # known = the train devices
