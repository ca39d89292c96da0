"""``blenav-calibrate DATASET [--sessions ID,ID] [--out FILE.yaml]``: fit the path-loss model on labelled data.

Prints a_X (dBm at 1 m), gamma and the residual spread fitted on every RSSI reading of the chosen
labelled sessions against the distance to the anchors' prior positions; ``--out`` writes them as YAML
(use them as measurement-model overrides, or let blenav-eval fit them with ``calibration=...``).
"""

from __future__ import annotations

import sys

from blenav.paths import inside

from .args import ArgumentParser
from .common import run_main


def _main(argv: list[str] | None) -> int:
    p = ArgumentParser(prog="blenav-calibrate", description=__doc__.splitlines()[0])
    p.add_argument("dataset")
    p.add_argument("--sessions", default=None, help="comma-separated session ids (default: every labelled session)")
    p.add_argument("--out", default=None, help="write the fit to this YAML file")
    args = p.parse_args(argv)
    if args.out:
        from pathlib import Path

        out, data = Path(args.out).resolve(), Path(args.dataset).resolve()
        if out.is_dir() or (out.exists() and inside(out, data)):  # --out SESSION/rssi.csv replaced the readings
            raise ValueError(f"--out {args.out} is a folder or a file of the dataset {args.dataset}; write the fit "
                             "to a new file")

    import yaml

    from blenav.data import Dataset
    from blenav.errors import DatasetError
    from blenav.filters.calibration import fit_sessions

    try:
        ds = Dataset.open(args.dataset)
        ids = args.sessions.split(",") if args.sessions else None
        sessions = [s for s in ds.sessions(ids) if s.labelled]
        fit = fit_sessions(sessions)
    except (DatasetError, ValueError) as exc:
        print(f"blenav-calibrate: error: {exc}", file=sys.stderr)
        return 1
    print(f"a_X = {fit.a_x:.2f} dBm at d0 = {fit.d0:g} m, gamma = {fit.gamma:.3f}, residual std = "
          f"{fit.residual_std_db:.2f} dB ({fit.n_readings} readings from {len(fit.sessions)} session(s))")
    if args.out:
        with open(args.out, "w", encoding="utf-8") as f:
            yaml.safe_dump(fit.as_dict(), f, sort_keys=False)
        print(f"wrote {args.out}")
    return 0


def main(argv: list[str] | None = None) -> int:
    """``blenav-calibrate``: errors the user can fix print one line and exit 1 (``--debug``: with the traceback)."""
    return run_main("blenav-calibrate", _main, argv)


if __name__ == "__main__":
    sys.exit(main())
