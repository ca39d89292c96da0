"""The evaluation's HTML page (``report.html``): plotly figures and a sortable table in one self-contained file.

:func:`render_report` turns a :class:`blenav.eval.report_html.ReportData` into the page: the leaderboard (a table
sorted by clicking a column), the CDF of every method's error, per session the trajectories on the floor plan (a
legend entry per method toggles it; a time slider moves each method's current position and the truth's), and the
methods that were skipped with their reasons. plotly.js is inlined once, so the page works offline; nothing is
fetched. Drawing only: the numbers come from the data given (computed in :mod:`blenav.eval.report_html`).
"""

from __future__ import annotations

import html
import json

import numpy as np

#: the most points of one track drawn on the page (longer tracks are thinned evenly; the errors use all points)
MAX_TRACK_POINTS = 3000
#: the most track points of the whole page (each track thinned to its share; the page stays a few MB)
MAX_PAGE_POINTS = 150_000
#: slider steps of a session's time slider
SLIDER_STEPS = 60
#: points of a CDF curve
CDF_POINTS = 400
#: (results.json key, sub-key, column title) of the leaderboard, in order; a column shows when a method has it
COLUMNS = (("rmse_m", "mean", "RMSE [m]"), ("rmse_m", "ci99", "99% CI (n)"), ("error_m", "mean", "mean error [m]"),
           ("error_m", "median", "median [m]"), ("error_m", "p90", "p90 [m]"), ("ate_m", None, "ATE [m]"),
           ("segment_error_m", "mean", "segment error [m]"), ("realtime_factor", None, "x real time"))

#: columns of other results.json keys ({"mean": ...}) shown beside COLUMNS (a cross-phone evaluation's keys, say)
MAX_EXTRA_COLUMNS = 6

_PALETTE = ("#1b9e77", "#d95f02", "#7570b3", "#e7298a", "#66a61e", "#e6ab02", "#a6761d", "#1f78b4", "#b2df8a",
            "#fb9a99", "#cab2d6", "#6a3d9a", "#ff7f00", "#b15928", "#8dd3c7", "#bebada", "#80b1d3", "#fdb462")

_SORT_JS = """
document.querySelectorAll('table.sortable th').forEach(function (th, col) {
  th.addEventListener('click', function () {
    var table = th.closest('table'), body = table.tBodies[0];
    var rows = Array.prototype.slice.call(body.rows);
    var asc = th.getAttribute('data-dir') !== 'asc';
    table.querySelectorAll('th').forEach(function (h) { h.removeAttribute('data-dir'); });
    th.setAttribute('data-dir', asc ? 'asc' : 'desc');
    rows.sort(function (a, b) {
      var x = a.cells[col].getAttribute('data-v'), y = b.cells[col].getAttribute('data-v');
      var nx = parseFloat(x), ny = parseFloat(y);
      var c = (isNaN(nx) || isNaN(ny)) ? String(x).localeCompare(String(y)) : nx - ny;
      return asc ? c : -c;
    });
    rows.forEach(function (r) { body.appendChild(r); });
  });
});
"""

_CSS = """
body { font-family: system-ui, sans-serif; margin: 1.5em auto; max-width: 1200px; color: #222; }
table.sortable { border-collapse: collapse; font-size: 0.9em; }
table.sortable th, table.sortable td { border-bottom: 1px solid #ddd; padding: 0.3em 0.7em; text-align: right; }
table.sortable th { cursor: pointer; background: #f4f4f4; position: sticky; top: 0; }
table.sortable th[data-dir=asc]::after { content: " \\25B2"; } table.sortable th[data-dir=desc]::after { content: " \\25BC"; }
table.sortable td:first-child, table.sortable th:first-child { text-align: left; }
.note { color: #666; font-size: 0.9em; }
"""


def _value(m: dict, key: str, sub: str | None):
    v = m.get(key)
    if sub is not None:
        v = v.get(sub) if isinstance(v, dict) else None
    return v


def _cell(key: str, sub: str | None, m: dict) -> tuple[str, str]:
    """(the text shown, the value sorted by) of one table cell."""
    v = _value(m, key, sub)
    if v is None:
        return "", ""
    if sub == "ci99" and isinstance(v, (list, tuple)) and len(v) == 2:
        n = html.escape(str((m.get(key) or {}).get("n", "")))
        if not all(isinstance(x, (int, float)) for x in v):
            return html.escape(str(v)), ""
        if v[0] == v[1]:
            return f"- (n={n})", str(v[1])
        return f"[{v[0]:.2f}, {v[1]:.2f}] (n={n})", str(v[1])
    if isinstance(v, (int, float)) and np.isfinite(v):
        return (f"{v:.0f}" if key == "realtime_factor" else f"{v:.2f}"), repr(float(v))
    return html.escape(str(v)), html.escape(str(v))


def leaderboard_table(methods: dict) -> str:
    """The leaderboard as an HTML table (sortable), rows in results.json's order sorted by the first column."""
    dicts = [m for m in methods.values() if isinstance(m, dict)]
    cols = [c for c in COLUMNS if any(_value(m, c[0], c[1]) is not None for m in dicts)]
    known = {c[0] for c in COLUMNS}
    other = dict.fromkeys(k for m in dicts for k, v in m.items()
                          if k not in known and isinstance(v, dict) and isinstance(v.get("mean"), (int, float)))
    cols += [(k, "mean", f"{k} (mean)") for k in list(other)[:MAX_EXTRA_COLUMNS]]  # an evaluation of another kind
    ran = {n: m for n, m in methods.items() if isinstance(m, dict) and any(_value(m, k, s) is not None
                                                                           for k, s, _ in cols)}
    if not ran:
        return "<p>No method produced an estimate.</p>"
    first = cols[0]

    def key(item):
        v = _value(item[1], first[0], first[1])
        return (0, float(v)) if isinstance(v, (int, float)) and np.isfinite(v) else (1, 0.0)

    head = "".join(f"<th>{html.escape(c[2])}</th>" for c in cols)
    rows = []
    for name, m in sorted(ran.items(), key=key):
        label = html.escape(name) + (" <i>(bound)</i>" if m.get("kind") == "bound" else "")
        cells = [f'<td data-v="{html.escape(name)}">{label}</td>']
        for k, s, _ in cols:
            text, v = _cell(k, s, m)
            cells.append(f'<td data-v="{v}">{text}</td>')
        rows.append("<tr>" + "".join(cells) + "</tr>")
    return (f'<table class="sortable" id="leaderboard"><thead><tr><th>method</th>{head}</tr></thead><tbody>'
            + "\n".join(rows) + "</tbody></table>")


def _colors(names) -> dict[str, str]:
    return {n: _PALETTE[i % len(_PALETTE)] for i, n in enumerate(names)}


def _thin(t: np.ndarray, xy: np.ndarray, n: int) -> tuple[np.ndarray, np.ndarray]:
    if len(t) <= n:
        return t, xy
    idx = np.unique(np.linspace(0, len(t) - 1, n).round().astype(int))
    return t[idx], xy[idx]


def cdf_figure(errors: dict[str, np.ndarray], colors: dict[str, str]):
    import plotly.graph_objects as go

    fig = go.Figure()
    for name, e in errors.items():
        e = np.sort(e[np.isfinite(e)])
        if not len(e):
            continue
        q = np.linspace(0, 1, min(CDF_POINTS, len(e)))
        fig.add_trace(go.Scatter(x=np.quantile(e, q), y=q, mode="lines", name=name,
                                 line=dict(color=colors.get(name))))
    fig.update_layout(title="Error CDF (run 0 of each method, every session)", xaxis_title="error [m]",
                      yaxis_title="fraction of estimates", height=450, margin=dict(l=60, r=20, t=50, b=50))
    return fig


def session_figure(view, colors: dict[str, str], max_points: int):
    """One session: the floor plan, the truth and every method's track; a time slider moving a marker per track."""
    import plotly.graph_objects as go

    fig = go.Figure()
    if view.plan is not None:
        occ, (x0, x1, y0, y1) = view.plan
        h, w = occ.shape
        z = occ[::-1].astype(np.uint8)  # row 0 of the grid is its top: plotly's y grows upwards; 0 drawn clear
        fig.add_trace(go.Heatmap(z=z, x0=x0 + (x1 - x0) / w / 2, dx=(x1 - x0) / w, y0=y0 + (y1 - y0) / h / 2,
                                 dy=(y1 - y0) / h, colorscale=[[0, "rgba(0,0,0,0)"], [1, "#9a9a9a"]], zmin=0, zmax=1,
                                 showscale=False, hoverinfo="skip", name="floor plan"))
    lines = []
    if view.gt is not None and len(view.gt[0]):
        lines.append(("ground truth", *_thin(*view.gt, max_points), "#000000"))
    for name, (t, xy) in view.tracks.items():
        lines.append((name, *_thin(t, xy, max_points), colors.get(name, "#444")))
    for name, t, xy, color in lines:
        fig.add_trace(go.Scatter(x=xy[:, 0], y=xy[:, 1], mode="lines", name=name, legendgroup=name,
                                 line=dict(color=color, width=2.5 if name == "ground truth" else 1.5),
                                 customdata=t, hovertemplate="t=%{customdata:.1f} s<br>x=%{x:.2f} y=%{y:.2f}"))
    first_marker = len(fig.data)
    t_all = np.concatenate([t for _, t, _, _ in lines]) if lines else np.zeros(0)
    for name, t, xy, color in lines:
        fig.add_trace(go.Scatter(x=[xy[0, 0]], y=[xy[0, 1]], mode="markers", legendgroup=name, showlegend=False,
                                 marker=dict(color=color, size=10, line=dict(color="white", width=1)),
                                 hoverinfo="skip", name=f"{name} now"))
    steps = []
    if len(t_all):
        for tk in np.linspace(t_all.min(), t_all.max(), SLIDER_STEPS):
            xs, ys = [], []
            for _, t, xy, _ in lines:
                inside = t[0] <= tk <= t[-1]
                xs.append([float(np.interp(tk, t, xy[:, 0])) if inside else None])
                ys.append([float(np.interp(tk, t, xy[:, 1])) if inside else None])
            steps.append(dict(method="restyle", label=f"{tk:.0f}",
                              args=[{"x": xs, "y": ys}, list(range(first_marker, first_marker + len(lines)))]))
    fig.update_layout(title=f"session {view.id}", height=600, margin=dict(l=60, r=20, t=50, b=40),
                      xaxis_title="x [m]", yaxis_title="y [m]", yaxis=dict(scaleanchor="x", scaleratio=1),
                      legend=dict(title="click to hide / show"),
                      sliders=[dict(steps=steps, currentvalue=dict(prefix="t = ", suffix=" s"), pad=dict(t=40))]
                      if steps else [])
    return fig


def render_report(data, max_points: int | None = None) -> str:
    """The whole page (a string of HTML) of a :class:`blenav.eval.report_html.ReportData`."""
    import plotly.offline

    n_tracks = sum(len(v.tracks) + (v.gt is not None) for v in data.sessions)
    max_points = max_points or max(50, min(MAX_TRACK_POINTS, MAX_PAGE_POINTS // max(n_tracks, 1)))
    methods = data.results.get("methods", {})
    colors = _colors(methods)
    parts = [f"<h1>{html.escape(data.title)}</h1>",
             f'<p class="note">experiment {html.escape(data.experiment)}; dataset '
             f'{html.escape(str(data.results.get("dataset", "")))}; {html.escape(str(data.results.get("runs", "?")))} '
             f'run(s) per session; {len(data.results.get("sessions", []) or [])} session(s). Click a column to sort; '
             'bounds (PCRLB) are not methods: no estimator can beat them.</p>',
             "<h2>Leaderboard</h2>", leaderboard_table(methods)]
    if data.versus:
        parts.append("<h2>Learned models beside the simplest baseline</h2><ul id=\"versus\">"
                     + "".join(f"<li>{html.escape(v)}</li>" for v in data.versus) + "</ul>")
    figs = []
    if data.errors:
        figs.append(("<h2>Error CDF</h2>", cdf_figure(data.errors, colors)))
    for i, view in enumerate(data.sessions):
        head = "<h2>Trajectories on the floor plan</h2>" if i == 0 else ""
        figs.append((head, session_figure(view, colors, max_points)))
    for head, fig in figs:
        parts.append(head + fig.to_html(full_html=False, include_plotlyjs=False,
                                        config={"displaylogo": False, "responsive": True}))
    if data.skipped:
        items = "".join(f"<li><b>{html.escape(n)}</b>: " + "; ".join(
            f"{html.escape(s)}: {html.escape(r)}" for s, r in why.items()) + "</li>" for n, why in data.skipped.items())
        parts.append(f'<h2>Skipped methods</h2><ul id="skipped">{items}</ul>')
    for note in data.notes:
        parts.append(f'<p class="note">{html.escape(note)}</p>')
    meta = json.dumps({"methods": list(methods), "skipped": list(data.skipped)})
    meta = meta.replace("<", "\\u003c").replace(">", "\\u003e").replace("&", "\\u0026")  # inert inside <script>
    return ("<!DOCTYPE html>\n<html><head><meta charset=\"utf-8\">"
            f"<title>{html.escape(data.title)}</title><style>{_CSS}</style>"
            f"<script type=\"text/javascript\">{plotly.offline.get_plotlyjs()}</script>"
            f"<script type=\"application/json\" id=\"blenav-report\">{meta}</script>"
            "</head><body>\n" + "\n".join(parts) + f"\n<script>{_SORT_JS}</script>\n</body></html>\n")
