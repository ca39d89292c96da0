"""``blenav-calibrate DATASET [--sessions ID,ID] [--out FILE.yaml]``: fit the path-loss model on labelled data.

Prints a_X (dBm at 1 m), gamma and the residual spread fitted on every RSSI reading of the chosen
labelled sessions against the distance to the anchors' prior positions; ``--out`` writes them as YAML
(use them as measurement-model overrides, or let blenav-eval fit them with ``calibration=...``).
"""

from __future__ import annotations

import argparse
import sys


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="blenav-calibrate", description=__doc__.splitlines()[0])
    p.add_argument("dataset")
    p.add_argument("--sessions", default=None, help="comma-separated session ids (default: every labelled session)")
    p.add_argument("--out", default=None, help="write the fit to this YAML file")
    args = p.parse_args(argv)

    import yaml

    from blenav.data import Dataset, DatasetError
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


if __name__ == "__main__":
    sys.exit(main())
