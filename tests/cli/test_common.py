"""Every entry point turns an error the user can fix into one line ``PROG: error: ...`` and exit code 1."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

from helpers import REPO, make_tiny_dataset

ROOT = REPO
BIN = Path(sys.executable).parent


def _run(*args, env=None):
    e = {**os.environ, **(env or {})}
    e.pop("BLENAV_DEBUG", None) if not env else None
    return subprocess.run(list(args), capture_output=True, text=True, cwd=ROOT, env=e, timeout=300)


def _one_line_error(p, prog, *words):
    lines = [ln for ln in p.stderr.splitlines() if ln.strip() and "Warning" not in ln and "warnings.warn" not in ln
             and "Seed set to" not in ln and not ln.startswith("evaluating:")]
    assert p.returncode == 1, (p.returncode, p.stderr)
    assert "Traceback" not in p.stderr, p.stderr
    assert len(lines) == 1 and lines[0].startswith(f"{prog}: error: "), p.stderr
    assert all(w in lines[0] for w in words), lines[0]
    return lines[0]


@pytest.fixture(scope="module")
def tiny(tmp_path_factory):
    return make_tiny_dataset(tmp_path_factory.mktemp("cli") / "tiny")


# One blenav-eval process each (~5 s): the nearest-key messages are checked in-process by
# tests/eval/test_config.py::test_a_misspelt_key_or_bad_value_fails_naming_it, the one-line CLI path by '+runz=3'
# here; the other spellings of a misspelt key run with -m slow.
SLOW = pytest.mark.slow


@pytest.mark.parametrize("override, words", [
    ("+runz=3", ["unknown key 'runz'", "did you mean 'runs'"]),
    pytest.param("runz=3", ["unknown key 'runz'", "did you mean 'runs'"], marks=SLOW),
    pytest.param("filter.n_particle=3", ["did you mean 'filter.n_particles'"], marks=SLOW),
    pytest.param("+plan_error.barriers=1", ["plan_error.barriers", "did you mean 'plan_error.barriers_per_100m2'"],
                 marks=SLOW),
    ("experiment=mapfusion_00", ["no experiment named 'mapfusion_00'", "did you mean 'mapfusion_002'"]),
])
def test_eval_refuses_unknown_keys_with_the_nearest(tiny, tmp_path, override, words):
    p = _run(BIN / "blenav-eval", "experiment=mapfusion_002", f"data={tiny}", f"out={tmp_path / 'o'}", override)
    _one_line_error(p, "blenav-eval", *words)
    assert not (tmp_path / "o").exists()


@pytest.mark.parametrize("flag", [["-cp", "CFG"], ["--config-path=CFG"], ["--config-pa", "CFG"]])
def test_config_path_is_refused_in_one_line(tmp_path, flag):
    """``--config-path`` would replace blenav's conf/ (Hydra printed 'Cannot find primary config' over several lines,
    exit 1 only by chance of its message); --config-dir is the way to add configs."""
    (tmp_path / "cfg").mkdir()
    args = [a.replace("CFG", str(tmp_path / "cfg")) for a in flag]
    p = _run(BIN / "blenav-sim", *args, "-cn", "sim", f"out={tmp_path / 'o'}")
    _one_line_error(p, "blenav-sim", "--config-path replaces blenav's own configs", "--config-dir DIR")
    assert not (tmp_path / "o").exists()


def test_a_failing_run_leaves_no_output_folder_and_the_bar_does_not_hide_the_error(tiny, tmp_path):
    out = tmp_path / "o"
    # a setting only the run can refuse (the obstacle rule is built per session): fails after OUT was made
    p = _run(BIN / "blenav-eval", "experiment=mapfusion_002", f"data={tiny}", f"out={out}", "runs=1", "progress=true",
             "calibration=none", "+methods.pf_pl.filter.reinit_fraction=1.5")
    line = _one_line_error(p, "blenav-eval", "reinit_fraction", "PF-PL")
    assert p.stderr.rstrip().endswith(line)  # the last thing on the terminal
    assert not out.exists()


# slow (one more blenav-eval run, ~10 s): the traceback only with --debug is
# tests/cli/test_outdir.py::test_memory_and_import_errors_are_one_line_and_the_traceback_only_with_debug
@pytest.mark.slow
def test_a_failing_run_shows_its_traceback_with_debug(tiny, tmp_path):
    p = _run(BIN / "blenav-eval", "experiment=mapfusion_002", f"data={tiny}", f"out={tmp_path / 'o'}", "runs=1",
             "calibration=none", "+methods.pf_pl.filter.reinit_fraction=1.5", "--debug")
    assert p.returncode == 1 and "Traceback" in p.stderr


def test_train_and_export_say_what_is_missing(tmp_path):
    from blenav.configs import compose
    from blenav.learn.export import export
    from blenav.learn.train import train

    _one_line_error(_run(sys.executable, "train.py"), "train.py", "data=DIR")
    _one_line_error(_run(sys.executable, "export.py"), "export.py", "ckpt=")
    # a path that does not exist: the errors the entry points print (in-process; through them: the slow test below)
    with pytest.raises(ValueError, match=r"nope: \[missing-dataset\] dataset folder does not exist"):
        train(compose("train", f"data={tmp_path / 'nope'}", f"out={tmp_path / 'run'}"))
    with pytest.raises(FileNotFoundError, match=r"checkpoint .*x\.ckpt does not exist"):
        export(compose("export", f"ckpt={tmp_path / 'x.ckpt'}", f"out={tmp_path / 'x.onnx'}"))


# slow (two more train.py / export.py processes, ~30 s): the same errors in-process and the one-line path of both
# entry points are in the test above
@pytest.mark.slow
def test_train_and_export_name_a_path_that_does_not_exist(tmp_path):
    _one_line_error(_run(sys.executable, "train.py", f"data={tmp_path / 'nope'}"), "train.py", "does not exist")
    _one_line_error(_run(sys.executable, "export.py", f"ckpt={tmp_path / 'x.ckpt'}", f"out={tmp_path / 'x.onnx'}"),
                    "export.py", "does not exist")


def test_fixes_refuses_a_file_that_is_not_onnx(tiny, tmp_path):
    bad = tmp_path / "garbage.onnx"
    bad.write_bytes(b"\x00not a model")
    _one_line_error(_run(BIN / "blenav-fixes", str(tiny), str(bad)), "blenav-fixes", "garbage.onnx",
                    "not an ONNX model")


# One blenav-eval process each (~10 s): the readers' messages are checked in-process (tests/data/test_dataset.py,
# tests/data/test_schema.py), corrupted datasets through the command line by
# tests/cli/test_fuzz_cli.py::test_cli_refuses_a_corrupted_dataset_in_one_line; two of the three run with -m slow.
@pytest.mark.parametrize("fault", ["no-building-yaml", pytest.param("unknown-building", marks=SLOW),
                                   pytest.param("labelled-without-groundtruth", marks=SLOW)])
def test_eval_on_a_broken_dataset_is_one_line_naming_the_file(tiny, tmp_path, fault):
    """Issue 19: these printed a ~20-line Hydra traceback ending in the clear message."""
    import shutil

    import yaml

    data = tmp_path / "d"
    shutil.copytree(tiny, data)
    if fault == "no-building-yaml":
        (data / "buildings" / "house" / "building.yaml").unlink()
        words = ["building.yaml"]
    elif fault == "unknown-building":
        meta = data / "sessions" / "walk0" / "session.yaml"
        doc = yaml.safe_load(meta.read_text())
        doc["building"] = "castle"
        meta.write_text(yaml.safe_dump(doc))
        words = ["session.yaml", "castle"]
    else:
        (data / "sessions" / "walk0" / "groundtruth.csv").unlink()
        words = ["walk0", "groundtruth"]
    p = _run(BIN / "blenav-eval", "experiment=mapfusion_002", f"data={data}", f"out={tmp_path / 'o'}", "runs=1")
    _one_line_error(p, "blenav-eval", *words)
    assert not (tmp_path / "o").exists()


_COUNT_COMPOSITIONS = """
import sys, hydra
made = []
real = hydra.compose
def counting(*a, **k):
    made.append(1)
    return real(*a, **k)
hydra.compose = counting  # blenav's checks compose through hydra.compose; Hydra's own run does not
from blenav.cli.common import run_hydra
got = []
run_hydra('prog', 'eval', lambda cfg: got.append(cfg.runs), sys.argv[1:])
print('compositions', len(made), 'runs', got)
"""


@pytest.mark.parametrize("extra, checks", [(["runs=3"], 1), (["++runs=3"], 3)])
def test_plain_overrides_are_composed_once_before_hydra(extra, checks):
    """The start-up checks compose the config once when no override adds or deletes a key (check_overrides' two
    compositions could only fail where that one fails: they run then, or for ``+`` / ``~``): ~0.4 s each."""
    p = _run(sys.executable, "-c", _COUNT_COMPOSITIONS, "experiment=mapfusion_002", "data.path=/x", *extra)
    assert p.returncode == 0, p.stderr
    assert p.stdout.splitlines()[-1] == f"compositions {checks} runs [3]"
