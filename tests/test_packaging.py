"""The package as a user installs it (issue 33, section 1): the wheel built from this tree, installed
non-editable into fresh virtual environments outside the repository.

- base install (numpy, pandas, pillow, shapely, pyyaml, onnxruntime, onnx, numba, scipy; no torch, Lightning,
  Hydra, GTSAM or matplotlib):
  ``blenav localize BUNDLE SESSION --out FILE.csv`` runs from another folder and writes the track; the commands
  of the extras say which extra they need in one line;
- the wheel carries every config of ``conf/`` (Hydra's search path inside the package);
- ``[all]`` (slow: minutes of downloads on a cold pip cache): ``blenav eval experiment=mapfusion_002 ...``, ``blenav
  sim`` and ``blenav train --help`` from outside the repository.

The environments install from the package registry (pip's cache where warm). Without a reachable registry the
installs cannot run: the tests skip and say so (and only then).
"""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
import zipfile
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from helpers import REPO, simulate_small

NET_ERRORS = ("NewConnectionError", "Temporary failure in name resolution", "Network is unreachable",
              "No matching distribution found", "Could not find a version that satisfies")


def run(cmd: list[str], cwd: Path, timeout: float, env: dict | None = None) -> subprocess.CompletedProcess:
    return subprocess.run(cmd, cwd=cwd, capture_output=True, text=True, timeout=timeout,
                          env={**os.environ, **(env or {})})


def clean_env() -> dict:
    """The environment of a user's shell: no PYTHONPATH or BLENAV_CONF pointing into this tree."""
    return {"PYTHONPATH": "", "BLENAV_CONF": ""}


@pytest.fixture(scope="module")
def wheel(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("wheel")
    tree = tmp_path_factory.mktemp("tree")  # a copy: setuptools writes build/ beside the sources it builds
    shutil.copytree(REPO / "src", tree / "src", ignore=shutil.ignore_patterns("__pycache__", "*.egg-info"))
    for f in ("pyproject.toml", "README.md"):
        shutil.copy2(REPO / f, tree / f)
    r = run([sys.executable, "-m", "pip", "wheel", "--no-deps", "--no-build-isolation", "-q", "-w", str(out),
             str(tree)], cwd=out, timeout=300)
    assert r.returncode == 0, r.stderr[-2000:]
    (whl,) = out.glob("blenav-*.whl")
    return whl


def venv_with(root: Path, spec: str, timeout: float) -> Path:
    """A fresh virtual environment at ``root`` with ``pip install spec``; its bin folder."""
    r = run([sys.executable, "-m", "venv", str(root)], cwd=root.parent, timeout=120)
    assert r.returncode == 0, r.stderr[-2000:]
    pip = root / "bin" / "pip"
    # --no-compile: no byte-compiling of every installed file (numpy, scipy, pandas: tens of seconds); the modules the
    # commands import are compiled when first imported, as from any install
    r = run([str(pip), "install", "-q", "--disable-pip-version-check", "--no-compile", spec], cwd=root.parent,
            timeout=timeout, env=clean_env())
    if r.returncode != 0 and any(e in r.stderr for e in NET_ERRORS):
        pytest.skip(f"the package registry cannot be reached from here, so no fresh environment can be installed: "
                    f"{r.stderr.strip().splitlines()[-1][:200]}")
    assert r.returncode == 0, r.stderr[-3000:]
    return root / "bin"


def test_wheel_carries_every_config(wheel):
    names = set(zipfile.ZipFile(wheel).namelist())
    confs = {p.relative_to(REPO / "src").as_posix() for p in (REPO / "src" / "blenav" / "conf").rglob("*.yaml")}
    assert len(confs) > 50 and confs <= names, sorted(confs - names)[:5]
    assert "blenav/cli/main.py" in names and not any(n.startswith(("tests/", "conf/")) for n in names)


@pytest.fixture(scope="module")
def bundle(tmp_path_factory) -> dict:
    """A 'small' building with 2 one-minute walks, a tiny LocNet and its bundle (no map prior, float only)."""
    from blenav.configs import compose
    from blenav.learn.bundle import export_bundle
    from blenav.learn.train import train

    root = tmp_path_factory.mktemp("pkg_bundle")
    data = simulate_small(root / "d", 5, 60, 2)
    train(compose("train", "model=locnet", f"data={data}", f"out={root / 'loc'}", "data.batch_size=32",
                  "trainer.enable_progress_bar=false", "trainer.max_epochs=1", "model.locnet.hidden=16",
                  "model.locnet.fc_hidden=8"))
    export_bundle(compose("export", "bundle=true", "variants=false", f"ckpt={root / 'loc' / 'last.ckpt'}",
                          f"out={root / 'B'}", f"data={data}", "eval_sessions=1"))
    return {"data": data, "bundle": root / "B"}


@pytest.mark.onnx
def test_base_install_localizes_without_torch(wheel, bundle, tmp_path):
    """``pip install WHEEL`` (no extra) in an empty environment: ``blenav localize`` works from another folder, with
    no torch, lightning, hydra or gtsam installed; a command of an extra says in one line which extra it needs."""
    bin_ = venv_with(tmp_path / "venv", str(wheel), timeout=600)
    py = str(bin_ / "python")
    probe = "import importlib.util as u; print([m for m in ('torch','lightning','hydra','gtsam','matplotlib') if u.find_spec(m)])"
    r = run([py, "-c", probe], cwd=tmp_path, timeout=60, env=clean_env())
    assert r.returncode == 0 and r.stdout.strip() == "[]", (r.stdout, r.stderr)

    work = tmp_path / "elsewhere"
    work.mkdir()
    session = sorted((bundle["data"] / "sessions").iterdir())[0]
    out = work / "track.csv"
    r = run([str(bin_ / "blenav"), "localize", str(bundle["bundle"]), str(session), "--out", str(out),
             "--no-progress"], cwd=work, timeout=300, env=clean_env())
    assert r.returncode == 0, r.stderr[-3000:]
    df = pd.read_csv(out)
    assert list(df.columns) == ["t", "x", "y", "std"] and len(df) > 30 and np.isfinite(df.to_numpy()).all()
    r = run([str(bin_ / "blenav-localize"), str(bundle["bundle"]), str(session), "out=" + str(work / "b.csv")],
            cwd=work, timeout=300, env=clean_env())  # the alias, key=value, a progress bar
    assert r.returncode == 0, r.stderr[-3000:]
    assert pd.read_csv(work / "b.csv").equals(df)

    # a plan without rooms.geojson / navgraph.geojson (most importers write neither): the filter derives them, and
    # the AHRS of the inertial motion models, with the base install's modules
    derive = tmp_path / "derive"
    shutil.copytree(bundle["data"], derive)
    for f in derive.rglob("*.geojson"):
        f.unlink()
    code = ("import sys, numpy as np; from blenav.data import Dataset; from blenav.filters.map.geometry import "
            "MapGeometry; from blenav.filters.attitude import estimate_attitude; s = Dataset.open(sys.argv[1])."
            "session(Dataset.open(sys.argv[1]).session_ids[0]); g = MapGeometry.from_building(s.building, "
            "s.meta.get('floor'), derive_missing=True); imu = s.imu; q = estimate_attitude(imu['t'].to_numpy(), "
            "imu[['ax','ay','az']].to_numpy(), imu[['gx','gy','gz']].to_numpy()); print(len(g.rooms), len(q))")
    r = run([py, "-c", code, str(derive)], cwd=work, timeout=300, env=clean_env())
    assert r.returncode == 0, r.stderr[-3000:]
    assert int(r.stdout.split()[0]) > 0
    r = run([str(bin_ / "blenav"), "validate", str(bundle["data"])], cwd=work, timeout=300, env=clean_env())
    assert r.returncode == 0, r.stderr[-3000:]
    r = run([str(bin_ / "blenav"), "eval", "experiment=leaderboard"], cwd=work, timeout=120, env=clean_env())
    assert r.returncode == 1 and r.stderr.count("\n") == 1, r.stderr[-3000:]
    assert r.stderr.startswith("blenav eval: error: ") and "pip install 'blenav[eval]'" in r.stderr


@pytest.mark.slow
def test_full_install_runs_every_command_outside_the_repository(wheel, tmp_path):
    """``pip install 'WHEEL[all]'`` (CPU torch first, as ``make install``): the Hydra commands find their configs
    inside the package, from a folder that is not the repository."""
    root = tmp_path / "venv"
    run([sys.executable, "-m", "venv", str(root)], cwd=tmp_path, timeout=120)
    r = run([str(root / "bin" / "pip"), "install", "-q", "torch==2.13.0"], cwd=tmp_path, timeout=1200,
            env=clean_env())
    assert r.returncode == 0, r.stderr[-3000:]
    bin_ = venv_with(root, f"{wheel}[all]", timeout=2400)
    work = tmp_path / "elsewhere"
    work.mkdir()
    blenav = str(bin_ / "blenav")
    r = run([blenav, "sim", "sim=small", "seed=3", "duration_s=60", "sessions=2", f"out={work / 'd'}",
             "progress=false"], cwd=work, timeout=600, env=clean_env())
    assert r.returncode == 0, r.stderr[-3000:]
    r = run([blenav, "eval", "experiment=mapfusion_002", f"data={work / 'd'}", "runs=1", f"out={work / 'o'}",
             "progress=false"], cwd=work, timeout=1200, env=clean_env())
    assert r.returncode == 0, r.stderr[-3000:]
    assert (work / "o" / "results.json").is_file()
    r = run([blenav, "train", "--help"], cwd=work, timeout=300, env=clean_env())
    assert r.returncode == 0 and r.stdout.startswith("usage: blenav train "), r.stderr[-2000:]
