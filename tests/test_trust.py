"""Nothing from a file runs code (issue 28, section 1): a ``_target_`` is data, checked against blenav's own classes
(:data:`blenav.trust.TARGETS`) by name before anything is imported.

- the registry: every ``_target_`` of conf/**/*.yaml and of the configs code writes is in it, and every entry imports
  to a class under ``blenav`` (so it cannot drift from conf/);
- checkpoints: a ``blenav.model`` node naming ``numpy.savetxt`` at any depth is refused by the cross-phone loader, the
  export (also ``python export.py``) and the map prior's loader, and the file it would write is never written;
- configs: a nested ``_target_`` from a command-line override or from an experiment file of ``--config-dir`` (also
  in its ``hydra`` node, and with a ``-`` flag such as ``-r`` on the command line) ends as one line
  ``blenav-eval: error:`` with exit code 1, before anything runs;
- bundles: settings.json naming a class that does not exist (or is not a motion model) is one ValueError naming the
  file and the field; a manifest without files, or a folder with a file the manifest does not list, is refused;
- a property test: configs with a foreign ``_target_`` at a random depth are refused, and the function it names (in
  this module) is never called.
"""

from __future__ import annotations

import hashlib
import json
import re
import subprocess
import sys
from pathlib import Path
from types import SimpleNamespace

import pytest
import torch
import yaml
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from omegaconf import OmegaConf

from blenav.cli.common import _hydra_args
from blenav.learn.crossphone.checkpoint import build_networks, load_module
from blenav.learn.export import export
from blenav.learn.mapprior.checkpoint import build_net, load_mapprior
from blenav.runtime.bundle import DEFAULT_SETTINGS, FORMAT, MANIFEST, Bundle
from blenav.runtime.bundle.settings import MOTION_TARGETS, build_method
from blenav.runtime.bundle.verify import verify_files
from blenav.trust import (HYDRA_TARGETS, TARGETS, UntrustedTargetError, check_hydra_node, check_targets,
                          safe_instantiate)

REPO = Path(__file__).resolve().parents[1]
BIN = Path(sys.executable).parent
CALLS: list = []


def record_call(*args, **kwargs):
    """The 'code' a hostile config names (as :data:`RECORD_CALL`): it records that it ran."""
    CALLS.append((args, kwargs))


#: record_call's dotted name as this module is imported (``test_trust`` or ``tests.test_trust``, by import mode): a
#: config naming it reaches this module's CALLS, not those of a second copy imported under another name.
RECORD_CALL = f"{__name__}.record_call"


# --- the registry ----------------------------------------------------------------------------------------------

def _targets(node, path=""):
    """(key path, value) of every ``_target_`` below a YAML document."""
    if isinstance(node, dict):
        for k, v in node.items():
            p = f"{path}.{k}" if path else str(k)
            if k == "_target_":
                yield p, v
            yield from _targets(v, p)
    elif isinstance(node, list):
        for i, v in enumerate(node):
            yield from _targets(v, f"{path}[{i}]")


def test_every_target_of_conf_and_code_is_in_the_registry():
    found = {}
    for f in sorted((REPO / "conf").rglob("*.yaml")):
        for path, value in _targets(yaml.safe_load(f.read_text(encoding="utf-8")) or {}):
            found[f"{f.relative_to(REPO)}:{path}"] = value
    assert len(found) >= 30  # conf/ names its classes in many files
    hydra_own = {k: v for k, v in found.items() if k.split(":")[1].startswith("hydra.")}
    assert hydra_own and all(v in HYDRA_TARGETS for v in hydra_own.values()), hydra_own
    missing = {k: v for k, v in found.items() if k not in hydra_own and v not in TARGETS}
    assert not missing, f"_target_ of conf/ not in blenav.trust.TARGETS: {missing}"
    # targets written by code: "_target_": "NAME" literals in src/
    literals = {m for p in (REPO / "src").rglob("*.py")
                for m in re.findall(r"""["']_target_["']\s*:\s*["']([\w.]+)["']""", p.read_text(encoding="utf-8"))}
    assert "blenav.filters.motion.OdometryIncrement" in literals and literals <= TARGETS
    assert DEFAULT_SETTINGS["motion"]["_target_"] in MOTION_TARGETS


def test_every_registry_entry_is_a_blenav_class():
    import importlib

    assert len(TARGETS) >= 30
    for name in sorted(TARGETS):
        mod, _, attr = name.rpartition(".")
        obj = getattr(importlib.import_module(mod), attr)
        assert isinstance(obj, type) and obj.__module__.startswith("blenav."), name
    assert MOTION_TARGETS == {t for t in TARGETS if t.startswith("blenav.filters.motion.")} and len(MOTION_TARGETS) == 5


def test_the_test_target_is_reachable_without_the_check():
    """The property test below is meaningful: Hydra itself would call :data:`RECORD_CALL`."""
    from hydra.utils import instantiate

    CALLS.clear()
    instantiate({"a": [{"_target_": RECORD_CALL, "x": 1}]})
    assert CALLS == [((), {"x": 1})]
    CALLS.clear()


# --- checkpoints -----------------------------------------------------------------------------------------------

def _savetxt(path: Path) -> dict:
    return {"_target_": "numpy.savetxt", "fname": str(path), "X": [1.0, 2.0]}


def _locnet(**extra) -> dict:
    return {"_target_": "blenav.models.LocNet", "hidden": 8, "layers": 1, "fc_hidden": 4, **extra}


@pytest.mark.parametrize("where", ["locnet", "locnet.init", "transnet.list", "weights"])
def test_a_checkpoint_naming_savetxt_is_refused_and_nothing_is_written(tmp_path, where):
    pwned = tmp_path / "pwned.txt"
    model = {"name": "locnet", "lr": 1e-3, "locnet": _locnet()}
    if where == "locnet":
        model["locnet"] = _savetxt(pwned)
    elif where == "locnet.init":
        model["locnet"] = _locnet(init=_savetxt(pwned))
    elif where == "transnet.list":
        model["transnet"] = {"_target_": "blenav.models.TransNet", "hidden": [4, {"deep": [_savetxt(pwned)]}]}
    else:
        model["weights"] = {"ps": 0.1, "x": _savetxt(pwned)}
    meta = {"model": model, "beacons": ["b1", "b2", "b3"], "building": "house",
            "window": {"history": 4, "step_hz": 1.0, "offset_db": 100.0, "floor_u": 1.0, "u_scale": 100.0}}
    ck = tmp_path / "last.ckpt"
    torch.save({"blenav": meta, "state_dict": {}}, ck)
    for load in (lambda: load_module(ck), lambda: export(SimpleNamespace(ckpt=str(ck), out=str(tmp_path / "m.onnx")))):
        with pytest.raises(UntrustedTargetError, match=r"'numpy\.savetxt'") as e:
            load()
        assert str(ck) in str(e.value) and "_target_" in str(e.value) and "\n" not in str(e.value)
    path = {"locnet": "blenav.model.locnet._target_", "locnet.init": "blenav.model.locnet.init._target_",
            "transnet.list": "blenav.model.transnet.hidden[1].deep[0]._target_",
            "weights": "blenav.model.weights.x._target_"}[where]
    assert path in str(e.value)
    with pytest.raises(UntrustedTargetError):  # the builder checks the node itself too (train.py, other callers)
        build_networks(model, 3)
    assert not pwned.exists()
    assert not (tmp_path / "m.onnx").exists()


def test_export_py_refuses_it_in_one_line(tmp_path):
    pwned = tmp_path / "pwned.txt"
    ck = tmp_path / "last.ckpt"
    torch.save({"blenav": {"model": {"locnet": _locnet(init=_savetxt(pwned))}, "beacons": ["b1"],
                           "window": {"history": 4}}, "state_dict": {}}, ck)
    p = subprocess.run([sys.executable, str(REPO / "export.py"), f"ckpt={ck}", f"out={tmp_path / 'm.onnx'}"],
                       capture_output=True, text=True, cwd=tmp_path, timeout=300)
    lines = p.stderr.strip().splitlines()
    assert p.returncode == 1 and len(lines) == 1 and lines[0].startswith("export.py: error: checkpoint "), p.stderr
    assert "blenav.model.locnet.init._target_ = 'numpy.savetxt'" in lines[0]
    assert not pwned.exists()


def test_a_map_prior_checkpoint_naming_savetxt_is_refused(tmp_path):
    pwned = tmp_path / "pwned.txt"
    net = {"_target_": "blenav.models.mapprior.MapPriorNet", "channels": 4, "unet_channels": [4, {"x": _savetxt(pwned)}]}
    model = {"kind": "mapprior", "name": "mapprior", "net": net, "resolution_m": 0.5}
    ck = tmp_path / "last.ckpt"
    torch.save({"blenav": {"kind": "mapprior", "model": model, "window": {"n_points": 6, "step_hz": 1.0}},
                "state_dict": {}}, ck)
    with pytest.raises(UntrustedTargetError, match=r"blenav\.model\.net\.unet_channels\[1\]\.x\._target_"):
        load_mapprior(ck)
    with pytest.raises(UntrustedTargetError, match=r"model\.net\.unet_channels\[1\]\.x\._target_"):
        build_net(model, 6, 1.0)
    assert not pwned.exists()


# --- command line and config files ------------------------------------------------------------------------------

def _eval(tmp_path, *args):
    return subprocess.run([str(BIN / "blenav-eval"), *args], capture_output=True, text=True, cwd=tmp_path, timeout=300)


def _refused(p, *words):
    lines = p.stderr.strip().splitlines()
    assert p.returncode == 1, p.stderr[-2000:]
    assert len(lines) == 1 and lines[0].startswith("blenav-eval: error: "), p.stderr[-2000:]
    for w in words:
        assert w in lines[0], lines[0]


@pytest.mark.parametrize("flag", [[], ["-r"]])
def test_an_override_with_a_nested_target_is_refused(tiny_dataset, tmp_path, flag):
    pwned = tmp_path / "pwned.txt"
    p = _eval(tmp_path, *flag, "experiment=mapfusion_002", f"data={tiny_dataset}", "runs=1", f"out={tmp_path / 'o'}",
              "plots=false", "progress=false",
              f"+methods.pf_pl.motion.init={{_target_: numpy.savetxt, fname: '{pwned}', X: [1]}}")
    _refused(p, "methods.pf_pl.motion.init._target_ = 'numpy.savetxt'")
    assert not pwned.exists() and not (tmp_path / "o").exists()


def test_an_experiment_file_from_config_dir_is_checked(tiny_dataset, tmp_path):
    pwned = tmp_path / "pwned.txt"
    d = tmp_path / "confdir" / "experiment"
    d.mkdir(parents=True)
    head = "# @package _global_\ndefaults:\n  - mapfusion_002\n"
    (d / "evil.yaml").write_text(head + f"methods:\n  pf_ps:\n    measurements:\n      ps:\n        extra:\n"
                                 f"          - {{_target_: numpy.savetxt, fname: '{pwned}', X: [1]}}\n")
    (d / "evil_hydra.yaml").write_text(head + "hydra:\n  callbacks:\n    x:\n"
                                       f"      _target_: numpy.savetxt\n      fname: '{pwned}'\n      X: [1]\n")
    common = [f"data={tiny_dataset}", "runs=1", f"out={tmp_path / 'o'}", "plots=false", "progress=false"]
    _refused(_eval(tmp_path, "--config-dir", str(tmp_path / "confdir"), "experiment=evil", *common),
             "methods.pf_ps.measurements.ps.extra[0]._target_ = 'numpy.savetxt'")
    _refused(_eval(tmp_path, f"--config-dir={tmp_path / 'confdir'}", "experiment=evil_hydra", *common),
             "hydra.callbacks.x._target_ = 'numpy.savetxt'")
    assert not pwned.exists() and not (tmp_path / "o").exists()


def test_hydra_flags_are_read_as_hydra_reads_them():
    over, opts = _hydra_args(["-m", "a=1", "--config-d=/x", "-cn", "eval", "--info", "b=2", "--cfg", "job", "-r"])
    assert over == ["a=1", "b=2"]
    assert opts == {"--multirun": None, "--config-dir": "/x", "--config-name": "eval", "--info": None,
                    "--cfg": "job", "--run": None}
    assert _hydra_args(["--experimental-r", "f.pickle"])[1] == {"--experimental-rerun": "f.pickle"}


def test_hydra_node_checks_logging_factories_and_search_space():
    ok = {"launcher": {"_target_": "hydra._internal.core_plugins.basic_launcher.BasicLauncher"},
          "job_logging": {"handlers": {"console": {"class": "logging.StreamHandler"}}}}
    check_hydra_node(OmegaConf.create(ok), "cfg")
    for bad, words in [({"job_logging": {"formatters": {"f": {"()": "os.system"}}}}, "hydra.job_logging.formatters.f.()"),
                       ({"hydra_logging": {"handlers": {"h": {"class": "subprocess.Popen"}}}}, "hydra.hydra_logging"),
                       ({"sweeper": {"custom_search_space": RECORD_CALL}}, "custom_search_space"),
                       ({"callbacks": {"c": {"_target_": RECORD_CALL}}}, "hydra.callbacks.c._target_"),
                       # red-team: a --config-dir file's env_set reached os.environ (LD_PRELOAD for any child
                       # process, BLENAV_MAX_MEMORY_GB lifting the memory bound)
                       ({"job": {"env_set": {"LD_PRELOAD": "/tmp/x.so"}}}, "hydra.job.env_set sets LD_PRELOAD"),
                       ({"job": {"env_set": {"BLENAV_MAX_MEMORY_GB": "1e9"}}}, "sets BLENAV_MAX_MEMORY_GB")]:
        with pytest.raises(UntrustedTargetError, match=re.escape(words)):
            check_hydra_node(OmegaConf.create(bad), "cfg")


# --- bundles ---------------------------------------------------------------------------------------------------

@pytest.mark.parametrize("target", ["nonexistent.module.Cls", "blenav.filters.nope.X", "blenav.models.LocNet"])
def test_bundle_settings_naming_an_unknown_class_is_one_value_error(tmp_path, target):
    settings = json.loads(json.dumps(DEFAULT_SETTINGS))
    settings["motion"]["_target_"] = target
    where = str(tmp_path / "B" / "settings.json")
    with pytest.raises(ValueError) as e:
        build_method(settings, where=where)
    msg = str(e.value)
    assert isinstance(e.value, UntrustedTargetError) and "\n" not in msg
    assert msg.startswith(where + ": ") and f"motion._target_ = '{target}'" in msg
    assert "blenav.filters.motion.OdometryIncrement" in msg  # names what it may be


def test_bundle_motion_with_an_argument_it_does_not_take_is_a_value_error():
    settings = json.loads(json.dumps(DEFAULT_SETTINGS))
    settings["motion"]["sigma_typo"] = 1.0
    with pytest.raises(ValueError, match=r"^B/settings\.json: motion \(OdometryIncrement\): .*sigma_typo"):
        build_method(settings, where="B/settings.json")
    assert build_method(json.loads(json.dumps(DEFAULT_SETTINGS))).motion.__class__.__name__ == "OdometryIncrement"


def _fake_bundle(root: Path, settings: dict | None = None) -> dict:
    """A bundle folder whose manifest lists its files (the graph is a placeholder: nothing here reaches it)."""
    root.mkdir(parents=True)
    (root / "settings.json").write_text(json.dumps(settings or DEFAULT_SETTINGS))
    (root / "building.json").write_text(json.dumps({"building": "house", "beacons": []}))
    (root / "localizer.onnx").write_bytes(b"not a graph")
    files = {p.name: {"sha256": hashlib.sha256(p.read_bytes()).hexdigest(), "bytes": p.stat().st_size}
             for p in sorted(root.iterdir())}
    manifest = {"format": FORMAT, "files": files, "variants_available": ["float"]}
    (root / MANIFEST).write_text(json.dumps(manifest))
    return manifest


def _write(root: Path, manifest: dict) -> None:
    (root / MANIFEST).write_text(json.dumps(manifest))


def test_bundle_verification_is_whole(tmp_path):
    B = tmp_path / "B"
    m = _fake_bundle(B)
    verify_files(B, m)  # every file listed, as written
    for files, words in [({}, "lists no files ('files' is empty)"), (None, "'files' is missing"),
                         ({"settings.json": m["files"]["settings.json"]}, "does not list building.json, localizer.onnx"),
                         ({**m["files"], "../outside": {"sha256": "0"}}, "'../outside' is not a path inside")]:
        bad = {k: v for k, v in m.items() if k != "files"} | ({} if files is None else {"files": files})
        _write(B, bad)
        for check in (lambda: verify_files(B, bad), lambda: Bundle.open(B)):
            with pytest.raises(ValueError, match=r"bundle .*" + re.escape(words)):
                check()
    _write(B, m)
    (B / "evil.py").write_text("print('hi')\n")
    (B / "map_prior").mkdir()
    (B / "map_prior" / "x.onnx").write_bytes(b"x")
    with pytest.raises(ValueError, match=r"2 file\(s\) the manifest does not list: evil\.py, map_prior/x\.onnx"):
        Bundle.open(B)


def test_bundle_open_refuses_settings_naming_another_class(tmp_path):
    s = json.loads(json.dumps(DEFAULT_SETTINGS))
    s["motion"]["hook"] = {"_target_": RECORD_CALL}
    _fake_bundle(tmp_path / "B", s)
    with pytest.raises(UntrustedTargetError, match=re.escape(f"settings.json: motion.hook._target_ = '{RECORD_CALL}'")):
        Bundle.open(tmp_path / "B")


# --- the property: a foreign target anywhere is refused, and never called -----------------------------------

_keys = st.text(alphabet="abcdefghijklmnopqrstuvwxyz", min_size=1, max_size=6)
_leaf = st.one_of(st.none(), st.booleans(), st.integers(-5, 5), st.floats(allow_nan=False, allow_infinity=False),
                  st.text(alphabet="abc xyz019", max_size=8), st.just({"_target_": "blenav.filters.motion.RandomWalk", "sigma_p": 0.1}))
_benign = st.recursive(_leaf, lambda inner: st.one_of(st.lists(inner, max_size=3),
                                                      st.dictionaries(_keys, inner, max_size=3)), max_leaves=8)
_step = st.one_of(st.tuples(st.just("dict"), _keys, st.dictionaries(_keys, _benign, max_size=2)),
                  st.tuples(st.just("list"), st.integers(0, 3), st.lists(_benign, max_size=3)))


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(steps=st.lists(_step, min_size=1, max_size=6), kwargs=st.dictionaries(_keys, _benign, max_size=2),
       partial=st.booleans(), as_omegaconf=st.booleans())
def test_a_foreign_target_at_any_depth_is_refused_and_never_called(steps, kwargs, partial, as_omegaconf):
    node = {**kwargs, "_target_": RECORD_CALL, **({"_partial_": True} if partial else {})}
    segments = []
    for kind, key, siblings in reversed(steps):  # from the foreign node outwards
        if kind == "dict":
            node = {**{k: v for k, v in siblings.items() if k != key}, key: node}
            segments.append(f".{key}")
        else:
            i = min(key, len(siblings))
            node = siblings[:i] + [node] + siblings[i:]
            segments.append(f"[{i}]")
    path = "root" + "".join(reversed(segments)) + "._target_"
    cfg = {"root": node}
    if as_omegaconf:
        cfg = OmegaConf.create(cfg)
    CALLS.clear()
    with pytest.raises(UntrustedTargetError) as e:
        check_targets(cfg, "generated")
    assert f"{path} = '{RECORD_CALL}'" in str(e.value)
    with pytest.raises(UntrustedTargetError):
        safe_instantiate(cfg, "generated")
    with pytest.raises(UntrustedTargetError):
        build_networks({"locnet": {**_locnet(), "x": node}}, 3)
    settings_ = json.loads(json.dumps(DEFAULT_SETTINGS))
    settings_["motion"]["x"] = node
    with pytest.raises(UntrustedTargetError):
        build_method(settings_, where="generated/settings.json")
    assert CALLS == []


def test_a_plain_dict_whose_interpolation_creates_a_target_is_refused_before_hydra_builds_it(monkeypatch):
    """A plain dict (e.g. a checkpoint's meta) holding ``${oc.create:{_target_: ...}}``: Hydra's instantiate turns it
    into an omegaconf node and resolves it, so the check resolves it too and refuses the created target; the target
    is never called. A plain dict without interpolations needs no omegaconf."""
    import os

    from blenav.trust import UntrustedTargetError, check_targets, safe_instantiate

    called = []
    monkeypatch.setattr(os, "getcwd", lambda: called.append(1) or "/")
    node = {"_target_": "blenav.models.LocNet", "n_beacons": 3, "hidden": "${oc.create:{_target_: os.getcwd}}"}
    with pytest.raises(UntrustedTargetError, match=r"hidden\._target_ = 'os\.getcwd'"):
        check_targets(node, "meta")
    with pytest.raises(UntrustedTargetError):
        safe_instantiate(node, "meta")
    assert not called
    check_targets({"a": 1, "b": ["x", {"c": "plain"}]}, "meta")
