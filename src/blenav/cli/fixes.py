"""``blenav-fixes DATASET MODEL.onnx [--source NAME] [--sessions ID,ID] [--calibrate]``: write a localizer's fixes.

Runs an exported cross-phone localizer (``python export.py ...``) over the sessions' RSSI and merges its
position fixes into each session's ``fixes.csv`` under ``--source`` (default: the model's name), keeping
rows of other sources. A particle filter then uses them through the ``fix_003`` measurement model
(``blenav-eval experiment=fused_003 ...``).

``--calibrate`` writes nothing: on labelled sessions it prints the fixes' error statistics
(:func:`blenav.runtime.fixes.calibrate_model_fixes`; for a model with a std head also how its own std covers the
errors) and, as its last line, ``sigma_eff_m=VALUE``, the sigma to give the fix likelihood
(``...measurements.fix.sigma_m=VALUE``) so that correlated fixes are not over-counted.
"""

from __future__ import annotations

import sys

from .args import ArgumentParser
from .common import run_main


def _main(argv: list[str] | None) -> int:
    p = ArgumentParser(prog="blenav-fixes", description=__doc__.splitlines()[0])
    p.add_argument("dataset")
    p.add_argument("model", help="an ONNX file written by export.py")
    p.add_argument("--source", default="TransNet+LocNet", help="the fixes.csv source name (default %(default)s)")
    p.add_argument("--sessions", default=None, help="comma-separated session ids (default: every session)")
    p.add_argument("--calibrate", action="store_true",
                   help="write nothing; print the fixes' error statistics against ground truth and sigma_eff_m")
    args = p.parse_args(argv)

    from blenav.data import Dataset
    from blenav.errors import DatasetError
    from blenav.runtime.fixes import calibrate_model_fixes, write_model_fixes

    try:
        ds = Dataset.open(args.dataset)
        ids = args.sessions.split(",") if args.sessions else None
        if args.calibrate:
            st = calibrate_model_fixes(ds, args.model, ids)
            print(f"{st['fixes']} fixes in {len(st['sessions'])} session(s): RMSE {st['rmse_m']:.2f} m, per-axis sigma "
                  f"{st['sigma_m']:.2f} m, error correlation time {st['tau_fixes']:.1f} fixes (rho above 0.05 up "
                  f"to lag {st['last_lag']}), effective sigma {st['sigma_eff_m']:.2f} m")
            if st.get("trained_on"):
                print(f"blenav-fixes: warning: session(s) {', '.join(st['trained_on'])} trained the model: their "
                      f"errors understate what unseen walks give; calibrate on walks it never saw", file=sys.stderr)
            ss = st.get("stated_std")
            if ss:
                rho = "--" if ss["rank_correlation"] is None else f"{ss['rank_correlation']:.2f}"
                scale = "--" if ss["ml_scale"] is None else f"{ss['ml_scale']:.2f}"
                print(f"the model's own std (std_m) on {ss['fixes']} fixes: {100 * ss['coverage_1sigma']:.0f} % within "
                      f"1 sigma, {100 * ss['coverage_2sigma']:.0f} % within 2 (a calibrated 2-D Gaussian: 39 / 86 %); "
                      f"scale that would calibrate it here {scale} (1: calibrated), rank correlation with the error {rho}")
            print(f"sigma_eff_m={st['sigma_eff_m']:.2f}")
            return 0
        report = write_model_fixes(ds, args.model, args.source, ids)
    except (DatasetError, ValueError, FileNotFoundError) as exc:
        print(f"blenav-fixes: error: {exc}", file=sys.stderr)
        return 1
    total = sum(r["fixes"] for r in report.values())
    silent = sum(r["no_beacon_windows"] for r in report.values())
    with_std = any(r["std"] for r in report.values())
    print(f"wrote {total} fixes (source {args.source!r}) to {len(report)} session(s); "
          f"{silent} window(s) without any beacon heard gave no fix; std column: "
          + ("the model's own std per fix (its std head)" if with_std else "empty (the model states none)"))
    return 0


def main(argv: list[str] | None = None) -> int:
    """``blenav-fixes``: errors the user can fix print one line and exit 1 (``--debug``: with the traceback)."""
    return run_main("blenav-fixes", _main, argv)


if __name__ == "__main__":
    sys.exit(main())
