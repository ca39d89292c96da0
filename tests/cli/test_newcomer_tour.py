"""The five-minute tour on the ``small`` preset works as written (issue 19, section 4): simulate, train the
scenario-2 localizer, export it, write its fixes -- four commands, no error, and the test error train.py
prints is the one of the fixes the exported model writes on the test phone's walk. And the devices of the
cross-phone experiments follow the dataset (conf/experiment/crossphone_s2.yaml, resolver
``blenav.dataset_devices``)."""

from __future__ import annotations

import ast
import os
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
import yaml

from blenav.configs import compose
from blenav.data import Dataset

from helpers import REPO

BIN = Path(sys.executable).parent


def _run(args: list, timeout: int = 600) -> subprocess.CompletedProcess:
    env = {**os.environ, "PATH": f"{BIN}{os.pathsep}{os.environ.get('PATH', '')}"}
    r = subprocess.run([str(a) for a in args], cwd=REPO, capture_output=True, text=True, timeout=timeout, env=env)
    assert r.returncode == 0, f"{args}\n{r.stdout[-2000:]}\n{r.stderr[-3000:]}"
    return r


@pytest.fixture(scope="module")
def small(tmp_path_factory) -> Path:
    """`blenav-sim sim=small seed=0 out=DIR`, exactly as the tour says (2 sessions of 120 s)."""
    out = tmp_path_factory.mktemp("tour") / "small"
    r = _run([BIN / "blenav-sim", "sim=small", "seed=0", f"out={out}", "progress=false"])
    assert f"wrote {out}" in r.stdout
    return out


def _devices(root: Path) -> list[str]:
    return sorted(yaml.safe_load(p.read_text())["device_model"] for p in root.glob("sessions/*/session.yaml"))


@pytest.mark.onnx
def test_the_tour_runs_on_the_small_preset(small, tmp_path):
    run = tmp_path / "run"
    r = _run([sys.executable, "train.py", "experiment=crossphone_s2", f"data={small}", f"out={run}",
              "trainer.max_epochs=1", "trainer.enable_progress_bar=false"])
    test_err = ast.literal_eval(r.stdout.strip().splitlines()[-1])["test/err_m"]  # train.py's last line: metrics
    r = _run([sys.executable, "export.py", f"ckpt={run / 'last.ckpt'}", f"out={run / 'model.onnx'}"])
    assert r.stdout.strip() == f"wrote {run / 'model.onnx'}"
    data = Path(shutil.copytree(small, tmp_path / "small"))  # fixes.csv goes into the dataset
    r = _run([BIN / "blenav-fixes", data, run / "model.onnx"])
    assert r.stdout.startswith("wrote ") and "to 2 session(s)" in r.stdout and not r.stderr.strip()
    assert len(list(data.glob("sessions/*/fixes.csv"))) == 2
    # the printed test error is the exported model's: the mean distance of its fixes on the test phone's walk to
    # the ground truth, over the windows the test step scores (each with a previous window, so not the first one;
    # labelled, so ending within the ground truth); 4 decimals printed, fixes written to 0.1 mm
    train_devices = yaml.safe_load((run / "config.yaml").read_text())["data"]["train_devices"]
    test = [s for s in Dataset.open(data).sessions() if s.device_model not in train_devices]
    assert [s.device_model for s in test] == ["pixel-3xl"]
    err = []
    for s in test:
        fixes, gt = pd.read_csv(s.root / "fixes.csv"), s.groundtruth
        fixes = fixes[fixes["t"] <= gt["t"].iloc[-1]].iloc[1:]
        err.append(np.hypot(fixes["x"] - np.interp(fixes["t"], gt["t"], gt["x"]),
                            fixes["y"] - np.interp(fixes["t"], gt["t"], gt["y"])))
    assert test_err == pytest.approx(np.concatenate(err).mean(), abs=5e-4)
    x0, x1, y0, y1 = test[0].floor.extent
    assert np.isfinite(test_err) and 0 < test_err < np.hypot(x1 - x0, y1 - y0)  # inside the 20 x 15 m floor
    # --calibrate on a walk the model trained on warns (issue 19); on a walk it never saw, it does not
    from blenav.runtime import OnnxLocalizer

    seen = OnnxLocalizer(run / "model.onnx").meta.get("train_sessions")
    assert seen, "the export records the sessions the model saw"
    r = _run([BIN / "blenav-fixes", data, run / "model.onnx", "--calibrate", "--sessions", seen[0]])
    assert f"warning: session(s) {seen[0]} trained the model" in r.stderr
    unseen = [p.parent.name for p in data.glob("sessions/*/session.yaml") if p.parent.name not in seen]
    if unseen:
        r = _run([BIN / "blenav-fixes", data, run / "model.onnx", "--calibrate", "--sessions", unseen[0]])
        assert "warning" not in r.stderr


def test_experiment_devices_follow_the_dataset(small, two_phones, tmp_path):
    assert _devices(small) == ["iphone-8", "pixel-3xl"]
    d = compose("train", "experiment=crossphone_s2", f"data={small}").data
    assert (list(d.train_devices), list(d.known_devices), d.unlabelled_devices) == (["iphone-8"], ["iphone-8"], None)
    d = compose("train", "experiment=crossphone_s3", f"data={two_phones}").data
    assert list(d.train_devices) == ["iphone-8", "galaxy-s10"] and list(d.known_devices) == ["iphone-8"]
    assert d.unlabelled_devices is None  # no Xiaomi-like phone here: the semi stage asks for data.unlabelled_devices
    # none of the named phones: every device (null), known = the train devices
    other = Path(shutil.copytree(small, tmp_path / "other"))
    for p in other.glob("sessions/*/session.yaml"):
        doc = yaml.safe_load(p.read_text())
        doc["device_model"] = "phone-" + doc["device_model"]
        p.write_text(yaml.safe_dump(doc))
    d = compose("train", "experiment=crossphone_s2", f"data={other}").data
    assert d.train_devices is None and d.known_devices is None and d.unlabelled_devices is None
    # devices named on the command line are taken as named; the known devices follow them
    d = compose("train", "experiment=crossphone_s2", f"data={small}", "data.train_devices=[pixel-3xl]").data
    assert list(d.train_devices) == ["pixel-3xl"] and d.known_devices is None
    # no dataset (yet): the lists are the experiment's, for the data module to check
    d = compose("train", "experiment=crossphone_s2", f"data={tmp_path / 'none'}").data
    assert list(d.known_devices) == ["iphone-7", "iphone-8", "iphone-xr"]


# slow (a train.py process, ~12 s): the message is tests/features/test_windows.py's split_by_device check
# ("no session"), train.py's one-line path tests/cli/test_common.py::test_train_and_export_say_what_is_missing
@pytest.mark.slow
def test_named_devices_the_dataset_lacks_are_one_line_naming_its_devices(small, tmp_path):
    r = subprocess.run([sys.executable, "train.py", "experiment=crossphone_s2", f"data={small}",
                        f"out={tmp_path / 'run'}", "data.train_devices=[galaxy-s10]"], cwd=REPO, capture_output=True,
                       text=True, timeout=300)
    assert r.returncode == 1
    line = r.stderr.strip().splitlines()[-1]
    assert line == ("train.py: error: train devices ['galaxy-s10'] have no session; device models here: "
                    "['iphone-8', 'pixel-3xl']"), r.stderr[-2000:]
