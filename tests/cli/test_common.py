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


@pytest.mark.parametrize("override, words", [
    ("+runz=3", ["unknown key 'runz'", "did you mean 'runs'"]),
    ("runz=3", ["unknown key 'runz'", "did you mean 'runs'"]),
    ("filter.n_particle=3", ["did you mean 'filter.n_particles'"]),
    ("+plan_error.barriers=1", ["plan_error.barriers", "did you mean 'plan_error.barriers_per_100m2'"]),
    ("experiment=mapfusion_00", ["no experiment named 'mapfusion_00'", "did you mean 'mapfusion_002'"]),
])
def test_eval_refuses_unknown_keys_with_the_nearest(tiny, tmp_path, override, words):
    p = _run(BIN / "blenav-eval", "experiment=mapfusion_002", f"data={tiny}", f"out={tmp_path / 'o'}", override)
    _one_line_error(p, "blenav-eval", *words)
    assert not (tmp_path / "o").exists()


def test_a_failing_run_leaves_no_output_folder_and_the_bar_does_not_hide_the_error(tiny, tmp_path):
    out = tmp_path / "o"
    # a setting only the run can refuse (the obstacle rule is built per session): fails after OUT was made
    p = _run(BIN / "blenav-eval", "experiment=mapfusion_002", f"data={tiny}", f"out={out}", "runs=1", "progress=true",
             "calibration=none", "+methods.pf_pl.filter.reinit_fraction=1.5")
    line = _one_line_error(p, "blenav-eval", "reinit_fraction", "PF-PL")
    assert p.stderr.rstrip().endswith(line)  # the last thing on the terminal
    assert not out.exists()
    p = _run(BIN / "blenav-eval", "experiment=mapfusion_002", f"data={tiny}", f"out={out}", "runs=1",
             "calibration=none", "+methods.pf_pl.filter.reinit_fraction=1.5", "--debug")
    assert p.returncode == 1 and "Traceback" in p.stderr


def test_train_and_export_say_what_is_missing(tmp_path):
    _one_line_error(_run(sys.executable, "train.py"), "train.py", "data=DIR")
    _one_line_error(_run(sys.executable, "train.py", f"data={tmp_path / 'nope'}"), "train.py", "does not exist")
    _one_line_error(_run(sys.executable, "export.py"), "export.py", "ckpt=")
    _one_line_error(_run(sys.executable, "export.py", f"ckpt={tmp_path / 'x.ckpt'}", f"out={tmp_path / 'x.onnx'}"),
                    "export.py", "does not exist")


def test_fixes_refuses_a_file_that_is_not_onnx(tiny, tmp_path):
    bad = tmp_path / "garbage.onnx"
    bad.write_bytes(b"\x00not a model")
    _one_line_error(_run(BIN / "blenav-fixes", str(tiny), str(bad)), "blenav-fixes", "garbage.onnx",
                    "not an ONNX model")


@pytest.mark.parametrize("fault", ["no-building-yaml", "unknown-building", "labelled-without-groundtruth"])
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
