"""``blenav-plot``, :mod:`blenav.plotting` and the plotting-free :mod:`blenav.radio_stats`."""

from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
import yaml
from PIL import Image

from blenav.cli.plot import main as plot_main
from blenav.data import Dataset
from blenav.data.writer import write_building, write_session
from blenav.radio_stats import anchor_positions, fit_path_loss, path_loss_rssi, rssi_distance_pairs
from helpers import REPO, tiny_grid

SRC = REPO / "src" / "blenav"

# anchors of tests/helpers.py: id -> (x, y, z)
TINY_ANCHORS = {"b1": (1.0, 1.0, 2.5), "b2": (9.0, 1.0, 2.5), "b3": (1.0, 7.0, 2.5), "b4": (9.0, 7.0, 2.5),
                "ap1": (5.0, 4.0, 2.5)}




def add_true_anchor_positions(root: Path, dx: dict[str, tuple[float, float, float]]) -> None:
    """Give anchors x_true, y_true, z_true = prior + offset (NaN for anchors not in ``dx``)."""
    p = root / "buildings" / "house" / "anchors.csv"
    a = pd.read_csv(p, dtype={"anchor_id": str})
    for k, c in enumerate(("x_true", "y_true", "z_true")):
        a[c] = [a[c[0]].iloc[i] + dx[aid][k] if aid in dx else np.nan for i, aid in enumerate(a["anchor_id"])]
    a.to_csv(p, index=False)


def png_ok(path: Path, size: tuple[int, int]) -> None:
    assert path.is_file(), path
    assert path.stat().st_size > 10_000, f"{path} is only {path.stat().st_size} bytes"
    with Image.open(path) as im:
        assert im.format == "PNG"
        assert im.size == size
        a = np.asarray(im.convert("L"))
    assert a.std() > 5  # not a blank canvas


def fig_px(fig) -> tuple[int, int]:
    from blenav.plotting import DPI

    w, h = fig.get_size_inches()
    return int(round(w * DPI)), int(round(h * DPI))


# --------------------------------------------------------------------------- radio_stats


def test_fit_path_loss_noiseless():
    d = np.geomspace(0.3, 40.0, 200)
    a, n, sd = fit_path_loss(d, -59.0 - 10 * 2.2 * np.log10(d))
    assert a == pytest.approx(-59.0, abs=1e-9) and n == pytest.approx(2.2, abs=1e-9) and sd < 1e-9


@pytest.mark.parametrize("a_true,n_true,sigma", [(-59.0, 2.0, 4.0), (-70.0, 3.1, 2.0), (-45.0, 1.6, 6.0)])
def test_fit_path_loss_noisy(a_true, n_true, sigma):
    rng = np.random.default_rng(42)
    d = rng.uniform(0.5, 30.0, 5000)
    rssi = path_loss_rssi(d, a_true, n_true) + rng.normal(0, sigma, d.size)
    a, n, sd = fit_path_loss(d, rssi)
    assert a == pytest.approx(a_true, abs=0.5)
    assert n == pytest.approx(n_true, abs=0.1)
    assert sd == pytest.approx(sigma, rel=0.05)


def test_fit_path_loss_ignores_invalid_points():
    d = np.array([1.0, 2.0, 4.0, 8.0, 0.0, -1.0, np.nan, 3.0])
    r = np.append(path_loss_rssi(d[:4], -60.0, 2.5), [-50.0, -50.0, -50.0, np.inf])
    a, n, sd = fit_path_loss(d, r)
    assert (a, n) == pytest.approx((-60.0, 2.5)) and sd < 1e-9


@pytest.mark.parametrize("d,r", [([], []), ([2.0], [-70.0]), ([2.0, 2.0, 2.0], [-70.0, -71.0, -72.0]),
                                 ([1.0, 2.0], [-60.0])])
def test_fit_path_loss_degenerate(d, r):
    with pytest.raises(ValueError):
        fit_path_loss(d, r)


def expected_distances(rssi: pd.DataFrame, anchors: dict) -> np.ndarray:
    """Tiny-dataset ground truth: x = 2.5 + 5 t / 20, y = 4, z = 1.2 (tests/helpers.py)."""
    t = rssi["t"].to_numpy()
    phone = np.column_stack([2.5 + 5.0 * t / 20.0, np.full_like(t, 4.0), np.full_like(t, 1.2)])
    a = np.array([anchors[i] for i in rssi["anchor_id"]])
    return np.linalg.norm(phone - a, axis=1)


def test_rssi_distance_pairs_on_tiny_dataset(tiny_dataset):
    s = Dataset.open(tiny_dataset).session("walk0")
    pairs = rssi_distance_pairs(s)
    assert list(pairs.columns) == ["t", "anchor_id", "rssi", "distance_m"]
    assert len(pairs) == len(s.rssi) == 400
    np.testing.assert_array_equal(pairs["rssi"], s.rssi["rssi"])
    np.testing.assert_allclose(pairs["distance_m"], expected_distances(pairs, TINY_ANCHORS), rtol=1e-9)
    # first reading: phone (2.5, 4, 1.2), b1 (1, 1, 2.5)
    assert pairs["distance_m"].iloc[0] == pytest.approx(np.sqrt(1.5**2 + 3.0**2 + 1.3**2))


def test_rssi_distance_pairs_use_true_anchor_positions(tiny_dataset):
    offsets = {"b1": (0.5, -0.25, 0.0), "b2": (-1.0, 0.5, -0.5), "b4": (0.0, 0.0, 0.3)}  # b3: prior only
    add_true_anchor_positions(tiny_dataset, offsets)
    s = Dataset.open(tiny_dataset).session("walk0")
    pos = anchor_positions(s.building)
    assert pos["true"].to_dict() == {"b1": True, "b2": True, "b3": False, "b4": True, "ap1": False}
    truth = {k: tuple(np.add(v, offsets.get(k, (0, 0, 0)))) for k, v in TINY_ANCHORS.items()}
    pairs = rssi_distance_pairs(s)
    np.testing.assert_allclose(pairs["distance_m"], expected_distances(pairs, truth), rtol=1e-9)
    prior = rssi_distance_pairs(s, prefer_true=False)
    np.testing.assert_allclose(prior["distance_m"], expected_distances(prior, TINY_ANCHORS), rtol=1e-9)


def test_rssi_distance_pairs_leave_out_readings_outside_groundtruth(tiny_dataset):
    p = tiny_dataset / "sessions" / "walk0" / "rssi.csv"
    with p.open("a") as f:
        f.write("19.95,b1,-80\n25.0,b2,-81\n")  # ground truth ends at t = 19.9
    pairs = rssi_distance_pairs(Dataset.open(tiny_dataset).session("walk0"))
    assert len(pairs) == 400 and pairs["t"].max() <= 19.9


def test_rssi_distance_pairs_empty_without_labels(tiny_dataset):
    y = tiny_dataset / "sessions" / "walk0" / "session.yaml"
    y.write_text(y.read_text().replace("labelled: true", "labelled: false"))
    pairs = rssi_distance_pairs(Dataset.open(tiny_dataset).session("walk0"))
    assert len(pairs) == 0 and list(pairs.columns) == ["t", "anchor_id", "rssi", "distance_m"]


# --------------------------------------------------------------------------- a richer dataset


def add_building_and_session(root: Path, n_true: float = 2.0, a_true: float = -60.0, sigma: float = 3.0) -> None:
    """Add floor 1 to 'house', a second building 'annex' and a session there whose RSSI follows a path-loss
    model (a different receiver than the tiny session)."""
    occ = tiny_grid()
    y = root / "buildings" / "house" / "building.yaml"
    doc = yaml.safe_load(y.read_text())
    doc["floors"].append(dict(doc["floors"][0], id=1, z=3.0))
    y.write_text(yaml.safe_dump(doc, sort_keys=False))

    rng = np.random.default_rng(7)
    ids = [f"beacon-{k}" for k in range(6)]
    xy = rng.uniform([0.5, 0.5], [9.5, 7.5], size=(6, 2))
    anchors = pd.DataFrame({"anchor_id": ids, "kind": ["ble"] * 5 + ["wifi_rtt"], "x": xy[:, 0], "y": xy[:, 1],
                            "z": 2.8, "floor": 0, "tx_power_dbm": np.nan, "channel_model": "sim",
                            "x_true": xy[:, 0] + rng.normal(0, 0.7, 6), "y_true": xy[:, 1] + rng.normal(0, 0.7, 6),
                            "z_true": 2.8})
    write_building(root, "annex", "annex", [{"id": 0, "occupancy": occ, "resolution": 0.1, "origin": (0.0, 0.0)}],
                   anchors)
    t = np.arange(0.0, 60.0, 0.1)
    ang = 2 * np.pi * t / 60.0
    gt = pd.DataFrame({"t": t, "x": 5 + 3 * np.cos(ang), "y": 4 + 2.5 * np.sin(ang), "z": 1.3,
                       "qw": 1.0, "qx": 0.0, "qy": 0.0, "qz": 0.0})
    tr = np.repeat(t[::2], 6)
    aid = np.tile(ids, len(t[::2]))
    truth = anchors.set_index("anchor_id").loc[aid, ["x_true", "y_true", "z_true"]].to_numpy()
    phone = np.column_stack([np.interp(tr, t, gt.x), np.interp(tr, t, gt.y), np.full_like(tr, 1.3)])
    d = np.linalg.norm(phone - truth, axis=1)
    rssi = np.clip(path_loss_rssi(d, a_true, n_true) + rng.normal(0, sigma, d.size), -120, -20)
    write_session(root, "loop1", {"building": "annex", "floor": 0, "device_model": "other-phone",
                                  "carrier": "robot", "labelled": True},
                  {"rssi": pd.DataFrame({"t": tr, "anchor_id": aid, "rssi": rssi}), "groundtruth": gt})


def test_path_loss_recovered_from_simulated_session(tiny_dataset):
    add_building_and_session(tiny_dataset, n_true=2.4, a_true=-62.0, sigma=2.0)
    pairs = rssi_distance_pairs(Dataset.open(tiny_dataset).session("loop1"))
    a, n, sd = fit_path_loss(pairs["distance_m"], pairs["rssi"])
    assert n == pytest.approx(2.4, abs=0.15) and a == pytest.approx(-62.0, abs=1.0) and sd == pytest.approx(2.0, 0.1)


# --------------------------------------------------------------------------- figures


def test_plot_floor_draws_in_world_coordinates(tiny_dataset):
    from blenav.plotting import new_figure, plot_floor, plot_tracks

    add_true_anchor_positions(tiny_dataset, {"b1": (0.5, 0.5, 0.0), "b2": (-0.5, 0.5, 0.0)})
    ds = Dataset.open(tiny_dataset)
    b = ds.building("house")
    fig = new_figure(6, 5)
    ax = fig.subplots()
    plot_floor(ax, b, 0)
    plot_tracks(ax, [ds.session("walk0")])
    (img,) = ax.get_images()
    assert tuple(img.get_extent()) == pytest.approx(b.floor(0).extent)
    assert ax.get_aspect() == 1.0 and ax.get_xlim() == (0.0, 10.0) and ax.get_ylim() == (0.0, 8.0)
    labels = ax.get_legend_handles_labels()[1]
    assert labels == ["room", "navigation graph", "true anchor position", "BLE beacon (4)", "WiFi RTT AP (1)",
                      "walk0 (test-phone, pedestrian)"]
    assert {t.get_text() for t in ax.texts} >= {"west", "east", "b1", "b2", "b3", "b4", "ap1"}
    assert ax.get_legend() is not None
    # two prior -> true segments
    segs = [c for c in ax.collections if type(c).__name__ == "LineCollection" and len(c.get_segments()) == 2
            and c.get_label() != "room"]
    rooms = [c for c in ax.collections if c.get_label() == "room"]  # every room's outline, one artist
    assert len(rooms) == 1 and len(rooms[0].get_segments()) == len(list(b.rooms_on(b.floor(0).id)))
    assert segs and np.allclose(segs[0].get_segments()[0], [[1.0, 1.0], [1.5, 1.5]])


def test_figures_of_a_richer_dataset(tiny_dataset, tmp_path):
    from blenav.plotting import figure_overview, figure_radio

    add_building_and_session(tiny_dataset)
    ds = Dataset.open(tiny_dataset)
    fig = figure_overview(ds, ds.session_ids, building_id="house")
    axes = [ax for ax in fig.axes if ax.get_visible() and ax.get_images()]
    assert [ax.get_title() for ax in axes] == ["tiny house: floor 0", "tiny house: floor 1"]
    assert all(ax.get_aspect() == 1.0 for ax in axes)
    with pytest.raises(ValueError, match="building_id"):
        figure_overview(ds, ds.session_ids)
    assert "annex" in figure_overview(ds, ["loop1"])._suptitle.get_text()

    fig = figure_radio(list(ds.sessions()))
    ax_d, ax_h = fig.axes[:2]
    labels = ax_d.get_legend_handles_labels()[1]
    assert labels[:2] == ["other-phone (1800 readings)", "test-phone (400 readings)"]
    assert re.fullmatch(r"fit: A = -?\d+\.\d dBm at 1 m, n = -?\d+\.\d\d, residual std = \d+\.\d dB", labels[2])
    assert ax_d.get_xscale() == "log"
    assert [lbl.split(" (")[0] for lbl in ax_h.get_legend_handles_labels()[1]] == ["other-phone", "test-phone"]


def test_figure_radio_without_rssi(tiny_dataset):
    from blenav.plotting import figure_radio

    (tiny_dataset / "sessions" / "walk0" / "rssi.csv").unlink()
    fig = figure_radio(Dataset.open(tiny_dataset).sessions())
    assert "no RSSI readings with ground truth" in [t.get_text() for t in fig.axes[0].texts]


# --------------------------------------------------------------------------- blenav-plot


def test_cli_writes_overview_and_radio_pngs(tiny_dataset, capsys):
    from blenav.plotting import figure_overview, figure_radio

    add_true_anchor_positions(tiny_dataset, {"b1": (0.5, 0.4, 0.0), "b3": (0.3, -0.7, 0.1)})
    assert plot_main([str(tiny_dataset)]) == 0
    out = tiny_dataset / "plots"
    printed = capsys.readouterr().out.split()
    assert printed == [str(out / "house_overview.png"), str(out / "radio.png")]
    ds = Dataset.open(tiny_dataset)
    png_ok(out / "house_overview.png", fig_px(figure_overview(ds, ["walk0"])))
    png_ok(out / "radio.png", fig_px(figure_radio([])))


def test_cli_several_buildings_out_and_session_options(tiny_dataset, tmp_path, capsys):
    from blenav.plotting import figure_overview

    add_building_and_session(tiny_dataset)
    out = tmp_path / "figs"
    assert plot_main([str(tiny_dataset), "--out", str(out)]) == 0
    assert sorted(p.name for p in out.iterdir()) == ["annex_overview.png", "house_overview.png", "radio.png"]
    ds = Dataset.open(tiny_dataset)
    for b in ("annex", "house"):
        png_ok(out / f"{b}_overview.png", fig_px(figure_overview(ds, ds.session_ids, building_id=b)))
    capsys.readouterr()

    out2 = tmp_path / "only_loop"
    assert plot_main([str(tiny_dataset), "--session", "loop1", "--out", str(out2)]) == 0
    assert capsys.readouterr().out.split() == [str(out2 / "annex_overview.png"), str(out2 / "radio.png")]


def test_cli_unknown_session(tiny_dataset, capsys):
    assert plot_main([str(tiny_dataset), "--session", "walk0", "nope"]) == 1
    err = capsys.readouterr().err
    assert "nope" in err and "walk0" in err
    assert not (tiny_dataset / "plots").exists()


@pytest.mark.parametrize("corrupt,expect", [
    (lambda r: (r / "dataset.yaml").unlink(), "dataset.yaml: [missing-file]"),
    (lambda r: (r / "sessions/walk0/rssi.csv").write_text("t,anchor_id,rssi\n0.0,b1,-70\n0.1,b2,-200\n"),
     "sessions/walk0/rssi.csv:3: [rssi-range]"),
    (lambda r: (r / "buildings/house/floor_0.png").write_bytes(b"junk"), "floor_0.png: [image-unreadable]"),
], ids=["no-dataset-yaml", "rssi-sentinel", "broken-floor-image"])
def test_cli_invalid_dataset_exits_1(tiny_dataset, capsys, corrupt, expect):
    corrupt(tiny_dataset)
    assert plot_main([str(tiny_dataset)]) == 1
    err = capsys.readouterr().err
    assert "not a valid blenav/1 dataset" in err and expect in err
    assert not (tiny_dataset / "plots" / "radio.png").exists()


# --------------------------------------------------------------------------- module boundaries


def test_only_plotting_imports_matplotlib():
    """Plotting lives in one package: matplotlib is imported by the modules of blenav.plotting and no other."""
    pattern = re.compile(r"^\s*(import matplotlib|from matplotlib)", re.M)
    users = sorted(p.relative_to(SRC).as_posix() for p in SRC.rglob("*.py") if pattern.search(p.read_text()))
    assert users and all(u.startswith("plotting/") for u in users), users
    assert "plotting/common.py" in users


def test_radio_stats_and_cli_import_without_matplotlib_and_plotting_keeps_the_backend():
    code = (
        "import sys\n"
        "import blenav.radio_stats, blenav.data, blenav.cli.plot\n"
        "assert 'matplotlib' not in sys.modules, 'matplotlib imported'\n"
        "import matplotlib\n"
        "matplotlib.use('svg')\n"
        "import blenav.plotting\n"
        "assert matplotlib.get_backend() == 'svg', matplotlib.get_backend()\n"
    )
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stderr


def test_rssi_vs_distance_figure_draws_every_panel(tmp_path):
    import numpy as np
    import pandas as pd
    from PIL import Image

    from blenav.plotting import figure_rssi_vs_distance, save_figure

    rng = np.random.default_rng(0)
    d = rng.uniform(1, 20, 500)
    panels = {f"set {k}": pd.DataFrame({"distance_m": d, "rssi": -60 - 22 * np.log10(d) + rng.normal(0, 4, d.size)})
              for k in range(4)}
    fig = figure_rssi_vs_distance(panels)
    assert sum(ax.get_visible() for ax in fig.axes) == 4
    import re

    for ax in fig.axes:
        if ax.get_visible():
            n = float(re.search(r"n = ([0-9.]+)", ax.get_legend().get_texts()[0].get_text()).group(1))
            assert abs(n - 2.2) < 0.15
    path = save_figure(fig, tmp_path / "r.png")
    assert Image.open(path).size[0] > 800


def test_plot_floor_room_labels_off_when_asked_and_unplaced_anchors_not_counted(tiny_dataset, tmp_path):
    """room_labels=False writes no room id; an anchor without a position is neither drawn nor counted."""
    import pandas as pd

    from blenav.plotting import new_figure, plot_floor

    p = tiny_dataset / "buildings" / "house" / "anchors.csv"
    a = pd.read_csv(p)
    a.loc[a["anchor_id"] == "b1", ["x", "y", "z"]] = float("nan")  # an unplaced beacon (the format: all three empty)
    a.to_csv(p, index=False)
    b = Dataset.open(tiny_dataset).building("house")
    ax = new_figure(6, 5).subplots()
    plot_floor(ax, b, 0, room_labels=False)
    texts = {t.get_text() for t in ax.texts}
    assert not texts & {"west", "east"} and "b1" not in texts
    assert "BLE beacon (3)" in ax.get_legend_handles_labels()[1]


# --------------------------------------------------------------------------- pictures that read (issue 33 sec. 3)


def test_keep_apart_is_greedy_and_deterministic():
    from blenav.plotting.common import keep_apart

    xy = np.array([[0.0, 0.0], [0.3, 0.0], [1.0, 0.0], [1.0, 0.9], [np.nan, 5.0], [0.0, 0.5]])
    np.testing.assert_array_equal(keep_apart(xy, 0.5), [True, False, True, True, False, True])
    np.testing.assert_array_equal(keep_apart(xy, 0.0), [True, True, True, True, False, True])
    np.testing.assert_array_equal(keep_apart(xy[::-1], 0.5), [True, False, True, True, True, False])


def test_overview_labels_never_overprint_and_the_legend_covers_no_panel(tiny_dataset):
    """Two beacons 0.2 m apart on a 10 m floor: only the first is labelled (LABEL_SPACING 0.045 * 10 m = 0.45 m); the
    figure's one legend sits in its own column, its box outside every floor panel; no two label boxes overlap."""
    from blenav.plotting import figure_overview

    add_building_and_session(tiny_dataset)
    p = tiny_dataset / "buildings" / "house" / "anchors.csv"
    a = pd.read_csv(p, dtype={"anchor_id": str})
    a.loc[a["anchor_id"] == "b2", ["x", "y"]] = [1.2, 1.0]  # next to b1 (1, 1)
    a.to_csv(p, index=False)
    ds = Dataset.open(tiny_dataset)
    fig = figure_overview(ds, ds.session_ids, building_id="house")
    fig.canvas.draw()
    r = fig.canvas.get_renderer()
    panels = [ax for ax in fig.axes if ax.get_visible() and ax.get_images()]
    texts = {t.get_text() for t in panels[0].texts}
    assert {"b1", "b3", "b4", "ap1", "west", "east"} <= texts and "b2" not in texts
    legends = [ax.get_legend() for ax in fig.axes if ax.get_legend() is not None] + list(fig.legends)
    assert len(legends) == 1
    lb = legends[0].get_window_extent(r)
    assert all(not lb.overlaps(ax.get_window_extent(r)) for ax in panels)
    assert "walk0 (test-phone, pedestrian)" in [t.get_text() for t in legends[0].get_texts()]
    W, H = fig.canvas.get_width_height()
    assert lb.x1 <= W + 1 and lb.y0 >= 0
    boxes = [t.get_window_extent(r) for t in panels[0].texts]
    assert not any(boxes[i].overlaps(boxes[j]) for i in range(len(boxes)) for j in range(i + 1, len(boxes)))


def test_rmse_box_names_n_and_draws_points_below_five_runs():
    """Two and one runs: their values as points (no box), their median as a bar; eight runs: a box with its median
    4.5 at x = 2; every tick names its n."""
    from blenav.plotting import figure_rmse_box
    from blenav.plotting.evaluation import MIN_BOX_VALUES

    assert MIN_BOX_VALUES == 5
    fig = figure_rmse_box({"PF-PL": np.array([2.0, 9.0]), "KNN": np.arange(1.0, 9.0), "one": np.array([3.0])})
    ax = fig.axes[0]
    assert [t.get_text() for t in ax.get_xticklabels()] == ["PF-PL\nn=2", "KNN\nn=8", "one\nn=1"]
    pts = [np.asarray(c.get_offsets()) for c in ax.collections if type(c).__name__ == "PathCollection"]
    assert len(pts) == 2  # the two methods with fewer than 5 runs: their points
    np.testing.assert_allclose(pts[0], [[1 - 0.12, 2.0], [1 + 0.12, 9.0]])  # spread sideways, deterministically
    np.testing.assert_allclose(pts[1], [[3.0, 3.0]])
    bars = [np.asarray(c.get_segments()[0]) for c in ax.collections if type(c).__name__ == "LineCollection"]
    np.testing.assert_allclose(bars, [[[0.78, 5.5], [1.22, 5.5]], [[2.78, 3.0], [3.22, 3.0]]])
    two = [ln for ln in ax.lines if len(ln.get_xdata()) == 2]
    medians = [ln for ln in two if np.allclose(ln.get_xdata(), [1.75, 2.25]) and np.allclose(ln.get_ydata(), 4.5)]
    assert len(medians) == 1  # KNN's box: one box in all
    xs = [ln.get_xdata() for ln in ax.lines if len(ln.get_xdata())]
    assert all(1.5 <= min(x) and max(x) <= 2.5 for x in xs)  # the box's lines all at KNN's x = 2
    assert ax.get_ylim()[0] == 0.0


def _err_t(n_sessions: int, methods=("A", "B")) -> dict:
    t = np.arange(100.0, 160.0, 1.0)  # a clock that does not start at 0
    return {f"walk{k:02d}": {m: (t + k, np.full((3, t.size), 1.0 + j)) for j, m in enumerate(methods)}
            for k in range(n_sessions)}


def test_error_over_time_draws_every_session_up_to_the_cap():
    from blenav.plotting import figure_error_over_time
    from blenav.plotting.evaluation import MAX_SESSION_PANELS

    assert MAX_SESSION_PANELS == 12
    fig = figure_error_over_time(_err_t(2), 10.0)
    shown = [ax for ax in fig.axes if ax.get_visible()]
    assert [ax.get_title() for ax in shown] == ["walk00", "walk01"]
    assert "2 session(s)" in fig._suptitle.get_text() and "left out" not in fig._suptitle.get_text()
    assert shown[0].get_shared_x_axes().joined(shown[0], shown[1])
    assert shown[0].get_shared_y_axes().joined(shown[0], shown[1])
    for ax in shown:  # time from the session's first estimate; the median of A is 1 m, of B 2 m
        a, b = ax.lines[:2]
        assert a.get_xdata()[0] == 0.0 and a.get_xdata()[-1] == 59.0
        np.testing.assert_allclose(a.get_ydata(), 1.0)
        np.testing.assert_allclose(b.get_ydata(), 2.0)
        assert a.get_color() == shown[0].lines[0].get_color() != b.get_color()  # one colour per method
    fig = figure_error_over_time(_err_t(14), 10.0)
    shown = [ax for ax in fig.axes if ax.get_visible()]
    assert len(shown) == 12 and shown[-1].get_title() == "walk11"
    assert "12 session(s); 2 more left out (at most 12 panels)" in fig._suptitle.get_text()
    # a method missing from the first session keeps the colour its place in `methods` gives it
    e = _err_t(2, ("A", "B"))
    del e["walk00"]["A"]
    fig = figure_error_over_time(e, 10.0, methods=["A", "B"])
    first, second = [ax for ax in fig.axes if ax.get_visible()]
    assert first.lines[0].get_color() == second.lines[1].get_color()  # B in both


def test_track_panels_one_per_method_then_per_family():
    from blenav.plotting.evaluation import MAX_TRACK_PANELS, track_panels

    assert MAX_TRACK_PANELS == 20
    tracks = {f"m{k}": None for k in range(25)}
    panels, left = track_panels({k: None for k in list(tracks)[:6]})
    assert panels == [(f"m{k}", [f"m{k}"]) for k in range(6)] and left == 0
    panels, left = track_panels(tracks)
    assert len(panels) == 20 and left == 5
    fam = {f"m{k}": ("PF" if k % 2 else "CRF") for k in range(25)}
    panels, left = track_panels(tracks, fam)
    assert [p for p, _ in panels] == ["CRF", "PF"] and left == 0
    assert panels[1][1] == [f"m{k}" for k in range(1, 25, 2)]


def test_trajectories_are_small_multiples_with_the_truth_in_every_panel(tiny_dataset):
    from blenav.plotting import figure_trajectories

    s = Dataset.open(tiny_dataset).session("walk0")
    gt = s.groundtruth
    xy = gt[["x", "y"]].to_numpy()
    tracks = {f"method {k}": (gt["t"].to_numpy(), xy + 0.1 * k) for k in range(7)}
    fig = figure_trajectories(s, tracks)
    shown = [ax for ax in fig.axes if ax.get_visible()]
    assert len(shown) == 7 and len(fig.axes) == 9  # ceil(sqrt(7)) = 3 columns, 3 rows
    for k, ax in enumerate(shown):
        assert ax.get_title() == f"method {k}"
        labels = [ln.get_label() for ln in ax.lines]
        assert "ground truth" in labels and labels.count(f"method {k}") == 1
        assert not [lab for lab in labels if lab.startswith("method ") and lab != f"method {k}"]
        est = next(ln for ln in ax.lines if ln.get_label() == f"method {k}")
        np.testing.assert_allclose(est.get_xydata(), xy + 0.1 * k)
        anchors = [c for c in ax.collections if c.get_label().startswith("BLE beacon")]
        assert anchors and anchors[0].get_alpha() < 0.5  # faint
        assert not ax.texts  # no anchor or room label in a panel
    assert "session walk0 (first run)" in fig._suptitle.get_text()
    fig = figure_trajectories(s, {f"m{k}": tracks["method 0"] for k in range(23)})
    assert sum(ax.get_visible() for ax in fig.axes) == 20
    assert "3 more method(s) not drawn (at most 20 panels)" in fig._suptitle.get_text()


def test_plan_image_is_reduced_by_whole_blocks_keeping_thin_walls(monkeypatch):
    """A grid wider than MAX_PLAN_PX is drawn reduced by an integer factor, each pixel the darkest of its block: a wall
    one cell thick survives; free white, unknown light grey, occupied black."""
    from blenav.data.floor import FREE, OCCUPIED, UNKNOWN
    from blenav.plotting import floor

    monkeypatch.setattr(floor, "MAX_PLAN_PX", 4)
    occ = np.full((6, 9), FREE, dtype=np.int8)
    occ[:, 4] = OCCUPIED  # a wall one cell thick
    occ[0, 0] = UNKNOWN
    img = floor.plan_image(occ)
    assert img.shape == (2, 3, 3) and img.dtype == np.uint8  # factor ceil(9 / 4) = 3
    assert (img[:, 1] == 0).all()  # the wall's blocks are black
    assert img[0, 0, 0] == round(255 * floor.UNKNOWN_GREY) and (img[1, 0] == 255).all() and (img[:, 2] == 255).all()
    small = floor.plan_image(np.full((3, 4), FREE, dtype=np.int8))
    assert small.shape == (3, 4, 3)  # within the bound: unchanged
