"""blenav-eval experiment=leaderboard: every method of the project composes, the table / PCRLB / peak memory /
families / TUM trajectories / CDF are written, the PCRLB is skipped on data without simulator parameters, and
the fleet merge (python -m blenav.cli.tables leaderboard) writes one table. Tiny sims (seconds); the slow methods
(back-end, CRF) are switched off in the run test, but are built (so checked) by the composition test."""

from __future__ import annotations

import json
import shutil

import numpy as np
import pytest
import yaml
from PIL import Image

from blenav.configs import compose
from blenav.eval.config import parse_eval_config
from blenav.eval.harness import build_methods, evaluate
from helpers import simulate_small

SLOW = ("F-end", "B-end", "crf", "crf_recursive", "DR", "IMU", "grid_l1", "srls", "pf_pl_offset", "pf_ps_map_offset",
        "pf_pl_map")


def cfg(*overrides):
    return compose("eval", *["progress=false", *overrides])


@pytest.fixture(scope="module")
def tiny(tmp_path_factory):
    """One 25 s pedestrian walk with non-default building and receiver names."""
    return simulate_small(tmp_path_factory.mktemp("lb") / "sim", 6, 25, 1, "sim.name=dock_hall",
                          "sim.receivers=[redmi-note8]")


def test_every_family_is_built_and_labelled():
    c = cfg("experiment=leaderboard", "data=unused")
    methods = build_methods(c)
    fam = {label for labels in c.experiment.families.values() for label in labels}
    missing = [m for m in methods if m not in fam]
    assert not missing, f"methods without a family: {missing}"
    for want in ("RW", "IMU", "PF-PS+MAP", "F-end", "B-end", "CRF", "grid-L2", "SRLS", "centroid", "IO+map", "PF-FIX+MAP"):
        assert want in methods


def test_leaderboard_on_a_tiny_sim(tiny, tmp_path):
    out = tmp_path / "lb"
    res = evaluate(cfg("experiment=leaderboard", f"data={tiny}", "runs=2", f"out={out}", "init_s=5",
                       *[f"methods.{k}=null" for k in SLOW]))
    ms = json.loads((out / "results.json").read_text())["methods"]
    assert set(ms) == set(res["methods"])
    ran = [n for n, m in ms.items() if "rmse_m" in m and m.get("kind") != "bound"]
    assert {"RW", "PF-PL", "PF-PS+MAP", "grid-L2", "centroid"} <= set(ran)
    for n in ran:
        m = ms[n]
        assert m["family"] != "other" and m["peak_memory"]["peak_memory_mb"] >= 0
        assert np.isfinite(m["realtime_factor"]) and set(m["error_m"]) >= {"mean", "median", "p75", "p90"}
        assert (out / next(iter(m["per_session"])) / "trajectories" / f"{n}.tum").is_file(), n  # evo's TUM format
    # learned rows without a model / fixes: skipped with the reason
    assert "model_path" in next(iter(ms["IO+map"]["skipped"].values()))
    assert "fixes" in next(iter(ms["PF-FIX+MAP"]["skipped"].values()))
    b = ms["PCRLB"]
    assert b["kind"] == "bound" and b["family"] == "bound" and 0 < b["rmse_m"]["mean"] < min(ms[n]["rmse_m"]["mean"] for n in ran)
    assert b["best"]["method"] in ran and b["best"]["ratio"] > 1
    ble = ms["PCRLB-BLE"]  # BLE alone: less information than BLE + RTT + visual fixes
    assert ble["kind"] == "bound" and ble["rmse_m"]["mean"] >= b["rmse_m"]["mean"] - 1e-9
    md = (out / "results.md").read_text()
    assert "| - | PCRLB | bound |" in md and "## Skipped" in md and "x PCRLB (" in md and "| - | PCRLB-BLE | bound |" in md
    assert md.index("| 1 | " + b["best"]["method"] + " |") < md.index("| - | PCRLB |")  # sorted by RMSE, the bound last
    for png in ("leaderboard_cdf.png", "pcrlb_over_time.png", "trajectories.png", "leaderboard_trajectories.png"):
        with Image.open(out / png) as im:
            assert im.size[0] > 500

    # real data (no simulator parameters in dataset.yaml): the PCRLB is skipped with the reason
    real = tmp_path / "real"
    shutil.copytree(tiny, real)
    meta = yaml.safe_load((real / "dataset.yaml").read_text())
    meta.pop("simulator")
    (real / "dataset.yaml").write_text(yaml.safe_dump(meta))
    res2 = evaluate(cfg("experiment=leaderboard", f"data={real}", "runs=1", f"out={tmp_path / 'lb2'}", "init_s=5",
                        "plots=false", *[f"methods.{k}=null" for k in SLOW], "methods.pf_ps=null", "methods.grid_l2=null"))
    assert "rmse_m" not in res2["methods"]["PCRLB"] and "simulator" in next(iter(res2["methods"]["PCRLB"]["skipped"].values()))
    assert "PCRLB: not a simulated dataset" in (tmp_path / "lb2" / "results.md").read_text()

    # the fleet merge: both folders in one table
    from blenav.cli.tables import main as tables_main

    assert tables_main(["leaderboard", str(tmp_path / "fleet.md"), "Fleet", str(out), str(tmp_path / "lb2")]) == 0
    merged = json.loads((tmp_path / "fleet.json").read_text())
    assert [d["name"] for d in merged["datasets"]] == ["sim", "real"]
    assert set(merged["methods"]["RW"]["rmse_m"]) == {"sim", "real"} and merged["methods"]["RW"]["sessions"] == 2
    assert "sim" in merged["best"] and "real" not in merged["best"]
    assert "| - | PCRLB | bound |" in (tmp_path / "fleet.md").read_text()


def test_peak_memory_counts_reused_heap():
    """Memory a method takes from the heap freed by an earlier one is counted as its own (malloc_trim)."""
    from blenav.eval.memory import PeakMemory, rss_probe_available

    if not rss_probe_available():
        pytest.skip("no writable /proc/self/clear_refs (not Linux)")
    x = [np.ones(1000) for _ in range(10000)]  # ~80 MB of small blocks, freed into the heap
    del x
    with PeakMemory("rss") as m:
        y = [np.ones(1000) for _ in range(4000)]  # ~32 MB
        del y
    assert 20 < m.result()["peak_memory_mb"] < 80
    with PeakMemory("none") as m:
        pass
    assert m.result() is None
    with pytest.raises(ValueError, match="peak_memory"):
        PeakMemory("psutil")


def test_static_survey_drawn_as_points_and_legend_inside_the_figure(tmp_path):
    """A static survey jumps between points: drawn as points, not a line through walls, in every panel of the
    trajectories' small multiples; the legend sits in the figure's margin, inside the saved image."""
    from blenav.data import Dataset
    from blenav.plotting import figure_trajectories, new_figure, plot_tracks, save_figure

    out = simulate_small(tmp_path / "survey", 1, 30, 1, "sim.carriers=[static]", "sim.name=quay_survey")
    s = Dataset.open(out).session(Dataset.open(out).session_ids[0])
    assert s.carrier == "static"
    fig = new_figure(6, 4)
    ax = fig.subplots()
    plot_tracks(ax, [s], legend=False)
    assert not ax.lines and len(ax.collections) == 1  # points only
    gt = s.groundtruth
    tracks = {f"method {k}": (gt["t"].to_numpy(), gt[["x", "y"]].to_numpy() + k * 0.1) for k in range(30)}
    fig = figure_trajectories(s, tracks)
    shown = [ax for ax in fig.axes if ax.get_visible()]
    assert len(shown) == 20 and "10 more method(s) not drawn" in fig._suptitle.get_text()  # one panel per method
    for ax in shown:  # the survey points in every panel, the estimates as points too: no line at all
        assert not [ln for ln in ax.lines if ln.get_label() in ("ground truth", ax.get_title())]
        labels = [c.get_label() for c in ax.collections]
        assert "ground truth (survey points)" in labels and ax.get_title() in labels
    legend = fig.legends[0]
    save_figure(fig, tmp_path / "t.png")
    bb = legend.get_window_extent(fig.canvas.get_renderer())
    W, H = fig.canvas.get_width_height()
    assert bb.x0 >= 0 and bb.y0 >= 0 and bb.x1 <= W + 1 and bb.y1 <= H + 1  # the whole legend is in the image
    assert fig.axes[0].yaxis.label.get_window_extent(fig.canvas.get_renderer()).x0 >= 0  # and the y label


@pytest.mark.slow  # scale-out end to end (17-28 s here): make test-slow
def test_fleet_as_a_hydra_multirun_then_merged(tiny, tmp_path):
    """blenav-eval -m ... data=A,B with the joblib launcher: one output folder per dataset, merged into one
    table by python -m blenav.cli.tables leaderboard (only the fast centroid row kept)."""
    import subprocess
    import sys

    from blenav.configs import compose as _compose

    keep = "centroid"
    off = [f"methods.{k}=null" for k in _compose("eval", "experiment=leaderboard").methods if k != keep]
    second = tmp_path / "second"
    shutil.copytree(tiny, second)
    fleet = tmp_path / "fleet"
    cmd = [sys.executable, "-m", "blenav.cli.eval", "-m", "experiment=leaderboard", f"data={tiny},{second}", "runs=1",
           f"out={fleet}/${{hydra:job.num}}", "hydra/launcher=joblib", "hydra.launcher.n_jobs=1",
           f"hydra.sweep.dir={fleet}/.multirun", "progress=false", "plots=false", "init_s=5", *off]
    r = subprocess.run(cmd, capture_output=True, text=True, timeout=300, cwd=tmp_path)
    assert r.returncode == 0, r.stderr[-2000:]
    assert (fleet / "0" / "results.json").is_file() and (fleet / "1" / "results.json").is_file()
    r = subprocess.run([sys.executable, "-m", "blenav.cli.tables", "leaderboard", str(tmp_path / "fleet.md"), "Fleet",
                        str(fleet)], capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stderr
    merged = json.loads((tmp_path / "fleet.json").read_text())
    assert [d["folder"] for d in merged["datasets"]] == [str(fleet / "0"), str(fleet / "1")]
    assert merged["methods"]["centroid"]["datasets"] == 2 and merged["methods"]["PCRLB"]["datasets"] == 2


def test_leaderboard_results_md_prints_the_common_lines(tmp_path):
    """The leaderboard's results.md is written by the common report (blenav.eval.report): besides its own table it
    prints what every experiment's results.md prints (calibration, wrong plans, beacon map, estimates kept on the
    floor, rows dropped while reading)."""
    from blenav.eval.report import write_markdown

    stats = {"mean": 1.0, "stderr": 0.1, "ci99": [0.8, 1.2], "median": 0.9, "p75": 1.2, "p90": 1.6, "max": 3.0}
    m = {"rmse_m": stats, "error_m": stats, "ate_m": 1.0, "ee_m": 0.5, "wall_s": 1.0, "realtime_factor": 50.0,
         "family": "PF classical", "per_session": {"walk-A": {"rmse_m": stats}}, "map_notes": ["a map note"],
         "confined": {"bbox": 2, "off_free": 1, "free": 1, "estimates": 100}}
    results = {"experiment": "leaderboard", "title": "t", "dataset": "/d", "runs": 1, "sessions": ["walk-A"],
               "init_s": 5.0, "seed": 0, "methods": {"PF-PL": m},
               "calibration": {"a_x": -60.0, "gamma": 2.1, "d0": 1.0, "residual_std_db": 4.0, "n_readings": 10,
                               "note": "fitted"},
               "plan_error": {"barriers_per_100m2": 1.0, "max_span_m": 2.0, "offset_m": [0.0, 0.0], "seed": 1,
                              "buildings": {"hall": {"0": {"barriers": 1, "closed_m2": 2.0, "free_m2": 100.0,
                                                           "image": "p.png"}}}},
               "beacon_map": {"source": "given", "noise_m": 0.5, "vertical": False},
               "dropped": {"walk-A": {"rssi": {"unknown-anchor": 3}}}}
    md = {}
    for name, c in (("leaderboard", parse_eval_config(cfg("experiment=leaderboard", "data=unused")).experiment),
                    ("default", None)):
        write_markdown(tmp_path / f"{name}.md", results, c)
        md[name] = (tmp_path / f"{name}.md").read_text()
    assert "| 1 | PF-PL | PF classical |" in md["leaderboard"] and "| 1 | PF-PL |" not in md["default"]
    for line in ("Path-loss parameters a_X = -60.0 dBm", "Wrong floor plans (plan_error)", "Beacon map (beacon_map)",
                 "- a map note", "Estimates kept on the floor", "- walk-A, rssi.csv: 3 rows (unknown-anchor)"):
        assert line in md["leaderboard"] and line in md["default"], line


def test_bound_over_time_legend_counts_its_entries():
    """Four sessions without BLE-only curves are four legend entries: inside the axes (not 8, in the margin)."""
    from blenav.plotting import figure_bound_over_time

    curves = {f"walk-{k}": {"t": np.arange(5.0), "bound_m": np.ones(5) + k} for k in range(4)}
    fig = figure_bound_over_time(curves)
    assert fig.axes[0].get_legend() is not None and not fig.legends
    fig = figure_bound_over_time(curves, curves)  # eight entries: in the figure's margin
    assert fig.axes[0].get_legend() is None and len(fig.legends) == 1
