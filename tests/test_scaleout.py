"""Scale-out without new code: 2-process DDP on CPU (gloo) and a Hydra multirun with the joblib launcher."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest
import torch


ROOT = Path(__file__).resolve().parents[1]
TINY = ["trainer.max_epochs=1", "trainer.enable_progress_bar=false", "model.locnet.hidden=16",
        "model.locnet.fc_hidden=8", "data.batch_size=32"]


def _train(*args, cwd):
    return subprocess.run([sys.executable, str(ROOT / "train.py"), *args], cwd=cwd, capture_output=True, text=True,
                          timeout=600)


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
    p = _train("-m", "hydra/launcher=joblib", "hydra.launcher.n_jobs=2", f"hydra.sweep.dir={tmp_path / 'sweep'}",
               f"data={two_phones}", f"out={tmp_path}/s${{seed}}", "seed=0,1", *TINY, cwd=tmp_path)
    assert p.returncode == 0, p.stderr[-3000:]
    a, b = (torch.load(tmp_path / f"s{k}" / "last.ckpt", map_location="cpu", weights_only=True) for k in (0, 1))
    wa, wb = a["state_dict"]["locnet.head.2.weight"], b["state_dict"]["locnet.head.2.weight"]
    assert not torch.equal(wa, wb)  # two seeds, two different runs
