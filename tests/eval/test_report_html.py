"""``OUT/report.html`` (issue 33, section 3): written by every ``blenav eval`` with plots and by ``blenav report``;
the numbers it draws are the evaluation's; it renders in headless Chromium (Debian's package) without console
errors and shows every method, the time slider and the skipped methods with their reasons."""

from __future__ import annotations

import json
import re
import shutil
import subprocess
from pathlib import Path

import numpy as np
import pytest

from blenav.data.writer import write_tum
from blenav.eval.metrics import errors_vs_groundtruth
from blenav.eval.report_html import read_tum, report_data, write_report
from blenav.plotting.html import leaderboard_table
from helpers import simulate_small

CHROMIUM = shutil.which("chromium") or shutil.which("chromium-browser")
FLAGS = ["--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
         "--disable-background-networking", "--disable-component-update", "--disable-sync",
         "--enable-logging=stderr", "--v=0", "--virtual-time-budget=20000"]


@pytest.fixture(scope="module")
def evaluated(tmp_path_factory) -> Path:
    """``blenav eval experiment=mapfusion_002`` on two one-minute walks, 2 runs, through the command's main."""
    from blenav.cli.eval import main

    root = tmp_path_factory.mktemp("report")
    data = simulate_small(root / "d", 4, 60, 2)
    main([f"data={data}", "experiment=mapfusion_002", "runs=2", f"out={root / 'o'}", "progress=false"])
    return root / "o"


def test_every_evaluation_writes_the_page_from_its_own_numbers(evaluated):
    assert (evaluated / "report.html").is_file()
    res = json.loads((evaluated / "results.json").read_text())
    data = report_data(evaluated)
    assert set(data.errors) == set(res["methods"]) and len(data.sessions) == len(res["sessions"])
    sid = res["sessions"][0]
    d = evaluated / sid / "trajectories"
    gt_t, gt_xy = read_tum(d / "groundtruth.tum")
    errs = []
    for s in res["sessions"]:
        t, xy = read_tum(evaluated / s / "trajectories" / "PF-PL.tum")
        g = read_tum(evaluated / s / "trajectories" / "groundtruth.tum")
        errs.append(errors_vs_groundtruth(t, xy[None], *g)[0][0])
    np.testing.assert_allclose(data.errors["PF-PL"], np.concatenate(errs))
    view = data.sessions[0]
    assert view.plan is not None and view.plan[0].any() and view.gt is not None
    np.testing.assert_array_equal(view.gt[0], gt_t)
    page = (evaluated / "report.html").read_text()
    assert external_refs(page) == []  # nothing fetched: it works offline
    for name, m in res["methods"].items():  # every method in the table, with results.json's RMSE
        assert f'data-v="{m["rmse_m"]["mean"]!r}">{m["rmse_m"]["mean"]:.2f}<' in page, name


def external_refs(page: str) -> list[str]:
    """The src / href attributes of the page's elements (a script's text is not parsed as tags)."""
    from html.parser import HTMLParser

    refs: list[str] = []

    class P(HTMLParser):
        def handle_starttag(self, tag, attrs):
            refs.extend(v for k, v in attrs if k in ("src", "href") and v)

    P().feed(page)
    return refs


def test_table_sorts_escapes_and_says_n():
    methods = {"B<x>": {"rmse_m": {"mean": 2.0, "ci99": [1.0, 3.0], "n": 4}},
               "A": {"rmse_m": {"mean": 1.0, "ci99": [1.0, 1.0], "n": 1}},
               "C": {"skipped": {"s1": "no WiFi"}}}
    t = leaderboard_table(methods)
    assert t.index(">A<") < t.index("B&lt;x&gt;") and "C" not in re.sub(r"<[^>]+>", " ", t).split()
    assert "[1.00, 3.00] (n=4)" in t and "- (n=1)" in t
    other = leaderboard_table({"LocNet": {"err_m": {"mean": 1.5}}})  # another kind of evaluation: its own keys
    assert "err_m (mean)" in other and "1.50" in other


def test_bad_trajectory_is_named(tmp_path):
    p = tmp_path / "x.tum"
    p.write_text("0.1 1.0 oops\n")
    with pytest.raises(ValueError, match=r"x.tum: not a TUM trajectory"):
        read_tum(p)
    z = tmp_path / "zero.tum"  # a file whose size says nothing: the read itself is bounded
    z.symlink_to("/dev/zero")
    with pytest.raises(ValueError, match=r"zero.tum: trajectory file of .* above the limit"):
        read_tum(z)
    write_tum(p, np.array([2.0, 1.0]), np.array([[0.0, 1.0], [2.0, 3.0]]))
    t, xy = read_tum(p)
    np.testing.assert_array_equal(t, [1.0, 2.0]) and np.testing.assert_array_equal(xy, [[2.0, 3.0], [0.0, 1.0]])


def chromium(url: str, *extra: str) -> subprocess.CompletedProcess:
    return subprocess.run([CHROMIUM, *FLAGS, *extra, url], capture_output=True, text=True, timeout=120)


@pytest.mark.skipif(CHROMIUM is None, reason="Debian's chromium is not installed (.ci/run installs it)")
def test_page_renders_in_headless_chromium_without_console_errors(evaluated, tmp_path):
    out = tmp_path / "o"
    shutil.copytree(evaluated, out)
    res = json.loads((out / "results.json").read_text())
    res["methods"]["LIO"] = {"skipped": {res["sessions"][0]: "no io_model given (io_model=DIR)"}}
    (out / "results.json").write_text(json.dumps(res))
    page = write_report(out)

    probe = tmp_path / "probe.html"  # the console check sees an error where there is one
    probe.write_text("<html><body><script>console.error('probe-error-42')</script></body></html>")
    assert "probe-error-42" in chromium(probe.as_uri(), "--dump-dom").stderr

    r = chromium(page.as_uri(), "--dump-dom")
    assert r.returncode == 0, r.stderr[-2000:]
    console = [l for l in r.stderr.splitlines() if "CONSOLE" in l]
    assert not console, console[:5]
    dom = r.stdout
    assert dom.count("js-plotly-plot") >= 1 + len(res["sessions"])  # the CDF and one figure per session, drawn
    legend = set(re.findall(r'class="legendtext"[^>]*data-unformatted="([^"]*)"', dom))
    methods = [m for m in res["methods"] if m != "LIO"]
    assert set(methods) | {"ground truth"} <= legend
    assert dom.count('class="slider-container"') == len(res["sessions"])
    skipped = re.search(r'<ul id="skipped">(.*?)</ul>', dom, re.S).group(1)
    assert "LIO" in skipped and "no io_model given" in skipped
    rows = re.search(r'<table class="sortable" id="leaderboard">.*?</table>', dom, re.S).group(0)
    assert all(f">{m}<" in rows for m in methods)


def test_learned_rows_beside_their_simplest_baseline():
    from blenav.eval.report_html import learned_vs_baseline

    tr = {"floors": {"f": {"training": {"steps": 500, "stop_reason": "max_steps", "converged": False,
                                        "best_val_error_m": 1.82, "knn_val_error_m": 1.44}}}}
    methods = {"KNN-BLE": {"family": "fingerprint", "rmse_m": {"mean": 4.88}},
               "KNN-WiFi": {"family": "fingerprint", "rmse_m": {"mean": 3.0}},
               "LocNet-BLE": {"family": "fingerprint", "rmse_m": {"mean": 11.72}, "training": tr},
               "PF-FIX+MAP": {"family": "learned", "rmse_m": {"mean": 2.5}},
               "PDR (rotation vector)": {"error_m": {"mean": 3.3}}, "PDR+map": {"error_m": {"mean": 3.1}},
               "LIO+map": {"error_m": {"mean": 2.9}}, "IO+map": {"family": "learned", "skipped": {"s": "no model"}}}
    assert learned_vs_baseline(methods) == [
        "LocNet-BLE 11.72 m (RMSE) is behind KNN-BLE 4.88 m on these walks; its training: 500 steps (stopped: "
        "max_steps, not converged), validation 1.82 m vs KNN 1.44 m.",
        "PF-FIX+MAP 2.50 m (RMSE) is ahead of KNN-WiFi 3.00 m on these walks.",
        "LIO+map 2.90 m (mean error) is ahead of PDR+map 3.10 m on these walks."]
