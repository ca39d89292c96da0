"""``blenav-localize BUNDLE SESSION_DIR --out FILE.csv``: run a runtime bundle on a recorded session, torch-free.

Replays the session's samples (rssi.csv, odometry.csv, imu.csv, mag.csv; its fixes.csv is not read: the bundle's
localizer makes its own fixes; a bundle with a learned inertial odometry, ``inertial/``, makes the odometry from
imu.csv instead of reading odometry.csv) in time order through the bundle's push API (:class:`blenav.runtime.BundleLocalizer`)
and writes one row per filter step as it is made: ``t,x,y,std`` (s; m in the building's world frame; m, the RMS of
the particle cloud's per-axis standard deviations), flushed per row, so the file can be followed while it grows.
``SESSION_DIR`` is a session folder of a dataset (``DATASET/sessions/ID``). The bundle refuses a session whose
building's beacons or floor plan differ from its own, saying what differs.
"""

from __future__ import annotations

import sys
from pathlib import Path

from blenav.paths import inside

from .args import ArgumentParser
from .common import run_main


def _open_session(path: Path):
    """The session at ``path`` (``DATASET/sessions/ID``), read with its dataset."""
    from blenav.data import Dataset

    path = Path(path)
    if not path.is_dir():
        raise FileNotFoundError(f"session folder {path} does not exist")
    if not (path / "session.yaml").is_file():
        raise ValueError(f"{path} is not a session folder (no session.yaml); pass DATASET/sessions/ID")
    root = path.resolve().parent.parent
    if not (root / "dataset.yaml").is_file():
        raise ValueError(f"{path} is not inside a dataset (no dataset.yaml in {root}); pass DATASET/sessions/ID")
    return Dataset.open(root).session(path.name)


def _set_total(bar):
    if bar is None:
        return None

    def set_total(n: int) -> None:
        bar.total = n
        bar.refresh()
    return set_total


def _check_out(out: Path, bundle: Path, session: Path) -> None:
    """Refuse (ValueError) an ``--out`` that is a folder or lies inside the bundle or the session's dataset: the
    CSV would overwrite the model or the recording it reads (``--out BUNDLE/localizer.onnx`` replaced the graph,
    ``--out SESSION/rssi.csv`` the readings)."""
    if out.is_dir():
        raise ValueError(f"--out {out} is a folder; give the CSV file to write")
    dataset = session.resolve().parent.parent if session.resolve().parent.name == "sessions" else session.resolve()
    for what, root in (("the bundle", bundle.resolve()), ("the dataset of the session", dataset)):
        if inside(out, root):
            raise ValueError(f"--out {out} lies inside {what} ({root}): it would overwrite what it reads; write the "
                             "CSV elsewhere")


def _main(argv: list[str] | None) -> int:
    p = ArgumentParser(prog="blenav-localize", description=__doc__.splitlines()[0])
    p.add_argument("bundle", help="a bundle folder written by `python export.py bundle=true ...`")
    p.add_argument("session", help="a session folder DATASET/sessions/ID")
    p.add_argument("--out", required=True, help="the CSV to write (t,x,y,std)")
    p.add_argument("--seed", type=int, default=0, help="the filter's seed (default %(default)s)")
    p.add_argument("--variant", default="float", choices=["float", "ort", "int8", "int8_ort"],
                   help="which of the bundle's models to run (default %(default)s)")
    p.add_argument("--threads", type=int, default=1, help="onnxruntime intra-op threads (default %(default)s)")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    args = p.parse_args(argv)
    _check_out(Path(args.out), Path(args.bundle), Path(args.session))

    from blenav.runtime import Bundle

    bundle = Bundle.open(args.bundle, variant=args.variant, threads=args.threads)
    session = _open_session(Path(args.session))
    bundle.check_session(session)
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    bar = None
    if not args.no_progress:
        from tqdm import tqdm

        bar = tqdm(total=None, unit="sample", desc=f"localize {session.id}", file=sys.stderr, leave=False)
    n = 0
    with open(out, "w", encoding="utf-8", newline="") as f:
        f.write("t,x,y,std\n")
        f.flush()

        def row(e) -> None:
            nonlocal n
            f.write(f"{e.t:.6f},{e.x:.4f},{e.y:.4f},{e.std:.4f}\n")
            f.flush()
            n += 1

        est = bundle.run_session(session, seed=args.seed, on_estimate=row,
                                 on_event=(lambda k: bar.update(k)) if bar is not None else None,
                                 on_total=_set_total(bar))
    if bar is not None:
        bar.close()
    fixes = len(bundle.last_fixes)
    print(f"wrote {n} estimates (t,x,y,std) to {out}; {fixes} fixes from the bundle's localizer "
          f"({bundle.variant} models); odometry: {bundle.last_odometry}")
    return 0 if est is not None else 1


def main(argv: list[str] | None = None) -> int:
    """``blenav-localize``: errors the user can fix print one line and exit 1 (``--debug``: with the traceback)."""
    return run_main("blenav-localize", _main, argv)


if __name__ == "__main__":
    sys.exit(main())
