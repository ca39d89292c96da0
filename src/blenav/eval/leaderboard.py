"""The leaderboard experiment (``experiment.kind: leaderboard``, conf/experiment/leaderboard.yaml).

The harness runs the methods as for any experiment; this module adds what the leaderboard shows:

- :class:`PeakMemory`: each method's peak memory, measured around its runs (``peak_memory`` in the config):
  ``rss`` (default, Linux) returns the free heap to the OS (glibc ``malloc_trim(0)``, so memory the method
  reuses from earlier methods counts as its own), resets the process's RSS high-water mark
  (``/proc/self/clear_refs``, value 5) before the method and reads ``VmHWM`` after it: the peak resident memory
  while the method ran, reported as the increase over the resident memory when it started (``peak_memory_mb``)
  and as the absolute peak (``peak_rss_mb``). Every allocation counts (numpy, numba, torch, ONNX Runtime),
  timing is unaffected. The harness reads every session's streams and floor plan before the first method
  (:func:`blenav.eval.harness.evaluate`), so no method pays for reading the data; what the methods load or
  build on first use and share (imported code, JIT-compiled kernels, map geometry per floor and attitude per
  session in ``RunContext.cache``) is counted in the first method that needs it. ``tracemalloc`` (the fallback where /proc is not writable) counts Python and
  numpy allocations only and slows Python-heavy methods (their real-time factor then includes that).
  ``none``: not measured.
- :func:`finish`: the ``PCRLB`` entries (:mod:`blenav.eval.pcrlb`, ``kind: bound``, on simulated data; skipped
  with the reason elsewhere) and every method's ``family``.
- :func:`plot`: the leaderboard CDF (one colour per family, from the CDFs the harness draws error_cdf.png
  with), the bound over time and the best method per family.
- results.md: :func:`blenav.eval.report.write_markdown` (one table sorted by RMSE, the skipped methods with
  their reasons, how far the best method is from the bound, and the notes every experiment prints).
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

    from blenav.errors import EvalError

    from .pcrlb import BoundSettings

    node = cfg.get("bound") or {}
    try:
        return OmegaConf.to_object(OmegaConf.merge(OmegaConf.structured(BoundSettings), node))
    except Exception as exc:
        raise EvalError(f"bound: {exc}") from exc


def finish(results: dict, ds, sessions: list, cfg) -> dict:
    """Add the bound entries and the families to ``results``; returns what the leaderboard's plots need of the
    bounds (``{"curves": {variant: {session: {t, bound_m}}}, "errors": {variant: efficient-estimator errors}}``,
    for :func:`plot`).

    ``PCRLB``: the bound with every measurement the ``bound`` block switches on (BLE RSSI, RTT, visual fixes);
    ``PCRLB-BLE``: the same with BLE RSSI alone, the information the BLE-only filters have (only when the
    first uses more than BLE); each session's information is computed once for both
    (:func:`blenav.eval.pcrlb.bound_entries`). Each has ``best``: the best method's RMSE and its ratio to the bound."""
    from dataclasses import replace

    from .pcrlb import bound_entries

    st = bound_settings(cfg)
    variants = {"PCRLB": st}
    if st.rssi and (st.rtt or st.visual):
        variants["PCRLB-BLE"] = replace(st, rtt=False, visual=False)
    curves, errors = {}, {}
    for name, entry in bound_entries(ds.meta, sessions, float(cfg.init_s), variants, seed=int(cfg.seed)).items():
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
    return {"curves": curves, "errors": errors}


# ------------------------------------------------------------------------------------------ plots
def plot(out: Path, results: dict, outcomes: dict, sessions: list, grid: np.ndarray, cdfs: dict[str, np.ndarray],
         bounds: dict) -> None:
    """The leaderboard's figures, from the error CDFs the harness drew error_cdf.png with (``cdfs[name]`` (G,)
    the median over runs on ``grid``) and :func:`finish`'s ``bounds``: leaderboard_cdf.png (one colour per
    family, the bounds as the error CDF of an estimator that attains them), pcrlb_over_time.png (simulated
    data), leaderboard_trajectories.png."""
    from blenav import plotting

    errors, curves = bounds.get("errors", {}), bounds.get("curves", {})
    b_cdfs = {}
    for name, e in errors.items():  # an efficient estimator's error CDF (errors ~ N(0, J^-1) per step)
        if e is not None and len(e):
            b_cdfs[name] = (results["methods"][name]["rmse_m"]["mean"],
                            np.searchsorted(np.sort(e), grid, side="right") / len(e))
    fam = {n: m.get("family", "other") for n, m in results["methods"].items()}
    rmse = {n: m["rmse_m"]["mean"] for n, m in results["methods"].items() if "rmse_m" in m}
    fig = plotting.figure_leaderboard_cdf(grid, cdfs, fam, results.get("title", ""), rmse=rmse, bounds=b_cdfs)
    plotting.save_figure(fig, out / "leaderboard_cdf.png")
    if curves.get("PCRLB"):
        plotting.save_figure(plotting.figure_bound_over_time(curves["PCRLB"], curves.get("PCRLB-BLE")),
                             out / "pcrlb_over_time.png")
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
