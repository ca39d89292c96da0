"""results.md: the experiment as a table like the papers', the leaderboard's table, the cross-phone tables (no
plotting here)."""

from __future__ import annotations

from pathlib import Path

from .beacon_map import checked_by_heard
from .common import write_text


def _f(v, nd=2) -> str:
    return "-" if v is None else f"{v:.{nd}f}"


def _ci(r: dict) -> str:
    """The 99 % CI cell of a ``rmse_m`` summary (:func:`blenav.eval.metrics.summary`) with the number of values it
    is over: ``[lo, hi] (n=6)``; ``- (n=1)`` where one value gives no interval."""
    n = r.get("n")
    if n is not None and n < 2:
        return f"- (n={n})"
    ci = f"[{_f(r['ci99'][0])}, {_f(r['ci99'][1])}]"
    return ci if n is None else f"{ci} (n={n})"


#: what the RMSE 99 % CI column means, printed under the tables that show it
CI_NOTE = ("RMSE 99% CI: the Student t interval of the mean RMSE over its n values (one per session and run; a bound: "
           "one per session), mean +- t(0.995, n-1) stderr, its lower end clipped at 0 m; none with n = 1.")


def write_markdown(path: Path, results: dict, experiment=None) -> None:
    """results.md of an evaluation. Every experiment prints one frame: the heading and what was evaluated, what
    the methods were given (path-loss calibration, wrong plans, beacon map), the experiment's tables, then the
    map notes, the estimates kept on the floor, the rows dropped while reading, the paper comparison and the
    plots. The tables: the papers' layout (:func:`_method_tables`), or for the leaderboard one table sorted by RMSE
    with the PCRLB rows, peak memory and the skipped methods (:func:`_leaderboard_tables`). ``experiment``: the
    :class:`~blenav.eval.config.ExperimentConfig` (its evaluator, its ``paper``), or None."""
    leaderboard = experiment is not None and experiment.is_leaderboard
    intro, tables, plots = (_leaderboard_tables if leaderboard else _method_tables)(results)
    ms = {n: m for n, m in results["methods"].items() if "rmse_m" in m}
    lines = [f"# {results['experiment']}: {results.get('title', '')}", "", intro, "",
             _calibration_line(results), "", *_plan_error_lines(results), *_beacon_map_lines(results), *tables]
    notes = sorted({n for m in ms.values() for n in m.get("map_notes", [])})
    if notes:
        lines += ["", "Map notes:", ""] + [f"- {n}" for n in notes]
    lines += _confined_lines(ms) + _dropped_lines(results)
    lines += _paper_comparison(results, ms, experiment)
    lines += ["", plots]
    write_text(path, "\n".join(lines) + "\n")


def _method_tables(results: dict) -> tuple[str, list[str], str]:
    """The papers' layout: (intro, one row per method in the configured order plus the per-session RMSE and the
    skipped sessions, the plots line)."""
    ms = results["methods"]
    intro = (f"Dataset `{results['dataset']}`, {len(results['sessions'])} labelled session(s), "
             f"{results['runs']} run(s) per session and method, seed {results.get('seed', 0)}. "
             f"Errors are planar, against ground truth interpolated at the estimate times; the first "
             f"{results['init_s']:g} s of each session (global localization) are reported separately.")
    lines = ["| method | RMSE [m] mean +- stderr | RMSE 99% CI | error median | CDF p75 | p90 | max | ATE | EE | "
             "init error mean | orientation RMSE [deg] | recoveries | wall [s] | x real time |",
             "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|"]
    skipped = {n: m["skipped"] for n, m in ms.items() if "skipped" in m}
    ms = {n: m for n, m in ms.items() if "rmse_m" in m}
    for name, m in ms.items():
        r, e = m["rmse_m"], m["error_m"]
        init = m.get("init_error_m") or {}
        lines.append(
            f"| {name} | {_f(r['mean'])} +- {_f(r['stderr'], 3)} | {_ci(r)} | "
            f"{_f(e['median'])} | {_f(e['p75'])} | {_f(e['p90'])} | {_f(e['max'])} | {_f(m['ate_m'])} | {_f(m['ee_m'])} | "
            f"{_f(init.get('mean'))} | {_f(m.get('orientation_rmse_deg'), 1)} | {m.get('recoveries', 0)} | "
            f"{_f(m['wall_s'], 1)} | {_f(m['realtime_factor'], 0)} |")
    lines += ["", CI_NOTE, "", "Per session (RMSE mean over runs, m):", "",
              "| session | " + " | ".join(ms) + " |", "|---|" + "---|" * len(ms)]
    for sid in results["sessions"]:
        cells = [_f(m["per_session"][sid]["rmse_m"]["mean"]) if sid in m["per_session"] else "skipped" for m in ms.values()]
        lines.append(f"| {sid} | " + " | ".join(cells) + " |")
    for n, sk in skipped.items():
        lines += ["", f"{n}: skipped on {len(sk)} session(s) ({', '.join(sorted(sk))[:300]}): "
                  + "; ".join(sorted(set(sk.values())))]
    return intro, lines, ("Plots: error_cdf.png (median CDF over runs with 5-95 % band), rmse_box.png (per-run RMSE; "
                          "a method with fewer than 5 runs as points, each tick with its n), error_over_time.png (one "
                          "panel per session, at most 12), trajectories.png (first run, first session, one panel per "
                          "method).")


# --------------------------------------------------------------------------- the leaderboard (issue 18 sec. 2)

def _leaderboard_tables(results: dict) -> tuple[str, list[str], str]:
    """The leaderboard (blenav.eval.leaderboard): (intro, one table sorted by RMSE with the bounds last, what the
    bounds and the peak memory mean, the skipped methods with their reasons, the per-session RMSE, the plots
    line)."""
    ms = results["methods"]
    ran = {n: m for n, m in ms.items() if "rmse_m" in m and m.get("kind") != "bound"}
    bounds = {n: m for n, m in ms.items() if m.get("kind") == "bound"}
    scored = {n: m for n, m in bounds.items() if "rmse_m" in m}
    order = sorted(ran, key=lambda n: ran[n]["rmse_m"]["mean"])
    how = next((m["peak_memory"]["how"] for m in ran.values() if m.get("peak_memory")), None)
    intro = (f"Dataset `{results['dataset']}`, {len(results['sessions'])} labelled session(s) "
             f"({', '.join(results['sessions'])}), {results['runs']} run(s) per session and method, seed "
             f"{results.get('seed', 0)}: every method on the same sessions and seeds. Errors are planar (m) against "
             f"the ground truth at the estimate times, after the first {results['init_s']:g} s of each session "
             "(global localization). Sorted by RMSE.")
    lines = ["| # | method | family | mean | median | p75 | p90 | RMSE mean +- stderr | RMSE 99% CI | ATE | "
             "x real time | peak memory [MB] |", "|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for i, name in enumerate(order, 1):
        m = ran[name]
        r, e = m["rmse_m"], m["error_m"]
        pk = m.get("peak_memory") or {}
        pm = "-" if pk.get("peak_memory_mb") is None else (
            f"+{pk['peak_memory_mb']:.1f}" + (f" ({pk['peak_rss_mb']:.0f})" if pk.get("peak_rss_mb") is not None else ""))
        lines.append(f"| {i} | {name} | {m.get('family', '-')} | {_f(e['mean'])} | {_f(e['median'])} | {_f(e['p75'])} | "
                     f"{_f(e['p90'])} | {_f(r['mean'])} +- {_f(r['stderr'], 3)} | {_ci(r)} | "
                     f"{_f(m['ate_m'])} | {_f(m['realtime_factor'], 0)} | {pm} |")
    for name, b in scored.items():
        r, e = b["rmse_m"], b["error_m"]
        lines.append(f"| - | {name} | bound | {_f(e['mean'])}* | {_f(e['median'])}* | {_f(e['p75'])}* | {_f(e['p90'])}* | "
                     f"{_f(r['mean'])} +- {_f(r['stderr'], 3)} | {_ci(r)} | "
                     f"{_f(b['ate_m'])} | - | - |")
    lines += ["", CI_NOTE]
    lines += ["", _bound_text(scored)] if scored else []
    if how:
        lines += ["", f"Peak memory: {how} (MB: +increase, and in brackets the process's peak resident memory while "
                  "the method ran). Every session's streams and floor plan are read before the first method, so no "
                  "method is charged for reading the data; what methods load or build on first use and then share "
                  "(imported code, JIT-compiled kernels, map geometry per floor, attitude per session) is counted in "
                  "the first method that needs it, so the first method of a kind reads higher than the next."]
    lines += ["", "x real time: seconds of data per second of computing, all runs (one core, this machine; training of "
              "the fingerprint rows not included)."]
    skipped = {n: m["skipped"] for n, m in ms.items() if "skipped" in m and m.get("kind") != "bound"}
    if skipped:
        lines += ["", "## Skipped", ""]
        for n, sk in skipped.items():
            whole = "rmse_m" not in ms[n]
            why = (ms[n].get("training") or {}).get("unavailable")  # a Trained method that could not be trained
            lines.append(f"- {n} ({ms[n].get('family', '-')}): {'skipped' if whole else 'skipped on'} "
                         f"{len(sk)} session(s): " + (f"training: {why}" if why else "; ".join(sorted(set(sk.values())))))
    model = results.get("model") or {}
    for n, why in (model.get("unavailable") or {}).items():
        if n not in skipped:
            lines.append(f"- {n}: {why}")
    for n, b in bounds.items():
        if "skipped" in b and "rmse_m" not in b:
            lines += ["", f"{n}: " + "; ".join(sorted(set(b["skipped"].values()))) + "."]
    if ran:
        cols = order + list(scored)
        lines += ["", "## Per session (RMSE mean over runs, m)", "", "| session | " + " | ".join(cols) + " |",
                  "|---|" + "---|" * len(cols)]
        for sid in results["sessions"]:
            cells = [_f(ms[n]["per_session"][sid]["rmse_m"]["mean"]) if sid in ms[n].get("per_session", {}) else
                     ("skipped" if n in ran else "-") for n in cols]
            lines.append(f"| {sid} | " + " | ".join(cells) + " |")
    return intro, lines, ("Plots: leaderboard_cdf.png (median error CDF over runs, one colour per family; the bounds "
                          "as the error CDF of an estimator that attains them), leaderboard_trajectories.png (the best "
                          "method of each family), pcrlb_over_time.png (simulated data), error_cdf.png, rmse_box.png, "
                          "error_over_time.png, trajectories.png. Trajectories of every method: "
                          "OUT/<session>/trajectories/<method>.tum (evo_ape tum groundtruth.tum <method>.tum).")


def _bound_text(scored: dict) -> str:
    parts = []
    for name, bound in scored.items():
        b = bound["rmse_m"]["mean"]
        s = bound.get("settings", {})
        used = ", ".join(k for k in ("rssi", "rtt", "visual") if s.get(k)) or "none"
        if name == "PCRLB":
            parts.append(
                f"{name}: the posterior Cramer-Rao lower bound of the position error (Tichavsky et al. 1998) along the "
                f"true trajectories, from the simulator's own channel models (measurements: {used}) and a "
                f"constant-velocity motion prior fitted to the simulated walks (blenav.eval.pcrlb): RMSE {b:.2f} m. "
                "The columns marked * are those of an estimator that attains the bound (errors drawn from N(0, J^-1) "
                "at each step). The bound counts no inertial, odometry or floor-plan information (methods using them "
                "are not bound by it) and treats the channel parameters as known and shadowing as independent between "
                f"{s.get('dt_s', 1):g} s steps: every simplification lowers it.")
        else:
            parts.append(f"{name}: the same bound from the BLE RSSI alone (the information the BLE-only filters use): "
                         f"RMSE {b:.2f} m.")
        best = bound.get("best")
        if best:
            verdict = "within" if best["ratio"] <= 1.5 else "NOT within"
            parts[-1] += (f" Best method: {best['method']} at {best['rmse_m']:.2f} m, {best['ratio']:.1f}x {name} "
                          f"({verdict} 1.5x).")
        for sid, ids in (bound.get("no_position") or {}).items():
            parts[-1] += (f" Session {sid}: anchor(s) {', '.join(ids)} heard but without a position in anchors.csv, "
                          "their packets not counted.")
    parts.append("What keeps a method above the bound (unknown beacon powers and receiver offset, wall and body "
                 "losses it does not model, information it does not use) is discussed in docs/results-leaderboard.md.")
    return "\n\n".join(parts)


def _confined_lines(ms: dict) -> list[str]:
    """Which methods' estimates the evaluation kept on the floor (blenav.localizers.confine), and how many."""
    rows = []
    for name, m in ms.items():
        c = m.get("confined")
        if c and (c["bbox"] or c["off_free"]):
            moved = (f", {c['free']} moved into free space" if c["free"]
                     else " (a map-free method: not moved)" if c["off_free"] else "")
            rows.append(f"- {name}: {c['bbox']} of {c['estimates']} estimates clamped to the plan's bounding box; "
                        f"{c['off_free']} off free space by more than 2 sigma{moved}")
    if not rows:
        return []
    return ["", "Estimates kept on the floor (every method's estimates are clamped to the floor plan's bounding box, "
            "and moved into free space when farther from it than twice their standard deviation, unless the "
            "method is map-free):", ""] + rows


def _dropped_lines(results: dict) -> list[str]:
    """The rows the readers dropped, per session and stream."""
    dropped = results.get("dropped") or {}
    if not dropped:
        return []
    out = ["", "Rows dropped while reading (not used by any method):", ""]
    for sid, streams in dropped.items():
        for stream, reasons in streams.items():
            out.append(f"- {sid}, {stream}.csv: " + ", ".join(f"{n} rows ({why})" for why, n in reasons.items()))
    return out


def _beacon_map_lines(results: dict) -> list[str]:
    """The map the methods were given (when not anchors.csv as is) and the beacon errors of the methods that
    return a map (prior -> optimized, mean horizontal distance to the true positions)."""
    bm = results.get("beacon_map")
    lines = []
    if bm:
        noise = f", every BLE beacon moved by N(0, {bm['noise_m']:g}^2) m per {'axis' if bm['vertical'] else 'horizontal axis'} " \
                f"anew in each run (the same draw for every method)" if bm["noise_m"] else ""
        where = "; ".join(f"{b}: {i}" for b, i in bm.get("buildings", {}).items())
        lines.append(f"Beacon map (beacon_map): source {bm['source']}{noise}{f' ({where})' if where else ''}.")
    errs = {n: m["beacon_error_m"] for n, m in results["methods"].items() if m.get("beacon_error_m")}
    for n, e in errs.items():
        heard = "; ".join(f"{label}: {_f(b['given_m'])} -> {_f(b['optimized_m'])} m ({b['beacons']})"
                          for label, b in checked_by_heard(e.get("by_heard")).items())
        lines.append(f"Beacon error of {n} (mean horizontal distance to the true positions, over beacons and runs): "
                     f"given map {_f(e.get('prior'))} m, optimized {_f(e.get('optimized'))} m"
                     + (f"; by rssi.csv rows per beacon, given -> optimized (beacons): {heard}." if heard else "."))
    return lines + [""] if lines else []


def _plan_error_lines(results: dict) -> list[str]:
    """What was wrong with the plans the methods were given (nothing when they had the true plans)."""
    pe = results.get("plan_error")
    if not pe:
        return []
    per = "; ".join(f"{b} floor {f}: {i['barriers']} barrier(s) closing {i['closed_m2']:.1f} of {i['free_m2']:.0f} m^2 "
                    f"(`{i['image']}`)" for b, fl in pe["buildings"].items() for f, i in fl.items())
    return [f"Wrong floor plans (plan_error): {pe['barriers_per_100m2']:g} spurious barrier(s) per 100 m^2 of free "
            f"space, at most {pe['max_span_m']:g} m wide, plan offset ({pe['offset_m'][0]:g}, {pe['offset_m'][1]:g}) m, "
            f"seed {pe['seed']}: {per}. Ground truth is unchanged.", ""]


def _calibration_line(results: dict) -> str:
    c = results.get("calibration")
    if not c:
        return "Path-loss parameters: as configured (the papers' Table I values)."
    return (f"Path-loss parameters a_X = {c['a_x']:.1f} dBm, gamma = {c['gamma']:.2f} (d0 = {c['d0']:g} m, residual "
            f"std {c['residual_std_db']:.1f} dB, {c['n_readings']} readings): {c['note']}.")


def _paper_comparison(results: dict, ms: dict, experiment) -> list[str]:
    """Does the measured RMSE ordering follow the paper's? Name every inverted pair and what the data
    say about it (the AHRS error for inertial models), so a reader sees at once where and why we differ."""
    paper = (experiment.paper if experiment is not None else None) or {}
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


# --------------------------------------------------------------------------- cross-phone (Roy, Tables 3.3-3.5)

def write_crossphone_markdown(path: Path, results: dict, experiment=None) -> None:
    """Tables 3.3 (per phone mean/std), 3.4 (overall statistics) and 3.5 (per brand) of Roy, measured."""
    ms = results["methods"]
    names = list(ms)
    split = results.get("split", {})
    lines = [f"# {results['experiment']}: {results.get('title', '')}", "",
             f"Dataset `{results['dataset']}`; {sum(m['n_windows'] for m in list(ms.values())[:1])} test windows in "
             f"{len(results['sessions'])} session(s); seed {results.get('seed', 0)}. Labelled training devices: "
             f"{', '.join(split.get('train', [])) or '-'}; unlabelled (semi-supervised stage): "
             f"{', '.join(split.get('unlabelled', [])) or '-'}. Absolute error (m) of each window's position at its "
             "end against ground truth; every method is scored on the same windows.", "",
             "## Per phone (Table 3.3): mean / std of absolute error [m]", "",
             "| test phone | seen in training | " + " | ".join(names) + " |", "|---|---|" + "---|" * len(names)]
    devices = sorted({d for m in ms.values() for d in m["per_device"]})
    train = set(split.get("train", []))
    unl = set(split.get("unlabelled", []))
    for d in devices:
        seen = "labelled" if d in train else ("unlabelled" if d in unl else "no")
        cells = [f"{_f(m['per_device'][d]['mean'])} / {_f(m['per_device'][d]['std'])}" if d in m["per_device"] else "-"
                 for m in ms.values()]
        lines.append(f"| {d} | {seen} | " + " | ".join(cells) + " |")
    lines += ["", "## All test windows (Table 3.4) [m]", "", "| statistic | " + " | ".join(names) + " |",
              "|---|" + "---|" * len(names)]
    for k, label in (("mean", "Mean"), ("std", "Std. dev."), ("median", "Median"), ("p90", "90 %ile"), ("max", "Max.")):
        lines.append(f"| {label} | " + " | ".join(_f(m["error_m"][k]) for m in ms.values()) + " |")
    lines += ["", "## Per brand (Table 3.5): mean / std [m]", "", "| test brand | " + " | ".join(names) + " |",
              "|---|" + "---|" * len(names)]
    brands = sorted({b for m in ms.values() for b in m["per_brand"]})
    for b in brands:
        lines.append(f"| {b} | " + " | ".join(
            f"{_f(m['per_brand'][b]['mean'])} / {_f(m['per_brand'][b]['std'])}" if b in m["per_brand"] else "-"
            for m in ms.values()) + " |")
    lines += ["", "| method | source | train [s] (this call) | predict [s] |", "|---|---|---|---|"]
    lines += [f"| {n} | {m['source']} | {_f(m['train_s'], 1)} | {_f(m['predict_s'], 2)} |" for n, m in ms.items()]
    nofix = sum(results.get("no_fix_windows", {}).values())
    if nofix:
        lines += ["", f"{nofix} test window(s) had no beacon heard in any step: no method gives a fix there and "
                  "they are not scored."]
    lines += crossphone_claims(results)
    lines += ["", "Plots: error_cdf.png (all test windows), per_device.png (mean error per phone and method)."]
    write_text(path, "\n".join(lines) + "\n")


def _pooled_mean(m: dict, devices) -> float | None:
    rows = [m["per_device"][d] for d in devices if d in m["per_device"]]
    n = sum(r["n"] for r in rows)
    return sum(r["mean"] * r["n"] for r in rows) / n if n else None


pooled_mean = _pooled_mean  # public: benchmarks/crossphone_sweep.py pools per-device errors with it too


def crossphone_claims(results: dict) -> list[str]:
    """The thesis' claims (section 3.1.4) checked on these numbers, each stated as holds / does not hold."""
    ms = results["methods"]
    split = results.get("split", {})
    train, unl = set(split.get("train", [])), set(split.get("unlabelled", []))
    devices = sorted({d for m in ms.values() for d in m["per_device"]})
    seen = [d for d in devices if d in train]
    unseen = [d for d in devices if d not in train and d not in unl]
    adapted = [d for d in devices if d in unl]
    out = ["", "## The thesis' claims on these numbers", ""]

    def verdict(ok: bool) -> str:
        return "holds" if ok else "does NOT hold"

    p, b = ms.get("TransNet+LocNet"), ms.get("LocNet")
    if p and b and unseen:
        pu, bu = _pooled_mean(p, unseen), _pooled_mean(b, unseen)
        out.append(f"- TransNet+LocNet beats LocNet (same labelled data) on phones never seen: {pu:.2f} vs {bu:.2f} m "
                   f"-> {verdict(pu < bu)}.")
    if p and seen and unseen:
        ps, pu = _pooled_mean(p, seen), _pooled_mean(p, unseen)
        out.append(f"- TransNet+LocNet's unseen-phone mean error within 15 % of its seen-phone error: {pu:.2f} vs "
                   f"{ps:.2f} m ({100 * (pu / ps - 1):+.0f} %) -> {verdict(pu <= 1.15 * ps)}.")
    a = ms.get("LocNet+aug")
    if p and a and unseen:  # our ablation, not a thesis claim: what TransNet adds beyond the receiver augmentation
        pu, au = _pooled_mean(p, unseen), _pooled_mean(a, unseen)
        out.append(f"- (ablation, not in the thesis) TransNet+LocNet beats LocNet trained with the same receiver "
                   f"augmentation (LocNet+aug) on phones never seen: {pu:.2f} vs {au:.2f} m -> {verdict(pu < au)}.")
    s = ms.get("TransNet+LocNet+semi")
    if p and s and adapted:
        pa, sa = _pooled_mean(p, adapted), _pooled_mean(s, adapted)
        out.append(f"- The semi-supervised stage improves the adapted brand's phones ({', '.join(adapted)}): "
                   f"{sa:.2f} vs {pa:.2f} m -> {verdict(sa < pa)}.")
    best = min(ms, key=lambda n: ms[n]["error_m"]["mean"])
    out.append(f"- Lowest overall mean error: {best} ({ms[best]['error_m']['mean']:.2f} m); the thesis reports "
               "1.37 m (scenario 2) and 1.34 m (scenario 3) on its building with unseen brands under 2 m.")
    return out
