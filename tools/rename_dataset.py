#!/usr/bin/env python3
"""Copy a dataset with other names: its one building, every session and every phone renamed, so that a command can be
checked on names the simulator never writes (the contract checks from outside use their own; issue 30's check of
``experiment=realwalks`` on a simulated office used this).

    python tools/rename_dataset.py SRC DST [--building "Annex West"] [--session walk-{i:02d}-rx{rx}] [--phone handset-{i}]

SRC: a dataset with one building (``blenav sim`` writes one). DST is created (refused when it exists). The building's
folder and the ``building:`` of every session.yaml take the new building name (the building's YAML files have the old
id replaced), session folders become ``--session`` formatted with i (0, 1, ... in SRC's sorted order) and rx (3 + 7 i),
``device_model`` becomes ``--phone``. The copy is checked with ``blenav validate``'s checks before this returns.
"""

from __future__ import annotations

import argparse
import re
import shutil
from pathlib import Path


def rename(src: Path, dst: Path, building: str, session: str, phone: str) -> list[str]:
    """The renamed copy of ``src`` at ``dst``; returns its session ids."""
    if dst.exists():
        raise FileExistsError(f"{dst} exists: choose a new folder")
    blds = sorted(p for p in (src / "buildings").iterdir() if p.is_dir())
    if len(blds) != 1:
        raise ValueError(f"{src}: {len(blds)} buildings, this renames a dataset with one")
    old = blds[0].name
    shutil.copytree(src, dst)
    (dst / "buildings" / old).rename(dst / "buildings" / building)
    for p in (dst / "buildings" / building).glob("*.yaml"):
        p.write_text(p.read_text().replace(old, building))
    ids = []
    for i, s in enumerate(sorted(p for p in (dst / "sessions").iterdir() if p.is_dir())):
        y = s / "session.yaml"
        text = re.sub(r"(?m)^building: .*$", f"building: {building}", y.read_text())
        text = re.sub(r"(?m)^device_model: .*$", f"device_model: {phone.format(i=i)}", text)
        y.write_text(text)
        ids.append(session.format(i=i, rx=3 + 7 * i))
        s.rename(dst / "sessions" / ids[-1])
    from blenav.data.validate import validate

    errors = [i for i in validate(dst) if i.is_error]  # blenav-validate's checks on the renamed copy
    if errors:
        raise ValueError(f"the renamed copy {dst} is not a valid dataset: {errors[0]}")
    return ids


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("src", type=Path)
    ap.add_argument("dst", type=Path)
    ap.add_argument("--building", default="Annex West")
    ap.add_argument("--session", default="walk-{i:02d}-rx{rx}")
    ap.add_argument("--phone", default="handset-{i}")
    a = ap.parse_args()
    try:
        ids = rename(a.src, a.dst, a.building, a.session, a.phone)
    except (FileExistsError, FileNotFoundError, ValueError) as exc:
        raise SystemExit(f"rename_dataset: {exc}") from None
    print(f"wrote {a.dst}: building {a.building!r}, sessions {', '.join(ids)}")


if __name__ == "__main__":
    main()
