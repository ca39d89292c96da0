"""Where the project's Hydra configs live (``blenav/conf/`` inside the package; the repository's ``conf/`` is a link to
it), and :func:`inside`, the one test of
whether a path lies in a folder (the commands refuse an output inside what they read)."""

from __future__ import annotations

import os
from pathlib import Path


def conf_dir() -> Path:
    """The config folder: $BLENAV_CONF if set (a copy a user edits), else the one installed with the package
    (``blenav/conf``, shipped in the wheel as package data)."""
    env = os.environ.get("BLENAV_CONF")
    candidates = [Path(env)] if env else []
    candidates.append(Path(__file__).resolve().parent / "conf")
    for c in candidates:
        if (c / "sim.yaml").is_file():
            return c
    where = f"BLENAV_CONF={env} has no sim.yaml; " if env else ""
    raise FileNotFoundError(
        f"{where}cannot find blenav's config folder (blenav/conf inside the installed package): reinstall blenav, "
        "or set BLENAV_CONF to a folder holding its configs")


def inside(path, folder) -> bool:
    """Whether ``path`` is ``folder`` or lies below it, both resolved (symbolic links followed); False when either
    cannot be resolved."""
    try:
        return Path(path).resolve().is_relative_to(Path(folder).resolve())
    except (OSError, RuntimeError):
        return False
