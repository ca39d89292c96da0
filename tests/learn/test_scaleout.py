"""Scale-out without new code: 2-process DDP on CPU (gloo) and a Hydra multirun with the joblib launcher."""

from __future__ import annotations

import ast
import csv
import subprocess
import sys
from pathlib import Path

import pytest
import torch

from helpers import REPO

ROOT = REPO
TINY = ["trainer.max_epochs=1", "trainer.enable_progress_bar=false", "model.locnet.hidden=16",
        "model.locnet.fc_hidden=8", "data.batch_size=32"]


def _train(*args, cwd):
    return subprocess.run([sys.executable, str(ROOT / "train.py"), *args], cwd=cwd, capture_output=True, text=True,
                          timeout=600)


def _test_error(run: Path) -> float:
    """The run's test/err_m (m) as its CSVLogger wrote it (OUT/logs/version_0/metrics.csv, one test row)."""
    lines = (run / "logs" / "version_0" / "metrics.csv").read_text().splitlines()
    rows = [r for r in csv.DictReader(lines) if r.get("test/err_m")]
    assert len(rows) == 1, rows
    return float(rows[0]["test/err_m"])


@pytest.mark.slow  # scale-out end to end (17-28 s here): make test-slow
def test_two_process_ddp_on_cpu_with_gloo(two_phones, tmp_path):
    p = _train(f"data={two_phones}", f"out={tmp_path / 'run'}", "trainer.devices=2", "trainer.strategy=ddp", *TINY,
               cwd=tmp_path)
    assert p.returncode == 0, p.stderr[-3000:]
    log = p.stdout + p.stderr
    assert "distributed_backend=gloo" in log and "MEMBER: 2/2" in log
    state = torch.load(tmp_path / "run" / "last.ckpt", map_location="cpu", weights_only=True)
    assert state["global_step"] > 0 and state["blenav"]["beacons"]


@pytest.mark.slow
def test_multirun_sweep_with_the_joblib_launcher(two_phones, tmp_path):
    """Each job of a 2-process joblib sweep over seed=0,1 is the run a plain serial ``train.py seed=1`` gives
    (same step count, weights and test error to float tolerance), and the two seeds differ."""
    p = _train("-m", "hydra/launcher=joblib", "hydra.launcher.n_jobs=2", f"hydra.sweep.dir={tmp_path / 'sweep'}",
               f"data={two_phones}", f"out={tmp_path}/s${{seed}}", "seed=0,1", *TINY, cwd=tmp_path)
    assert p.returncode == 0, p.stderr[-3000:]
    q = _train(f"data={two_phones}", f"out={tmp_path / 'serial1'}", "seed=1", *TINY, cwd=tmp_path)
    assert q.returncode == 0, q.stderr[-3000:]
    a, b, ref = (torch.load(tmp_path / k / "last.ckpt", map_location="cpu", weights_only=True)
                 for k in ("s0", "s1", "serial1"))
    assert b["global_step"] == ref["global_step"] > 0
    assert b["state_dict"].keys() == ref["state_dict"].keys()
    for k, w in ref["state_dict"].items():  # the sweep's seed-1 job is the serial seed-1 run
        torch.testing.assert_close(b["state_dict"][k], w, rtol=1e-5, atol=1e-6, msg=lambda m, k=k: f"{k}: {m}")
    err = {k: _test_error(tmp_path / k) for k in ("s0", "s1", "serial1")}
    assert err["s1"] == pytest.approx(err["serial1"], rel=1e-5)
    printed = ast.literal_eval(q.stdout.strip().splitlines()[-1])  # train.py's last line: metrics, 4 decimals
    assert printed["test/err_m"] == pytest.approx(err["serial1"], abs=1e-4)
    wa, wb = a["state_dict"]["locnet.head.2.weight"], b["state_dict"]["locnet.head.2.weight"]
    assert (wa - wb).abs().max() > 1e-3  # two seeds, two different runs (far beyond the tolerance above)
    assert err["s0"] != pytest.approx(err["s1"], rel=1e-5)
