"""Where the project's Hydra configs live (``conf/`` at the repository root), and :func:`inside`, the one test of
whether a path lies in a folder (the commands refuse an output inside what they read)."""

from __future__ import annotations

import os
from pathlib import Path


def conf_dir() -> Path:
    """The ``conf/`` folder: $BLENAV_CONF if set, else the repository's (editable install)."""
    env = os.environ.get("BLENAV_CONF")
    candidates = [Path(env)] if env else []
    candidates.append(Path(__file__).resolve().parents[2] / "conf")
    for c in candidates:
        if (c / "sim.yaml").is_file():
            return c
    raise FileNotFoundError(
        "cannot find blenav's conf/ folder; install the package editable from a clone (`make install`) "
        "or set BLENAV_CONF to the path of conf/")


def inside(path, folder) -> bool:
    """Whether ``path`` is ``folder`` or lies below it, both resolved (symbolic links followed); False when either
    cannot be resolved."""
    try:
        return Path(path).resolve().is_relative_to(Path(folder).resolve())
    except (OSError, RuntimeError):
        return False
