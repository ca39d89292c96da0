from __future__ import annotations

import shutil
from pathlib import Path

import pytest

from helpers import RAW, make_tiny_dataset, simulate_small
from ilc20_helpers import write_coded


@pytest.fixture(scope="session")
def _tiny_template(tmp_path_factory):
    return make_tiny_dataset(tmp_path_factory.mktemp("template") / "tiny")


@pytest.fixture
def tiny_dataset(_tiny_template, tmp_path):
    """A small valid dataset written by the project's writer, copied fresh per test (tests may corrupt it)."""
    return Path(shutil.copytree(_tiny_template, tmp_path / "tiny"))


@pytest.fixture(scope="session")
def two_phones(tmp_path_factory):
    """A simulated 'small' building, 4 one-minute walks by an iPhone 8 and a Galaxy S10 profile (read-only)."""
    out = tmp_path_factory.mktemp("two_phones") / "d"
    simulate_small(out, 5, 60, 4, "sim.receivers=[iphone-8,galaxy-s10]")
    return out


@pytest.fixture(scope="session")
def three_walks(tmp_path_factory):
    """A simulated 'small' building, 3 one-minute pedestrian walks, seed 3 (read-only): the map prior's tiny
    training data of tests/learn/test_mapprior.py, tests/learn/test_checkpoint.py and tests/test_onnx_io.py."""
    return simulate_small(tmp_path_factory.mktemp("three_walks") / "d", 3, 60, 3)


@pytest.fixture(scope="session")
def map_walks(tmp_path_factory):
    """A simulated 'small' building, 2 pedestrian walks of 240 s, seed 11 (read-only): beacon mapping's data
    (tests/backend/test_mapping.py, tests/backend/test_pooled.py)."""
    return simulate_small(tmp_path_factory.mktemp("map_walks") / "sim", 11, 240.0, 2)


@pytest.fixture
def raw_dir():
    """../shared/data/raw, or skip with the reason when it is absent."""
    if not RAW.is_dir():
        pytest.skip(f"public recordings not found at {RAW} (../shared/data/raw is absent)")
    return RAW


@pytest.fixture
def coded(tmp_path):
    """Three position-coded ILC 2.0 walks imported (tests/ilc20_helpers.py: :func:`write_coded`): walkA at y = 5 m,
    walkB at y = 7 m (both trained on), walkC at y = 5 m (tested)."""
    return write_coded(tmp_path)
