from __future__ import annotations

import pytest

from helpers import RAW, make_tiny_dataset


@pytest.fixture
def tiny_dataset(tmp_path):
    """A small valid dataset written by the project's writer (fresh per test, so tests may corrupt it)."""
    return make_tiny_dataset(tmp_path / "tiny")


@pytest.fixture
def raw_dir():
    """../shared/data/raw, or skip with the reason when it is absent."""
    if not RAW.is_dir():
        pytest.skip(f"public recordings not found at {RAW} (../shared/data/raw is absent)")
    return RAW
