"""Figures of an evaluation: error CDFs, per-device means, RMSE boxes, error over time, trajectories on the floor
plan and learning curves; the leaderboard's CDF by method family and the PCRLB over time; and where a survey's
fingerprints fail (:func:`figure_coverage`).
"""

from __future__ import annotations

import math
import textwrap
from collections.abc import Sequence

import numpy as np
from matplotlib.figure import Figure
from matplotlib.lines import Line2D
from matplotlib.patches import Patch

from blenav.data import Session

from .common import legend_in_figure, new_figure, session_colors, survey_points
from .floor import plot_floor

def figure_error_cdf(grid: np.ndarray, cdfs: dict[str, np.ndarray], title: str = "") -> Figure:
    """Position-error CDF per method: median over runs with the 5-95 % band (``cdfs[name]`` (3, G))."""
    fig = new_figure(7.0, 4.6)
    ax = fig.subplots()
    for (name, band), c in zip(cdfs.items(), session_colors(len(cdfs))):
        ax.fill_between(grid, band[0], band[2], color=c, alpha=0.2, linewidth=0)
        ax.plot(grid, band[1], color=c, lw=1.8, label=name)
    ax.set_xlabel("position error [m]")
    ax.set_ylabel("fraction of estimates")
    ax.set_ylim(0, 1)
    ax.set_xlim(grid[0], grid[-1])
    ax.grid(True, alpha=0.3)
    legend_in_figure(fig, ax, len(cdfs), inside="lower right")
    ax.set_title(title or "error CDF (median over runs, 5-95 % band)", fontsize=9)
    return fig


def figure_per_device(means: dict[str, dict[str, float]], title: str = "") -> Figure:
    """Grouped bars: mean error (m) per test device (x) and method (colour); ``means[method][device]``."""
    devices = sorted({d for m in means.values() for d in m})
    fig = new_figure(max(6.0, 0.55 * len(devices) * max(1, len(means)) ** 0.5 + 2), 4.4)
    ax = fig.subplots()
    w = 0.8 / max(len(means), 1)
    x = np.arange(len(devices))
    for k, ((name, m), c) in enumerate(zip(means.items(), session_colors(len(means)))):
        ax.bar(x + (k - (len(means) - 1) / 2) * w, [m.get(d, np.nan) for d in devices], w, color=c, label=name)
    ax.set_xticks(x, devices, rotation=45, ha="right", fontsize=8)
    ax.set_ylabel("mean absolute error [m]")
    ax.grid(True, axis="y", alpha=0.3)
    ax.legend(fontsize=7, ncol=2)
    ax.set_title(title or "mean error per test device", fontsize=9)
    return fig


#: a method with fewer per-run values than this gets its values drawn as points, not a box (a box of 2-4 values
#: draws quartiles and whiskers the data cannot give)
MIN_BOX_VALUES = 5


def figure_rmse_box(rmses: dict[str, np.ndarray], title: str = "") -> Figure:
    """Per-run RMSE (m) per method: a box plot where a method has at least :data:`MIN_BOX_VALUES` values, else its
    values as points (spread sideways, deterministically) with a bar at their median; every tick label names its n
    ("METHOD\nn=2"). Non-finite values are left out (and not counted)."""
    names = list(rmses)
    vals = [np.asarray(rmses[n], float).ravel() for n in names]
    vals = [v[np.isfinite(v)] for v in vals]
    width = float(np.clip(1.4 + 0.95 * len(names), 6.0, 16.0))
    fig = new_figure(width, 4.6)
    ax = fig.subplots()
    pos = np.arange(1, len(names) + 1, dtype=float)
    boxed = [i for i, v in enumerate(vals) if v.size >= MIN_BOX_VALUES]
    if boxed:
        ax.boxplot([vals[i] for i in boxed], positions=pos[boxed], widths=0.5, showfliers=True, manage_ticks=False)
    few = [i for i, v in enumerate(vals) if 0 < v.size < MIN_BOX_VALUES]
    for k, i in enumerate(few):
        v = vals[i]
        x = pos[i] + (np.linspace(-0.12, 0.12, v.size) if v.size > 1 else np.zeros(1))
        ax.scatter(x, v, s=24, color="tab:blue", edgecolors="k", linewidths=0.4, zorder=3,
                   label=f"per-run RMSE (n < {MIN_BOX_VALUES}: points, no box)" if k == 0 else None)
        ax.hlines(np.median(v), pos[i] - 0.22, pos[i] + 0.22, color="tab:orange", lw=1.6, zorder=2,
                  label="median" if k == 0 else None)
    crowded = len(names) > 8 or max((len(n) for n in names), default=0) > 14
    ax.set_xticks(pos, [f"{n}\nn={v.size}" for n, v in zip(names, vals)], fontsize=8,
                  rotation=35 if crowded else 0, ha="right" if crowded else "center",
                  rotation_mode="anchor" if crowded else "default")
    ax.set_xlim(0.4, len(names) + 0.6)
    ax.set_ylim(bottom=0.0)
    ax.set_ylabel("RMSE per run [m]")
    ax.grid(True, axis="y", alpha=0.3)
    if few:
        ax.legend(fontsize=7, loc="upper left")
    ax.set_title(textwrap.fill(title or "RMSE per run", int(width * 14)), fontsize=9)  # ~14 characters per inch
    return fig


#: error_over_time.png draws at most this many sessions (one panel each, in the evaluation's order); the figure's
#: title says how many were left out
MAX_SESSION_PANELS = 12


def figure_error_over_time(err_t: dict[str, dict[str, tuple[np.ndarray, np.ndarray]]], init_s: float,
                           title: str = "", methods: Sequence[str] | None = None) -> Figure:
    """Error over time, one panel per session (small multiples with shared axes, at most
    :data:`MAX_SESSION_PANELS`): per method the median over runs with the 5-95 % band, the global-localization period
    shaded; ``err_t[session][method] = (t (K,), err (R, K))``. Time runs from the session's first estimate (sessions
    on one axis whatever their clocks); a method keeps its colour in every panel (colours in the order of ``methods``,
    default: as the methods first appear); one legend for the figure."""
    sids = list(err_t)[:MAX_SESSION_PANELS]
    left = len(err_t) - len(sids)
    n = max(len(sids), 1)
    ncols = 1 if n <= 3 else (2 if n <= 8 else 3)
    nrows = math.ceil(n / ncols)
    drawn = {m for sid in sids for m in err_t[sid]}
    methods = [m for m in dict.fromkeys([*(methods or []), *(m for sid in sids for m in err_t[sid])]) if m in drawn]
    colors = dict(zip(methods, session_colors(len(methods))))
    fig = new_figure({1: 9.0, 2: 12.0, 3: 14.0}[ncols], 4.0 if nrows == 1 else 1.0 + 2.3 * nrows)
    axes = fig.subplots(nrows, ncols, sharex=True, sharey=True, squeeze=False)
    for ax, sid in zip(axes.ravel(), sids):
        starts = [t[0] for t, _ in err_t[sid].values() if len(t)]
        t0 = min(starts) if starts else 0.0
        for name, (t, err) in err_t[sid].items():
            if not len(t):
                continue
            q = np.quantile(err, [0.05, 0.5, 0.95], axis=0)
            ax.fill_between(t - t0, q[0], q[2], color=colors[name], alpha=0.15, linewidth=0)
            ax.plot(t - t0, q[1], color=colors[name], lw=1.1)
        ax.axvspan(0.0, init_s, color="0.85", zorder=0)
        ax.set_title(sid, fontsize=8)
        ax.grid(True, alpha=0.3)
    for ax in axes.ravel()[len(sids):]:
        ax.set_visible(False)
    for r in range(nrows):
        axes[r, 0].set_ylabel("position error [m]", fontsize=8)
    for k, ax in enumerate(axes.ravel()[:len(sids)]):
        if k + ncols >= len(sids):  # the lowest panel of its column
            ax.set_xlabel("time since the first estimate [s]", fontsize=8)
            ax.xaxis.set_tick_params(labelbottom=True)
    handles = [Line2D([], [], color=colors[m], lw=1.5) for m in methods] + [Patch(color="0.85")]
    fig.legend(handles, methods + [f"global localization ({init_s:g} s)"], loc="outside right upper", fontsize=7,
               frameon=False, ncols=max(1, math.ceil((len(methods) + 1) / 30)))
    head = title or "error over time (median over runs, 5-95 % band)"
    more = f"; {left} more left out (at most {MAX_SESSION_PANELS} panels)" if left else ""
    fig.suptitle(f"{head}: {len(sids)} session(s){more}", fontsize=9)
    return fig


#: trajectories.png draws at most this many panels: one per method, or, with more methods and their families
#: given, one per family; beyond it the figure's title says how many methods were left out
MAX_TRACK_PANELS = 20


def track_panels(tracks: dict, groups: dict[str, str] | None = None,
                 max_panels: int = MAX_TRACK_PANELS) -> tuple[list[tuple[str, list[str]]], int]:
    """Which methods each panel of :func:`figure_trajectories` draws: ``[(panel title, [method, ...]), ...]`` and
    how many methods were left out. One panel per method while they fit in ``max_panels``; with more and ``groups``
    (method -> family) one panel per family (families in their first method's order); the first ``max_panels`` panels
    in either case."""
    names = list(tracks)
    if len(names) <= max_panels or not groups:
        panels = [(n, [n]) for n in names]
    else:
        by: dict[str, list[str]] = {}
        for n in names:
            by.setdefault(groups.get(n) or "other", []).append(n)
        panels = list(by.items())
    shown = panels[:max_panels]
    return shown, len(names) - sum(len(ms) for _, ms in shown)


def figure_trajectories(session: Session, tracks: dict[str, tuple[np.ndarray, np.ndarray]], title: str = "",
                        groups: dict[str, str] | None = None) -> Figure:
    """Estimated trajectories (one run per method) on the floor plan as small multiples: one panel per method (per
    family with more than :data:`MAX_TRACK_PANELS` methods and ``groups``, :func:`track_panels`), in a grid of
    ceil(sqrt(panels)) columns with shared axes; the ground truth (black) in every panel, the floor's rooms, routes
    and anchors faint behind. A static survey: points, not lines through walls. ``tracks[name] = (t (K,),
    xy (K, 2))``; a method keeps its colour of the evaluation's other figures."""
    b = session.building
    x0, x1, y0, y1 = session.floor.extent
    panels, left = track_panels(tracks, groups)
    n = max(len(panels), 1)
    ncols = math.ceil(math.sqrt(n))
    nrows = math.ceil(n / ncols)
    width = 9.0 if ncols == 1 else min(16.0, 4.0 * ncols)
    aspect = (y1 - y0) / max(x1 - x0, 1e-9)
    panel_w = (width - 2.4) / ncols  # the legend takes ~1.9 in of the right margin, the y tick labels ~0.5 in
    fig = new_figure(width, float(np.clip(nrows * (panel_w * aspect + 0.35) + 0.9, 3.5, 24.0)))
    fig.get_layout_engine().set(wspace=0.06)  # room between panels for their tick labels
    axes = fig.subplots(nrows, ncols, sharex=True, sharey=True, squeeze=False)
    gt = session.groundtruth
    static = session.carrier == "static"  # a survey: points (the device jumps between them), not lines through walls
    colors = dict(zip(tracks, session_colors(len(tracks))))
    for ax, (head, names) in zip(axes.ravel(), panels):
        plot_floor(ax, b, session.meta.get("floor"), faint=True)
        if static:
            ax.scatter(*survey_points(gt["x"].to_numpy(), gt["y"].to_numpy()), s=14, marker="s", color="k",
                       label="ground truth (survey points)", zorder=6)
        else:
            ax.plot(gt["x"], gt["y"], color="k", lw=1.4, label="ground truth", zorder=5)
        for name in names:
            t, p = tracks[name]
            if static:
                ax.scatter(p[:, 0], p[:, 1], s=5, color=colors[name], alpha=0.8, label=name, zorder=7)
            else:
                ax.plot(p[:, 0], p[:, 1], color=colors[name], lw=0.9, alpha=0.9, label=name, zorder=6)
        ax.set_title(head, fontsize=8)
        if len(names) > 1:  # a family's panel: its methods named inside
            ax.legend(handles=[ln for ln in (ax.lines + ax.collections) if ln.get_label() in names], fontsize=6,
                      loc="upper right", framealpha=0.7)
        ax.set_xlabel("")
        ax.set_ylabel("")
    for ax in axes.ravel()[len(panels):]:
        ax.set_visible(False)
    for r in range(nrows):
        axes[r, 0].set_ylabel("y (north) [m]", fontsize=8)
    for k, ax in enumerate(axes.ravel()[:len(panels)]):
        if k + ncols >= len(panels):
            ax.set_xlabel("x (east) [m]", fontsize=8)
            ax.xaxis.set_tick_params(labelbottom=True)
    if panels:  # the ground truth and the faint floor's entries, once
        h, lab = axes[0, 0].get_legend_handles_labels()
        keep = [(hh, ll) for hh, ll in zip(h, lab) if ll not in tracks]
        fig.legend([hh for hh, _ in keep], [ll for _, ll in keep], loc="outside right upper", fontsize=7,
                   frameon=False)
    more = f"; {left} more method(s) not drawn (at most {MAX_TRACK_PANELS} panels)" if left else ""
    fig.suptitle(f"{title or 'trajectories'}, session {session.id} (first run){more}", fontsize=9)
    return fig


def figure_learning_curves(history: Sequence[dict], knn_val_err_m: float | None = None, title: str = "",
                           baseline: str = "KNN") -> Figure:
    """Learning curves of one training run (:class:`blenav.learn.common.trainer.TrainingMonitor` history): left, the
    training and validation loss per validation check against optimizer steps (log scale) and the learning
    rate (right axis); right, the validation error in metres with the simplest ``baseline``'s on the same validation
    data (KNN for a fingerprint network, PDR for the inertial odometry)."""
    fig = new_figure(9.0, 3.6)
    ax, ax2 = fig.subplots(1, 2)
    step = np.array([h.get("step", np.nan) for h in history], float)

    def col(key):
        return np.array([np.nan if h.get(key) is None else h[key] for h in history], float)

    ax.plot(step, col("train_loss"), label="train loss", lw=1.0)
    ax.plot(step, col("val_loss"), label="validation loss", lw=1.0)
    if np.isfinite(col("val_loss")).any() or np.isfinite(col("train_loss")).any():
        ax.set_yscale("log")
    ax.set_xlabel("optimizer step")
    ax.set_ylabel("loss")
    ax.grid(True, alpha=0.3)
    lr = col("lr")
    if np.isfinite(lr).any():
        axr = ax.twinx()
        axr.plot(step, lr, color="0.6", lw=0.8, ls=":", label="learning rate")
        axr.set_ylabel("learning rate", fontsize=8)
    ax.legend(fontsize=7)
    ax2.plot(step, col("val_err_m"), label="network, validation", lw=1.0)
    if knn_val_err_m is not None and np.isfinite(knn_val_err_m):
        ax2.axhline(knn_val_err_m, color="k", ls="--", lw=0.8, label=f"{baseline}, validation ({knn_val_err_m:.2f} m)")
    ax2.set_xlabel("optimizer step")
    ax2.set_ylabel("mean validation error [m]")
    ax2.grid(True, alpha=0.3)
    ax2.legend(fontsize=7)
    fig.suptitle(title or "learning curves", fontsize=9)
    return fig



# --------------------------------------------------------------------------- leaderboard

#: one colour per method family of the leaderboard (conf/experiment/leaderboard.yaml ``experiment.families``)
FAMILY_COLORS = {"PF classical": "tab:blue", "map fusion": "tab:green", "back-end": "tab:purple", "CRF": "tab:orange",
                 "learned": "tab:red", "fingerprint": "tab:brown", "bound": "black", "other": "tab:gray"}
_FAMILY_STYLES = ["-", "--", ":", "-."]


def figure_leaderboard_cdf(grid: np.ndarray, cdfs: dict[str, np.ndarray], families: dict[str, str], title: str = "",
                           rmse: dict[str, float] | None = None,
                           bounds: dict[str, tuple[float, np.ndarray]] | None = None) -> Figure:
    """The leaderboard's error CDF: one colour per method family (:data:`FAMILY_COLORS`), methods of one family
    told apart by line style; ``cdfs[name]`` (G,) the median CDF over runs, ``rmse[name]`` shown in the
    legend; ``bounds[name] = (RMSE, CDF (G,))``: a bound as the error CDF of an estimator that attains it
    (black, dashed / dotted) and its RMSE as a thin vertical line. The legend, grouped by family and sorted by
    RMSE within it, sits in the figure's right margin."""
    rmse = rmse or {}
    fig = new_figure(10.0, 5.2)
    ax = fig.subplots()
    fam_rank = {f: i for i, f in enumerate(FAMILY_COLORS)}
    seen: dict[str, int] = {}
    for name in sorted(cdfs, key=lambda n: (fam_rank.get(families.get(n, "other"), 99), rmse.get(n, np.inf))):
        fam = families.get(name, "other")
        k = seen.get(fam, 0)
        seen[fam] = k + 1
        lab = f"{name} ({rmse[name]:.2f} m)" if name in rmse else name
        ax.plot(grid, cdfs[name], color=FAMILY_COLORS.get(fam, "tab:gray"), ls=_FAMILY_STYLES[k % 4],
                lw=2.0 if k < 4 else 1.0, label=f"{fam}: {lab}")
    for k, (name, (b_rmse, b_cdf)) in enumerate((bounds or {}).items()):
        ls = "--" if k == 0 else ":"
        ax.plot(grid, b_cdf, color="black", ls=ls, lw=2.0, label=f"bound: {name} ({b_rmse:.2f} m RMSE)")
        ax.axvline(b_rmse, color="black", lw=0.7, ls=ls)
    ax.set_xlabel("position error [m]")
    ax.set_ylabel("fraction of estimates")
    ax.set_ylim(0, 1)
    ax.set_xlim(grid[0], grid[-1])
    ax.grid(True, alpha=0.3)
    legend_in_figure(fig, ax, len(cdfs) + len(bounds or {}), rows=26)
    ax.set_title(title or "leaderboard: error CDF (median over runs), one colour per family", fontsize=9)
    return fig


def figure_bound_over_time(curves: dict[str, dict], curves_ble: dict[str, dict] | None = None) -> Figure:
    """The PCRLB (sqrt of the trace of the position block of J_k^-1, m) over time per session (solid) and,
    when given, the BLE-only bound (dashed); ``curves[session] = {"t" (K,), "bound_m" (K,)}``."""
    fig = new_figure(8.0, 3.8)
    ax = fig.subplots()
    for (sid, c), col in zip(curves.items(), session_colors(len(curves))):
        ax.plot(c["t"], c["bound_m"], color=col, lw=1.2, label=f"{sid}: PCRLB")
        if curves_ble and sid in curves_ble:
            ax.plot(curves_ble[sid]["t"], curves_ble[sid]["bound_m"], color=col, lw=1.0, ls="--", label=f"{sid}: BLE only")
    ax.set_yscale("log")
    ax.set_xlabel("time [s]")
    ax.set_ylabel("PCRLB of the position error [m]")
    ax.grid(True, alpha=0.3, which="both")
    legend_in_figure(fig, ax, len(curves) + sum(sid in (curves_ble or {}) for sid in curves), inside="upper right")
    ax.set_title("posterior Cramer-Rao lower bound along the true trajectories", fontsize=9)
    return fig


def figure_coverage(session: Session, train_xy: np.ndarray, truth_xy: np.ndarray, err_m: np.ndarray, title: str = "",
                    vmax_m: float = 20.0) -> Figure:
    """Where a fingerprint survey needs more walks: the floor of ``session``, the train walks' positions (grey) and
    each test fix at its true position (``truth_xy`` (M, 2) m) coloured by its error (``err_m`` (M,) m, clipped at
    ``vmax_m``)."""
    fl = session.floor
    x0, x1, y0, y1 = fl.extent
    w = 9.0
    fig = new_figure(w, max(3.5, w * (y1 - y0) / max(x1 - x0, 1e-9) * 0.85))
    ax = fig.subplots()
    plot_floor(ax, session.building, session.meta.get("floor"), anchor_labels=False)
    if len(train_xy):
        ax.scatter(train_xy[:, 0], train_xy[:, 1], s=2, color="0.6", alpha=0.5, label="train walks", zorder=4)
    sc = ax.scatter(truth_xy[:, 0], truth_xy[:, 1], c=np.minimum(err_m, vmax_m), s=10, cmap="viridis", vmin=0.0,
                    vmax=vmax_m, label="test fixes (true position)", zorder=5)
    fig.colorbar(sc, ax=ax, shrink=0.8, label=f"fix error (m, clipped at {vmax_m:g})")
    ax.legend(loc="upper right", fontsize=7)
    ax.set_title(title or "fingerprint fix error by where it was taken", fontsize=9)
    return fig
