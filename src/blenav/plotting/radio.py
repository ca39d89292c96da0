"""Figures of a dataset's radio streams: RSSI statistics per receiver (:func:`figure_radio`) and RSSI against
anchor distance with the path-loss fit (:func:`figure_rssi_vs_distance`); the numbers are
:mod:`blenav.radio_stats`'s.
"""

from __future__ import annotations

import math
from collections.abc import Iterable

import numpy as np
import pandas as pd
from matplotlib.figure import Figure
from matplotlib.ticker import FuncFormatter, NullFormatter

from blenav.data import Session
from blenav.radio_stats import fit_path_loss, path_loss_rssi, rssi_distance_pairs

from .common import MAX_SCATTER_POINTS, new_figure, session_colors

def figure_radio(sessions: Iterable[Session]) -> Figure:
    """RSSI statistics of ``sessions``.

    Left: RSSI against the 3-D phone-anchor distance (labelled sessions; ground truth interpolated at each
    reading, true anchor positions when known) per receiver model, with the least-squares log-distance
    path-loss line ``A - 10 n log10(d)`` over all points (``n`` and the residual std in the legend).
    Right: RSSI histograms per receiver (``device_model``), all sessions.
    """
    sessions = list(sessions)
    fig = new_figure(13.0, 5.0)
    ax_d, ax_h = fig.subplots(1, 2, width_ratios=[1.35, 1.0])

    pairs, values = [], {}
    for s in sessions:
        r = s.rssi
        if len(r):
            values.setdefault(s.device_model or "?", []).append(r["rssi"].to_numpy(dtype=float))
        p = rssi_distance_pairs(s)
        if len(p):
            pairs.append(p.assign(device_model=s.device_model or "?"))
    models = sorted(values)
    colors = dict(zip(models, session_colors(len(models))))

    if pairs:
        allp = pd.concat(pairs, ignore_index=True)
        rng = np.random.default_rng(0)
        for m, grp in allp.groupby("device_model", sort=True):
            count = len(grp)
            if count > MAX_SCATTER_POINTS:
                grp = grp.iloc[np.sort(rng.choice(count, MAX_SCATTER_POINTS, replace=False))]
            ax_d.scatter(grp["distance_m"], grp["rssi"], s=5, alpha=0.35, color=colors[m], linewidths=0,
                         label=f"{m} ({count} readings)", rasterized=True)
        d = allp["distance_m"].to_numpy()
        try:
            a_dbm, n, sd = fit_path_loss(d, allp["rssi"].to_numpy())
        except ValueError as exc:
            ax_d.text(0.5, 0.05, f"no path-loss fit: {exc}", transform=ax_d.transAxes, ha="center", fontsize=8)
        else:
            dd = np.geomspace(max(d[d > 0].min(), 0.05), d.max(), 200)
            ax_d.plot(dd, path_loss_rssi(dd, a_dbm, n), color="k", lw=2,
                      label=f"fit: A = {a_dbm:.1f} dBm at 1 m, n = {n:.2f}, residual std = {sd:.1f} dB")
        ax_d.set_xscale("log")
        ax_d.xaxis.set_major_formatter(FuncFormatter(lambda v, _: f"{v:g}"))
        span = np.log10(d.max() / max(d[d > 0].min(), 1e-9)) if (d > 0).any() else 0.0
        ax_d.xaxis.set_minor_formatter(FuncFormatter(lambda v, _: f"{v:g}") if span < 1.3 else NullFormatter())
        ax_d.legend(loc="upper right", fontsize=7, markerscale=2.5)
    else:
        ax_d.text(0.5, 0.5, "no RSSI readings with ground truth", transform=ax_d.transAxes, ha="center",
                  va="center")
    ax_d.set_xlabel("3-D distance phone - anchor [m]")
    ax_d.set_ylabel("RSSI [dBm]")
    ax_d.set_title("RSSI against distance", fontsize=10)
    ax_d.grid(True, which="both", alpha=0.3)

    if values:
        allv = np.concatenate([np.concatenate(v) for v in values.values()])
        bins = np.arange(np.floor(allv.min()) - 0.5, np.ceil(allv.max()) + 1.5, 1.0)
        if len(bins) > 121:  # wide ranges: about 120 bins
            bins = np.linspace(bins[0], bins[-1], 121)
        for m in models:
            v = np.concatenate(values[m])
            ax_h.hist(v, bins=bins, density=True, histtype="step", lw=1.4, color=colors[m],
                      label=f"{m} (N = {v.size}, median {np.median(v):.0f} dBm)")
        ax_h.legend(loc="upper left", fontsize=7)
    else:
        ax_h.text(0.5, 0.5, "no RSSI readings", transform=ax_h.transAxes, ha="center", va="center")
    ax_h.set_xlabel("RSSI [dBm]")
    ax_h.set_ylabel("density")
    ax_h.set_title("RSSI per receiver", fontsize=10)
    ax_h.grid(True, alpha=0.3)
    fig.suptitle(f"Received signal strength, {len(sessions)} session(s)", fontsize=11)
    return fig


def figure_rssi_vs_distance(panels: dict[str, pd.DataFrame]) -> Figure:
    """One panel per data set: RSSI against distance (2-D histogram) with its fitted path-loss line.

    ``panels`` maps a title to a frame with ``distance_m`` and ``rssi`` (as from
    :func:`blenav.radio_stats.rssi_distance_pairs`); shared axes so the sets compare at a glance.
    """
    n = max(len(panels), 1)
    cols = min(n, 3)
    rows = math.ceil(n / cols)
    fig = new_figure(4.6 * cols, 3.6 * rows)
    axes = np.atleast_1d(fig.subplots(rows, cols, sharex=True, sharey=True)).ravel()
    dmin = min((p["distance_m"][p["distance_m"] > 0].min() for p in panels.values() if len(p)), default=0.1)
    dmax = max((p["distance_m"].max() for p in panels.values() if len(p)), default=10.0)
    xbins = np.geomspace(max(dmin, 0.1), dmax, 50)
    ybins = np.arange(-110, -20, 2.0)
    for ax, (title, p) in zip(axes, panels.items()):
        d, r = p["distance_m"].to_numpy(float), p["rssi"].to_numpy(float)
        ax.hist2d(d, r, bins=[xbins, ybins], cmap="Greys", cmin=1, rasterized=True)
        try:
            a_dbm, nexp, sd = fit_path_loss(d, r)
            dd = np.geomspace(xbins[0], xbins[-1], 100)
            ax.plot(dd, path_loss_rssi(dd, a_dbm, nexp), color="tab:red", lw=1.8,
                    label=f"A = {a_dbm:.1f} dBm, n = {nexp:.2f}, std {sd:.1f} dB")
            ax.legend(loc="lower left", fontsize=7)
        except ValueError as exc:
            ax.text(0.5, 0.5, str(exc), transform=ax.transAxes, ha="center", fontsize=7)
        ax.set_xscale("log")
        ax.xaxis.set_major_formatter(FuncFormatter(lambda v, _: f"{v:g}"))
        ax.set_title(f"{title} ({len(p):,} readings)", fontsize=9)
        ax.grid(True, which="both", alpha=0.3)
    for ax in axes[len(panels):]:
        ax.set_visible(False)
    for ax in axes[::cols]:
        ax.set_ylabel("RSSI [dBm]")
    for ax in axes[-cols:]:
        ax.set_xlabel("distance [m]")
    return fig
