"""The learned inertial odometry (issue 31): the segment-integral loss against a hand computation, the windows and the
heading frame (a walk turned by any yaw gives the same speeds), training with resume, the ONNX export's parity on real
windows and the runtime's odometry track, and a stranger's checkpoint refused."""

from __future__ import annotations

import shutil

import numpy as np
import pytest
import torch

from blenav.configs import compose
from blenav.features.inertial import (CHANNELS, InertialGrid, displacement_errors, heading_frame, integrate,
                                      rotate_velocity, segment_weights, turn_pairs, windows)
from blenav.filters.inertial_odometry import world_frame_imu
from blenav.filters.quaternions import qmul, qz
from blenav.learn.inertial.module import segment_loss, to_attitude_frame
from blenav.models.inertial import TCN, ResNet1D, YawEnsemble

from helpers import as_waypoint_walks

GRID = InertialGrid(50.0, 2.0, 0.5)


def test_segment_weights_and_loss_by_hand():
    # four windows tiling [0, 2] s; a segment [0.25, 1.25] holds 0.25 s of window 0, 0.5 s of 1, 0.25 s of 2
    seg, win, w = segment_weights(0.0, GRID, 4, np.array([0.25]), np.array([1.25]))
    assert seg.tolist() == [0, 0, 0] and win.tolist() == [0, 1, 2]
    np.testing.assert_allclose(w, [0.25, 0.5, 0.25])
    v = np.array([[1.0, 0.0], [2.0, 1.0], [0.0, 4.0]])
    lv = np.log(np.array([[0.5, 1.0], [2.0, 0.25], [1.0, 1.0]]))
    out = torch.tensor(np.hstack([v, lv]), dtype=torch.float64)
    d = np.array([1.0, 2.0])
    batch = {"segment": torch.zeros(3, dtype=torch.long), "weight": torch.tensor(w), "target": torch.tensor(d[None])}
    got = segment_loss(out, batch, nll_weight=0.5)
    D = 0.25 * v[0] + 0.5 * v[1] + 0.25 * v[2]  # [1.25, 1.5]
    V = 0.0625 * np.exp(lv[0]) + 0.25 * np.exp(lv[1]) + 0.0625 * np.exp(lv[2])
    r = D - d
    mse = (r ** 2).sum() / 1.0 ** 2  # T = 1 s
    nll = 0.5 * (r ** 2 / V + np.log(V)).sum()
    assert float(got["mse"]) == pytest.approx(mse)
    assert float(got["nll"]) == pytest.approx(nll)
    assert float(got["loss"]) == pytest.approx(mse + 0.5 * nll)
    assert float(got["err_m"]) == pytest.approx(np.linalg.norm(r))


def test_windows_integrate_and_displacement():
    X = np.arange(301, dtype=np.float32)[:, None].repeat(len(CHANNELS), axis=1)  # 6 s at 50 Hz
    W = windows(X, GRID)
    assert W.shape == (12, 100, len(CHANNELS))
    for k in (0, 5, 11):
        assert W[k, -1, 0] == 25 * (k + 1)  # window k ends at sample (k + 1) n_stride
    assert (W[0, :75, 0] == 0).all() and W[0, 75, 0] == 1  # before the first sample: the first sample held
    t, xy, var = integrate(10.0, GRID, np.ones((4, 2)), np.log(np.full((4, 2), 4.0)))
    np.testing.assert_allclose(t, [10, 10.5, 11, 11.5, 12])
    np.testing.assert_allclose(xy[-1], [2.0, 2.0])
    np.testing.assert_allclose(var, [0, 1, 2, 3, 4])  # 0.5^2 * 4 per stride
    e = displacement_errors(t, xy, np.array([10.0, 10.25]), np.array([11.0, 12.0]), np.array([[0.5, 0.5], [1.75, 1.0]]))
    np.testing.assert_allclose(e, [np.hypot(0.5, 0.5), 0.75])


def _walk(seed=0, n=600):
    rng = np.random.default_rng(seed)
    t = np.arange(n) / 100.0
    acc = rng.normal(0, 1, (n, 3)) + [0, 0, 9.81]
    gyr = rng.normal(0, 0.3, (n, 3))
    yaw = np.cumsum(rng.normal(0, 0.01, n))
    q = np.stack([np.cos(yaw / 2), 0.1 * np.ones(n), np.zeros(n), np.sin(yaw / 2)], axis=1)
    return t, acc, gyr, q / np.linalg.norm(q, axis=1, keepdims=True)


@pytest.mark.parametrize("theta", [0.7, -2.5, np.pi])
def test_heading_frame_is_yaw_invariant(theta):
    """The same walk with its attitude turned by a yaw: identical network inputs in the heading frame, the same speeds
    out of any network, velocities turned by the yaw."""
    t, acc, gyr, q = _walk()
    q2 = np.stack([qmul(qz(theta), qi) for qi in q])
    _, X1 = world_frame_imu(t, acc, gyr, t, q, 50.0)
    _, X2 = world_frame_imu(t, acc, gyr, t, q2, 50.0)
    W1, p1 = heading_frame(windows(X1, GRID))
    W2, p2 = heading_frame(windows(X2, GRID))
    np.testing.assert_allclose(W1, W2, atol=1e-4)
    # the headings differ by theta modulo 2 pi (compared on the circle: theta = pi may come out as -pi)
    np.testing.assert_allclose(np.angle(np.exp(1j * (p2 - p1 - theta))), 0.0, atol=1e-5)
    net = ResNet1D(GRID.n_window, GRID.n_stride).eval()
    with torch.no_grad():
        o1, o2 = net(torch.from_numpy(W1)).numpy(), net(torch.from_numpy(W2)).numpy()
    v1, _ = rotate_velocity(o1[:, :2], o1[:, 2:], p1)
    v2, _ = rotate_velocity(o2[:, :2], o2[:, 2:], p2)
    np.testing.assert_allclose(np.linalg.norm(v1, axis=1), np.linalg.norm(v2, axis=1), rtol=1e-4, atol=1e-5)
    c, s = np.cos(theta), np.sin(theta)
    np.testing.assert_allclose(v2, np.stack([c * v1[:, 0] - s * v1[:, 1], s * v1[:, 0] + c * v1[:, 1]], 1), atol=1e-4)


def test_torch_and_numpy_frames_agree():
    rng = np.random.default_rng(1)
    out, psi = rng.normal(size=(5, 4)), rng.uniform(-3, 3, 5)
    v, var = to_attitude_frame(torch.tensor(out), torch.tensor(psi))
    vn, lvn = rotate_velocity(out[:, :2], out[:, 2:], psi)
    np.testing.assert_allclose(v.numpy(), vn)
    np.testing.assert_allclose(np.log(var.numpy()), lvn)


@pytest.mark.parametrize("cls", [ResNet1D, TCN])
def test_networks_shapes(cls):
    net = cls(GRID.n_window, GRID.n_stride).eval()
    out = net(torch.zeros(3, GRID.n_window, len(CHANNELS)))
    assert out.shape == (3, 4) and torch.isfinite(out).all()


def _turned(x: torch.Tensor, a: float) -> torch.Tensor:
    n = len(x)
    return torch.from_numpy(turn_pairs(x.numpy(), np.full(n, np.cos(a)), np.full(n, np.sin(a))))


def _turn_v(v: np.ndarray, a: float) -> np.ndarray:
    c, s = np.cos(a), np.sin(a)
    return np.stack([c * v[:, 0] - s * v[:, 1], s * v[:, 0] + c * v[:, 1]], 1)


def test_yaw_ensemble_by_hand_and_equivariant():
    """k = 1 is the network; k = 2 is the mean of the network and its answer to the frame turned by pi, turned back
    (variance: the members' mean plus their spread, by hand); turning the input by a multiple of 2 pi / k turns the
    output exactly (the members are permuted); the per-axis variance is the same for a quarter turn's multiple of
    k = 4 with the axes swapped."""
    from blenav.learn.inertial.export import sample_windows

    torch.manual_seed(0)
    net = TCN(GRID.n_window, GRID.n_stride).eval()
    x = sample_windows(6, GRID.n_window, seed=3)
    with torch.no_grad():
        ref = net(x).numpy()
        np.testing.assert_array_equal(YawEnsemble(net, 1)(x).numpy(), ref)
        o2 = YawEnsemble(net, 2)(x).numpy()
        turned = net(_turned(x, np.pi)).numpy()
    v1, v2 = ref[:, :2], -turned[:, :2]  # turned back by -pi
    mean = (v1 + v2) / 2
    np.testing.assert_allclose(o2[:, :2], mean, atol=1e-5)
    var = (np.exp(ref[:, 2:]) + np.exp(turned[:, 2:])) / 2 + ((v1 - mean) ** 2 + (v2 - mean) ** 2) / 2
    np.testing.assert_allclose(o2[:, 2:], np.log(var), atol=1e-4)
    for k, j in ((4, 1), (8, 3)):
        ens, a = YawEnsemble(net, k), 2 * np.pi * j / k
        with torch.no_grad():
            o, oa = ens(x).numpy(), ens(_turned(x, a)).numpy()
        np.testing.assert_allclose(oa[:, :2], _turn_v(o[:, :2], a), atol=1e-5)
        if k == 4:  # a quarter turn swaps the axes' variances
            np.testing.assert_allclose(oa[:, 2:], o[:, ::-1][:, :2], atol=1e-4)
    with pytest.raises(ValueError, match="1 .. 64"):
        YawEnsemble(net, 0)


@pytest.fixture(scope="module")
def trained(tmp_path_factory, three_walks):
    """Three simulated walks turned into ILC-like waypoint walks; a 40-step run, resumed to 60, exported."""
    root = tmp_path_factory.mktemp("lio")
    data = as_waypoint_walks(shutil.copytree(three_walks, root / "data"))
    from blenav.learn.train import train

    def cfg(steps):
        return compose("train", "experiment=inertial", f"data.path={data}", f"out={root / 'run'}", "plots=false",
                       f"trainer.budget.max_steps={steps}", "trainer.budget.val_every_steps=20",
                       "trainer.enable_progress_bar=false", "data.val_fraction=0.34")

    _, first = train(cfg(40))
    _, second = train(cfg(60))  # resumes from RUN/last.ckpt
    from blenav.learn.export import export

    io = export(compose("export", f"ckpt={root / 'run' / 'last.ckpt'}", f"out={root / 'io'}"))
    return {"data": data, "root": root, "first": first, "second": second, "io": io}


def test_training_resumes_and_reports(trained):
    assert trained["first"]["training"]["steps"] == 40
    assert trained["second"]["training"]["steps"] == 60  # 20 more, not 60 from scratch
    info = trained["second"]["training"]
    assert info["baseline"] == "PDR" and info["data"]["train"]["waypoint_walks"] == 2
    assert info["best_val_error_m"] is not None and np.isfinite(info["best_val_error_m"])
    import json

    assert json.loads((trained["root"] / "run" / "training.json").read_text())["fit_wall_s"] > 0


def test_export_parity_and_runtime_track(trained):
    import json

    from blenav.data import Dataset
    from blenav.filters.inertial_odometry import session_frame_imu
    from blenav.learn.inertial.checkpoint import load_inertial
    from blenav.runtime.inertial import InertialModel

    meta = json.loads((trained["io"] / "meta.json").read_text())
    assert meta["parity"]["velocity"] <= 1e-4 and meta["parity"]["log_var"] <= 1e-4
    assert meta["input_frame"] == "world" and meta["channels"] == list(CHANNELS)
    assert meta["yaw_ensemble"] == 4  # the default of a world-frame network
    model = InertialModel(trained["io"])
    net, _ = load_inertial(trained["root"] / "run" / "last.ckpt")
    net = YawEnsemble(net, 4).eval()
    s = next(iter(Dataset.open(trained["data"]).sessions()))
    _, X, _ = session_frame_imu(s, model.grid, "auto")
    W = windows(X, model.grid)  # real (simulated) walk windows
    v, lv = model.predict(W)
    with torch.no_grad():
        ref = net(torch.from_numpy(W)).numpy()
    assert np.abs(v - ref[:, :2]).max() <= 1e-4 * max(1.0, np.abs(ref).max())
    assert np.abs(lv - ref[:, 2:]).max() <= 1e-4 * max(1.0, np.abs(ref).max())
    odo = model.odometry(s)
    assert list(odo.columns) == ["t", "x", "y", "var"] and np.isfinite(odo.to_numpy()).all()
    assert (np.diff(odo["var"]) > 0).all()


def test_export_yaw_ensemble_setting(trained, tmp_path):
    """export.py yaw_ensemble=1: the plain network (its graph answers as the checkpoint's net); a count out of 1 .. 64
    or not whole is refused before anything is written; meta.json telling another count than the graph's is refused."""
    import json

    from blenav.learn.export import export
    from blenav.learn.inertial.checkpoint import load_inertial
    from blenav.learn.inertial.export import sample_windows
    from blenav.runtime.inertial import InertialModel

    ckpt = trained["root"] / "run" / "last.ckpt"
    io = export(compose("export", f"ckpt={ckpt}", f"out={tmp_path / 'io1'}", "yaw_ensemble=1"))
    assert json.loads((io / "meta.json").read_text())["yaw_ensemble"] == 1
    net, _ = load_inertial(ckpt)
    x = sample_windows(5, net.n_window, seed=2)
    v, _ = InertialModel(io).predict(x.numpy())
    with torch.no_grad():
        np.testing.assert_allclose(v, net(x).numpy()[:, :2], atol=1e-5)
    for bad in (0, 65, 2.5):
        with pytest.raises(ValueError, match="yaw_ensemble"):
            export(compose("export", f"ckpt={ckpt}", f"out={tmp_path / f'bad{bad}'}", f"yaw_ensemble={bad}"))
        assert not (tmp_path / f"bad{bad}").exists()
    edited = shutil.copytree(io, tmp_path / "io_edited")
    (edited / "meta.json").write_text(json.dumps({**json.loads((io / "meta.json").read_text()), "yaw_ensemble": 8}))
    with pytest.raises(ValueError, match="yaw_ensemble"):
        InertialModel(edited)


def test_changed_export_refused(trained, tmp_path):
    from blenav.runtime.inertial import InertialModel

    import json

    bad = shutil.copytree(trained["io"], tmp_path / "io")
    meta = json.loads((bad / "meta.json").read_text())
    meta["grid"]["stride_s"] = 1.0  # a contract the graph was not trained for
    (bad / "meta.json").write_text(json.dumps(meta))
    with pytest.raises(ValueError, match="changed after export"):
        InertialModel(bad)
    bad2 = shutil.copytree(trained["io"], tmp_path / "io2")
    (bad2 / "inertial.onnx").write_bytes((bad2 / "inertial.onnx").read_bytes() + b"\0")
    with pytest.raises(ValueError, match="inertial.onnx"):
        InertialModel(bad2)


def test_an_export_naming_a_training_only_attitude_is_refused(trained, tmp_path):
    """meta.json chooses the attitude source the odometry reads: one a phone does not have at run time
    (groundtruth, the simulated walks' training source) is refused when the model opens, naming the file."""
    from blenav.runtime.inertial import InertialModel

    import json

    bad = shutil.copytree(trained["io"], tmp_path / "io")
    meta = json.loads((bad / "meta.json").read_text())
    meta["attitude"] = {"attitude": "groundtruth"}
    (bad / "meta.json").write_text(json.dumps(meta))
    with pytest.raises(ValueError, match="meta.json: attitude 'groundtruth'"):
        InertialModel(bad)


def test_foreign_target_in_checkpoint_refused(trained, tmp_path):
    from blenav.learn.inertial.checkpoint import load_inertial
    from blenav.trust import UntrustedTargetError

    ck = torch.load(trained["root"] / "run" / "last.ckpt", weights_only=True)
    ck["blenav"]["model"]["net"]["_target_"] = "os.system"
    torch.save(ck, tmp_path / "bad.ckpt")
    with pytest.raises(UntrustedTargetError):
        load_inertial(tmp_path / "bad.ckpt")


def test_eval_rows_with_io_model(trained, tmp_path):
    """blenav-eval experiment=realwalks_inertial ... io_model=IO_DIR: rows LIO and LIO+map with segment_error_m; without
    io_model they are skipped with the reason."""
    import json

    from blenav.eval.harness import evaluate as eval_run

    out = tmp_path / "out"
    eval_run(compose("eval", "experiment=realwalks_inertial", f"data={trained['data']}", "runs=1", f"out={out}",
                     f"io_model={trained['io']}", "split.train_fraction=0.67", "plots=false", "progress=false"))
    ms = json.loads((out / "results.json").read_text())["methods"]
    for row in ("LIO", "LIO+map", "PDR (rotation vector)"):
        assert ms[row]["segment_error_m"]["segments"] > 0, row
        assert np.isfinite(ms[row]["error_m"]["mean"])
    out2 = tmp_path / "out2"
    eval_run(compose("eval", "experiment=realwalks_inertial", f"data={trained['data']}", "runs=1", f"out={out2}",
                     "split.train_fraction=0.67", "plots=false", "progress=false"))
    ms2 = json.loads((out2 / "results.json").read_text())["methods"]
    assert "io_model" in next(iter(ms2["LIO"]["skipped"].values()))


def test_heading_frame_run_exports_and_runs(trained, tmp_path):
    """data.frame=heading: the windows turned into their heading frames for training, the export says so, and the
    runtime turns them the same way (the track equals the network's own velocities turned back and integrated)."""
    import json

    from blenav.data import Dataset
    from blenav.filters.inertial_odometry import session_frame_imu
    from blenav.learn.export import export
    from blenav.learn.inertial.checkpoint import load_inertial
    from blenav.learn.train import train
    from blenav.runtime.inertial import InertialModel

    run = tmp_path / "run"
    train(compose("train", "experiment=inertial", f"data.path={trained['data']}", f"out={run}", "plots=false",
                  "data.frame=heading", "trainer.budget.max_steps=10", "trainer.enable_progress_bar=false",
                  "model=inertial_resnet"))
    io = export(compose("export", f"ckpt={run / 'last.ckpt'}", f"out={tmp_path / 'io'}"))
    meta = json.loads((io / "meta.json").read_text())
    assert meta["input_frame"] == "heading" and meta["attitude"]["yaw"] == "auto"  # data.yaw's default
    assert meta["yaw_ensemble"] == 1  # exactly equivariant already: nothing to average
    edited = shutil.copytree(io, tmp_path / "io_edited")  # meta.json told another yaw after export: refused
    (edited / "meta.json").write_text(json.dumps({**meta, "attitude": {**meta["attitude"], "yaw": "attitude"}}))
    with pytest.raises(ValueError, match="attitude"):
        InertialModel(edited)
    model = InertialModel(io)
    s = next(iter(Dataset.open(trained["data"]).sessions()))
    odo = model.odometry(s)
    net, _ = load_inertial(run / "last.ckpt")
    _, X, _ = session_frame_imu(s, model.grid, "auto", yaw=model.yaw)  # the runtime holds the yaw as training did
    W, psi = heading_frame(windows(X, model.grid))
    with torch.no_grad():
        out = net(torch.from_numpy(W)).numpy()
    v, lv = rotate_velocity(out[:, :2], out[:, 2:], psi)
    _, xy, _ = integrate(0.0, model.grid, v, lv)
    np.testing.assert_allclose(odo[["x", "y"]].to_numpy(), xy, atol=1e-3)


def test_resume_with_another_contract_refused(trained, tmp_path):
    """A run folder trained with one grid cannot be resumed with another: the TCN's weights would load and the new meta
    would describe inputs they never saw."""
    from blenav.learn.train import train

    run = shutil.copytree(trained["root"] / "run", tmp_path / "run")
    with pytest.raises(ValueError, match="grid"):
        train(compose("train", "experiment=inertial", f"data.path={trained['data']}", f"out={run}", "plots=false",
                      "data.stride_s=1.0", "trainer.budget.max_steps=70", "trainer.enable_progress_bar=false"))
    with pytest.raises(ValueError, match="data.yaw"):
        train(compose("train", "experiment=inertial", f"data.path={trained['data']}", f"out={run}", "plots=false",
                      "data.yaw=attitude", "trainer.budget.max_steps=70", "trainer.enable_progress_bar=false"))


def test_a_checkpoint_from_before_data_yaw_resumes_with_the_attitudes_own_yaw(tmp_path, monkeypatch):
    """A checkpoint whose meta has no attitude.yaw trained on the attitude's own yaw: data.yaw=attitude resumes it,
    another yaw is refused naming data.yaw."""
    from blenav.learn.inertial import train as T

    (tmp_path / T.LAST).write_bytes(b"")
    old = {"kind": "inertial", "grid": {"g": 1}, "channels": ["a"], "input_frame": "world", "model": {"net": "tcn"},
           "attitude": {"attitude": "auto", "dense_attitude": "groundtruth"}}
    monkeypatch.setattr(T, "read_checkpoint", lambda path, what: {"blenav": old})
    meta = {**old, "attitude": {**old["attitude"], "yaw": "attitude"}}
    T.check_resume(tmp_path, meta)
    with pytest.raises(ValueError, match=r"data.yaw \('attitude', now 'gyro'\)"):
        T.check_resume(tmp_path, {**old, "attitude": {**old["attitude"], "yaw": "gyro"}})


def test_memory_of_a_strangers_grid_or_clock_is_bounded():
    from blenav.limits import MemoryLimitError

    t = np.array([0.0, 1e7])  # a 10^7 s gap (t in ms read as s)
    q = np.array([[1.0, 0, 0, 0]] * 2)
    with pytest.raises(MemoryLimitError, match="IMU resampled"):
        world_frame_imu(t, np.zeros((2, 3)), np.zeros((2, 3)), t, q, 50.0)
    fine = InertialGrid(1000.0, 10.0, 0.001)  # within every range, yet 10,000 samples per window, one per sample
    with pytest.raises(MemoryLimitError, match="IMU windows"):
        windows(np.zeros((600_000, len(CHANNELS)), np.float32), fine)  # 10 min at 1 kHz


def test_fused_rows_say_when_a_given_io_model_cannot_be_used(tmp_path):
    """odometry.source auto: no io_model -> PDR; an io_model that cannot be loaded -> the reason, not PDR in silence."""
    from blenav.localizers.fusedwalk import FusedWalk

    fw = FusedWalk("fused-offline")
    assert fw.attach_io_model(None, lambda p, loader: loader(p)) is None
    why = fw.attach_io_model(str(tmp_path / "nothing"), lambda p, loader: loader(p))
    assert why and "io_model=" in why
