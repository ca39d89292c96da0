"""The leaderboard experiment (``experiment.kind: leaderboard``, conf/experiment/leaderboard.yaml).

The harness runs the methods as for any experiment; this module adds what the leaderboard shows:

- :class:`PeakMemory`: each method's peak memory, measured around its runs (``peak_memory`` in the config):
  ``rss`` (default, Linux) returns the free heap to the OS (glibc ``malloc_trim(0)``, so memory the method
  reuses from earlier methods counts as its own), resets the process's RSS high-water mark
  (``/proc/self/clear_refs``, value 5) before the method and reads ``VmHWM`` after it: the peak resident memory while the method ran, reported
  as the increase over the resident memory when it started (``peak_memory_mb``) and as the absolute peak
  (``peak_rss_mb``). Every allocation counts (numpy, numba, torch, ONNX Runtime), timing is unaffected. The
  data streams and floor-plan caches that the harness shares between methods are loaded by the first
  method that reads them and counted there. ``tracemalloc`` (the fallback where /proc is not writable)
  counts Python and numpy allocations only and slows Python-heavy methods (their real-time factor then
  includes that). ``none``: not measured.
- :func:`finish`: the ``PCRLB`` entry (:mod:`blenav.eval.pcrlb`, ``kind: bound``, on simulated data; skipped
  with the reason elsewhere), every method's ``family``, and the leaderboard CDF plot (one colour per family).
- :func:`write_markdown`: results.md as one table sorted by RMSE, the skipped methods with their reasons,
  and how far the best method is from the bound.
"""

from __future__ import annotations

import logging
import re
import tracemalloc
from pathlib import Path

import numpy as np

log = logging.getLogger("blenav.eval")

_CLEAR_REFS = Path("/proc/self/clear_refs")
_STATUS = Path("/proc/self/status")


def _status_kb(field: str) -> int:
    m = re.search(rf"^{field}:\s+(\d+)\s+kB", _STATUS.read_text(), re.M)
    if m is None:
        raise OSError(f"{_STATUS} has no {field}")
    return int(m.group(1))


def _malloc_trim() -> None:
    """glibc's malloc_trim(0): return free heap memory to the OS (a no-op where there is no glibc)."""
    import ctypes
    import gc

    gc.collect()
    try:
        ctypes.CDLL("libc.so.6").malloc_trim(0)
    except (OSError, AttributeError):
        pass


def rss_probe_available() -> bool:
    try:
        _CLEAR_REFS.write_text("5")
        _status_kb("VmHWM")
        return True
    except OSError:
        return False


class PeakMemory:
    """Context manager measuring the peak memory of the code it wraps; ``result()`` is
    ``{"peak_memory_mb", "peak_rss_mb" (rss only), "how"}`` or None (``how='none'``)."""

    def __init__(self, how: str | None = "rss"):
        how = str(how or "none")
        if how not in ("rss", "tracemalloc", "none"):
            raise ValueError(f"peak_memory must be rss, tracemalloc or none, got {how!r}")
        if how == "rss" and not rss_probe_available():
            log.warning("peak_memory=rss needs a writable /proc/self/clear_refs (Linux): using tracemalloc")
            how = "tracemalloc"
        self.how, self._res, self._started = how, None, False

    def __enter__(self):
        if self.how == "rss":
            _malloc_trim()  # freed heap pages back to the OS, so memory the method reuses is counted as its own
            _CLEAR_REFS.write_text("5")  # VmHWM := VmRSS
            self._base = _status_kb("VmRSS")
        elif self.how == "tracemalloc":
            self._started = not tracemalloc.is_tracing()
            if self._started:
                tracemalloc.start()
            tracemalloc.reset_peak()
            self._base = tracemalloc.get_traced_memory()[0]
        return self

    def __exit__(self, *exc):
        if self.how == "rss":
            peak = _status_kb("VmHWM")
            self._res = {"peak_memory_mb": max(peak - self._base, 0) / 1024.0, "peak_rss_mb": peak / 1024.0,
                         "how": "rss: peak resident memory while the method ran (glibc malloc_trim, then VmHWM after clear_refs) minus "
                                "the resident memory when it started"}
        elif self.how == "tracemalloc":
            peak = tracemalloc.get_traced_memory()[1]
            if self._started:
                tracemalloc.stop()
            self._res = {"peak_memory_mb": max(peak - self._base, 0) / 2**20,
                         "how": "tracemalloc: peak of Python/numpy allocations while the method ran"}
        return False

    def result(self) -> dict | None:
        return self._res


# ------------------------------------------------------------------------------------------ families
def families(cfg) -> dict[str, str]:
    """{method label: family} from ``experiment.families`` ({family: [labels]})."""
    fam = (cfg.experiment.get("families") if cfg is not None else None) or {}
    return {str(label): str(f) for f, labels in fam.items() for label in (labels or [])}


def family_of(name: str, fam: dict[str, str]) -> str:
    return fam.get(name, "other")


# ------------------------------------------------------------------------------------------ finish
def bound_settings(cfg):
    from omegaconf import OmegaConf

    from .common import EvalError
    from .pcrlb import BoundSettings

    node = cfg.get("bound") or {}
    try:
        return OmegaConf.to_object(OmegaConf.merge(OmegaConf.structured(BoundSettings), node))
    except Exception as exc:
        raise EvalError(f"bound: {exc}") from exc


def finish(results: dict, outcomes: dict, ds, sessions: list, cfg, out: Path) -> None:
    """Add the bound entries and the families to ``results`` and draw the leaderboard CDF (``plots``).

    ``PCRLB``: the bound with every measurement the ``bound`` block switches on (BLE RSSI, RTT, visual fixes);
    ``PCRLB-BLE``: the same with BLE RSSI alone, the information the BLE-only filters have (only when the
    first uses more than BLE). Each has ``best``: the best method's RMSE and its ratio to the bound."""
    from dataclasses import replace

    from .pcrlb import bound_entry

    st = bound_settings(cfg)
    variants = {"PCRLB": st}
    if st.rssi and (st.rtt or st.visual):
        variants["PCRLB-BLE"] = replace(st, rtt=False, visual=False)
    curves, errors = {}, {}
    for name, settings in variants.items():
        entry = bound_entry(ds.meta, sessions, float(cfg.init_s), settings, seed=int(cfg.seed))
        curves[name], errors[name] = entry.pop("_curves", {}), entry.pop("_errors", None)
        results["methods"][name] = entry
    fam = families(cfg)
    for name, m in results["methods"].items():
        m["family"] = "bound" if m.get("kind") == "bound" else family_of(name, fam)
    ran = {n: m["rmse_m"]["mean"] for n, m in results["methods"].items() if "rmse_m" in m and m.get("kind") != "bound"}
    for name in variants:  # how far the best method is from what any estimator could do
        entry = results["methods"][name]
        if "rmse_m" in entry and ran:
            best = min(ran, key=ran.get)
            entry["best"] = {"method": best, "rmse_m": ran[best], "ratio": ran[best] / max(entry["rmse_m"]["mean"], 1e-12)}
    if cfg.get("plots", True):
        _plot(out, results, outcomes, curves, errors)
        _plot_best_tracks(out, results, outcomes, sessions)


def _plot_best_tracks(out: Path, results: dict, outcomes: dict, sessions: list) -> None:
    """leaderboard_trajectories.png: the first session with the best method of each family (first run), a
    picture one reads at a glance (trajectories.png draws every method)."""
    from blenav import plotting

    ms = results["methods"]
    best: dict[str, str] = {}
    for n, m in ms.items():
        if "rmse_m" in m and m.get("kind") != "bound" and n in outcomes:
            f = m.get("family", "other")
            if f not in best or m["rmse_m"]["mean"] < ms[best[f]]["rmse_m"]["mean"]:
                best[f] = n
    s = next((s for s in sessions if any(s.id in outcomes[n].results for n in best.values())), None)
    if s is None:
        return
    tracks = {f"{n} ({f})": (outcomes[n].results[s.id].t, outcomes[n].results[s.id].position[0])
              for f, n in best.items() if s.id in outcomes[n].results}
    fig = plotting.figure_trajectories(s, tracks)
    fig.axes[0].set_title(f"best method per family, session {s.id} (first run)", fontsize=9)
    plotting.save_figure(fig, out / "leaderboard_trajectories.png")


def _plot(out: Path, results: dict, outcomes: dict, curves: dict, errors: dict) -> None:
    from blenav import plotting

    from .metrics import cdf_band

    grid = np.linspace(0, 15, 301)
    cdfs = {}
    for name, oc in outcomes.items():
        if not oc.metrics:
            continue
        R = next(iter(oc.metrics.values()))["_runs"]["err"].shape[0]
        per_run = [np.concatenate([m["_runs"]["err"][r] for m in oc.metrics.values()]) for r in range(R)]
        cdfs[name] = cdf_band(per_run, grid)[1]
    bounds = {}
    for name, e in errors.items():  # an efficient estimator's error CDF (errors ~ N(0, J^-1) per step)
        if e is not None and len(e):
            bounds[name] = (results["methods"][name]["rmse_m"]["mean"],
                            np.searchsorted(np.sort(e), grid, side="right") / len(e))
    fam = {n: m.get("family", "other") for n, m in results["methods"].items()}
    rmse = {n: m["rmse_m"]["mean"] for n, m in results["methods"].items() if "rmse_m" in m}
    fig = plotting.figure_leaderboard_cdf(grid, cdfs, fam, results.get("title", ""), rmse=rmse, bounds=bounds)
    plotting.save_figure(fig, out / "leaderboard_cdf.png")
    if curves.get("PCRLB"):
        plotting.save_figure(plotting.figure_bound_over_time(curves["PCRLB"], curves.get("PCRLB-BLE")),
                             out / "pcrlb_over_time.png")


# ------------------------------------------------------------------------------------------ results.md
def _f(v, nd=2) -> str:
    return "-" if v is None else f"{v:.{nd}f}"




def write_markdown(path: Path, results: dict, cfg=None) -> None:
    """results.md of the leaderboard: one table sorted by RMSE (the bounds last), then the skipped methods."""
    ms = results["methods"]
    ran = {n: m for n, m in ms.items() if "rmse_m" in m and m.get("kind") != "bound"}
    bounds = {n: m for n, m in ms.items() if m.get("kind") == "bound"}
    scored = {n: m for n, m in bounds.items() if "rmse_m" in m}
    order = sorted(ran, key=lambda n: ran[n]["rmse_m"]["mean"])
    how = next((m["peak_memory"]["how"] for m in ran.values() if m.get("peak_memory")), None)
    lines = [f"# {results['experiment']}: {results.get('title', '')}", "",
             f"Dataset `{results['dataset']}`, {len(results['sessions'])} labelled session(s) "
             f"({', '.join(results['sessions'])}), {results['runs']} run(s) per session and method, seed "
             f"{results.get('seed', 0)}: every method on the same sessions and seeds. Errors are planar (m) against "
             f"the ground truth at the estimate times, after the first {results['init_s']:g} s of each session "
             "(global localization). Sorted by RMSE.", "",
             "| # | method | family | mean | median | p75 | p90 | RMSE mean +- stderr | RMSE 99% CI | ATE | "
             "x real time | peak memory [MB] |", "|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for i, name in enumerate(order, 1):
        m = ran[name]
        r, e = m["rmse_m"], m["error_m"]
        pk = m.get("peak_memory") or {}
        pm = "-" if pk.get("peak_memory_mb") is None else (
            f"+{pk['peak_memory_mb']:.1f}" + (f" ({pk['peak_rss_mb']:.0f})" if pk.get("peak_rss_mb") is not None else ""))
        lines.append(f"| {i} | {name} | {m.get('family', '-')} | {_f(e['mean'])} | {_f(e['median'])} | {_f(e['p75'])} | "
                     f"{_f(e['p90'])} | {_f(r['mean'])} +- {_f(r['stderr'], 3)} | [{_f(r['ci99'][0])}, {_f(r['ci99'][1])}] | "
                     f"{_f(m['ate_m'])} | {_f(m['realtime_factor'], 0)} | {pm} |")
    for name, b in scored.items():
        r, e = b["rmse_m"], b["error_m"]
        lines.append(f"| - | {name} | bound | {_f(e['mean'])}* | {_f(e['median'])}* | {_f(e['p75'])}* | {_f(e['p90'])}* | "
                     f"{_f(r['mean'])} +- {_f(r['stderr'], 3)} | [{_f(r['ci99'][0])}, {_f(r['ci99'][1])}] | "
                     f"{_f(b['ate_m'])} | - | - |")
    lines += ["", _bound_text(scored)] if scored else []
    if how:
        lines += ["", f"Peak memory: {how} (MB: +increase, and in brackets the process's peak resident memory while "
                  "the method ran; data streams and floor-plan caches shared by the methods are counted in the first "
                  "method that loads them)."]
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
    lines += ["", "Plots: leaderboard_cdf.png (median error CDF over runs, one colour per family; the bounds as the "
              "error CDF of an estimator that attains them), leaderboard_trajectories.png (the best method of each "
              "family), pcrlb_over_time.png (simulated data), error_cdf.png, "
              "rmse_box.png, error_over_time.png, trajectories.png. Trajectories of every method: "
              "OUT/<session>/trajectories/<method>.tum (evo_ape tum groundtruth.tum <method>.tum)."]
    Path(path).write_text("\n".join(lines) + "\n", encoding="utf-8")


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
    parts.append("What keeps a method above the bound (unknown beacon powers and receiver offset, wall and body "
                 "losses it does not model, information it does not use) is discussed in docs/results-leaderboard.md.")
    return "\n\n".join(parts)
