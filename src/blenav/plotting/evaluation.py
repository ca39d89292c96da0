"""Figures of an evaluation: error CDFs, per-device means, RMSE boxes, error over time, trajectories on the floor
plan and learning curves; the leaderboard's CDF by method family and the PCRLB over time; and where a survey's
fingerprints fail (:func:`figure_coverage`).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from matplotlib.figure import Figure

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


def figure_rmse_box(rmses: dict[str, np.ndarray], title: str = "") -> Figure:
    """Box plot of per-run RMSE (m) per method."""
    fig = new_figure(1.4 + 1.2 * len(rmses), 4.4)
    ax = fig.subplots()
    ax.boxplot(list(rmses.values()), tick_labels=list(rmses), showfliers=True)
    ax.set_ylabel("RMSE per run [m]")
    ax.grid(True, axis="y", alpha=0.3)
    ax.set_title(title or "RMSE per run", fontsize=9)
    return fig


def figure_error_over_time(err_t: dict[str, tuple[np.ndarray, np.ndarray]], init_s: float, session_id: str) -> Figure:
    """Error over time per method (median over runs, 5-95 % band); the global-localization period shaded."""
    fig = new_figure(9.0, 4.0)
    ax = fig.subplots()
    t0 = None
    for (name, (t, err)), c in zip(err_t.items(), session_colors(len(err_t))):
        q = np.quantile(err, [0.05, 0.5, 0.95], axis=0)
        ax.fill_between(t, q[0], q[2], color=c, alpha=0.15, linewidth=0)
        ax.plot(t, q[1], color=c, lw=1.2, label=name)
        t0 = t[0] if t0 is None else min(t0, t[0])
    if t0 is not None:
        ax.axvspan(t0, t0 + init_s, color="0.85", zorder=0, label="global localization")
    ax.set_xlabel("time [s]")
    ax.set_ylabel("position error [m]")
    ax.set_title(f"error over time, session {session_id}", fontsize=9)
    ax.grid(True, alpha=0.3)
    legend_in_figure(fig, ax, len(err_t) + 1, inside="upper right")
    return fig


def figure_trajectories(session: Session, tracks: dict[str, tuple[np.ndarray, np.ndarray]]) -> Figure:
    """Estimated trajectories (one run per method) over the floor plan with the ground truth."""
    b = session.building
    fl = session.floor
    x0, x1, y0, y1 = fl.extent
    w = 9.0
    fig = new_figure(w, max(3.5, w * (y1 - y0) / max(x1 - x0, 1e-9) * 0.85))
    ax = fig.subplots()
    plot_floor(ax, b, session.meta.get("floor"), anchor_labels=False)
    gt = session.groundtruth
    static = session.carrier == "static"  # a survey: points (the device jumps between them), not lines through walls
    if static:
        ax.scatter(*survey_points(gt["x"].to_numpy(), gt["y"].to_numpy()), s=30, marker="s", color="k",
                   label="ground truth (survey points)", zorder=6)
    else:
        ax.plot(gt["x"], gt["y"], color="k", lw=2.0, label="ground truth")
    for (name, (t, p)), c in zip(tracks.items(), session_colors(len(tracks))):
        if static:
            ax.scatter(p[:, 0], p[:, 1], s=6, color=c, alpha=0.7, label=name, zorder=5)
        else:
            ax.plot(p[:, 0], p[:, 1], color=c, lw=1.0, alpha=0.9, label=name)
    legend_in_figure(fig, ax, len(tracks) + 1)
    ax.set_anchor("W")  # the equal aspect narrows the axes: keep them (and the y label) at the left, beside the legend
    ax.set_title(f"trajectories, session {session.id} (first run)", fontsize=9)
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
