"""End-to-end localization on simulated sessions: streaming = batch, convergence, kidnapping, outages."""

from __future__ import annotations

import shutil

import numpy as np
import pandas as pd
import pytest
from blenav.configs import compose

from blenav.cli.sim import run as sim_run
from blenav.data import Dataset
from blenav.data.writer import write_session
from blenav.eval.harness import build_methods
from blenav.filters.calibration import apply_fit, fit_sessions
from blenav.filters.motion import Pdr
from blenav.filters.measurement import AnchorTable
from blenav.filters.online import OnlineLocalizer, replay
from blenav.filters.runner import magnetometer_offset, run_session
from blenav.filters.steps import SessionArrays
from helpers import streamed


def eval_cfg(*overrides):
    return compose("eval", *["data=unused", *overrides])


def sim(out, *overrides):
    cfg = compose("sim", *[f"out={out}", "progress=false", *overrides])
    return sim_run(cfg)


@pytest.fixture(scope="module")
def office(tmp_path_factory):
    """Two 90 s pedestrian sessions in office_45x55 plus a static calibration survey."""
    out = tmp_path_factory.mktemp("loc") / "office"
    sim(out, "sim=office_45x55", "seed=11", "duration_s=90", "sessions=3", "sim.carriers=[pedestrian,pedestrian,static]")
    return Dataset.open(out)


def methods(experiment, ds, **filter_over):
    cfg = eval_cfg(f"experiment={experiment}", *[f"filter.{k}={v}" for k, v in filter_over.items()])
    ms = {k: v.method for k, v in build_methods(cfg).items()}
    fit = fit_sessions([s for s in ds.sessions(labelled=True) if s.carrier == "static"])
    for m in ms.values():
        apply_fit(m.measurements, fit)
    return ms


def test_streaming_equals_batch(office):
    s = office.session(office.session_ids[0])
    m = methods("frontend_000", office, n_particles=100)["IMU"]
    batch = run_session(m, s, n_runs=3, seed=5)
    m2 = methods("frontend_000", office, n_particles=100)["IMU"]
    arrays = SessionArrays.from_session(s, AnchorTable.from_frame(s.building.anchors))
    online = OnlineLocalizer(m2, s, n_runs=3, seed=5, t_start=0.0, mag_offset=magnetometer_offset(arrays, m2))
    pos = streamed(online, replay(s), batch.t[-1])
    assert pos.shape == batch.position.shape
    np.testing.assert_array_equal(pos, batch.position)


def test_streaming_equals_batch_with_the_odometry_variance(office):
    """Issue 31's odo_var_scale: the streaming path reads the odometry's stated variance (the events' fourth field,
    the column var) as the batch path does, so the two give the same positions; and the variance matters (a track
    without it gives other positions)."""
    import dataclasses

    from blenav.filters.motion import OdometryIncrement

    s = office.session(office.session_ids[0])
    odo = s.odometry
    odo = odo.assign(var=0.02 * (odo["t"] - odo["t"].iloc[0]) + 0.3 * (np.arange(len(odo)) % 7 == 0).cumsum())

    def method():
        m = methods("mapfusion_002", office, n_particles=100)["PF-PS"]
        return dataclasses.replace(m, motion=OdometryIncrement(theta0=0.0, odo_var_scale=3.0))

    batch = run_session(method(), s, n_runs=2, seed=5, odometry=odo)
    online = OnlineLocalizer(method(), s, n_runs=2, seed=5, t_start=0.0)
    pos = streamed(online, replay(s, odo), batch.t[-1])
    np.testing.assert_array_equal(pos, batch.position)
    plain = run_session(method(), s, n_runs=2, seed=5, odometry=odo[["t", "x", "y"]])
    assert np.abs(plain.position - batch.position).max() > 0.01


def _err(res, s):
    gt = s.groundtruth
    ref = np.stack([np.interp(res.t, gt.t, gt.x), np.interp(res.t, gt.t, gt.y)], -1)
    return np.linalg.norm(res.position - ref[None], axis=-1)


@pytest.mark.parametrize("method", ["PF-PS+MAP", "PF-PS"])
def test_global_localization_converges(office, method):
    s = office.session(office.session_ids[0])
    res = run_session(methods("mapfusion_002", office)[method], s, n_runs=10, seed=1)
    e = _err(res, s)
    assert np.isfinite(res.position).all()
    # particles start spread over the whole 45 x 55 m floor (uniform, or eq. 3 of Patel et al.)
    # measured: about 2 m median from 5 s on
    assert np.median(e[:, res.t > 5]) < 3.5


def test_kidnapped_walker_is_recovered(office, tmp_path):
    """Teleport: the first 45 s of session 0 followed by the last 45 s of session 1 (another place)."""
    a, b = office.session(office.session_ids[0]), office.session(office.session_ids[1])
    cut = 45.0
    streams = {}
    for name in ("imu", "mag", "rssi", "groundtruth"):
        fa, fb = getattr(a, name), getattr(b, name)
        first = fa[fa.t < cut]
        second = fb[fb.t >= cut]
        streams[name] = pd.concat([first, second], ignore_index=True)
    root = tmp_path / "kid"
    shutil.copytree(office.root, root, ignore=shutil.ignore_patterns("sessions"))
    write_session(root, "kidnap", dict(a.meta), streams)
    ds = Dataset.open(root)
    s = ds.session("kidnap")
    jump = np.linalg.norm(s.positions_at(np.array([cut - 0.05])) - s.positions_at(np.array([cut + 0.05])))
    assert jump > 5.0
    m = methods("mapfusion_002", office)["PF-PS+MAP"]
    res = run_session(m, s, n_runs=5, seed=3)
    e = _err(res, s)
    assert np.isfinite(res.position).all()
    right_after = (res.t > cut) & (res.t < cut + 1.0)
    assert np.median(e[:, right_after]) > 0.5 * jump  # the cloud is where the walker was
    assert np.median(e[:, res.t > cut + 25]) < 3.5  # ... and finds it again


def test_ble_outage_is_bridged_by_the_imu_model(office, tmp_path):
    """30 s without BLE: step detection + AHRS heading (PDR, with per-particle heading offsets) carries
    the estimate through; a random walk, which has no inertial input, drifts away."""
    a = office.session(office.session_ids[0])
    t0, t1 = 40.0, 70.0
    rssi = a.rssi[(a.rssi.t < t0) | (a.rssi.t >= t1)]
    root = tmp_path / "outage"
    shutil.copytree(office.root, root, ignore=shutil.ignore_patterns("sessions"))
    write_session(root, "outage", dict(a.meta), {"imu": a.imu, "mag": a.mag, "rssi": rssi, "groundtruth": a.groundtruth})
    s = Dataset.open(root).session("outage")
    ms = methods("frontend_000", office)
    pdr = ms["IMU"]
    pdr.motion, pdr.name = Pdr(), "PDR"
    during = None
    errs = {}
    for name, m in (("PDR", pdr), ("RW", ms["RW"])):
        res = run_session(m, s, n_runs=5, seed=2)
        assert np.isfinite(res.position).all()
        during = (res.t >= t0) & (res.t < t1)
        errs[name] = (_err(res, s), res.t)
    e, t = errs["PDR"]
    # measured (seed 2): PDR median 1.7 / 2.8 / 5.3 m in the three 10 s blocks of the outage; RW 2.4 / 15 / 35 m
    assert np.median(e[:, during]) < 5.0
    assert np.median(e[:, during]) < 0.5 * np.median(errs["RW"][0][:, during])
    assert np.median(e[:, t >= t1 + 5]) < 4.0


def test_global_localization_converges_in_the_small_building(tmp_path):
    """From particles spread over the whole `small` floor (map-aware init) to metre-level tracking."""
    out = sim(tmp_path / "small", "sim=small", "seed=2", "duration_s=60", "sessions=2", "sim.carriers=[pedestrian]",
              "sim.receivers=[iphone-8]")
    ds = Dataset.open(out)
    m = build_methods(eval_cfg("experiment=mapfusion_002"))["PF-PL+MAP"].method
    apply_fit(m.measurements, fit_sessions([ds.session(ds.session_ids[0])]))
    s = ds.session(ds.session_ids[1])
    res = run_session(m, s, n_runs=10, seed=1)
    e = _err(res, s)
    assert np.isfinite(res.position).all()
    # measured (seed 1): median error 1.6 m from 10 s on; a 20 m x 15 m floor
    assert np.median(e[:, res.t > 10]) < 3.0


def test_misspelt_filter_keys_fail_early():
    from hydra.errors import ConfigCompositionException

    from blenav.errors import EvalError

    with pytest.raises(ConfigCompositionException):
        eval_cfg("experiment=mapfusion_002", "filter.n_particle=3")
    with pytest.raises(EvalError, match="RW"):
        build_methods(eval_cfg("experiment=frontend_000", "+methods.RW.motion.sigma_q=1"))
    with pytest.raises(EvalError, match="PF-PS"):
        build_methods(eval_cfg("experiment=mapfusion_002", "+methods.pf_ps.map.beta_typo=1"))
