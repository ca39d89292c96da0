"""World simulator: determinism, format validity per preset, sensor consistency, channel statistics."""

from __future__ import annotations

import hashlib
from pathlib import Path

import numpy as np
import pytest
from blenav.configs import compose
from scipy.spatial.transform import Rotation

from blenav.cli.sim import run
from blenav.data import Dataset, validate
from blenav.sim.config import make_sim_config
from blenav.sim.radio import gaussian_field
from blenav.sim.world import simulate


def compose_sim(*overrides: str):
    return compose("sim", *overrides)


def tree_digest(root: Path) -> str:
    h = hashlib.sha256()
    for p in sorted(root.rglob("*")):
        if p.is_file():
            h.update(str(p.relative_to(root)).encode())
            h.update(p.read_bytes())
    return h.hexdigest()


@pytest.fixture(scope="module")
def small_ds(tmp_path_factory):
    out = tmp_path_factory.mktemp("sim") / "small"
    run(compose_sim("sim=small", "seed=3", f"out={out}", "duration_s=40", "sessions=4", "progress=false"))
    return out


def test_same_seed_same_bytes(tmp_path):
    a, b, c = tmp_path / "a", tmp_path / "b", tmp_path / "c"
    for out, seed in ((a, 1), (b, 1), (c, 2)):
        run(compose_sim("sim=small", f"seed={seed}", f"out={out}", "duration_s=8", "sessions=2", "progress=false"))
    assert tree_digest(a) == tree_digest(b)
    assert tree_digest(a) != tree_digest(c)


def test_existing_output_is_not_clobbered(tmp_path):
    out = tmp_path / "x"
    run(compose_sim("sim=small", f"out={out}", "duration_s=3", "sessions=2", "progress=false"))
    with pytest.raises(ValueError, match="overwrite=true"):
        run(compose_sim("sim=small", f"out={out}", "duration_s=3", "sessions=1", "progress=false"))
    run(compose_sim("sim=small", f"out={out}", "duration_s=3", "sessions=1", "progress=false", "overwrite=true"))
    assert len(Dataset.open(out).session_ids) == 1
    (tmp_path / "y").mkdir()
    (tmp_path / "y" / "notes.txt").write_text("mine")
    with pytest.raises(ValueError, match="holds no dataset"):
        run(compose_sim("sim=small", f"out={tmp_path / 'y'}", "duration_s=3", "sessions=1", "progress=false",
                        "overwrite=true"))


def test_more_sessions_keep_earlier_ones(tmp_path):
    for k in (1, 2):
        run(compose_sim("sim=small", "seed=5", f"out={tmp_path / str(k)}", "duration_s=6", f"sessions={k}",
                        "progress=false"))
    s = next((tmp_path / "1" / "sessions").iterdir()).name
    assert tree_digest(tmp_path / "1" / "sessions" / s) == tree_digest(tmp_path / "2" / "sessions" / s)


def test_first_session_writes_the_later_sessions_of_a_longer_run(tmp_path):
    """first_session=1 sessions=1 writes session 1 of a sessions=2 run, byte for byte, in the same building."""
    run(compose_sim("sim=small", "seed=5", f"out={tmp_path / 'all'}", "duration_s=6", "sessions=2", "progress=false"))
    run(compose_sim("sim=small", "seed=5", f"out={tmp_path / 'tail'}", "duration_s=6", "sessions=1",
                    "first_session=1", "progress=false"))
    tail = sorted(p.name for p in (tmp_path / "tail" / "sessions").iterdir())
    assert tail == [sorted(p.name for p in (tmp_path / "all" / "sessions").iterdir())[1]]
    assert tail[0].startswith("s001_")
    a, b = tmp_path / "all" / "sessions" / tail[0], tmp_path / "tail" / "sessions" / tail[0]
    csvs = sorted(p.name for p in a.glob("*.csv"))
    assert csvs and csvs == sorted(p.name for p in b.glob("*.csv"))
    for name in csvs:
        assert (a / name).read_bytes() == (b / name).read_bytes(), name
    assert tree_digest(tmp_path / "all" / "buildings") == tree_digest(tmp_path / "tail" / "buildings")
    assert "first_session=1" in (tmp_path / "tail" / "dataset.yaml").read_text()
    with pytest.raises(ValueError, match="first_session"):
        run(compose_sim("sim=small", f"out={tmp_path / 'neg'}", "duration_s=6", "sessions=1", "first_session=-1",
                        "progress=false"))


@pytest.mark.parametrize("preset", ["small", "office_45x55", "campus_floor", "procedural"])
def test_every_preset_validates(tmp_path, preset):
    out = tmp_path / preset
    run(compose_sim(f"sim={preset}", "seed=0", f"out={out}", "duration_s=6", "sessions=4", "progress=false"))
    errors = [str(i) for i in validate(out) if i.is_error]
    assert errors == []
    ds = Dataset.open(out)
    assert len(ds.session_ids) == 4


def test_preset_sizes_match_the_papers():
    office = make_sim_config(compose_sim("sim=office_45x55").sim)
    assert (office.layout.width_m, office.layout.height_m, office.n_beacons) == (45.0, 55.0, 79)
    campus = make_sim_config(compose_sim("sim=campus_floor").sim)
    assert 1800 <= campus.layout.width_m * campus.layout.height_m <= 2200 and campus.n_beacons == 50
    assert len(set(campus.receivers)) >= 15


def test_misspelt_key_fails_early():
    with pytest.raises(Exception, match="n_beacon"):
        make_sim_config({"n_beacon": 3})
    with pytest.raises(Exception, match="n_beacon"):
        compose_sim("sim=small", "sim.n_beacon=3")
    with pytest.raises(ValueError, match="unknown profile"):
        make_sim_config({"receivers": ["nokia-3310"]})


def test_small_dataset_contents(small_ds):
    ds = Dataset.open(small_ds)
    metas = [ds.session(s).meta for s in ds.session_ids]
    assert [m["carrier"] for m in metas] == ["pedestrian", "pedestrian", "robot", "static"]
    s = ds.session(ds.session_ids[0])
    assert s.gyro_calibrated is False  # the simulated gyroscope has a bias: no held yaw for data.yaw=auto
    imu = s.imu
    assert np.allclose(np.diff(imu["t"]).mean(), 1 / 200, rtol=1e-3)
    rate = len(s.rssi) / 40.0
    assert 10 < rate < 8 * 10 * 0.7 + 1  # never more than 10 Hz x scan probability per beacon
    assert (s.rssi["rssi"] < 0).all()
    gt = s.groundtruth
    assert s.floor.is_free(gt[["x", "y"]].to_numpy()).mean() > 0.97
    q = gt[["qw", "qx", "qy", "qz"]].to_numpy()
    assert np.allclose(np.linalg.norm(q, axis=1), 1, atol=1e-5)


def test_unlabelled_sessions_have_no_groundtruth(tmp_path):
    out = tmp_path / "u"
    run(compose_sim("sim=small", "sim.unlabelled_every=2", f"out={out}", "duration_s=5", "sessions=2",
                    "progress=false"))
    ds = Dataset.open(out)
    s = ds.session(ds.session_ids[1])
    assert s.meta["labelled"] is False and not (s.root / "groundtruth.csv").exists()
    assert len(s.rssi) > 0


def _noise_free():
    """The small preset with a perfect IMU and ground truth at the IMU rate."""
    return make_sim_config(compose_sim(
        "sim=small", "sim.groundtruth_rate_hz=200", "sim.imu.acc_noise=0", "sim.imu.gyro_noise=0",
        "sim.imu.acc_bias_std=0", "sim.imu.gyro_bias_std=0", "sim.imu.acc_bias_rw=0", "sim.imu.gyro_bias_rw=0",
        "sim.imu.hand_tremor=0").sim)


def test_gyroscope_integrates_to_ground_truth_orientation(tmp_path):
    cfg = _noise_free()
    simulate(cfg, 7, tmp_path / "nf", 20.0, 1)
    s = Dataset.open(tmp_path / "nf").session(Dataset.open(tmp_path / "nf").session_ids[0])
    gt, imu = s.groundtruth, s.imu
    q = gt[["qx", "qy", "qz", "qw"]].to_numpy()
    R = Rotation.from_quat(q)
    w = imu[["gx", "gy", "gz"]].to_numpy()
    dt = 1 / 200
    i0, i1 = 400, 1400  # integrate 5 s of body rates
    est = R[i0]
    for k in range(i0, i1):
        est = est * Rotation.from_rotvec(w[k] * dt)
    err = (est.inv() * R[i1]).magnitude()
    assert np.degrees(err) < 1.0


def test_accelerometer_matches_ground_truth_motion(tmp_path):
    cfg = _noise_free()
    simulate(cfg, 8, tmp_path / "nf", 20.0, 1)
    ds = Dataset.open(tmp_path / "nf")
    s = ds.session(ds.session_ids[0])
    gt, imu = s.groundtruth, s.imu
    R = Rotation.from_quat(gt[["qx", "qy", "qz", "qw"]].to_numpy())
    f_w = R.apply(imu[["ax", "ay", "az"]].to_numpy())
    f_w[:, 2] -= 9.80665
    p = gt[["x", "y", "z"]].to_numpy()
    v = np.gradient(p, 1 / 200, axis=0)
    i0, i1 = 600, 1600
    dv = np.trapezoid(f_w[i0:i1 + 1], dx=1 / 200, axis=0)
    assert np.allclose(dv, v[i1] - v[i0], atol=0.05)


def test_static_survey_reads_gravity(small_ds):
    ds = Dataset.open(small_ds)
    s = ds.session(ds.session_ids[3])
    a = s.imu[["ax", "ay", "az"]].to_numpy()
    assert abs(np.linalg.norm(a.mean(axis=0)) - 9.81) < 0.2
    assert (s.imu[["gx", "gy", "gz"]].abs().mean() < 0.05).all()


def test_gaussian_field_correlation_length():
    rng = np.random.default_rng(0)
    f = gaussian_field(rng, (200, 64, 64), corr_px=4.0)
    assert abs(f.std() - 1) < 0.02
    rho = np.mean(f[:, :, :-4] * f[:, :, 4:])
    assert abs(rho - np.exp(-0.5)) < 0.05


def test_ar1_noise_has_the_requested_std_and_correlation_time():
    from blenav.sim.inertial import ar1_noise

    e = ar1_noise(np.random.default_rng(0), 200_000, 0.2, std=0.3, tau_s=3.0)
    assert e.shape == (200_000, 2)
    assert np.allclose(e.std(axis=0), 0.3, rtol=0.03)
    lag = 5  # 1 s at 0.2 s steps: correlation exp(-1 / 3)
    rho = np.mean(e[:-lag] * e[lag:]) / e.var()
    assert abs(rho - np.exp(-1.0 / 3.0)) < 0.02


def test_odometry_velocity_noise_is_off_by_default_and_leaves_the_walk_unchanged(tmp_path):
    base = ("sim=small", "seed=3", "duration_s=60", "sessions=1", "progress=false")
    a, b = tmp_path / "a", tmp_path / "b"
    run(compose_sim(*base, f"out={a}"))
    run(compose_sim(*base, f"out={b}", "sim.odometry.vel_noise_mps=0.3"))
    sa, sb = (Dataset.open(p).session(Dataset.open(p).session_ids[0]) for p in (a, b))
    for stream in ("groundtruth", "rssi", "imu"):  # drawn before the odometry: identical
        assert getattr(sa, stream).equals(getattr(sb, stream)), stream
    # the odometry's speed now errs by the AR(1) term: per-step speed differences of about 0.3 m/s
    va = np.linalg.norm(np.diff(sa.odometry[["x", "y"]].to_numpy(), axis=0), axis=1) / np.diff(sa.odometry.t)
    vb = np.linalg.norm(np.diff(sb.odometry[["x", "y"]].to_numpy(), axis=0), axis=1) / np.diff(sb.odometry.t)
    d = vb - va
    assert 0.1 < d.std() < 0.4
    c = compose_sim("sim=small")
    assert make_sim_config(c.sim).odometry.vel_noise_mps == 0.0
