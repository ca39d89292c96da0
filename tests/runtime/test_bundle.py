"""The runtime bundle (issue 18, section 1 and the bundle item of section 4).

- round trip: ``export_bundle(cfg)`` (``export.py bundle=true``) writes the localizer, the map prior, their ORT and
  int8 variants (measured in the manifest), settings and the building's signature; every variant opens and
  localizes; ``python export.py bundle=true`` writes the same files; what it refuses fails before a bundle is left;
- the CLI writes t,x,y,std, one row per filter step; its imports and its run load no torch, lightning or hydra;
- refusal: another building's beacons (missing, extra, moved) or floor plan, or a changed file, are named;
- parity: the bundle (onnxruntime, push API) reproduces the PyTorch pipeline (torch networks, batch windows,
  ``run_session``) within 1 cm on the same seed.
"""

from __future__ import annotations

import json
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from blenav.configs import compose
from blenav.data import Dataset
from blenav.learn.bundle import export_bundle
from blenav.learn.export import export
from blenav.learn.train import train
from blenav.runtime import Bundle, BuildingMismatch
from blenav.runtime.bundle import MANIFEST, variant_name
from helpers import REPO, simulate_small

pytestmark = pytest.mark.onnx
TINY_MP = ["trainer.enable_progress_bar=false", "data.samples_per_epoch=64", "data.val_samples=32",
           "data.batch_size=16", "data.crop_px=32", "model.net.unet_channels=[4,8]", "model.net.channels=8",
           "trainer.max_epochs=1", "early_stopping=null"]


@pytest.fixture(scope="module")
def made(tmp_path_factory):
    """A 'small' building with 3 one-minute walks, a tiny LocNet and map prior, and their bundle."""
    root = tmp_path_factory.mktemp("bundle")
    data = simulate_small(root / "d", 11, 60, 3)
    train(compose("train", "model=locnet", f"data={data}", f"out={root / 'loc'}", "data.batch_size=32",
                  "model.lr=3e-3", "trainer.enable_progress_bar=false", "trainer.max_epochs=1",
                  "model.locnet.hidden=16", "model.locnet.fc_hidden=8"))
    train(compose("train", "experiment=mapprior", f"data={data}", f"out={root / 'mp'}", *TINY_MP))
    cfg = compose("export", "bundle=true", f"ckpt={root / 'loc' / 'last.ckpt'}", f"out={root / 'B'}",
                  f"mapprior={root / 'mp' / 'last.ckpt'}", f"data={data}", "eval_sessions=1")
    assert export_bundle(cfg) == root / "B"
    return {"root": root, "data": data, "bundle": root / "B", "loc": root / "loc" / "last.ckpt",
            "mp": root / "mp" / "last.ckpt"}


def test_round_trip_files_variants_and_manifest(made):
    B = made["bundle"]
    m = json.loads((B / MANIFEST).read_text())
    assert m["format"] == "blenav-bundle/1" and m["has_map_prior"]
    assert set(m["variants_available"]) == {"float", "ort", "int8", "int8_ort"}, m["variants_failed"]
    for base in ("localizer", "map_prior/map_encoder", "map_prior/trajectory_encoder"):
        for v in m["variants_available"]:
            assert variant_name(base, v) in m["files"]
            r = m["measured"]["graphs"][base][v]
            assert r["bytes"] > 0 and r["latency_ms"]["median"] > 0
    assert {"settings.json", "building.json", "map_prior/meta.json"} <= set(m["files"])
    assert set(m["versions"]) >= {"blenav", "onnxruntime", "numpy"}
    assert m["measured"]["graphs"]["localizer"]["int8"]["bytes"] < m["measured"]["graphs"]["localizer"]["float"]["bytes"]
    pipe = m["measured"]["pipeline"]
    assert set(pipe) == set(m["variants_available"]) and abs(pipe["ort"]["rmse_change_m"]) < 0.01
    ds = Dataset.open(made["data"])
    s = ds.sessions()[0] if isinstance(ds.sessions(), list) else next(iter(ds.sessions()))
    for v in m["variants_available"]:
        est = Bundle.open(B, variant=v).run_session(s, seed=1)
        assert len(est) > 30 and all(np.isfinite([e.x, e.y, e.std]).all() for e in est)


def test_export_py_writes_the_same_bundle(made, tmp_path):
    """``python export.py bundle=true`` (the entry point over export_bundle) from the same checkpoints: without
    variants, the same graphs, settings and building byte for byte, and the summary names the bundle."""
    out = tmp_path / "C"
    r = subprocess.run([sys.executable, "export.py", "bundle=true", "variants=false", f"ckpt={made['loc']}",
                        f"out={out}", f"mapprior={made['mp']}", f"data={made['data']}", "eval_sessions=1"],
                       cwd=REPO, capture_output=True, text=True, timeout=600)
    assert r.returncode == 0, r.stderr[-2000:]
    assert r.stdout.startswith(f"wrote bundle {out}: building 'small', 8 beacons, map prior: yes, variants ['float']")
    m = json.loads((out / MANIFEST).read_text())
    assert m["variants_available"] == ["float"] and not (tmp_path / "C.part").exists()
    assert len(m["files"]) == 6 and set(m["files"]) < set(json.loads((made["bundle"] / MANIFEST).read_text())["files"])
    for f in m["files"]:
        assert (out / f).read_bytes() == (made["bundle"] / f).read_bytes(), f


def test_export_bundle_refuses_before_leaving_a_bundle(made, tmp_path):
    """Each refusal names what is wrong; none leaves OUT or OUT.part behind."""
    def cfg(*over):
        return compose("export", "bundle=true", f"ckpt={made['loc']}", f"out={tmp_path / 'B'}", f"data={made['data']}",
                       "eval_sessions=1", "variants=false", *over)

    (tmp_path / "f").write_text("x")
    with pytest.raises(ValueError, match=r"out=.*/f exists and is not a bundle"):
        export_bundle(cfg(f"out={tmp_path / 'f'}"))
    with pytest.raises(ValueError, match=r"is a map prior: a bundle is made around a cross-phone localizer"):
        export_bundle(cfg(f"ckpt={made['mp']}"))
    with pytest.raises(FileNotFoundError, match=r"dataset .*/nope \(the localizer's training data\) does not exist"):
        export_bundle(cfg(f"data={tmp_path / 'nope'}"))
    data = Path(shutil.copytree(made["data"], tmp_path / "d2"))
    anchors = next((data / "buildings").iterdir()) / "anchors.csv"
    a = pd.read_csv(anchors)
    a.loc[a.index[a["kind"] == "ble"][0], "x"] += 2.0
    a.to_csv(anchors, index=False)
    with pytest.raises(BuildingMismatch, match=r"building 'small' is not the one the localizer was trained on: .*moved"):
        export_bundle(cfg(f"data={data}"))
    with pytest.raises(FileNotFoundError, match=r"mapprior=.*/nope.ckpt does not exist"):
        export_bundle(cfg(f"mapprior={tmp_path / 'nope.ckpt'}"))  # after the localizer's export: the .part goes
    assert sorted(p.name for p in tmp_path.iterdir()) == ["d2", "f"]


def test_cli_writes_t_x_y_std_and_loads_no_torch(made, tmp_path):
    sdir = sorted((made["data"] / "sessions").iterdir())[0]
    out = tmp_path / "est.csv"
    code = f"""
import json, sys
from blenav.cli.localize import main
rc = main([{str(made['bundle'])!r}, {str(sdir)!r}, "--out", {str(out)!r}, "--no-progress"])
print(json.dumps({{"rc": rc, "heavy": sorted(m for m in ("torch", "lightning", "hydra") if m in sys.modules)}}))
"""
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr[-2000:]
    res = json.loads(r.stdout.strip().splitlines()[-1])
    assert res == {"rc": 0, "heavy": []}
    df = pd.read_csv(out)
    assert list(df.columns) == ["t", "x", "y", "std"] and len(df) > 30
    assert np.isfinite(df.to_numpy()).all() and (np.diff(df["t"]) > 0).all()
    bad = subprocess.run([sys.executable, "-m", "blenav.cli.localize", str(made["bundle"]), str(tmp_path / "nope"),
                          "--out", str(tmp_path / "x.csv")], capture_output=True, text=True, timeout=120)
    assert bad.returncode == 1 and "blenav-localize: error:" in bad.stderr and "does not exist" in bad.stderr


def test_bundle_graph_is_the_onnx_localizer_code(made):
    """The bundle's localizer graph and OnnxLocalizer share one implementation (LocalizerSession): the same sizes,
    beacons and, on the same windows, the same (K, 2) m to the bit; NaN where nothing was heard."""
    from blenav.runtime.bundle.graphs import LocalizerGraph
    from blenav.runtime.onnx_localizer import LocalizerSession, OnnxLocalizer

    g = Bundle.open(made["bundle"]).graph
    ref = OnnxLocalizer(made["bundle"] / "localizer.onnx")
    assert isinstance(g, LocalizerGraph) and isinstance(g, LocalizerSession) and isinstance(ref, LocalizerSession)
    assert (g.n_beacons, g.history, g.layers, g.hidden, g.beacons) == (ref.n_beacons, ref.history, ref.layers,
                                                                     ref.hidden, ref.beacons)
    S = np.random.default_rng(5).uniform(0.0, 60.0, (4, g.n_beacons, g.history)).astype(np.float32)
    S[2] = 0.0  # nothing heard
    xy = g.predict(S)
    np.testing.assert_array_equal(xy, ref.predict(S))
    assert xy.shape == (4, 2) and np.isnan(xy[2]).all() and np.isfinite(np.delete(xy, 2, axis=0)).all()
    assert g.predict(S[:0]).shape == (0, 2) and g.meta["window"] == ref.meta["window"]


def test_push_api_matches_replay(made):
    """Samples pushed one by one give the rows run_session gives (the same engine)."""
    from blenav.filters.online import replay

    b = Bundle.open(made["bundle"])
    s = Dataset.open(made["data"]).session(sorted(Dataset.open(made["data"]).session_ids)[1])
    loc = b.localizer(s.building, seed=3, keep_fixes=5)  # a live fix log of the latest 5 fixes: same rows
    rows, t_end = [], 0.0
    for ev in replay(s):
        if ev[0] == "rssi":
            rows += loc.push_rssi(ev[1], ev[2], ev[3])
        elif ev[0] == "odo":
            rows += loc.push_odometry(ev[1], ev[2])
        else:
            continue
        t_end = ev[1]
    rows += loc.close(t_end)
    ref = b.run_session(s, seed=3)
    assert len(rows) == len(ref) and np.allclose(np.array(rows), np.array(ref))
    assert len(b.last_fixes) > 5 and list(loc.fixes) == b.last_fixes[-5:]  # bounded live log, full replay log


def test_a_clock_jump_in_the_stream_is_one_error_not_a_network_run_per_step(made):
    """A packet 10^9 s after the first: one ValueError naming the jump and saying what to do, at once (it would have
    closed 10^10 empty window steps, each a network run)."""
    from blenav.runtime.bundle.windows import MAX_GAP_STEPS

    b = Bundle.open(made["bundle"])
    s = Dataset.open(made["data"]).session(sorted(Dataset.open(made["data"]).session_ids)[1])
    loc = b.localizer(s.building, seed=3)
    beacon = str(s.building.anchors["anchor_id"].iloc[0])
    loc.push_rssi(0.0, beacon, -70.0)
    with pytest.raises(ValueError, match=r"time jumps from .* to 1000000000\.000 s: .*split the recording"):
        loc.push_rssi(1e9, beacon, -70.0)
    assert MAX_GAP_STEPS >= 10_000


def _copy_building(made, tmp_path, change):
    data = Path(shutil.copytree(made["data"], tmp_path / "d2"))
    bdir = next((data / "buildings").iterdir())
    change(bdir)
    return Dataset.open(data).building(bdir.name)


def test_refuses_other_beacons_and_floor_plans_saying_what_differs(made, tmp_path):
    b = Bundle.open(made["bundle"])

    def beacons(bdir):
        a = pd.read_csv(bdir / "anchors.csv")
        ble = a.index[a["kind"] == "ble"]
        a.loc[ble[0], "anchor_id"] = "intruder-9"  # one renamed: one missing, one extra
        a.loc[ble[1], "x"] = a.loc[ble[1], "x"] + 2.0  # one moved 2 m
        a.to_csv(bdir / "anchors.csv", index=False)

    first = sorted(pd.read_csv(next((made["data"] / "buildings").iterdir()) / "anchors.csv")
                   .query("kind == 'ble'")["anchor_id"].astype(str))
    with pytest.raises(BuildingMismatch) as e:
        b.check_building(_copy_building(made, tmp_path / "a", beacons))
    msg = str(e.value)
    assert "missing from the building" in msg and "does not know: intruder-9" in msg and "moved" in msg
    assert "(2.00 m)" in msg

    def plan(bdir):
        from PIL import Image

        png = next(bdir.glob("*.png"))
        im = np.array(Image.open(png))
        im[im.shape[0] // 2, :] = 0  # a new wall across the floor
        Image.fromarray(im).save(png)

    with pytest.raises(BuildingMismatch, match=r"floor 0: another floor plan \(plan hash [0-9a-f]{12}\.\.\., "
                                               r"bundle's [0-9a-f]{12}\.\.\.\)"):
        b.localizer(_copy_building(made, tmp_path / "b", plan))
    assert first  # the bundle's beacons are the building's
    assert b.beacons == first


def test_refuses_a_changed_file(made, tmp_path):
    B = Path(shutil.copytree(made["bundle"], tmp_path / "B"))
    s = json.loads((B / "settings.json").read_text())
    s["fix"]["sigma_m"] = 1.0
    (B / "settings.json").write_text(json.dumps(s))
    with pytest.raises(ValueError, match=r"settings\.json changed"):
        Bundle.open(B)
    (B / "localizer.int8.ort").unlink()
    with pytest.raises(ValueError, match=r"localizer\.int8\.ort missing"):
        Bundle.open(B)


def test_runtime_reproduces_the_pytorch_pipeline_within_1cm(made):
    """Same seed, same settings except the filter's discrete choices: no resampling, no obstacle re-initialisation,
    the weighted mean as the estimate. With them (the default) float32 differences between onnxruntime and torch
    (~1e-6 m) flip a resampling or re-initialisation choice now and then, and from there the two runs are different
    draws of the same filter (benchmarks/runtime_latency.py reports how often and how far)."""
    import dataclasses

    from blenav.learn.reference import torch_pipeline

    b = Bundle.open(made["bundle"])
    settings = json.loads(json.dumps(b.settings))
    settings["filter"].update({"ess_threshold": 0.0, "reinit_fraction": None, "estimate": "mean"})
    b = dataclasses.replace(b, settings=settings)
    ds = Dataset.open(made["data"])
    for sid in sorted(ds.session_ids)[:2]:
        s = ds.session(sid)
        t_ref, xy_ref, fx_ref = torch_pipeline(b, made["loc"], made["mp"], s, seed=5)
        est = b.run_session(s, seed=5)
        fx = np.array(b.last_fixes)  # the live windows give the batch windows' fixes, to float32 engine noise
        assert fx.shape == (len(fx_ref), 3)
        np.testing.assert_allclose(fx[:, 0], fx_ref["t"], atol=1e-9)
        np.testing.assert_allclose(fx[:, 1:], fx_ref[["x", "y"]], atol=1e-4)
        t = np.array([e.t for e in est])
        common, i, j = np.intersect1d(np.round(t, 6), np.round(t_ref, 6), return_indices=True)
        assert len(common) >= len(t_ref) - 1 and len(common) > 30
        err = np.hypot(*(np.array([[e.x, e.y] for e in est])[i] - xy_ref[j]).T)
        assert err.max() < 0.01, f"{sid}: max {err.max():.4f} m"


@pytest.mark.parametrize("where", ["bundle/localizer.onnx", "data/sessions/s000/rssi.csv", "data/new.csv", "data"])
def test_cli_refuses_an_out_that_overwrites_what_it_reads(tmp_path, capsys, where):
    """Red-team (issue 28 sec. 3): ``--out BUNDLE/localizer.onnx`` replaced the bundle's graph by the CSV and
    ``--out SESSION/rssi.csv`` the session's readings; now refused in one line before anything is opened."""
    from blenav.cli.localize import main

    (tmp_path / "bundle").mkdir()
    session = tmp_path / "data" / "sessions" / "s000"
    session.mkdir(parents=True)
    (session / "rssi.csv").write_text("t,anchor_id,rssi\n")
    (tmp_path / "bundle" / "localizer.onnx").write_bytes(b"graph")
    with pytest.raises(SystemExit) as e:
        main([str(tmp_path / "bundle"), str(session), "--out", str(tmp_path / where), "--no-progress"])
    err = capsys.readouterr().err.strip()
    assert e.value.code == 1 and err.startswith(f"blenav-localize: error: --out {tmp_path / where} ") and "\n" not in err
    assert (session / "rssi.csv").read_text() == "t,anchor_id,rssi\n"
    assert (tmp_path / "bundle" / "localizer.onnx").read_bytes() == b"graph"
    assert not (tmp_path / "data" / "new.csv").exists()


def test_bundle_carries_the_learned_inertial_odometry(made, tmp_path):
    """Issue 31: ``export.py bundle=true io_model=IO_DIR`` puts the learned odometry in the bundle (``inertial/``, in the
    manifest); replaying a session (``blenav-localize``) runs it on the session's IMU, torch-free, instead of reading
    odometry.csv: the same track as the bundle without it on a copy of the session whose odometry.csv is that track."""
    from blenav.runtime.inertial import InertialModel

    train(compose("train", "experiment=inertial", f"data.path={made['data']}", f"out={tmp_path / 'iorun'}",
                  "plots=false", "trainer.budget.max_steps=20", "trainer.budget.val_every_steps=10",
                  "trainer.enable_progress_bar=false", "data.val_fraction=0.34"))
    io = export(compose("export", f"ckpt={tmp_path / 'iorun' / 'last.ckpt'}", f"out={tmp_path / 'io'}"))
    common = ["bundle=true", f"ckpt={made['loc']}", f"data={made['data']}", "variants=false"]
    export_bundle(compose("export", *common, f"out={tmp_path / 'LIO'}", f"io_model={io}"))
    export_bundle(compose("export", *common, f"out={tmp_path / 'PLAIN'}"))
    b = Bundle.open(tmp_path / "LIO")
    assert b.inertial is not None and {"inertial/inertial.onnx", "inertial/meta.json"} <= set(b.manifest["files"])
    assert b.manifest["models"]["inertial"]["source"] == str(Path(io).resolve())
    sid = Dataset.open(made["data"]).session_ids[0]
    s = Dataset.open(made["data"]).session(sid)
    est = b.run_session(s, seed=0)
    assert b.last_odometry.startswith("learned inertial odometry")
    # the reference: the bundle without the model, on a copy whose odometry.csv is the learned track
    copy = shutil.copytree(made["data"], tmp_path / "copy")
    track = InertialModel(io).odometry(s)
    track[["t", "x", "y"]].to_csv(copy / "sessions" / sid / "odometry.csv", index=False, float_format="%.17g")
    plain = Bundle.open(tmp_path / "PLAIN")
    ref = plain.run_session(Dataset.open(copy).session(sid), seed=0)
    assert plain.last_odometry == "the session's odometry.csv"
    a = np.array([[e.t, e.x, e.y] for e in est])
    r = np.array([[e.t, e.x, e.y] for e in ref])
    assert a.shape == r.shape and len(a) > 30
    np.testing.assert_allclose(a, r, atol=1e-6)
    # the CLI on it loads no torch
    out = tmp_path / "est.csv"
    code = f"""
import json, sys
from blenav.cli.localize import main
rc = main([{str(tmp_path / 'LIO')!r}, {str(made['data'] / 'sessions' / sid)!r}, "--out", {str(out)!r}, "--no-progress"])
print(json.dumps({{"rc": rc, "heavy": sorted(m for m in ("torch", "lightning", "hydra") if m in sys.modules)}}))
"""
    res = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300)
    assert res.returncode == 0, res.stderr[-2000:]
    assert json.loads(res.stdout.strip().splitlines()[-1]) == {"rc": 0, "heavy": []}
    assert "odometry: learned inertial odometry" in res.stdout
    np.testing.assert_allclose(pd.read_csv(out)[["t", "x", "y"]].to_numpy(), a, atol=1e-4)  # the CSV: 0.1 mm
    with pytest.raises(FileNotFoundError, match="io_model="):
        export_bundle(compose("export", *common, f"out={tmp_path / 'X'}", f"io_model={tmp_path / 'nope'}"))
    with pytest.raises(ValueError, match="reads no odometry"):
        export_bundle(compose("export", *common, f"out={tmp_path / 'X'}", f"io_model={io}",
                              "runtime.motion={_target_: blenav.filters.motion.RandomWalk}"))
    assert not (tmp_path / "X").exists()
    # the learned track's variance reaches the filter (settings with motion.odo_var_scale): replayed and pushed live
    # (push_odometry's var) alike, and it moves the track
    from blenav.filters.online import replay
    from blenav.runtime.bundle.settings import check_settings

    b.settings = {**b.settings, "motion": {**b.settings["motion"], "odo_var_scale": 4.0}}
    check_settings(b.settings, "settings.json")
    weighed = b.run_session(s, seed=0)
    w = np.array([[e.t, e.x, e.y] for e in weighed])
    assert w.shape == a.shape and np.abs(w - a).max() > 0.01
    loc = b.localizer(s.building, seed=0, keep_fixes=None, t_start=min(float(f["t"].iloc[0]) for f in (s.imu, s.rssi)))
    rows, t_end = [], 0.0
    for ev in replay(s, track):
        if ev[0] == "rssi":
            rows += loc.push_rssi(ev[1], ev[2], ev[3])
        elif ev[0] == "odo":
            rows += loc.push_odometry(ev[1], ev[2], var=ev[3])
        else:
            continue
        t_end = ev[1]
    rows += loc.close(t_end)
    np.testing.assert_allclose(np.array([[e.t, e.x, e.y] for e in rows]), w, atol=1e-9)
    # live, as a phone runs it: IMU, magnetometer and BLE samples pushed, the bundle's network making the odometry
    # (StreamingLio, the AHRS with the walk's hard-iron offset as the batch fits it): the same rows
    from blenav.filters.attitude import AttitudeConfig
    from blenav.filters.measurement import AnchorTable
    from blenav.filters.runner import hard_iron_offset
    from blenav.filters.steps import SessionArrays

    off = hard_iron_offset(SessionArrays.from_session(s, AnchorTable.empty()), AttitudeConfig())
    live = b.localizer(s.building, seed=0, keep_fixes=None, mag_offset=off, attitude="ahrs")
    rows, t_end = [], 0.0
    for ev in replay(s):  # every stream of the walk but its odometry.csv: the phone's samples
        if ev[0] == "rssi":  # a rotation vector the AHRS does not read: it neither moves nor releases anything
            rows += live.push_orientation(ev[1] + 0.003, [0.0, 0.0, 0.0, 1.0])
        if ev[0] != "odo":
            rows += live.push_event(ev)
            t_end = ev[1]
    rows += live.close(t_end)
    np.testing.assert_allclose(np.array([[e.t, e.x, e.y] for e in rows]), w, atol=1e-6)
    # the rotation vector as the attitude (auto: it comes before the first IMU sample), against run_session on a copy
    # of the walk with that orientation.csv (the batch path then reads it)
    gt = s.groundtruth.iloc[::4]
    gt[["t", "qw", "qx", "qy", "qz"]].to_csv(copy / "sessions" / sid / "orientation.csv", index=False,
                                            float_format="%.17g")
    so = Dataset.open(copy).session(sid)
    b.settings = dict(plain.settings)  # as exported: no odo_var_scale
    ref_o = np.array([[e.t, e.x, e.y] for e in b.run_session(so, seed=0)])
    ori = [("ori", float(r.t), np.array([r.qw, r.qx, r.qy, r.qz])) for r in so.orientation.itertuples(index=False)]
    events = sorted(ori + [e for e in replay(so) if e[0] != "odo"], key=lambda e: (e[1], e[0] != "ori"))
    # the simulator's gyroscope is raw (session.yaml gyro_calibrated: false): the app says so, as the batch path reads
    live = b.localizer(s.building, seed=0, keep_fixes=None, gyro_calibrated=so.gyro_calibrated)
    rows = []
    for ev in events:
        rows += live.push_orientation(ev[1], ev[2]) if ev[0] == "ori" else live.push_event(ev)
    rows += live.close(events[-1][1])
    np.testing.assert_allclose(np.array([[e.t, e.x, e.y] for e in rows]), ref_o, atol=1e-6)
    assert np.abs(ref_o[:, 1:] - w[:, 1:]).max() > 0.01  # another attitude, another track
    # a stream without IMU: held at most 10 s, then an error saying what to push
    mute = b.localizer(s.building, seed=0)
    r0 = s.rssi.iloc[0]
    with pytest.raises(ValueError, match="no IMU sample came: push_imu"):
        for k in range(200):
            mute.push_rssi(float(r0.t) + 0.1 * k, str(r0.anchor_id), float(r0.rssi))
    with pytest.raises(ValueError, match="runs none"):
        plain.localizer(s.building, attitude="ahrs")
    with pytest.raises(ValueError, match="runs none"):
        plain.localizer(s.building, gyro_calibrated=True)
    imu0 = s.imu.iloc[0]
    again = b.localizer(s.building, seed=0)
    again.push_imu(float(imu0.t), imu0[["ax", "ay", "az"]].to_numpy(float), imu0[["gx", "gy", "gz"]].to_numpy(float))
    with pytest.raises(ValueError, match="push one or the other"):  # the stream's odometry is the bundle's now
        again.push_odometry(float(imu0.t) + 0.1, [0.0, 0.0])


def test_a_std_head_bundle_feeds_each_live_fix_with_its_own_std(made, tmp_path):
    """Issue 29: the bundle of a LocNet with a std head hands each live fix the graph's own std (std_m), the same
    numbers the graph gives on the session's windows; a plain model's fixes carry none (the filter's sigma_m)."""
    from blenav.features.windows import WindowConfig, session_windows
    from blenav.filters.online import replay
    from blenav.runtime.bundle.windows import WindowFixer

    train(compose("train", "model=locnet", f"data={made['data']}", f"out={tmp_path / 'loc'}", "data.batch_size=32",
                  "model.lr=3e-3", "trainer.enable_progress_bar=false", "trainer.max_epochs=1",
                  "model.locnet.hidden=16", "model.locnet.fc_hidden=8", "+model.locnet.std_head=true"))
    export_bundle(compose("export", "bundle=true", f"ckpt={tmp_path / 'loc' / 'last.ckpt'}", f"out={tmp_path / 'B'}",
                          f"data={made['data']}", "variants=false", "eval_sessions=1"))
    s = Dataset.open(made["data"]).session(sorted(Dataset.open(made["data"]).session_ids)[1])

    def live_fixes(graph):
        fixer, out = WindowFixer(graph), []
        for ev in replay(s):
            if ev[0] == "rssi":
                out += fixer.advance(ev[1])
                fixer.add(ev[1], ev[2], ev[3])
        return out + fixer.flush()

    g = Bundle.open(tmp_path / "B").graph
    got = np.array(live_fixes(g), dtype=float)  # (F, 4): t, x, y, std
    w = g.meta["window"]
    win = session_windows(s, g.beacons, WindowConfig(history=int(w["history"]), step_hz=float(w["step_hz"]),
                                                     offset_db=float(w["offset_db"]), floor_u=float(w["floor_u"])))
    xy, std = g.predict_windows_std(win.S)
    ok = np.isfinite(xy).all(axis=1)
    assert g.has_std and len(got) == ok.sum() > 10
    np.testing.assert_allclose(got[:, 3], std[ok], rtol=1e-5)
    np.testing.assert_allclose(got[:, 1:3], xy[ok], atol=1e-4)
    plain = live_fixes(Bundle.open(made["bundle"]).graph)
    assert plain and all(f[3] is None for f in plain)
