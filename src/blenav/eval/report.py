"""results.md: the experiment as a table like the papers' (no plotting here)."""

from __future__ import annotations

from pathlib import Path


def _f(v, nd=2) -> str:
    return "-" if v is None else f"{v:.{nd}f}"


def write_markdown(path: Path, results: dict, cfg=None) -> None:
    ms = results["methods"]
    lines = [f"# {results['experiment']}: {results.get('title', '')}", "",
             f"Dataset `{results['dataset']}`, {len(results['sessions'])} labelled session(s), "
             f"{results['runs']} run(s) per session and method, seed {results.get('seed', 0)}. "
             f"Errors are planar, against ground truth interpolated at the estimate times; the first "
             f"{results['init_s']:g} s of each session (global localization) are reported separately.", "",
             _calibration_line(results), "",
             "| method | RMSE [m] mean +- stderr | RMSE 99% CI | error median | CDF p75 | p90 | max | ATE | EE | "
             "init error mean | orientation RMSE [deg] | recoveries | wall [s] | x real time |",
             "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|"]
    skipped = {n: m["skipped"] for n, m in ms.items() if "skipped" in m}
    ms = {n: m for n, m in ms.items() if "rmse_m" in m}
    for name, m in ms.items():
        r, e = m["rmse_m"], m["error_m"]
        init = m.get("init_error_m") or {}
        lines.append(
            f"| {name} | {_f(r['mean'])} +- {_f(r['stderr'], 3)} | [{_f(r['ci99'][0])}, {_f(r['ci99'][1])}] | "
            f"{_f(e['median'])} | {_f(e['p75'])} | {_f(e['p90'])} | {_f(e['max'])} | {_f(m['ate_m'])} | {_f(m['ee_m'])} | "
            f"{_f(init.get('mean'))} | {_f(m.get('orientation_rmse_deg'), 1)} | {m.get('recoveries', 0)} | "
            f"{_f(m['wall_s'], 1)} | {_f(m['realtime_factor'], 0)} |")
    lines += ["", "Per session (RMSE mean over runs, m):", "",
              "| session | " + " | ".join(ms) + " |", "|---|" + "---|" * len(ms)]
    for sid in results["sessions"]:
        cells = [_f(m["per_session"][sid]["rmse_m"]["mean"]) if sid in m["per_session"] else "skipped" for m in ms.values()]
        lines.append(f"| {sid} | " + " | ".join(cells) + " |")
    for n, sk in skipped.items():
        lines += ["", f"{n}: skipped on {len(sk)} session(s) ({', '.join(sorted(sk))[:300]}): "
                  + "; ".join(sorted(set(sk.values())))]
    notes = sorted({n for m in ms.values() for n in m.get("map_notes", [])})
    if notes:
        lines += ["", "Map notes:", ""] + [f"- {n}" for n in notes]
    lines += _paper_comparison(results, ms, cfg)
    lines += ["", "Plots: error_cdf.png (median CDF over runs with 5-95 % band), rmse_box.png, "
              "error_over_time.png, trajectories.png (first run, first session)."]
    path.write_text("\n".join(lines) + "\n", encoding="utf-8")


def _calibration_line(results: dict) -> str:
    c = results.get("calibration")
    if not c:
        return "Path-loss parameters: as configured (the papers' Table I values)."
    return (f"Path-loss parameters a_X = {c['a_x']:.1f} dBm, gamma = {c['gamma']:.2f} (d0 = {c['d0']:g} m, residual "
            f"std {c['residual_std_db']:.1f} dB, {c['n_readings']} readings): {c['note']}.")


def _paper_comparison(results: dict, ms: dict, cfg) -> list[str]:
    """Does the measured RMSE ordering follow the paper's? Name every inverted pair and what the data
    say about it (the AHRS error for inertial models), so a reader sees at once where and why we differ."""
    paper = (cfg.experiment.get("paper") if cfg is not None and "experiment" in cfg else None) or {}
    order = [m for m in paper.get("ordering", []) if m in ms]
    if len(order) < 2:
        return []
    rm = {m: ms[m]["rmse_m"]["mean"] for m in order}
    ref = paper.get("rmse_m") or {}
    out = ["", f"Paper comparison ({paper.get('source', 'the paper')}): expected RMSE order "
           + " < ".join(order) + "; measured " + " < ".join(sorted(order, key=rm.get)) + "."]
    if ref:
        out.append("Paper RMSE: " + ", ".join(f"{m} {ref[m]:g} m" for m in order if m in ref) + ".")
    inverted = [(a, b) for i, a in enumerate(order) for b in order[i + 1:] if rm[a] > rm[b]]
    if not inverted:
        out.append("The ordering holds.")
        return out
    for a, b in inverted:
        gap = rm[a] - rm[b]
        se = (ms[a]["rmse_m"]["stderr"] ** 2 + ms[b]["rmse_m"]["stderr"] ** 2) ** 0.5
        why = ""
        orient = ms[a].get("orientation_rmse_deg")
        if orient is not None and orient > 5 and ms[b].get("orientation_rmse_deg") is None:
            why = (f" {a} uses the AHRS, whose orientation RMSE here is {orient:.1f} deg: a heading error of "
                   "that size turns the measured acceleration direction, so its inertial input misleads; a "
                   "cleaner attitude (calibrated magnetometer, or the back-end's bias feedback) is what it needs.")
        common = [k for k in ms[a].get("per_session", {}) if k in ms[b].get("per_session", {})]
        if len(common) > 1:
            d = {k: ms[a]["per_session"][k]["rmse_m"]["mean"] - ms[b]["per_session"][k]["rmse_m"]["mean"] for k in common}
            worst = max(d, key=d.get)
            why += (f" Per session the gap ranges {min(d.values()):+.2f} to {d[worst]:+.2f} m, largest on {worst} "
                    f"({ms[a]['per_session'][worst]['rmse_m']['mean']:.2f} vs {ms[b]['per_session'][worst]['rmse_m']['mean']:.2f} m).")
        out.append(f"Inverted: {a} ({rm[a]:.2f} m) is worse than {b} ({rm[b]:.2f} m) by {gap:.2f} m "
                   f"({gap / se if se > 0 else float('inf'):.0f} standard errors).{why}")
    return out
